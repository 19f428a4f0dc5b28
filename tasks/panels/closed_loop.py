"""The world model as an environment: a policy that sees frames drives it, closed loop.

Open loop (`tasks.panels.world.world_model_rollout`) replays actions a simulator episode
recorded. Closed loop, the policy observes the world model's own decoded frames and its
actions drive the world model: from the episode's first true frame, one latent step at a time,

1. the policy is asked for an action at each control step of the coming latent step
   (control steps at ``control_hz`` from time 0; the ones leading into the latent step's
   video frames, as `tasks.world.data.align_actions` assigns them), seeing the newest frame
   generated so far (a latent step makes ``t`` video frames at once, so within it the policy
   sees the frame before: up to ``t / fps`` s of lag, the world model's own granularity);
2. every action so far is aligned into the model's action rows (with the checkpoint's action
   totals) and the model rolls out one more latent frame (greedy);
3. the latent frames so far are decoded and the newest ``t`` video frames are what the policy
   sees next,

until ``frames`` video frames exist. The frame detector then judges them as it judges any
rollout. A policy is any callable ``(frame, time_s) -> action``: ``frame`` H x W x 3 uint8 at
the camera's size (the world model's centre square put back, black around it, as the open-loop
rollout returns it), the action a vector in the episode's action layout.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tasks.panels.world import WorldModelUnavailable, _load, _unsquare

FramePolicy = Callable[[np.ndarray, float], np.ndarray]


@dataclass(frozen=True)
class ClosedLoopRequest:
    """context: 1 x H x W x 3 uint8, the episode's first true frame; frames: video frames to
    generate in all (the context frame included) at ``fps``; actions are asked at ``control_hz``."""

    camera: str
    context: np.ndarray
    control_hz: float
    fps: float
    frames: int
    text: str = ""


@dataclass
class ClosedLoopResult:
    frames: np.ndarray  # request.frames x H x W x 3 uint8
    actions: np.ndarray  # K x A, every action the policy chose, at control_hz from time 0
    seen: list[int]  # for each action, the index of the generated frame the policy saw


def closed_loop(checkpoint: Path | str, request: ClosedLoopRequest, policy: FramePolicy,
                root: Path | str = ".", device: str | None = None) -> ClosedLoopResult:
    import torch

    from tasks.world.data import align_actions, encode_frames
    from tasks.world.heldout import decode

    model, tokenizer, size = _load(str(Path(checkpoint).resolve()), str(Path(root).resolve()), device)
    from tasks.world.family import is_diffusion

    if is_diffusion(model):
        raise WorldModelUnavailable(f"{checkpoint}: a diffusion world model; closed loop drives autoregressive "
                                    "ones only")
    if not model.config.action_conditioned:
        raise WorldModelUnavailable(f"{checkpoint}: the world model is not action-conditioned, so no policy "
                                    "can drive it (post-train it on episodes first)")
    t = tokenizer.config.temporal_compression
    latent = max(1, math.ceil((request.frames - 1) / t))
    h, w = request.context.shape[1:3]
    frame_time = np.arange(1 + t * latent) / request.fps
    codes = torch.from_numpy(encode_frames(tokenizer, request.context[:1], size))[None]  # 1 x 1 x H' x W'
    shown = _unsquare(decode(tokenizer, codes[0]), h, w)  # generated frames so far (frame 0: the context's)
    text = [request.text] if request.text else None
    actions: list[np.ndarray] = []
    seen: list[int] = []
    for j in range(latent):
        # Control steps leading into this latent step's frames t j + 1 .. t j + t.
        end = frame_time[t * (j + 1)]
        while len(actions) / request.control_hz < end - 1e-9:
            frame = t * j  # the newest frame generated before this latent step
            actions.append(np.asarray(policy(shown[frame], len(actions) / request.control_hz), np.float64))
            seen.append(frame)
        steps = np.stack(actions)
        rows = align_actions(np.arange(len(steps)) / request.control_hz, steps, frame_time[:t * (j + 1) + 1], t,
                             j + 2, model.config.action_dim, model.config.action_totals)
        nxt = model.rollout(codes, 1, text=text, actions=torch.from_numpy(rows)[None])
        codes = torch.cat([codes, nxt], dim=1)
        shown = _unsquare(decode(tokenizer, codes[0]), h, w)
    return ClosedLoopResult(frames=shown[:request.frames], actions=np.stack(actions), seen=seen)
