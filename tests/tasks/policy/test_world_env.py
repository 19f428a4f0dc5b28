"""A vision policy inside a world model: proprioception from the kinematic twin (never object
state), frames only from the world model, and the refusals. Untrained tiny models: the
plumbing under test, not the skill."""

import cv2
import numpy as np
import pytest
import torch

import mujoco
from models.vision_policy import VisionPolicyNet, preset
from tasks.manifests import load
from tasks.panels.closed_loop import ClosedLoopRequest, closed_loop
from tasks.policy import world_env
from tasks.policy.base import ScriptedPolicy
from tasks.policy.vision import VisionPolicy
from tasks.policy.vision_obs import ObservationSpec, proprio_size
from tasks.policy.world_env import TwinDriven, drive_problem, world_model_mismatch
from tasks.sim import render
from tasks.sim.control import MAX_STEP, ArmController
from tasks.sim.scene import build_scene
from tasks.world.checkpoints import load_checkpoint, read_config, save_checkpoint

from tests.support import MANIFESTS
from tests.tasks.panels.test_world import checkpoint, diffusion_checkpoint  # noqa: F401 (the module fixtures)

PUSH = load(MANIFESTS / "conveyor_push.yaml").model_copy(update={"horizon_s": 1.0})


def vision_policy(manifest=PUSH, camera: str = "overhead", size: int = 32) -> VisionPolicy:
    """An untrained tiny vision policy for ``manifest``'s robot."""
    torch.manual_seed(0)
    arm = ArmController(build_scene(manifest, 0), 0)
    return VisionPolicy(VisionPolicyNet(preset("tiny", 1, size, proprio_size(arm))),
                        ObservationSpec(cameras=(camera,), image_size=size))


def _drive(driven: TwinDriven, steps: int = 30) -> tuple[np.ndarray, np.ndarray]:
    """(proprioception the policy got, actions it took) over ``steps`` steps of one grey frame."""
    frame = np.full((64, 64, 3), 90, np.uint8)
    got, acts = [], []
    for k in range(steps):
        got.append(driven.observe(frame)[1])
        acts.append(driven(frame, k / 50))
    return np.stack(got), np.stack(acts)


def _package_in_the_hand(driven: TwinDriven) -> None:
    """The package moved, in the twin, onto a finger pad: the finger is inside it."""
    twin = driven.twin
    body = twin.model.body(twin.scene.objects[0])
    qadr = twin.model.jnt_qposadr[twin.model.body_jntadr[body.id]]
    twin.data.qpos[qadr:qadr + 3] = twin.data.geom_xpos[twin.model.geom("finger_left_pad").id]
    mujoco.mj_forward(twin.model, twin.data)


def test_the_twins_proprioception_never_reads_the_package(monkeypatch):
    policy = vision_policy()
    alone = _drive(TwinDriven(policy, PUSH, 3))
    moved = TwinDriven(policy, PUSH, 3)
    _package_in_the_hand(moved)
    there = _drive(moved)
    assert np.array_equal(alone[0], there[0]) and np.array_equal(alone[1], there[1])
    assert np.ptp(alone[0][:, :7], axis=0).max() > 0  # the arm does move under the policy's commands
    # With the package in contact (as in the simulator) the same move would have told the arm.
    monkeypatch.setattr(world_env, "_moving_bodies", lambda scene: set())
    touched = TwinDriven(policy, PUSH, 3)
    _package_in_the_hand(touched)
    assert not np.array_equal(alone[0], _drive(touched)[0])


def test_actions_are_in_the_episodes_layout_at_the_twins_time():
    driven = TwinDriven(vision_policy(), PUSH, 0)
    _, acts = _drive(driven, 10)
    assert acts.shape == (10, 5)  # ee_delta: dx, dy, dz, dyaw, grip, as ArmController.apply records them
    assert np.all(np.linalg.norm(acts[:, :3], axis=1) <= MAX_STEP + 1e-12) and set(acts[:, 4]) <= {0.0, 1.0}
    with pytest.raises(ValueError, match="the twin is at 0.200 s; asked for an action at 0.500 s"):
        driven(np.zeros((64, 64, 3), np.uint8), 0.5)


