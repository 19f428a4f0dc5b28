"""Scripted control: each task succeeds from simulator state, noise matters, e-stops halt."""

import numpy as np
import pytest

from schemas.manifest import Embodiment, ForkliftCrossing
from tasks.manifests import load
from tasks.sim.control import ArmController
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


class _Shadowed:
    """The scripted expert drives; a second controller, told nothing of the path, takes its
    phase from each state (``resync``) and plans from the expert's commanded pose."""

    def __init__(self, scene, seed):
        self.expert, self.shadow = ArmController(scene, seed, noise=0.0), ArmController(scene, seed, noise=0.0)
        self.log = []

    def reset(self, data):
        self.expert.reset(data)
        self.shadow.reset(data)

    def action_size(self):
        return self.expert.action_size()

    def step(self, data):
        s, e = self.shadow, self.expert
        s.target_pos, s.target_yaw, s.grip = e.target_pos.copy(), e.target_yaw, e.grip
        s.phase, s.phase_t = "approach", 0.0  # no memory of the waypoints passed
        s.resync(data)
        delta, dyaw, _ = s.plan(data)
        pos, yaw, phase = e.target_pos.copy(), e.target_yaw, e.phase
        action = e.step(data)
        same = np.allclose(delta, e.target_pos - pos, atol=1e-9) and abs(dyaw - (e.target_yaw - yaw)) < 1e-9
        self.log.append((phase, same))
        return action


def test_a_push_phase_read_from_the_state_gives_the_experts_own_moves():
    """DAgger's labelling expert (ArmController.resync): on the expert's own path, a controller
    that knows only the state plans the expert's moves, pushing included; the few steps that
    differ are at phase changes (it descends within 0.03 m of the pre-push point, the expert
    within 0.015 m)."""
    manifest = load(MANIFESTS / "push_closeup.yaml")
    manifest = _small(manifest, task=manifest.task.model_copy(update={"controller_noise": 0.0}))
    made = []
    ep = rollout(manifest, 3, controller=lambda scene, seed: made.append(_Shadowed(scene, seed)) or made[-1],
                 record=())
    log = made[0].log
    assert ep.success and len(log) == ep.steps
    assert np.mean([same for _, same in log]) >= 0.95
    pushing = [same for phase, same in log if phase == "push"]
    assert len(pushing) > 50 and np.mean(pushing) >= 0.98


def test_a_pick_keeps_its_phase_when_resynced():
    from tasks.sim.scene import build_scene

    manifest = _small(load(MANIFESTS / "bin_pick_dim_forklift.yaml"), stressors=())
    arm = ArmController(build_scene(manifest, 2), 2, noise=0.0)
    arm.phase = "lift"
    arm.resync(None)  # a pick's phase is never read from the state
    assert arm.phase == "lift"
