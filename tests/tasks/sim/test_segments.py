"""sim_segment: continuous, moving, reproducible simulator footage at any size."""

import cv2
import numpy as np
import pytest

from tasks.manifests import load
from tasks.sim.segments import sim_segment

from tests.support import MANIFESTS


def _motion(frames: np.ndarray) -> np.ndarray:
    return np.abs(np.diff(frames.astype(np.int16), axis=0)).mean(axis=(1, 2, 3))


@pytest.mark.parametrize("name", ["bin_pick_dim_forklift", "conveyor_push", "mobile_rig_aisle"])
def test_segment_shape_and_motion(name):
    manifest = load(MANIFESTS / f"{name}.yaml")
    frames = sim_segment(manifest, 1, 60, 48, 32, fps=15)
    assert frames.shape == (60, 32, 48, 3) and frames.dtype == np.uint8
    assert (_motion(frames) > 0).mean() > 0.5  # the arm works, the base drives: most frames change


def test_long_segment_keeps_moving_after_the_task_is_done():
    manifest = load(MANIFESTS / "bin_pick_dim_forklift.yaml")
    manifest = manifest.model_copy(update={"stressors": ()})
    frames = sim_segment(manifest, 2, 120, 32, 32, fps=10)  # 12 s: a single episode would be still by 3 s
    late = _motion(frames[60:])
    assert (late > 0).mean() > 0.5


def test_same_arguments_same_frames_other_seed_differs():
    manifest = load(MANIFESTS / "conveyor_push.yaml")
    a = sim_segment(manifest, 3, 12, 40, 24)
    assert np.array_equal(a, sim_segment(manifest, 3, 12, 40, 24))
    assert not np.array_equal(a, sim_segment(manifest, 4, 12, 40, 24))


def test_large_output_is_rendered_small_and_scaled():
    manifest = load(MANIFESTS / "conveyor_push.yaml")
    frames = sim_segment(manifest, 3, 2, 640, 360, render_width=64)
    assert frames.shape == (2, 360, 640, 3)
    small = sim_segment(manifest, 3, 2, 64, 36)
    assert np.array_equal(frames[1], cv2.resize(small[1], (640, 360), interpolation=cv2.INTER_LINEAR))


def test_unknown_camera_is_refused():
    manifest = load(MANIFESTS / "conveyor_push.yaml")
    with pytest.raises(ValueError, match="conveyor-push.*'nope'"):
        sim_segment(manifest, 0, 2, 32, 32, camera="nope")


def test_take_from_start_s_is_the_same_run_from_later_on():
    manifest = load(MANIFESTS / "mobile_rig_aisle.yaml").model_copy(update={"stressors": ()})
    whole = sim_segment(manifest, 5, 40, 40, 24, fps=10)
    late = sim_segment(manifest, 5, 10, 40, 24, fps=10, start_s=3.0)
    assert np.array_equal(late, whole[30:])
    assert not np.array_equal(late, whole[:10])


def test_bad_start_is_refused():
    manifest = load(MANIFESTS / "conveyor_push.yaml")
    with pytest.raises(ValueError, match="from -1.0 s"):
        sim_segment(manifest, 3, 2, 40, 24, start_s=-1.0)
