"""Transferred variants of vision demonstrations: each step keeps its proprioception and move,
the frames it saw are found in the demonstration's own re-rendered rollout, and the variant's
frames are the transfer model's output in the look (a tiny untrained model, 16 px)."""

import numpy as np
import pytest
import torch

from tasks.manifests import load
from tasks.policy.vision import collect
from tasks.policy.vision_obs import ObservationSpec
from tasks.transfer import variants
from tasks.transfer.train import TrainConfig, new_model

from tests.support import MANIFESTS

PUSH = load(MANIFESTS / "push_closeup.yaml").model_copy(update={"horizon_s": 2.0})
SPEC = ObservationSpec(cameras=("side",), image_size=32)
WEIGHTS = dict.fromkeys(("edges", "blur", "depth", "segmentation"), 1.0)


@pytest.fixture(scope="module")
def demos():
    return collect(PUSH, [3], SPEC, successes_only=False)


@pytest.fixture(scope="module")
def clips(demos):
    return variants.episode_clips(PUSH, demos, SPEC, "side", 16)


def test_frame_index_maps_each_step_to_the_frame_it_saw():
    tau = (np.arange(100) / 50 / 2.0).astype(np.float32)  # 50 Hz steps of a 2 s episode, as proprio holds time
    index = variants.frame_index(tau, 2.0, seen_fps=1.0, fps=10.0)
    assert (index[:50] == 0).all() and (index[50:] == 10).all()
    assert (variants.frame_index(tau, 2.0, seen_fps=10.0, fps=10.0) == np.arange(100) // 5).all()


def test_the_rollout_is_the_demonstrations_own(demos, clips):
    (item,) = clips
    assert item.mismatch < 1.0  # area resizing 64 -> 32 -> 16 against 64 -> 16 rounds a little differently
    assert len(item.rows) == len(demos.act) and item.clip.frames.shape == (20, 16, 16, 3)
    assert item.clip.depth_mm.any() and item.clip.seg.any()
    assert np.array_equal(item.index, np.arange(100) // 5)  # each step saw the camera's latest 10 fps frame


def test_variants_keep_the_steps_and_change_the_frames(demos, clips):
    torch.manual_seed(0)
    model = new_model(TrainConfig(preset="tiny"))
    out = variants.with_variants(demos, SPEC, clips, model, ("dim", "textures"), WEIGHTS)
    n = len(demos.act)
    assert len(out.act) == 3 * n and out.frames.shape[1:] == demos.frames.shape[1:]
    assert np.array_equal(out.frames[:n], demos.frames)
    for k in (1, 2):
        assert np.array_equal(out.act[k * n:(k + 1) * n], demos.act)
        assert np.array_equal(out.proprio[k * n:(k + 1) * n], demos.proprio)
        assert not np.array_equal(out.frames[k * n:(k + 1) * n], demos.frames)
    # steps that saw the same camera frame see the same generated frame
    first = out.frames[n:2 * n]
    assert all((first[k:k + 5] == first[k]).all() for k in range(0, n, 5))


def test_without_rendered_controls_is_the_model_at_weight_zero(demos, clips):
    torch.manual_seed(0)
    model = new_model(TrainConfig(preset="tiny"))
    bare = variants.episode_clips(PUSH, demos, SPEC, "side", 16, rendered=False)
    assert not bare[0].clip.depth_mm.any()
    zero = {**WEIGHTS, "depth": 0.0, "segmentation": 0.0}
    a = variants.transferred(demos, SPEC, clips, model, "dim", zero)
    b = variants.transferred(demos, SPEC, bare, model, "dim", zero)
    assert np.array_equal(a.frames, b.frames)


def test_a_reference_model_takes_each_episodes_reference(demos, clips):
    from models.transfer import TransferNet, preset

    torch.manual_seed(0)
    model = TransferNet(preset("tiny").model_copy(update={"reference": True})).eval()
    refs = variants.look_references(PUSH, [40], "side", 16, ("colour shift",))
    assert refs["colour shift"][0].shape[0] == 1
    a = variants.transferred(demos, SPEC, clips, model, "colour shift", WEIGHTS, refs["colour shift"])
    b = variants.transferred(demos, SPEC, clips, model, "colour shift", WEIGHTS)
    assert a.frames.shape == b.frames.shape


def test_a_palette_models_references_carry_the_renders_class_colours():
    from models.transfer import ALL_CONTROLS, REFERENCE_FEATURES, preset

    config = preset("tiny").model_copy(update={"controls": ALL_CONTROLS, "reference": True, "head": "affine",
                                               "palette": True})
    refs = variants.look_references(PUSH, [40, 41], "side", 16, ("colour shift",), config)["colour shift"]
    assert len(refs) == 2 and refs[0].shape == (1, config.reference_size)
    known = [r[0, REFERENCE_FEATURES:].view(config.seg_classes, 4)[:, 3] for r in refs]
    assert all(k.sum() >= 3 for k in known)  # background, package, robot at least
    assert not torch.equal(refs[0], refs[1])  # each seed its own colour draw
