"""Closed loop on an untrained tiny world model: the policy sees the generated frames, and the
actions it chooses are the ones that drive the model. (Skill is the evaluation's business.)"""

import numpy as np
import pytest

from models.world_model import WorldModel
from tasks.panels.closed_loop import ClosedLoopRequest, closed_loop
from tasks.panels.world import WorldModelRequest, WorldModelUnavailable, world_model_rollout
from tasks.world.data import align_actions

from .test_world import SIZE, checkpoint  # noqa: F401 (the module fixture)


def _request(frames=13):
    context = np.random.default_rng(0).integers(0, 255, (1, 48, 64, 3), dtype=np.uint8)
    return ClosedLoopRequest(camera="overhead", context=context, control_hz=50, fps=30, frames=frames,
                             text="push the package")


class Brightness:
    """A policy that pushes as hard as the picture is bright: it sees frames, not state."""

    def __init__(self):
        self.frames: list[np.ndarray] = []

    def __call__(self, frame: np.ndarray, time_s: float) -> np.ndarray:
        self.frames.append(frame.copy())
        return np.array([frame.mean() / 255.0, 0.0, 0.0, 0.0, time_s])


def test_the_policy_sees_the_generated_frames_and_its_actions_drive_the_model(checkpoint, monkeypatch):  # noqa: F811
    seen_rows = []
    real = WorldModel.rollout
    monkeypatch.setattr(WorldModel, "rollout", lambda self, *a, **kw: seen_rows.append(kw["actions"]) or real(self, *a, **kw))
    policy = Brightness()
    result = closed_loop(checkpoint / "wm", _request(), policy, root=checkpoint)
    assert result.frames.shape == (13, 48, 64, 3) and result.frames.dtype == np.uint8
    # 12 frames after the context at 30 fps need 3 latent steps (t = 4) and 20 control steps at 50 Hz.
    assert len(result.actions) == len(policy.frames) == 20 and len(seen_rows) == 3
    for frame, index in zip(policy.frames, result.seen, strict=True):
        assert np.array_equal(frame, result.frames[index])  # what it saw is what was generated
    assert result.seen[0] == 0 and result.seen[-1] == 8 and sorted(result.seen) == result.seen
    # Each latent step got every action so far, aligned as the open-loop rollout aligns them.
    frame_time = np.arange(13) / 30
    want = align_actions(np.arange(20) / 50, result.actions, frame_time, 4, 4, 8)
    assert np.array_equal(seen_rows[-1][0].numpy(), want)
    # Replaying its actions open loop generates the very same frames.
    replay = world_model_rollout(checkpoint / "wm", WorldModelRequest(
        camera="overhead", context=_request().context, actions=result.actions, control_hz=50, fps=30, frames=13,
        text="push the package"), root=checkpoint)
    assert np.array_equal(replay, result.frames)


def test_a_model_without_actions_cannot_be_driven(checkpoint, tmp_path):  # noqa: F811
    from tasks.world.checkpoints import load_checkpoint, save_checkpoint

    model = load_checkpoint(checkpoint / "wm")
    plain = WorldModel(model.config.model_copy(update={"action_conditioned": False, "action_scale": None}))
    save_checkpoint(plain, tmp_path / "wm", {"tokenizer": str(checkpoint / "tok"), "size": SIZE})
    with pytest.raises(WorldModelUnavailable, match="not action-conditioned"):
        closed_loop(tmp_path / "wm", _request(), Brightness(), root=checkpoint)
