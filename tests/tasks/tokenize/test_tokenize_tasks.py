"""Tokenizer stage functions: decoding shard clips, training, token shards and checkpoints."""

import numpy as np
import pytest
import torch

from models.tokenizer import VideoTokenizer, preset
from tasks.tokenize import data, tokens
from tasks.tokenize.train import (TrainConfig, change_energy, motion_weights, psnr, reconstruction_loss, sample_batch,
                                  to_tensor, to_uint8, train_tokenizer)
from tasks.video import read_frames
from tests.support import scene_frames, write_video


@pytest.fixture(scope="module")
def clips():
    """Three 25-frame clips of procedural footage at 32 x 32 (content seeds 0, 2, 3)."""
    return [np.stack(scene_frames(seed, 32, 32, 25)) for seed in (0, 2, 3)]


def test_square(tmp_path):
    path = write_video(tmp_path / "v.mp4", scene_frames(0, 64, 48, 10))
    sq = data.square(read_frames(path), 32)
    assert sq.shape == (10, 32, 32, 3) and sq.dtype == np.uint8
    assert data.square(sq, 32) is not sq and np.array_equal(data.square(sq, 32), sq)


def test_usable_frames():
    assert [data.usable_frames(n, 4) for n in (0, 1, 4, 5, 8, 9, 120)] == [0, 1, 1, 5, 5, 9, 117]
    assert data.usable_frames(120, 4, limit=33) == 33


def test_tensor_conversions_and_psnr(clips):
    x = to_tensor(clips[0])
    assert x.shape == (3, 25, 32, 32) and x.min() >= -1 and x.max() <= 1
    assert np.array_equal(to_uint8(x), clips[0])
    assert 100 < psnr(x[None], x[None]).item() < float("inf")  # identical: capped, not infinite
    assert psnr(x[None], torch.zeros_like(x)[None]).item() < 15


def test_sample_batch_is_seeded(clips):
    a = sample_batch(clips, 9, 3, torch.Generator().manual_seed(1), crop=16)
    b = sample_batch(clips, 9, 3, torch.Generator().manual_seed(1), crop=16)
    assert a.shape == (3, 3, 9, 16, 16) and torch.equal(a, b)
    with pytest.raises(ValueError, match="no clip has 99 frames"):
        sample_batch(clips, 99, 1, torch.Generator())


def _train(clips, steps=4, seed=0, init_seed=0):
    torch.manual_seed(init_seed)
    model = VideoTokenizer(preset("tiny-dv4x8x8"))
    config = TrainConfig(steps=steps, batch_size=2, clip_frames=9, size=32, seed=seed, threads=1, log_every=2,
                         warmup_steps=1)
    return model, train_tokenizer(model, clips, config)


def _moving_square(frames: int = 9, side: int = 32) -> np.ndarray:
    """Grey frames with a white 4 x 4 square moving one pixel right per frame in the top-left corner."""
    clip = np.full((frames, side, side, 3), 90, np.uint8)
    for t in range(frames):
        clip[t, 2:6, 2 + t:6 + t] = 255
    return clip


def test_motion_weights_mark_only_what_moves():
    x = to_tensor(_moving_square())[None]
    w = motion_weights(x, 4.0)
    assert w.shape == (1, 1, 9, 32, 32) and float(w.min()) == 1.0 and float(w.max()) == 5.0
    moving = w[0, 0] > 1
    # the square's leading and trailing columns change in every frame, one pixel of spread around them
    assert moving[:, 1:7].any() and not moving[:, 8:].any() and not moving[:, :, 16:].any()
    still = to_tensor(np.repeat(_moving_square()[:1], 9, axis=0))[None]
    assert torch.equal(motion_weights(still, 4.0), torch.ones(1, 1, 9, 32, 32))


def test_reconstruction_loss_weights_moving_pixels():
    x = to_tensor(_moving_square())[None]
    off_still, off_moving = x.clone(), x.clone()
    off_still[..., 20:24, 20:24] += 0.5  # an error where nothing moves
    off_moving[..., 2:6, 2:6] += 0.5  # the same error on the square's path
    assert reconstruction_loss(x, off_still) == pytest.approx(reconstruction_loss(x, off_moving).item())
    assert reconstruction_loss(x, off_moving, 4.0) > 2 * reconstruction_loss(x, off_still, 4.0)
    assert torch.equal(reconstruction_loss(x, off_still, 0.0), (off_still - x).abs().mean())


def test_focus_crops_prefer_what_moves():
    clip = _moving_square(9, 32)
    def share_on_square(focus):
        gen = torch.Generator().manual_seed(0)
        batch = sample_batch([clip], 9, 64, gen, crop=16, focus=focus)
        return sum(change_energy(to_uint8(b)) > 0 for b in batch) / len(batch)
    assert change_energy(clip[:, 16:, 16:]) == 0 and change_energy(clip) > 0
    assert share_on_square(8) > 0.5 > share_on_square(1)


def test_training_lowers_the_loss_and_is_deterministic(clips):
    model, history = _train(clips)
    assert [h["step"] for h in history] == [2, 4]
    assert history[-1]["loss"] < history[0]["loss"]
    again, _ = _train(clips)
    assert all(torch.equal(p, q) for p, q in zip(model.state_dict().values(), again.state_dict().values()))
    other, _ = _train(clips, seed=1)  # the same initial weights, another seed: other batches, other weights
    assert not all(torch.equal(p, q) for p, q in zip(model.state_dict().values(), other.state_dict().values()))


def test_time_budget_stops_training(clips):
    torch.manual_seed(0)
    model = VideoTokenizer(preset("tiny-cv4x8x8"))
    history = train_tokenizer(model, clips, TrainConfig(steps=10_000, seconds=0.5, batch_size=1, size=32, threads=1))
    assert history[-1]["step"] < 10_000 and history[-1]["seconds"] >= 0.5


@pytest.mark.parametrize("name", ["tiny-dv4x8x8", "tiny-cv4x8x8"])
def test_checkpoint_and_token_shard_round_trip(tmp_path, clips, name):
    torch.manual_seed(0)
    model = VideoTokenizer(preset(name)).eval()
    weights, config = tokens.save_checkpoint(model, tmp_path / "ckpt", {"note": 1})
    loaded = tokens.load_checkpoint(tmp_path / "ckpt")
    assert loaded.config == model.config
    clip = data.Clip("c0", "shards/x.parquet", clips[0])
    row = tokens.encode_clip(loaded, clip)
    assert row["frames"] == 25 and row["grid"] == [7, 4, 4]
    if name.startswith("tiny-d"):
        assert len(row["codes"]) == 7 * 16 and 0 <= min(row["codes"]) and max(row["codes"]) < row["codebook_size"]
    else:
        assert len(row["latents"]) == 16 * 7 * 16 and row["codes"] is None
    path = tmp_path / "tokens.parquet"
    digest, size = tokens.write_token_shard([row], path)
    assert tokens.write_token_shard([row], tmp_path / "again.parquet") == (digest, size)  # same rows, same bytes
    back = tokens.read_token_shard(path).to_pylist()[0]
    with torch.no_grad():
        direct = model.decode(model.encode(to_tensor(clips[0])[None]))
    recon = tokens.decode_row(loaded, back)
    assert recon.shape == (1, 3, 25, 32, 32)
    tol = 1e-5 if name.startswith("tiny-d") else 0.2  # continuous latents went through 8 bits
    assert (recon - direct).abs().max() < tol
    assert tokens.encode_clip(loaded, data.Clip("short", "s", clips[0][:0])) is None
