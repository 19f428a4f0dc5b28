"""Behaviour cloning from the scripted controller: collect, train, save, load, act.

Demonstrations are scripted episodes rolled out through the policy seam with a recorder in
the loop: at each control step, the features the scripted controller acts on
(`tasks.policy.features`) and the move it then commands (change of the commanded tcp pose,
yaw and grip, whatever the action space). The learned policy acts through the same
`ArmController.apply`, so it commands the arm exactly as the scripted controller does.
Checkpoints are safetensors plus a config JSON (`{"bc": BCConfig, "train": TrainConfig,
"contract": PanelContract, ...}`).
"""

from __future__ import annotations

import copy
import hashlib
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field, model_serializer
from scipy import special

import tasks.sim  # noqa: F401  (sets MUJOCO_GL before mujoco loads)
from models.bc_policy import BCConfig, BCPolicyNet, preset
from schemas.manifest import ScenarioManifest
from schemas.panel import PanelContract, contract_hash, panel_contract
from tasks.checkpoint_files import (WEIGHTS_FILE, CheckpointError, load_weights, model_config, read_config,
                                     write_checkpoint)
from tasks.policy.base import Policy
from tasks.policy.fit import fit
from tasks.policy.features import FEATURES_VERSION, arm_features, obs_size
from tasks.sim.control import MAX_STEP, MAX_YAW_STEP, ArmController, make_controller
from tasks.sim.episode import rollout
from tasks.sim.scene import Scene, SimConfig