def test_the_policy_sees_only_the_world_models_frames(checkpoint, monkeypatch):  # noqa: F811
    def no_render(*a, **k):
        raise AssertionError("nothing may be rendered for a policy in the world model")

    monkeypatch.setattr(render.MultiCameraRenderer, "__init__", no_render)
    driven = TwinDriven(vision_policy(), PUSH, 0)
    seen, act = [], driven.learner.act
    monkeypatch.setattr(driven.learner, "act", lambda frames, state: seen.append(frames) or act(frames, state))
    context = np.random.default_rng(0).integers(0, 255, (1, 64, 64, 3), dtype=np.uint8)
    result = closed_loop(checkpoint / "wm", ClosedLoopRequest(camera="overhead", context=context, control_hz=50, fps=30,
                                                              frames=13), driven, root=checkpoint)
    assert len(seen) == len(result.actions) == 20
    for frames, index in zip(seen, result.seen, strict=True):
        want = cv2.resize(result.frames[index], (32, 32), interpolation=cv2.INTER_AREA)  # as Observer downscales
        assert frames.shape == (1, 3, 32, 32) and np.array_equal(frames[0], want.transpose(2, 0, 1))


def test_only_a_vision_policy_of_the_world_models_camera_can_be_driven():
    assert "reads the simulator's state, not frames" in drive_problem(ScriptedPolicy(), "overhead")
    assert drive_problem(vision_policy(), "overhead") is None
    said = drive_problem(vision_policy(camera="side"), "overhead")
    assert "sees camera(s) side; the world model generates overhead only" in said


@pytest.mark.parametrize("change, said", [
    ({"camera": "wrist"}, "it was post-trained on camera wrist; the panel's camera is overhead"),
    ({"codebook_size": 7}, "has codebook 1000 and temporal compression 4; the model reads codebook 7"),
    ({"action_dim": 6, "action_totals": 3}, "gives 5 action values a step (+ 3 totals); the model takes 6"),
    ({"action_conditioned": False, "action_scale": None}, "not action-conditioned, so no policy can drive it"),
    ({"episodes": ["ep"]}, "post-trained on actions of 7 values a step; the panel's robot (arm ee_delta) gives 5"),
])
def test_a_world_model_that_does_not_fit_the_panel_is_named(checkpoint, tmp_path, change, said):  # noqa: F811
    from tasks.world.data import read_steps

    assert world_model_mismatch(checkpoint / "wm", PUSH, "overhead", checkpoint, driven=True) is None
    model, extra = load_checkpoint(checkpoint / "wm"), read_config(checkpoint / "wm")
    arch = {k: v for k, v in change.items() if k in type(model.config).model_fields}
    extra = {**{k: v for k, v in extra.items() if k != "world_model"}, "tokenizer": str(checkpoint / "tok"),
             **{k: v for k, v in change.items() if k not in arch}}
    if arch:
        model.config = model.config.model_copy(update=arch)
    save_checkpoint(model, tmp_path / "wm", extra)
    if "episodes" in change:  # a training episode whose robot took 7 values a step (joint_position)
        import pyarrow as pa
        import pyarrow.parquet as pq

        (tmp_path / "ep").mkdir()
        steps = pa.table({"time": [0.0, 0.02], "action": [[0.0] * 7, [0.1] * 7]})
        pq.write_table(steps, tmp_path / "ep" / "steps.parquet")
        assert read_steps(tmp_path / "ep")[1].shape == (2, 7)
    assert said in world_model_mismatch(tmp_path / "wm", PUSH, "overhead", tmp_path, driven=True)


def test_a_diffusion_world_model_is_checked_against_the_panel_too(diffusion_checkpoint):  # noqa: F811
    """The same check reads a diffusion checkpoint (config key diffusion_world_model): its
    tokenizer must be continuous, and closed loop drives autoregressive models only."""
    root = diffusion_checkpoint
    assert world_model_mismatch(root / "wm", PUSH, "overhead", root) is None
    said = world_model_mismatch(root / "wrong", PUSH, "overhead", root)
    assert ("is discrete with 4 channels and temporal compression 4; the diffusion model reads continuous latents "
            "of 16") in said
    assert "closed loop ({in_world_model}) drives autoregressive world models only" in world_model_mismatch(
        root / "wm", PUSH, "overhead", root, driven=True)
