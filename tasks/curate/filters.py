"""Run the curation filters (motion, quality, overlay text, video type) and score them.

``run_filters`` runs every enabled filter's ``judge`` (even after one rejects, so a rejected
clip still carries every score), merges scores and tags, and reports the first rejecting
stage. ``precision_recall`` and ``confusion`` score a filter against corpus labels. The
contract and the shared pixel helpers live in ``filter_base.py``, which the filter modules
import; this module imports them, never the other way round.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Sequence

import numpy as np
from pydantic import BaseModel, ConfigDict

from tasks.curate.filter_base import FilterConfig, Verdict, check_frames, one_scene
from tasks.curate.motion import MotionConfig
from tasks.curate.overlay_text import OverlayTextConfig
from tasks.curate.quality import QualityConfig
from tasks.curate.video_type import VideoTypeConfig


def run_filters(
    frames: np.ndarray, times: np.ndarray, configs: Sequence[FilterConfig] | None = None
) -> tuple[Verdict, list[Verdict]]:
    """Run each enabled filter's ``judge`` in order; return (merged verdict, per-filter verdicts).

    Every filter runs even after one rejects. The merged verdict keeps the clip only if every
    filter keeps it; its reason and stage are those of the first rejecting filter; scores and
    tags are the union over filters (a score name used by two filters is an error).
    """
    check_frames(frames, times)
    configs = default_configs() if configs is None else tuple(configs)
    verdicts: list[Verdict] = []
    with one_scene():  # the video-type rules judge the scene once for every filter that asks
        for config in configs:
            if not config.enabled:
                continue
            verdict = config.judge(frames, times)
            verdicts.append(verdict.model_copy(update={"stage": config.stage}))
    scores: dict[str, float] = {}
    tags: list[str] = []
    for verdict in verdicts:
        clash = scores.keys() & verdict.scores.keys()
        if clash:
            raise ValueError(f"filter {verdict.stage}: score names {sorted(clash)} already used")
        scores.update(verdict.scores)
        tags.extend(t for t in verdict.tags if t not in tags)
    first = next((v for v in verdicts if not v.keep), None)
    merged = Verdict(
        keep=first is None,
        reason=None if first is None else first.reason,
        stage=None if first is None else first.stage,
        scores=scores,
        tags=tuple(tags),
    )
    return merged, verdicts


def default_configs() -> tuple[FilterConfig, ...]:
    """The four filters with their default thresholds, in pipeline order."""
    return MotionConfig(), QualityConfig(), OverlayTextConfig(), VideoTypeConfig()


class PrecisionRecall(BaseModel):
    """A filter's score on its own defect classes; precision/recall are NaN when undefined."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    precision: float
    recall: float
    tp: int
    fp: int
    fn: int
    tn: int


def precision_recall(
    predicted: Sequence[str | None], labels: Sequence[str | None], classes: set[str]
) -> PrecisionRecall:
    """Score one filter: ``predicted[i]`` is its reject reason for segment i (None = kept),
    ``labels[i]`` the segment's truth label (None = clean); ``classes`` is the filter's own
    label set. Precision = of rejected segments, the fraction labelled in ``classes``;
    recall = of segments labelled in ``classes``, the fraction rejected.
    """
    if len(predicted) != len(labels):
        raise ValueError(f"precision_recall: {len(predicted)} predictions for {len(labels)} labels")
    tp = fp = fn = tn = 0
    for p, y in zip(predicted, labels):
        rejected, positive = p is not None, y in classes
        tp += rejected and positive
        fp += rejected and not positive
        fn += positive and not rejected
        tn += not rejected and not positive
    return PrecisionRecall(
        precision=tp / (tp + fp) if tp + fp else math.nan,
        recall=tp / (tp + fn) if tp + fn else math.nan,
        tp=tp, fp=fp, fn=fn, tn=tn,
    )


def confusion(predicted: Sequence[str | None], labels: Sequence[str | None]) -> dict[tuple[str, str], int]:
    """Counts of (truth label or "clean", predicted reason or "keep") pairs, for bench tables."""
    return dict(Counter((y or "clean", p or "keep") for p, y in zip(predicted, labels, strict=True)))
