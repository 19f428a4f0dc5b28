"""Training the transfer model: the loss falls on a tiny pair set, runs are seeded, a
reference clip teaches a look the prompt cannot name, and a checkpoint round-trips. Pairs are synthetic (no simulator): the target is the blur control
recoloured per prompt, so the mapping is learnable in a few steps."""

import dataclasses

import numpy as np
import pytest
import torch

from tasks.checkpoint_files import CheckpointError
from models.transfer import ALL_CONTROLS, PROMPTS, REFERENCE_FEATURES, TransferNet, preset, reference_features
from tasks.transfer.pairs import LOOKS, SEG_CLASSES, PairClip
from tasks.transfer.train import (PairSet, TrainConfig, evaluate, frames_tensor, load_transfer, look_row, new_model,
                                  pair_tensors, save_transfer, temporal_l1, train_transfer)

TINT = {"nominal": (1.0, 1.0, 1.0), "dim": (0.3, 0.3, 0.3), "colour shift": (1.0, 0.5, 0.2)}


def _pairs(side=16, frames=6):
    rng = np.random.default_rng(0)
    out = []
    for seed in range(2):
        blur = rng.integers(0, 256, (frames, side, side, 3), dtype=np.uint8)
        for prompt, tint in TINT.items():
            target = (blur * np.array(tint)).astype(np.uint8)
            out.append(PairClip(prompt=prompt, seed=seed, camera="cam", edges=np.zeros((frames, side, side), np.uint8),
                                blur=blur, depth_mm=np.full((frames, side, side), 1000, np.uint16),
                                seg=np.zeros((frames, side, side), np.uint8), frames=target,
                                source_pose=np.zeros((1, 1, 7)), target_pose=np.zeros((1, 1, 7))))
    return out


def test_the_model_s_vocabulary_is_the_looks_the_simulator_renders():
    assert tuple(LOOKS) == PROMPTS
    assert all(preset(name).seg_classes == SEG_CLASSES for name in ("tiny", "small"))


CONFIG = TrainConfig(preset="tiny", steps=60, batch_size=4, clip_frames=3, lr=5e-3, warmup_steps=5, threads=1,
                     log_every=20)


@pytest.fixture(scope="module")
def trained():
    model = new_model(CONFIG)
    return model, train_transfer(model, _pairs(), CONFIG)


def test_the_loss_falls(trained):
    _, history = trained
    assert [r["step"] for r in history] == [20, 40, 60]
    assert history[-1]["loss"] < 0.6 * history[0]["loss"]
    assert set(history[0]) == {"step", "seconds", "loss", "psnr", "lr"}


def test_same_seed_same_history():
    config = CONFIG.model_copy(update={"steps": 6, "log_every": 3})
    runs = [train_transfer(new_model(config), _pairs(), config) for _ in range(2)]
    assert [r["loss"] for r in runs[0]] == [r["loss"] for r in runs[1]]
    # Another seed: other initial weights, and from the same ones other minibatches.
    other = config.model_copy(update={"seed": config.seed + 1})
    weights = zip(new_model(config).state_dict().values(), new_model(other).state_dict().values())
    assert not all(torch.equal(a, b) for a, b in weights)
    resampled = train_transfer(new_model(config), _pairs(), other)
    assert [r["loss"] for r in resampled] != [r["loss"] for r in runs[0]]


def test_the_temporal_loss_reads_frame_to_frame_change_only():
    g = torch.Generator().manual_seed(0)
    target = torch.rand(2, 3, 4, 8, 8, generator=g)
    assert temporal_l1(target + 0.3, target) < 1e-6  # off in colour, changing as the target does
    flicker = target.clone()
    flicker[:, :, 2] += 0.2  # one frame brighter than its neighbours
    assert temporal_l1(flicker, target) == pytest.approx(0.4 / 3, abs=1e-6)  # 0.2 in and out of it, of 3 changes
    config = CONFIG.model_copy(update={"steps": 6, "log_every": 3})
    plain = train_transfer(new_model(config), _pairs(), config)
    weighted = train_transfer(new_model(config), _pairs(), config.model_copy(update={"temporal": 1.0}))
    assert [r["loss"] for r in weighted] != [r["loss"] for r in plain]
    assert TrainConfig().temporal == 0.0


def test_batches_drop_controls_and_keep_windows_aligned():
    pairs = _pairs()
    data = PairSet(pairs, new_model(CONFIG).config)
    controls, target, prompts, weights, references = data.sample(3, 64, torch.Generator().manual_seed(0), dropout=0.5)
    assert references is None  # the model has no reference conditioning
    assert controls.shape[:3] == (64, data.items[0][0].shape[0], 3) and target.shape == (64, 3, 3, 16, 16)
    assert 0.3 < weights.mean() < 0.7 and set(weights.unique().tolist()) == {0.0, 1.0}
    with pytest.raises(ValueError, match="no pair has 7 frames"):
        data.sample(7, 1, torch.Generator())


def test_checkpoint_round_trip(trained, tmp_path):
    model, history = trained
    save_transfer(model, tmp_path, CONFIG, history)
    loaded = load_transfer(tmp_path)
    assert loaded.config == model.config
    scores = evaluate(model, _pairs(), frames=3)
    assert evaluate(loaded, _pairs(), frames=3) == scores and set(scores) == set(TINT)
    (tmp_path / "model.safetensors").write_bytes(b"not weights")
    with pytest.raises(CheckpointError, match="unreadable weights"):
        load_transfer(tmp_path)


