"""Rollouts: what is recorded never changes the physics; only the named cameras are recorded."""

import numpy as np
import pytest

from schemas.manifest import CameraJitter
from tasks.manifests import load
from tasks.sim.episode import rollout

from tests.support import MANIFESTS

ARRAYS = ("time", "joint_pos", "joint_vel", "action", "object_pose", "success_flag", "estop")


@pytest.fixture(scope="module")
def manifest():
    """Three cameras (two fixed, one on the wrist), a forklift and camera jitter, small and short."""
    m = load(MANIFESTS / "bin_pick_dim_forklift.yaml")
    cams = tuple(c.model_copy(update={"resolution": (64, 48)}) for c in m.cameras)
    return m.model_copy(update={"horizon_s": 1.2, "cameras": cams,
                                "stressors": (*m.stressors, CameraJitter(amplitude_deg=2.0))})


@pytest.fixture(scope="module")
def recorded(manifest):
    return rollout(manifest, 4)


def _same_physics(a, b) -> None:
    for name in ARRAYS:
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert (a.success, a.reason, a.stressor_values) == (b.success, b.reason, b.stressor_values)


def test_recording_nothing_keeps_the_physics_and_no_frames(manifest, recorded):
    assert set(recorded.frames) == {"front_left", "front_right", "wrist"}
    bare = rollout(manifest, 4, record=())
    _same_physics(recorded, bare)
    assert bare.frames == {} and bare.frame_time == {}
    assert bare.manifest == manifest  # the scene is the real manifest's, cameras and all


def test_recording_one_camera_gives_its_frames_and_hooks_only_it(manifest, recorded):
    seen = []
    one = rollout(manifest, 4, record=("wrist",), on_frame=lambda scene, r, data, cam, angles: seen.append(cam))
    _same_physics(recorded, one)
    assert set(one.frames) == set(one.frame_time) == {"wrist"}
    assert np.array_equal(one.frames["wrist"], recorded.frames["wrist"])
    assert np.array_equal(one.frame_time["wrist"], recorded.frame_time["wrist"])
    assert seen == ["wrist"] * len(recorded.frames["wrist"]) == ["wrist"] * 36  # 1.2 s at 30 fps


def test_record_names_the_manifests_cameras(manifest):
    with pytest.raises(ValueError, match="overhead not in bin-pick-dim-forklift"):
        rollout(manifest, 4, record=("wrist", "overhead"))
    for bad in ("wrist", False):
        with pytest.raises(TypeError, match="sequence of camera names"):
            rollout(manifest, 4, record=bad)
