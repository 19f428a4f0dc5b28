"""Running a transfer model on an episode: the controls are made as training pairs make them,
the clip keeps the source's frame count at the model's size, a weight of 0 removes a control,
and bad looks, weights, checkpoints, cameras and controls are refused in one line. The episode
is synthetic (a coded video, npz controls written by tasks.controls.files), no simulator."""

import dataclasses
import json

import numpy as np
import pytest
import torch

from models.transfer import ALL_CONTROLS, REFERENCE_FEATURES, TransferNet, preset
from tasks.checkpoint_files import CheckpointError
from tasks.controls.check import ControlError
from tasks.controls.files import write_rendered
from tasks.controls.render import Rendered
from tasks.controls.video import frame_controls
from tasks.guard.config import GuardConfig
from tasks.transfer import apply
from tasks.transfer.pairs import resize_frames, seg_classes
from tasks.transfer.train import TrainConfig, new_model, save_transfer
from tasks.video.read import display_frames

from tests.support import scene_frames, write_video

FRAMES, SIDE = 5, 16


@pytest.fixture(scope="module")
def episode(tmp_path_factory):
    """An episode folder with a 64 x 48 side video and its depth and segmentation."""
    folder = tmp_path_factory.mktemp("episode")
    video = write_video(folder / "side.mp4", scene_frames(1, 64, 48, FRAMES), fps=10)
    (folder / "meta.json").write_text(json.dumps({"manifest_hash": "ab" * 32, "index": 0, "seed": 3,
                                                  "cameras": ["side"]}))
    (folder / "steps.parquet").write_bytes(b"steps")
    n = len(list(display_frames(video)))
    rng = np.random.default_rng(0)
    rendered = Rendered(depth_mm={"side": rng.integers(500, 3000, (n, 48, 64), dtype=np.uint16)},
                        ids={"side": rng.integers(0, 3, (n, 48, 64), dtype=np.uint8)},
                        legend=("background", "package", "table"))
    write_rendered(rendered, folder, {"side": 10.0})
    return folder, rendered


@pytest.fixture(scope="module")
def model(tmp_path_factory):
    torch.set_num_threads(1)
    folder = tmp_path_factory.mktemp("model")
    net = new_model(TrainConfig(preset="tiny"))
    save_transfer(net, folder, extra={"size": SIDE, "camera": "side"})
    return folder, net


def test_controls_are_made_as_training_pairs_make_them(episode):
    folder, rendered = episode
    source = apply.episode_source(folder, None, apply.parse_weights(None))
    assert source.camera == "side" and sorted(source.controls) == ["depth", "segmentation"]
    clip = apply.source_clip(source, SIDE)
    frames = resize_frames(np.stack(list(display_frames(folder / "side.mp4"))), SIDE)
    made = frame_controls(frames)
    assert np.array_equal(clip.edges, made["edges"]) and np.array_equal(clip.blur, made["blur"])
    assert np.array_equal(clip.depth_mm, resize_frames(rendered.depth_mm["side"], SIDE, nearest=True))
    assert np.array_equal(clip.seg, resize_frames(seg_classes(rendered.ids["side"], rendered.legend), SIDE,
                                                  nearest=True))
    assert clip.frames.shape == (len(frames), SIDE, SIDE, 3)


def test_the_clip_has_the_source_frames_at_the_model_size_and_weight_0_removes_a_control(episode, model):
    folder, _ = episode
    _, net = model
    weights = apply.parse_weights(None)
    clip = apply.source_clip(apply.episode_source(folder, None, weights), SIDE)
    out, faces = apply.guarded_clip(net, clip, "dim", weights, GuardConfig(detect_every=5))
    assert out.shape == (clip.edges.shape[0], SIDE, SIDE, 3) and out.dtype == np.uint8 and faces == []
    assert not np.array_equal(out, apply.generate(net, clip, "very dim", weights))  # the prompt matters
    off = apply.parse_weights("depth=0")
    flat = dataclasses.replace(clip, depth_mm=np.zeros_like(clip.depth_mm))
    assert np.array_equal(apply.generate(net, clip, "dim", off), apply.generate(net, flat, "dim", off))


def test_looks_and_weights_are_parsed_or_refused_in_one_line():
    assert apply.parse_looks("dim, very dim,dim") == ("dim", "very dim")
    assert apply.parse_weights("edges=0.5, depth=0") == {**dict.fromkeys(ALL_CONTROLS, 1.0), "edges": 0.5,
                                                          "depth": 0.0}
    for text, said in (("sepia", "unknown look 'sepia'"), (" , ", "no look given")):
        with pytest.raises(ValueError, match=said):
            apply.parse_looks(text)
    for text, said in (("normals=1", "CONTROL=WEIGHT"), ("edges", "CONTROL=WEIGHT"), ("edges=x", "not a number"),
                       ("blur=-1", "from 0 to 100")):
        with pytest.raises(ValueError, match=said):
            apply.parse_weights(text)


