"""The `Policy` interface and the scripted policy.

A policy is a controller factory: `policy.controller(scene, seed)` returns what
`tasks.sim.episode.Simulation` steps each control period (reset, step, action_size), so
`rollout(manifest, seed, controller=policy.controller)` runs it. Without a controller,
`rollout` uses the scripted one: `ScriptedPolicy()` (the manifest's noise) reproduces that
bit for bit (tested).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any

from tasks.sim.control import make_controller
from tasks.sim.episode import Controller
from tasks.sim.scene import Scene


class Policy(ABC):
    """Something that drives the robot in the simulator."""

    @property
    @abstractmethod
    def name(self) -> str:
        """Short and stable, e.g. ``scripted@0.02``; names a column of the evaluation table."""

    @abstractmethod
    def controller(self, scene: Scene, seed: int) -> Controller:
        """A fresh controller for one episode of ``scene`` (seeded by ``seed``)."""

    def describe(self) -> dict[str, Any]:
        """What identifies the policy in lineage (hashed into evaluation ids)."""
        return {"name": self.name}


class ScriptedPolicy(Policy):
    """The scripted controller with privileged state at a given noise (None: the manifest's)."""

    def __init__(self, noise: float | None = None):
        if noise is not None and not 0.0 <= noise <= 1.0:
            raise ValueError(f"scripted noise must be in [0, 1], not {noise}")
        self.noise = noise

    @property
    def name(self) -> str:
        return "scripted" if self.noise is None else f"scripted@{self.noise:g}"

    def controller(self, scene: Scene, seed: int) -> Controller:
        return make_controller(scene, seed, noise=self.noise)

    def describe(self) -> dict[str, Any]:
        return {"name": self.name, "kind": "scripted", "noise": self.noise}
