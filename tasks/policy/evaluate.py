"""Evaluate policies on a panel: ground truth from the simulator, a verdict from frames, tables.

`run_episode` rolls a policy out on one variant and seed and judges it twice: the simulator's
verdict (the manifest's evaluation target, from state) and, when frames are rendered, the
frame detector's on the simulator's own render (`tasks.panels.detect`), which calibrates the
detector that judges world-model rollouts. `world_outcome` adds the world model's verdicts:
open loop (the episode's actions replayed) and closed loop (the policy drives the world model,
`tasks.policy.world_env`). `success_table` and `spearman` summarise.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import stats

from schemas.manifest import ScenarioManifest
from tasks.panels.detect import judge_frames
from tasks.panels.world import WorldModelRequest, world_model_rollout, world_text
from tasks.policy.base import Policy
from tasks.policy.world_env import closed_loop_verdict
from tasks.sim.episode import rollout
from tasks.sim.scene import SimConfig


@dataclass(frozen=True)
class EpisodeOutcome:
    cell: str
    seed: int
    success: bool
    reason: str
    detector: bool | None = None  # the frame detector on the simulator's render; None: undecided / not run
    detector_reason: str | None = None
    world: bool | None = None  # the frame detector on the world model's rollout; None: no world model / undecided
    world_reason: str | None = None
    world_sure: float | None = None  # share of sampled rollouts that agree with the verdict (None: greedy, one)
    closed: bool | None = None  # the frame detector on the policy's closed loop in the world model
    closed_reason: str | None = None  # None: no closed loop was run

    def as_dict(self) -> dict:
        """Without the closed-loop fields when none was run, so an evaluation's body is what it
        was before closed loops existed."""
        out = dict(self.__dict__)
        if self.closed_reason is None:
            del out["closed"], out["closed_reason"]
        return out


@dataclass(frozen=True)
class Rollout:
    """An outcome, plus what a world-model rollout of the same episode needs."""

    outcome: EpisodeOutcome
    context: np.ndarray | None  # the first frame of `camera`, when rendered
    actions: np.ndarray | None
    package_start: np.ndarray
    control_hz: float


def run_episode(variant: ScenarioManifest, cell: str, seed: int, policy: Policy, camera: str | None,
                config: SimConfig = SimConfig()) -> Rollout:
    """One episode of ``policy``; with ``camera``, that camera's frames are recorded and judged
    too, else no video is recorded (the policy's own cameras are rendered at their fps either way)."""
    ep = rollout(variant, seed, config, controller=policy.controller, record=(camera,) if camera else ())
    verdict, context = None, None
    if camera:
        frames = ep.frames[camera]
        cam = next(c for c in variant.cameras if c.name == camera)
        verdict = judge_frames(frames, cam, variant.evaluation, ep.object_pose[0, 0, :3])
        context = frames[:1].copy()
    outcome = EpisodeOutcome(cell=cell, seed=seed, success=bool(ep.success), reason=ep.reason,
                             detector=None if verdict is None else verdict.success,
                             detector_reason=None if verdict is None else verdict.reason)
    return Rollout(outcome, context, ep.action.copy(), ep.object_pose[0, 0, :3].copy(), ep.control_hz)


def rate(values: Sequence[bool | None]) -> float | None:
    """Share of True among decided values; None when none is decided."""
    decided = [v for v in values if v is not None]
    return sum(decided) / len(decided) if decided else None


def success_table(outcomes: Sequence[EpisodeOutcome], cells: Sequence[str]) -> list[dict]:
    """Per cell (in panel order) then 'all': episodes, simulator, detector and world-model rates
    (open loop; ``closed`` too when closed loops were run)."""
    rows = []
    closed = any(o.closed_reason is not None for o in outcomes)
    for cell in [*cells, "all"]:
        mine = [o for o in outcomes if cell == "all" or o.cell == cell]
        sure = [o.world_sure for o in mine if o.world_sure is not None]
        rows.append({"cell": cell, "episodes": len(mine), "sim": rate([o.success for o in mine]),
                     "detector": rate([o.detector for o in mine]), "world": rate([o.world for o in mine]),
                     "world_sure": float(np.mean(sure)) if sure else None,
                     **({"closed": rate([o.closed for o in mine])} if closed else {})})
    return rows


def agreement(outcomes: Sequence[dict], column: str) -> dict:
    """How often ``column``'s verdict ('detector' or 'world') matches the simulator's, episode by
    episode: decided, agree, and agreement on the simulator's successes and on its failures
    apart, since a judge that always says success agrees as often as the policies succeed.
    ``balanced``: the mean of the two (None unless both kinds were decided)."""
    decided = [o for o in outcomes if o.get(column) is not None]
    hits = [o for o in decided if o["success"]]
    misses = [o for o in decided if not o["success"]]
    on_hits = sum(bool(o[column]) for o in hits)
    on_misses = sum(not o[column] for o in misses)
    balanced = (on_hits / len(hits) + on_misses / len(misses)) / 2 if hits and misses else None
    return {"episodes": len(outcomes), "decided": len(decided), "agree": on_hits + on_misses,
            "successes": len(hits), "successes_agree": on_hits, "failures": len(misses),
            "failures_agree": on_misses, "balanced": balanced}


def spearman(a: Sequence[float | None], b: Sequence[float | None]) -> float | None:
    """Spearman's rank correlation over the pairs where both are known (ties share ranks);
    None with fewer than 2 pairs or when either side is constant (it is undefined then)."""
    pairs = [(x, y) for x, y in zip(a, b) if x is not None and y is not None]
    if len(pairs) < 2:
        return None
    x, y = np.array(pairs, float).T
    if np.ptp(x) == 0 or np.ptp(y) == 0:
        return None
    value = float(stats.spearmanr(x, y).statistic)
    return None if math.isnan(value) else value


def world_verdict(world_model: str, variant: ScenarioManifest, camera: str, done: Rollout,
                  root: Path, device: str | None = None) -> tuple[bool | None, str]:
    """The world model rolls the policy's actions out from the episode's first frame; the
    frame detector judges what it generates (nothing generated here is written, so the face
    guard has nothing to guard)."""
    cam = next(c for c in variant.cameras if c.name == camera)
    n_frames = int(variant.horizon_s * cam.fps + 1e-9)
    request = WorldModelRequest(camera=camera, context=done.context, actions=done.actions,
                                control_hz=done.control_hz, fps=cam.fps, frames=n_frames, text=world_text(variant))
    generated = world_model_rollout(world_model, request, root, device=device)
    verdict = judge_frames(generated, cam, variant.evaluation, done.package_start, reference=done.context[0])
    return verdict.success, verdict.reason


@dataclass(frozen=True)
class WorldJudgement:
    """The world model's verdict on one episode and how sure it is.

    ``votes``: the detector's verdict on each sampled rollout (None: undecided); ``sure``: the
    share of all samples whose verdict is the majority's (None for one greedy rollout). Below
    ``min_sure`` the judge says undecided (verdict None) rather than guess."""

    verdict: bool | None
    reason: str
    sure: float | None
    votes: tuple[bool | None, ...]


def world_judgement(world_model: str, variant: ScenarioManifest, camera: str, done: Rollout, root: Path,
                    samples: int = 1, temperature: float = 1.0, min_sure: float = 0.75,
                    device: str | None = None) -> WorldJudgement:
    """``samples`` = 1: one greedy rollout (``world_verdict``). More: that many rollouts sampled at
    ``temperature`` (seeds 0..samples-1, so a re-run judges the same), each judged by the frame
    detector; the verdict is the majority of the decided ones when at least ``min_sure`` of
    them agree, else undecided."""
    if samples <= 1:
        verdict, reason = world_verdict(world_model, variant, camera, done, root, device)
        return WorldJudgement(verdict, reason, None, (verdict,))
    cam = next(c for c in variant.cameras if c.name == camera)
    n_frames = int(variant.horizon_s * cam.fps + 1e-9)
    request = WorldModelRequest(camera=camera, context=done.context, actions=done.actions,
                                control_hz=done.control_hz, fps=cam.fps, frames=n_frames, text=world_text(variant))
    votes = []
    for seed in range(samples):
        generated = world_model_rollout(world_model, request, root, temperature=temperature, seed=seed,
                                        device=device)
        votes.append(judge_frames(generated, cam, variant.evaluation, done.package_start,
                                  reference=done.context[0]).success)
    decided = [v for v in votes if v is not None]
    if not decided:
        return WorldJudgement(None, f"undecided: the detector decided none of {samples} sampled rollouts", 0.0,
                              tuple(votes))
    yes = sum(decided)
    majority = yes * 2 >= len(decided)
    sure = (yes if majority else len(decided) - yes) / samples
    if sure < min_sure:
        return WorldJudgement(None, f"undecided: {yes} of {samples} sampled rollouts succeed "
                                    f"({len(decided)} decided; {min_sure:.0%} must agree)", sure, tuple(votes))
    return WorldJudgement(majority, f"{'success' if majority else 'failure'} in {yes if majority else len(decided) - yes}"
                                    f" of {samples} sampled rollouts", sure, tuple(votes))


def world_outcome(done: Rollout, variant: ScenarioManifest, policy: Policy, camera: str,
                  world_model: str, root: Path, samples: int = 1, closed: bool = False,
                  device: str | None = None) -> EpisodeOutcome:
    """The episode's outcome with the world model's verdicts: open loop from ``samples``
    rollouts (``world_judgement``), and with ``closed`` the policy's closed loop (greedy; a
    vision policy, `tasks.policy.world_env`)."""
    judged = world_judgement(world_model, variant, camera, done, root, samples, device=device)
    extra = {"world": judged.verdict, "world_reason": judged.reason, "world_sure": judged.sure}
    if closed:
        verdict, reason = closed_loop_verdict(world_model, variant, camera, done, policy, done.outcome.seed, root,
                                              device)
        extra.update(closed=verdict, closed_reason=reason)
    return EpisodeOutcome(**{**done.outcome.as_dict(), **extra})