def _shifted_pairs(seeds=4, side=16, frames=6):
    """'colour shift' pairs whose tint is a different random draw per seed, as the simulator's
    colour jitter is: the prompt alone cannot say which tint a clip should get."""
    rng = np.random.default_rng(1)
    out = []
    for seed in range(seeds):
        blur = rng.integers(0, 256, (frames, side, side, 3), dtype=np.uint8)
        target = (blur * rng.uniform(0.1, 1.0, 3)).astype(np.uint8)
        out.append(PairClip(prompt="colour shift", seed=seed, camera="cam", edges=np.zeros((frames, side, side), np.uint8),
                            blur=blur, depth_mm=np.full((frames, side, side), 1000, np.uint16),
                            seg=np.zeros((frames, side, side), np.uint8), frames=target,
                            source_pose=np.zeros((1, 1, 7)), target_pose=np.zeros((1, 1, 7))))
    return out


def test_a_reference_clip_teaches_a_look_the_prompt_cannot_name():
    config = CONFIG.model_copy(update={"steps": 120, "reference_dropout": 0.3})
    torch.manual_seed(config.seed)
    model = TransferNet(preset("tiny").model_copy(update={"reference": True}))
    pairs = _shifted_pairs()
    data = PairSet(pairs, model.config)
    *_, references = data.sample(3, 200, torch.Generator().manual_seed(0), reference_dropout=0.3)
    dropped = references.isnan().any(1)
    assert 0.15 < dropped.float().mean() < 0.45
    looks = torch.stack([reference_features(t[None])[0] for _, t, _ in data.items])
    assert all(any(torch.equal(r, look) for look in looks) for r in references[~dropped])
    train_transfer(model, pairs, config)
    with_reference = evaluate(model, pairs, frames=3, reference=lambda p: p.frames)["colour shift"]
    prompt_only = evaluate(model, pairs, frames=3)["colour shift"]
    assert with_reference > prompt_only + 1.0, (with_reference, prompt_only)


def test_the_frame_control_is_the_source_look_s_frames():
    config = preset("small-frame")
    pair = _pairs()[1]  # dim: its target differs from the source
    source = np.full_like(pair.frames, 200)
    controls, target = pair_tensors(dataclasses.replace(pair, source_frames=source), config)
    frame = controls[-3:]  # "frame" comes last in ALL_CONTROLS
    assert config.controls[-1] == "frame" and torch.allclose(frame, torch.full_like(frame, 200 / 127.5 - 1))
    assert torch.equal(target, frames_tensor(pair.frames))
    with pytest.raises(ValueError, match="takes the source's frames"):
        pair_tensors(pair, config)  # made without source frames


def _swapped_pairs(side=16, frames=6):
    """Two seeds whose colour shift paints the left half red and the right blue, or the other
    way round: the same clip-wide colour statistics, so only the colour per class tells them apart."""
    seg = np.zeros((frames, side, side), np.uint8)
    seg[..., side // 2:] = 2
    source = np.full((frames, side, side, 3), 128, np.uint8)
    red, blue = np.array([220, 30, 30], np.uint8), np.array([30, 30, 220], np.uint8)
    out = []
    for seed, (left, right) in enumerate(((red, blue), (blue, red))):
        target = np.where((seg == 0)[..., None], left, right).astype(np.uint8)
        out.append(PairClip(prompt="colour shift", seed=seed, camera="cam", edges=np.zeros((frames, side, side), np.uint8),
                            blur=source, depth_mm=np.full((frames, side, side), 1000, np.uint16), seg=seg, frames=target,
                            source_pose=np.zeros((1, 1, 7)), target_pose=np.zeros((1, 1, 7)), source_frames=source))
    return out


def test_a_palette_reference_teaches_which_object_takes_which_colour():
    pairs = _swapped_pairs()
    config = preset("tiny").model_copy(update={"controls": ALL_CONTROLS, "reference": True, "head": "affine",
                                               "palette": True})
    rows = [look_row(config, p.frames, p.seg) for p in pairs]
    assert torch.equal(rows[0][:, :REFERENCE_FEATURES], rows[1][:, :REFERENCE_FEATURES])  # the same global look
    assert not torch.equal(rows[0], rows[1]) and rows[0].shape == (1, config.reference_size)
    unknown = look_row(config, pairs[0].frames)
    assert torch.all(unknown[:, REFERENCE_FEATURES:] == 0)
    with pytest.raises(ValueError, match="segmentation of shape"):
        look_row(config, pairs[0].frames, pairs[0].seg[:2])
    *_, references = PairSet(pairs, config).sample(3, 400, torch.Generator().manual_seed(0), reference_dropout=0.2,
                                                   palette_dropout=0.3)
    given = ~references.isnan().any(1)
    withheld = given & (references[:, REFERENCE_FEATURES:] == 0).all(1)
    assert 0.2 < withheld.float().sum() / given.float().sum() < 0.4

    torch.manual_seed(0)
    model = TransferNet(config)
    train_transfer(model, pairs, CONFIG.model_copy(update={"steps": 150, "reference_dropout": 0.2}))
    with_palette = evaluate(model, pairs, frames=3, reference=lambda p: p)["colour shift"]
    global_only = evaluate(model, pairs, frames=3, reference=lambda p: p.frames)["colour shift"]
    assert with_palette > global_only + 3.0, (with_palette, global_only)


def test_a_per_object_model_reads_the_object_classes_and_refuses_a_clip_without_them():
    config = preset("small-palette")
    pair = _swapped_pairs()[0]
    with pytest.raises(ValueError, match="per object"):
        pair_tensors(pair, config)
    objects = (pair.seg > 0).astype(np.uint8) * 4  # floor on the right
    controls, _ = pair_tensors(dataclasses.replace(pair, objects=objects), config)
    start = sum(config.channels_of(c) for c in config.controls[:config.controls.index("segmentation")])
    seg = controls[start:start + config.seg_classes]
    assert torch.equal(seg.argmax(0), torch.from_numpy(objects).long())
