"""Scripted control: each task succeeds from simulator state, noise matters, e-stops halt."""

import numpy as np
import pytest

from schemas.manifest import Embodiment, ForkliftCrossing
from tasks.manifests import load
from tasks.sim.episode import rollout

from tests.support import MANIFESTS


def _small(manifest, **update):
    """The manifest with tiny, slow cameras: control and judging are what is tested here."""
    cams = tuple(c.model_copy(update={"resolution": (24, 24), "fps": 4}) for c in manifest.cameras)
    return manifest.model_copy(update={"cameras": cams, **update})


def test_push_reaches_the_goal_with_distractors_and_appearance():
    manifest = _small(load(MANIFESTS / "conveyor_push.yaml"))
    ep = rollout(manifest, 11)
    assert ep.success and ep.success_flag[-1], ep.reason
    start, end = ep.object_pose[0, 0, :2], ep.object_pose[-1, 0, :2]
    assert np.linalg.norm(end - start) > 0.2  # the package really travelled
    assert ep.action.shape == (ep.steps, 5)


def test_controller_noise_is_seeded_and_hurts():
    base = load(MANIFESTS / "bin_pick_dim_forklift.yaml")
    manifest = _small(base, stressors=(), horizon_s=3.0)
    noisy = manifest.model_copy(update={"task": manifest.task.model_copy(update={"controller_noise": 0.9})})
    clean = rollout(manifest, 2)
    a, b = rollout(noisy, 2), rollout(noisy, 2)
    assert clean.success, clean.reason
    assert np.array_equal(a.action, b.action)
    # Per-step jitter of the commanded pose: far rougher than the noise-free command.
    assert np.abs(np.diff(a.action[:, :3], axis=0)).mean() > 3 * np.abs(np.diff(clean.action[:, :3], axis=0)).mean()


def test_joint_position_actions_are_joint_targets():
    base = load(MANIFESTS / "bin_pick_dim_forklift.yaml")
    manifest = _small(base, stressors=(), horizon_s=3.0,
                      embodiment=Embodiment(kind="arm", action_space="joint_position"))
    ep = rollout(manifest, 0)
    assert ep.success, ep.reason
    assert ep.action.shape == (ep.steps, 7)
    # The arm follows its targets: joint angles one step later are close to the commanded ones.
    assert np.abs(ep.joint_pos[1:, :6] - ep.action[:-1, :6]).mean() < 0.05


def test_estop_freezes_the_arm():
    base = load(MANIFESTS / "bin_pick_dim_forklift.yaml")
    manifest = _small(base, horizon_s=4.0, stressors=(ForkliftCrossing(speed_mps=2.0, lane_m=0.2, start_s=0.0),))
    ep = rollout(manifest, 0)
    assert not ep.success and ep.reason.startswith("emergency stop: forklift contact")
    first = int(np.argmax(ep.estop))
    assert 0 < first < ep.steps - 10 and ep.estop[first:].all()
    assert not ep.action[first:].any()  # no commands after the stop
    assert not ep.success_flag[first:].any()


def test_base_waits_for_the_forklift_then_reaches_the_goal():
    manifest = _small(load(MANIFESTS / "mobile_rig_aisle.yaml"))
    ep = rollout(manifest, 3)
    assert ep.success and not ep.estop.any(), ep.reason
    x = ep.joint_pos[:, 0]
    fork = manifest.stressor("forklift_crossing")
    waiting = (np.abs(ep.joint_vel[:, 0]) < 0.05) & (x > 0.5) & (x < fork.lane_m)
    assert waiting.sum() * (1 / ep.control_hz) > 0.5  # it held at the stop line for a while


def test_without_the_forklift_the_base_does_not_wait():
    manifest = _small(load(MANIFESTS / "mobile_rig_aisle.yaml"), stressors=())
    ep = rollout(manifest, 3)
    assert ep.success, ep.reason
    x = ep.joint_pos[:, 0]
    assert not ((np.abs(ep.joint_vel[:, 0]) < 0.05) & (x > 0.5) & (x < 5.5)).any()


@pytest.mark.slow
def test_menagerie_ur5e_lifts_the_package(shared_data):
    from tasks.sim.scene import SimConfig

    base = load(MANIFESTS / "bin_pick_dim_forklift.yaml")
    arm = Embodiment(kind="arm", robot="ur5e", mjcf="universal_robots_ur5e/ur5e.xml")
    manifest = _small(base, stressors=(), horizon_s=3.5, embodiment=arm,
                      cameras=(base.cameras[0].model_copy(update={"resolution": (24, 24), "fps": 2}),))
    ep = rollout(manifest, 0, SimConfig(robots_root=shared_data / "robots"))
    assert ep.success, ep.reason
    assert any("gripper" in n for n in ep.joint_names)
