"""A policy that sees: camera frames and proprioception in, the next end-effector move out.

The scripted controller stays the privileged expert. Demonstrations are its episodes, with
what the cameras showed and the robot felt at each control step and the move it then
commanded. DAgger rounds (Ross et al., 2011) then roll out the *learner*, and the expert labels
every state the learner visits with the move it would make from there: a shadow scripted
controller whose commanded pose is set to the learner's before it plans (``ArmController.plan``),
so its label is the move from where the learner actually is. The learner acts through the same
``ArmController.apply`` as the expert and the state policy.

By default a DAgger round is gated (HG-DAgger, Kelly et al., 2019): the expert takes over, and
its label is kept, only on a step where the learner's move is off the expert's by more than
``gate`` times the demonstrations' spread of that action value (or the grip differs); the
learner's other steps are neither labelled nor changed. Labelling every step (``gate`` None,
plain DAgger) taught the learner to undo moves that worked: the shadow controller kept its own
phase (approach, descend, push ...), which advanced only when the arm reached that phase's
waypoint, so on a learner that pushed from a few millimetres off the expert's path it stayed
behind and labelled the push with a move back. The shadow now reads its phase from the state
before it plans (``ArmController.resync``, ``RESYNC``); neither that nor the gate has yet made
DAgger beat behaviour cloning (docs/evaluation.md).
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import torch

import tasks.sim  # noqa: F401  (sets MUJOCO_GL before mujoco loads)
from models.vision_policy import VisionPolicyNet
from schemas.manifest import ScenarioManifest
from schemas.panel import PanelContract
from tasks.device import model_device
from tasks.policy.base import Policy
from tasks.policy.bc import require_arm
from tasks.policy.vision_obs import ObservationSpec, Observer, proprio, proprio_size
from tasks.sim.control import MAX_STEP, MAX_YAW_STEP, ArmController, make_controller
from tasks.sim.episode import rollout
from tasks.sim.scene import Scene, SimConfig


@dataclass
class VisionDemonstrations:
    """frames N x C x 3 x S x S uint8; proprio N x P float32; act N x 5 float32; episode N
    (index into ``seeds``); ``successes`` per seed (of the expert, or of the learner in a
    DAgger round); ``round`` N (0 the expert's demonstrations, k the k-th DAgger round)."""

    frames: np.ndarray
    proprio: np.ndarray
    act: np.ndarray
    episode: np.ndarray
    round: np.ndarray
    seeds: tuple[int, ...]
    successes: tuple[bool, ...]

    def __add__(self, other: "VisionDemonstrations") -> "VisionDemonstrations":
        return VisionDemonstrations(
            frames=np.concatenate([self.frames, other.frames]), proprio=np.concatenate([self.proprio, other.proprio]),
            act=np.concatenate([self.act, other.act]),
            episode=np.concatenate([self.episode, other.episode + len(self.seeds)]),
            round=np.concatenate([self.round, other.round]), seeds=self.seeds + other.seeds,
            successes=self.successes + other.successes)


class _Learner:
    """Actuation half of the scripted controller with a network choosing the move; sees only
    the observer's frames and proprioception."""

    # The frames last encoded and what the frozen encoder made of them (class defaults, so a
    # subclass that builds itself, tasks/policy/world_env.py's twin, has them too).
    seen: np.ndarray | None = None
    frozen: torch.Tensor | None = None

    def __init__(self, model: VisionPolicyNet, spec: ObservationSpec, scene: Scene, seed: int):
        self.arm = ArmController(scene, seed, noise=0.0)
        if proprio_size(self.arm) != model.config.proprio_size:
            raise ValueError(f"policy expects {model.config.proprio_size} proprioceptive values; this robot gives "
                             f"{proprio_size(self.arm)}")
        self.model, self.observer = model, Observer(scene, spec)

    def reset(self, data: mujoco.MjData) -> None:
        self.arm.reset(data)

    def action_size(self) -> int:
        return self.arm.action_size()

    def observe(self, data: mujoco.MjData) -> tuple[np.ndarray, np.ndarray]:
        return self.observer.frames(data), proprio(data, self.arm)

    def act(self, frames: np.ndarray, state: np.ndarray) -> np.ndarray:
        # One thread: for one small frame torch's pool costs far more than the work
        # (1.7 ms a step on one thread, 32 ms on two, measured on this 2-core machine).
        threads = torch.get_num_threads()
        torch.set_num_threads(1)
        try:
            with torch.inference_mode():
                device = model_device(self.model)  # the CPU, or where it was just trained (DAgger)
                x = torch.from_numpy(frames)[None].to(device)
                if self.seen is None or not np.array_equal(frames, self.seen):
                    # A camera frame is held between its frame times (5 control steps at 10 fps):
                    # its encoding is too (a tokenizer encoder costs 10x the CNN).
                    self.seen, self.frozen = frames.copy(), self.model.frozen(x)
                return self.model(x, torch.from_numpy(state)[None].to(device), self.frozen)[0].cpu().numpy()
        finally:
            torch.set_num_threads(threads)

    def apply(self, data: mujoco.MjData, out: np.ndarray) -> np.ndarray:
        delta, dyaw, grip = out[:3].astype(np.float64), float(out[3]), float(out[4])
        norm = float(np.linalg.norm(delta))
        if norm > MAX_STEP:  # the scripted controller's speed limit binds the policy too
            delta = delta * (MAX_STEP / norm)
        return self.arm.apply(data, delta, float(np.clip(dyaw, -MAX_YAW_STEP, MAX_YAW_STEP)), 1.0 if grip >= 0.5 else 0.0)

    def step(self, data: mujoco.MjData) -> np.ndarray:
        return self.apply(data, self.act(*self.observe(data)))

    def close(self) -> None:
        self.observer.close()


RESYNC = True  # the labelling expert takes its phase from the state (ArmController.resync); False: its own


class _Recorder:
    """Records (frames, proprio, label) each step. Without a learner the expert acts (a
    demonstration, with the manifest's noise); with one the learner acts and a noiseless
    shadow expert, put at the learner's commanded pose, gives the label (DAgger). With a
    ``gate`` only the steps where the learner's move is off the label by more than ``gate``
    times the demonstrations' spread (the model's action scale), or its grip differs, are
    recorded, and there the expert's move is the one made (HG-DAgger); ``interventions``
    counts them out of ``steps``."""

    def __init__(self, scene: Scene, seed: int, spec: ObservationSpec, learner: _Learner | None = None,
                 gate: float | None = None):
        self.expert = make_controller(scene, seed) if learner is None else ArmController(scene, seed, noise=0.0)
        self.learner, self.gate = learner, gate
        self.resync = RESYNC
        self.observer = learner.observer if learner else Observer(scene, spec)
        self.frames, self.proprio, self.act = [], [], []
        self.steps = self.interventions = 0

    def reset(self, data: mujoco.MjData) -> None:
        self.expert.reset(data)
        if self.learner:
            self.learner.reset(data)

    def action_size(self) -> int:
        return self.expert.action_size()

    def step(self, data: mujoco.MjData) -> np.ndarray:
        acting = self.learner.arm if self.learner else self.expert
        frames, state = self.observer.frames(data), proprio(data, acting)
        if self.learner is None:
            pos, yaw = self.expert.target_pos.copy(), self.expert.target_yaw
            action = self.expert.step(data)
            self._record(frames, state, [*(self.expert.target_pos - pos), self.expert.target_yaw - yaw, self.expert.grip])
            return action
        e, a = self.expert, self.learner.arm
        e.target_pos, e.target_yaw, e.grip = a.target_pos.copy(), a.target_yaw, a.grip
        if self.resync:
            e.resync(data)
        delta, dyaw, grip = e.plan(data)
        label = np.array([*delta, dyaw, grip], np.float32)
        move = self.learner.act(frames, state)
        self.steps += 1
        if self.gate is not None and not self._off(move, label):
            return self.learner.apply(data, move)  # the learner's own move stands, unlabelled
        self._record(frames, state, label.tolist())
        if self.gate is None:
            return self.learner.apply(data, move)
        self.interventions += 1
        return self.learner.apply(data, label)  # the expert takes over this step

    def _off(self, move: np.ndarray, label: np.ndarray) -> bool:
        """Whether the learner's move is off the expert's by more than ``gate`` times the
        demonstrations' spread of a move value, or sets the grip otherwise."""
        scale = self.learner.model.act_std.detach().cpu().numpy()[:4]
        return bool(np.max(np.abs(move[:4] - label[:4]) / scale) > self.gate or (move[4] >= 0.5) != (label[4] >= 0.5))

    def _record(self, frames: np.ndarray, state: np.ndarray, label: list) -> None:
        self.frames.append(frames)
        self.proprio.append(state)
        self.act.append(label)

    def close(self) -> None:
        self.observer.close()


def collect(manifest: ScenarioManifest, seeds: Sequence[int], spec: ObservationSpec,
            learner: "VisionPolicy | None" = None, round_: int = 0, config: SimConfig = SimConfig(),
            successes_only: bool | None = None, gate: float | None = None,
            counts: dict[str, int] | None = None) -> VisionDemonstrations:
    """The expert's demonstrations on ``seeds`` (its failures left out), or with ``learner`` a
    DAgger round: the learner's episodes, every step labelled by the expert, or with ``gate``
    the steps where the expert took over (failures kept: they are where the labels teach
    most). ``counts`` (if given) gains the round's ``steps`` and ``interventions``. The
    episodes' videos are not recorded; the policy's cameras are rendered at the manifest's
    fps, as in evaluation."""
    require_arm(manifest)
    keep_failures = learner is not None if successes_only is None else not successes_only
    frames, state, act, index, outcomes = [], [], [], [], []
    for k, seed in enumerate(seeds):
        made: list[_Recorder] = []

        def factory(scene: Scene, s: int) -> _Recorder:
            inner = _Learner(learner.model, learner.spec, scene, s) if learner else None
            made.append(_Recorder(scene, s, spec, inner, gate))
            return made[-1]

        ep = rollout(manifest, seed, config, controller=factory, record=())
        outcomes.append(bool(ep.success))
        rec = made[0]
        if counts is not None:
            counts["steps"] = counts.get("steps", 0) + rec.steps
            counts["interventions"] = counts.get("interventions", 0) + rec.interventions
        if ep.success or keep_failures:
            frames += rec.frames
            state += rec.proprio
            act += rec.act
            index += [k] * len(rec.frames)
    if not frames and learner is not None and gate is not None:
        size = (len(spec.cameras), 3, spec.image_size, spec.image_size)  # the expert never took over
        return VisionDemonstrations(frames=np.zeros((0, *size), np.uint8),
                                    proprio=np.zeros((0, learner.model.config.proprio_size), np.float32),
                                    act=np.zeros((0, 5), np.float32), episode=np.zeros(0, np.int64),
                                    round=np.zeros(0, np.int64), seeds=tuple(seeds), successes=tuple(outcomes))
    if not frames:
        raise ValueError(f"manifest {manifest.name}: no successful demonstrations on seeds {list(seeds)}")
    return VisionDemonstrations(frames=np.stack(frames), proprio=np.asarray(state, np.float32),
                                act=np.asarray(act, np.float32), episode=np.asarray(index, np.int64),
                                round=np.full(len(frames), round_, np.int64), seeds=tuple(seeds),
                                successes=tuple(outcomes))


class VisionPolicy(Policy):
    def __init__(self, model: VisionPolicyNet, spec: ObservationSpec, meta: dict[str, Any] | None = None,
                 source: str | None = None):
        self.model, self.spec, self.meta, self.source = model.eval(), spec, meta or {}, source

    @classmethod
    def from_checkpoint(cls, folder: Path | str) -> "VisionPolicy":
        from tasks.policy.vision_train import WEIGHTS_FILE, load_checkpoint

        model, spec, meta = load_checkpoint(Path(folder))
        digest = hashlib.sha256((Path(folder) / WEIGHTS_FILE).read_bytes()).hexdigest()
        return cls(model, spec, {**meta, "weights_sha256": digest}, str(folder))

    @property
    def contract(self) -> PanelContract | None:
        return PanelContract.model_validate(self.meta["contract"]) if "contract" in self.meta else None

    @property
    def name(self) -> str:
        return f"vision:{(self.meta.get('checkpoint_id') or self.meta.get('weights_sha256') or 'memory')[:12]}"

    def controller(self, scene: Scene, seed: int) -> _Learner:
        return _Learner(self.model, self.spec, scene, seed)

    def describe(self) -> dict[str, Any]:
        digest = {k: self.meta.get(k) for k in ("checkpoint_id", "manifest_hash", "contract_hash", "weights_sha256")}
        return {"name": self.name, "kind": "vision", "observe": list(self.spec.cameras),
                "image_size": self.spec.image_size, **digest}