class TrainConfig(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")

    preset: str = "tiny"
    steps: int = Field(3000, ge=1, le=1_000_000)
    batch_size: int = Field(256, ge=1, le=65536)
    lr: float = Field(1e-3, gt=0, le=1)
    seed: int = 0
    threads: int = Field(1, ge=1, le=64)
    # Vision policies only: each training frame shifted by up to this many pixels (its edge
    # rows repeated), a new draw every step (random-shift augmentation, as DrQ and RAD use for
    # control from pixels). 0: none. Not with a tokenizer encoder, whose features are cached.
    shift: int = Field(0, ge=0, le=16)

    @model_serializer(mode="wrap")
    def _shift_only_when_set(self, handler):
        # Left out at 0: the configs, checkpoint ids and stage keys made before it existed stay as they were.
        data = handler(self)
        if not self.shift:
            data.pop("shift", None)
        return data


@dataclass(frozen=True)
class Demonstrations:
    """obs N x obs_size float32, act N x 5 float32 [dx, dy, dz, dyaw, grip]; episode N (index
    into seeds); the seeds rolled out and which of them the scripted controller solved."""

    obs: np.ndarray
    act: np.ndarray
    episode: np.ndarray
    seeds: tuple[int, ...]
    successes: tuple[bool, ...]


def require_arm(manifest: ScenarioManifest) -> None:
    if manifest.embodiment.kind != "arm":
        raise ValueError(f"manifest {manifest.name}: behaviour cloning drives arms; "
                         f"embodiment {manifest.embodiment.kind!r} has no arm")


class _Recorder:
    """The scripted controller, recording what it sees and the move it commands each step."""

    def __init__(self, inner: ArmController):
        self.inner, self.obs, self.act = inner, [], []

    def reset(self, data: mujoco.MjData) -> None:
        self.inner.reset(data)

    def action_size(self) -> int:
        return self.inner.action_size()

    def step(self, data: mujoco.MjData) -> np.ndarray:
        obs, pos, yaw = arm_features(data, self.inner), self.inner.target_pos.copy(), self.inner.target_yaw
        action = self.inner.step(data)
        self.obs.append(obs)
        self.act.append([*(self.inner.target_pos - pos), self.inner.target_yaw - yaw, self.inner.grip])
        return action


def collect(manifest: ScenarioManifest, seeds: Sequence[int], noise: float | None = None,
            successes_only: bool = True, config: SimConfig = SimConfig()) -> Demonstrations:
    """Scripted episodes of ``seeds`` (no episode videos recorded); failed ones are left out by default."""
    require_arm(manifest)
    obs, act, index, outcomes = [], [], [], []
    for k, seed in enumerate(seeds):
        made: list[_Recorder] = []

        def factory(scene: Scene, s: int) -> _Recorder:
            made.append(_Recorder(make_controller(scene, s, noise=noise)))
            return made[-1]

        ep = rollout(manifest, seed, config, controller=factory, record=())
        outcomes.append(bool(ep.success))
        if ep.success or not successes_only:
            rec = made[0]
            obs += rec.obs
            act += rec.act
            index += [k] * len(rec.obs)
    if not obs:
        raise ValueError(f"manifest {manifest.name}: no successful demonstrations on seeds {list(seeds)}")
    return Demonstrations(obs=np.asarray(obs, np.float32), act=np.asarray(act, np.float32),
                          episode=np.asarray(index, np.int64), seeds=tuple(seeds), successes=tuple(outcomes))


def train_bc(demos: Demonstrations, config: TrainConfig = TrainConfig(),
             log: Callable[[dict], None] | None = None,
             start: BCPolicyNet | None = None, device: str | torch.device = "cpu") -> tuple[BCPolicyNet, list[dict]]:
    """Seeded: the same demonstrations and config give the same weights. MSE on standardised
    actions; history rows every 1/20 of the run: step, loss, seconds. With ``start``, training
    continues from a copy of it (post-training) and keeps its normalisation statistics, so the
    network's inputs and outputs keep the meaning its weights were trained on. ``device``: where
    it trains (minibatch indices drawn on the CPU); the model is returned there."""
    torch.manual_seed(config.seed)
    threads = torch.get_num_threads()
    torch.set_num_threads(config.threads)
    try:
        obs, act = torch.from_numpy(demos.obs), torch.from_numpy(demos.act)
        if start is not None:
            model = copy.deepcopy(start)
        else:
            model = BCPolicyNet(preset(config.preset, obs.shape[1]))
            model.set_statistics(obs, act)
        model.to(device)
        obs = obs.to(device)
        target = (act.to(device) - model.act_mean) / model.act_std
        history = fit(model, lambda b: torch.nn.functional.mse_loss(model.forward_normalised(obs[b.to(device)]),
                                                                    target[b.to(device)]), obs.shape[0], config, log)
        return model.eval(), history
    finally:
        torch.set_num_threads(threads)


def save_checkpoint(model: BCPolicyNet, folder: Path, manifest: ScenarioManifest, train: TrainConfig,
                    extra: dict | None = None) -> tuple[Path, Path]:
    """Weights (safetensors) and config JSON, each written atomically."""
    contract = panel_contract(manifest)
    return write_checkpoint(model, folder, "bc", {
        "train": train.model_dump(mode="json"), "features_version": FEATURES_VERSION,
        "manifest_hash": manifest.sha256, "contract": contract.model_dump(mode="json"),
        "contract_hash": contract_hash(contract), **(extra or {})})


def load_checkpoint(folder: Path) -> tuple[BCPolicyNet, dict[str, Any]]:
    meta = read_config(folder, "bc", "behaviour-cloning checkpoint")
    if meta.get("features_version") != FEATURES_VERSION:
        raise CheckpointError(f"{folder}: features version {meta.get('features_version')} is not {FEATURES_VERSION}")
    return load_weights(BCPolicyNet(model_config(BCConfig, meta, "bc", folder)), folder), meta


class BCController:
    """Acts like the scripted controller's actuation half, with the network choosing the move."""

    def __init__(self, model: BCPolicyNet, scene: Scene, seed: int):
        self.arm = ArmController(scene, seed, noise=0.0)
        if obs_size(self.arm) != model.config.obs_size:
            raise ValueError(f"policy expects {model.config.obs_size} observations; this scene gives {obs_size(self.arm)}")
        # One small matrix product per control step: in numpy, because torch's thread pool
        # costs more than the product (4x slower per episode on a busy 2-core machine).
        state = {k: v.detach().cpu().numpy().astype(np.float64) for k, v in model.state_dict().items()}
        self.layers = [(state[f"net.{i}.weight"].T, state[f"net.{i}.bias"])
                       for i, layer in enumerate(model.net) if isinstance(layer, torch.nn.Linear)]
        self.obs_mean, self.obs_std = state["obs_mean"], state["obs_std"]
        self.act_mean, self.act_std = state["act_mean"], state["act_std"]

    def reset(self, data: mujoco.MjData) -> None:
        self.arm.reset(data)

    def action_size(self) -> int:
        return self.arm.action_size()

    def act(self, obs: np.ndarray) -> np.ndarray:
        """The network's output for one observation: [dx, dy, dz, dyaw, grip]."""
        x = (obs.astype(np.float64) - self.obs_mean) / self.obs_std
        for k, (weight, bias) in enumerate(self.layers):
            x = x @ weight + bias
            if k < len(self.layers) - 1:
                x = 0.5 * x * (1.0 + special.erf(x / math.sqrt(2.0)))  # exact GELU, as nn.GELU()
        return x * self.act_std + self.act_mean

    def step(self, data: mujoco.MjData) -> np.ndarray:
        out = self.act(arm_features(data, self.arm))
        delta, dyaw, grip = out[:3], float(out[3]), float(out[4])
        norm = float(np.linalg.norm(delta))
        if norm > MAX_STEP:  # the scripted controller's speed limit binds the policy too
            delta = delta * (MAX_STEP / norm)
        return self.arm.apply(data, delta, float(np.clip(dyaw, -MAX_YAW_STEP, MAX_YAW_STEP)), 1.0 if grip >= 0.5 else 0.0)


class BCPolicy(Policy):
    def __init__(self, model: BCPolicyNet, meta: dict[str, Any] | None = None, source: str | None = None):
        self.model, self.meta, self.source = model.eval(), meta or {}, source

    @classmethod
    def from_checkpoint(cls, folder: Path | str) -> "BCPolicy":
        model, meta = load_checkpoint(Path(folder))
        digest = hashlib.sha256((Path(folder) / WEIGHTS_FILE).read_bytes()).hexdigest()
        return cls(model, {**meta, "weights_sha256": digest}, str(folder))

    @property
    def contract(self) -> PanelContract | None:
        return PanelContract.model_validate(self.meta["contract"]) if "contract" in self.meta else None

    @property
    def name(self) -> str:
        return f"bc:{(self.meta.get('checkpoint_id') or self.meta.get('weights_sha256') or 'memory')[:12]}"

    def controller(self, scene: Scene, seed: int) -> BCController:
        return BCController(self.model, scene, seed)

    def describe(self) -> dict[str, Any]:
        digest = {k: self.meta.get(k) for k in ("checkpoint_id", "manifest_hash", "contract_hash", "weights_sha256")}
        return {"name": self.name, "kind": "bc", **digest}


def success_rate(manifest: ScenarioManifest, policy: Policy, seeds: Sequence[int],
                 config: SimConfig = SimConfig()) -> tuple[float, list[tuple[int, bool, str]]]:
    """Ground-truth success of ``policy`` on ``seeds`` (no episode videos recorded; a vision
    policy still sees its cameras at their fps): rate and (seed, ok, reason)."""
    outcomes = []
    for seed in seeds:
        ep = rollout(manifest, seed, config, controller=policy.controller, record=())
        outcomes.append((seed, bool(ep.success), ep.reason))
    return sum(ok for _, ok, _ in outcomes) / max(1, len(outcomes)), outcomes