def test_the_model_size_and_what_is_not_a_transfer_checkpoint(model, tmp_path):
    folder, _ = model
    config, info = apply.model_info(folder)
    assert info["size"] == SIDE and info["camera"] == "side" and config.name == "tiny"
    (tmp_path / "config.json").write_text(json.dumps({"tokenizer": {}}))
    with pytest.raises(CheckpointError, match="not a transfer checkpoint config"):
        apply.model_info(tmp_path)


def test_a_missing_camera_or_control_is_refused_unless_its_weight_is_0(episode, tmp_path):
    folder, _ = episode
    with pytest.raises(ControlError, match="camera 'wrist' is not one of the episode's"):
        apply.episode_source(folder, "wrist", apply.parse_weights(None))
    bare = tmp_path / "bare"
    bare.mkdir()
    for name in ("side.mp4", "meta.json", "steps.parquet"):
        (bare / name).write_bytes((folder / name).read_bytes())
    with pytest.raises(ControlError, match="no controls of camera 'side'"):
        apply.episode_source(bare, None, apply.parse_weights(None))
    (bare / "controls").mkdir()
    (bare / "controls" / "side.seg.npz").write_bytes((folder / "controls" / "side.seg.npz").read_bytes())
    with pytest.raises(ControlError, match=r"no depth control .* --weights depth=0"):
        apply.episode_source(bare, None, apply.parse_weights(None))
    source = apply.episode_source(bare, None, apply.parse_weights("depth=0"))
    assert sorted(source.controls) == ["segmentation"]
    assert not apply.source_clip(source, SIDE).depth_mm.any()


def test_outputs_are_their_own_folder_per_look_and_setting(episode, tmp_path):
    folder, _ = episode
    source = apply.episode_source(folder, None, apply.parse_weights(None))
    a = apply.output_paths(tmp_path, source, "very dim", apply.setting_id("1" * 64, apply.parse_weights(None)))
    b = apply.output_paths(tmp_path, source, "very dim", apply.setting_id("1" * 64, apply.parse_weights("edges=0")))
    assert a["video"].relative_to(tmp_path).parts[:4] == ("transfer", "ab" * 6, "episode_000000", "very-dim")
    assert a["video"].name == "side.mp4" and a["video"].parent != b["video"].parent
    apply.write_labels(source, a, tmp_path, {"look": "very dim"})
    assert a["steps.parquet"].read_bytes() == b"steps"
    assert a["meta.json"].read_bytes() == (folder / "meta.json").read_bytes()
    assert json.loads(a["info"].read_text())["look"] == "very dim"


def test_a_reference_video_gives_its_look_and_its_own_setting(episode):
    folder, _ = episode
    torch.manual_seed(0)
    net = TransferNet(preset("tiny").model_copy(update={"reference": True})).eval()
    weights = apply.parse_weights(None)
    clip = apply.source_clip(apply.episode_source(folder, None, weights), SIDE)
    bright = write_video(folder.parent / "bright.mp4", [np.full((48, 64, 3), 230, np.uint8)] * 3, fps=10)
    dark = write_video(folder.parent / "dark.mp4", [np.full((48, 64, 3), 20, np.uint8)] * 3, fps=10)
    looks = {name: apply.reference_look(path, SIDE, net.config) for name, path in (("bright", bright), ("dark", dark))}
    assert looks["bright"].shape == (1, REFERENCE_FEATURES) and looks["bright"][0, 0] > 0.7 > -0.7 > looks["dark"][0, 0]
    made = {name: apply.generate(net, clip, "dim", weights, reference=look) for name, look in looks.items()}
    assert not np.array_equal(made["bright"], made["dark"])
    assert not np.array_equal(made["bright"], apply.generate(net, clip, "dim", weights))
    assert apply.setting_id("m" * 64, weights, "r" * 64) != apply.setting_id("m" * 64, weights)


def test_a_palette_model_takes_class_colours_from_an_episode_reference_and_none_from_other_clips(episode):
    folder, rendered = episode
    config = preset("tiny").model_copy(update={"controls": ALL_CONTROLS, "reference": True, "head": "affine",
                                               "palette": True})
    row = apply.reference_look(folder / "side.mp4", SIDE, config)
    assert row.shape == (1, config.reference_size)
    palette = row[0, REFERENCE_FEATURES:].view(config.seg_classes, 4)
    present = set(seg_classes(np.unique(rendered.ids["side"]), rendered.legend).tolist())
    assert {k for k in range(config.seg_classes) if palette[k, 3] == 1} == present
    plain = write_video(folder.parent / "plain.mp4", [np.full((48, 64, 3), 90, np.uint8)] * 3, fps=10)
    other = apply.reference_look(plain, SIDE, config)
    assert other.shape == (1, config.reference_size) and torch.all(other[0, REFERENCE_FEATURES:] == 0)
