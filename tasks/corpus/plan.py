"""Plan a corpus: segment spans, labels, contents, duplicates and transitions. No pixels here.

A plan depends only on (seed, frame counts, fps, config, simulator manifests), never on the
frame size, so the same seed gives the same truth at every resolution.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict

from schemas.manifest import ScenarioManifest
from tasks.corpus import nonphysical, procedural
from tasks.corpus.config import DEFECT_LABELS, LOOKALIKE_PAIRS, NONPHYSICAL, TRANSFORMS, CorpusConfig


class Frozen(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")


class ContentSpec(Frozen):
    """The underlying footage of a segment; equal specs render equal frames."""

    content_id: str
    kind: Literal["procedural", "sim", "animation", "slides", "test_pattern"]
    seed: int
    scene: str
    manifest: int | None = None  # index into the run's simulator manifests
    camera: str | None = None


class DuplicateRef(Frozen):
    video: int
    segment: int
    transform: Literal["exact", "reencode", "rescale", "crop", "brightness"]
    seed: int


class SegmentPlan(Frozen):
    start: int
    end: int  # exclusive
    label: str | None
    content: ContentSpec
    defect_seed: int
    duplicate_of: DuplicateRef | None = None

    @property
    def n_frames(self) -> int:
        return self.end - self.start


class TransitionPlan(Frozen):
    kind: Literal["fade", "dissolve"]
    start: int
    end: int


class VideoPlan(Frozen):
    index: int
    seed: int
    fps: float
    n_frames: int
    segments: tuple[SegmentPlan, ...]
    transitions: tuple[TransitionPlan, ...]

    @property
    def cuts(self) -> list[int]:
        """First frame of every segment that follows its neighbour with no transition."""
        gradual = {t.end for t in self.transitions}
        return [s.start for s in self.segments[1:] if s.start not in gradual]


NONPHYSICAL_KIND = {"nonphysical_animation": "animation", "nonphysical_slides": "slides",
                    "nonphysical_test_pattern": "test_pattern"}


def _sim_cameras(manifest: ScenarioManifest) -> list[str]:
    # A wrist camera swings with the arm; it is not the steady view clean footage needs.
    steady = [c.name for c in manifest.cameras if c.mount != "wrist"]
    return steady or [c.name for c in manifest.cameras]


class _Planner:
    def __init__(self, seed: int, fps: float, config: CorpusConfig, sims: Sequence[ScenarioManifest],
                 sim_fraction: float):
        self.rng = np.random.default_rng([seed, 0xC0])
        self.seed, self.fps, self.cfg, self.sims, self.sim_fraction = seed, fps, config, list(sims), sim_fraction
        self.bag: list[str | None] = []
        self.previous: str | None = None
        self.n_contents = 0
        self.originals: list[tuple[int, int, SegmentPlan]] = []  # clean, non-duplicate segments so far
        self.min_len = math.ceil(config.min_segment_s * fps)
        self.max_len = max(self.min_len, math.floor(config.max_segment_s * fps))
        scale = fps / 30.0
        low, high = config.transition_frames
        self.t_low, self.t_high = max(2, round(low * scale)), max(2, round(high * scale))
        if self.max_len < 2 * self.min_len + self.t_high:
            raise ValueError(f"max_segment_s {config.max_segment_s} must exceed two minimum segments and a transition")

    def _seed(self) -> int:
        return int(self.rng.integers(0, 2**31 - 1))

    def _label(self) -> str | None:
        def allowed(label: str | None) -> bool:
            if label is None or self.previous is None:
                return True
            return label != self.previous and frozenset({label, self.previous}) not in LOOKALIKE_PAIRS

        while not any(allowed(x) for x in self.bag):
            block: list[str | None] = [None] * self.cfg.clean_per_block + list(DEFECT_LABELS)
            self.bag.extend(block)
        choices = [i for i, x in enumerate(self.bag) if allowed(x)]
        label = self.bag.pop(choices[int(self.rng.integers(len(choices)))])
        self.previous = label
        return label

    def _length(self, remaining: int, cap: int) -> int:
        spare = self.t_high + self.min_len  # what must stay free for a transition and one more segment
        if remaining <= cap and (remaining < 2 * self.min_len + self.t_high or self.rng.random() < 0.3):
            return remaining
        high = min(cap, remaining - spare)
        if high < self.min_len:
            return remaining  # only reachable when cap is above remaining; kept for safety
        typical = min(high, max(self.min_len, round(self.cfg.typical_segment_s * self.fps)))
        if self.rng.random() < 0.9 or typical >= high:
            length = math.exp(self.rng.uniform(math.log(self.min_len), math.log(typical + 1)))
        else:
            length = self.rng.uniform(typical, high + 1)
        return int(min(high, max(self.min_len, math.floor(length))))

    def _content(self, label: str | None) -> ContentSpec:
        cid = f"c{self.n_contents:04d}"
        self.n_contents += 1
        seed = self._seed()
        if label in NONPHYSICAL:
            kind = NONPHYSICAL_KIND[label]
            return ContentSpec(content_id=cid, kind=kind, seed=seed, scene=nonphysical.describe(kind, seed))
        if self.sims and self.rng.random() < self.sim_fraction:
            index = int(self.rng.integers(len(self.sims)))
            manifest = self.sims[index]
            cameras = _sim_cameras(manifest)
            camera = cameras[int(self.rng.integers(len(cameras)))]
            return ContentSpec(content_id=cid, kind="sim", seed=seed, manifest=index, camera=camera,
                               scene=f"sim {manifest.name} {manifest.task.kind} {camera}")
        return ContentSpec(content_id=cid, kind="procedural", seed=seed, scene=procedural.describe(seed))

    def _duplicate(self, video: int, segment: int, remaining: int) -> tuple[SegmentPlan, DuplicateRef] | None:
        spare = self.t_high + self.min_len
        fits = [(v, s, p) for v, s, p in self.originals
                if (p.n_frames == remaining or p.n_frames <= remaining - spare) and not (v == video and s == segment - 1)]
        # Choose the pool first, so the first video (which has no other to copy) stays mostly unique.
        across = self.rng.random() < self.cfg.cross_video_fraction
        pool = [f for f in fits if (f[0] != video) == across]
        if not pool:
            return None
        v, s, original = pool[int(self.rng.integers(len(pool)))]
        transform = TRANSFORMS[int(self.rng.integers(len(TRANSFORMS)))]
        return original, DuplicateRef(video=v, segment=s, transform=transform, seed=self._seed())

    def video(self, index: int, n_frames: int) -> VideoPlan:
        if n_frames < self.min_len:
            raise ValueError(f"video {index}: {n_frames} frames is shorter than one {self.cfg.min_segment_s} s segment")
        segments: list[SegmentPlan] = []
        transitions: list[TransitionPlan] = []
        pos = 0
        while True:
            remaining = n_frames - pos
            label = self._label()
            dup = None
            if label is None and self.rng.random() < self.cfg.duplicate_fraction:
                dup = self._duplicate(index, len(segments), remaining)
            if dup is not None:
                original, ref = dup
                content, length = original.content, original.n_frames
            else:
                content = self._content(label)
                cap = self.max_len
                if content.kind == "sim":
                    cap = max(self.min_len, min(cap, math.floor(self.cfg.sim_max_segment_s * self.fps)))
                length = self._length(remaining, cap)
                if length > cap:  # the tail is too long for a simulator take: make it procedural
                    content = content.model_copy(update={"kind": "procedural", "manifest": None, "camera": None,
                                                         "scene": procedural.describe(content.seed)})
                ref = None
            seg = SegmentPlan(start=pos, end=pos + length, label=label, content=content,
                              defect_seed=self._seed(), duplicate_of=ref)
            if label is None and ref is None:
                self.originals.append((index, len(segments), seg))
            segments.append(seg)
            pos += length
            if pos == n_frames:
                break
            draw = self.rng.random()
            if draw < self.cfg.fade_probability + self.cfg.dissolve_probability:
                kind = "fade" if draw < self.cfg.fade_probability else "dissolve"
                length = int(self.rng.integers(self.t_low, self.t_high + 1))
                transitions.append(TransitionPlan(kind=kind, start=pos, end=pos + length))
                pos += length
        return VideoPlan(index=index, seed=self.seed, fps=self.fps, n_frames=n_frames,
                         segments=tuple(segments), transitions=tuple(transitions))


def plan_corpus(seed: int, frames_per_video: Sequence[int], fps: float, config: CorpusConfig,
                sims: Sequence[ScenarioManifest] = (), sim_fraction: float = 0.3) -> list[VideoPlan]:
    """One plan per video; duplicates may point at any earlier video of the same corpus."""
    if not 0.0 <= sim_fraction <= 1.0:
        raise ValueError(f"sim_fraction {sim_fraction} is outside [0, 1]")
    planner = _Planner(seed, fps, config, sims, sim_fraction)
    return [planner.video(i, n) for i, n in enumerate(frames_per_video)]
