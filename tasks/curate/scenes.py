"""Streaming scene split: hard cuts from PySceneDetect, gradual transitions from frame statistics.

Frames arrive one at a time (``AnalysisFrame``s from ``decode.analysis_frames``). Hard cuts
come from a PySceneDetect 0.7 detector (AdaptiveDetector by default, taking RGB frames through
``detectors.py``) fed frame by frame, with FrameTimecodes built from the frames' timestamps.
Gradual transitions are found on per-frame statistics (mean luma, gradient energy, and a
blurred 64-px grey thumbnail).

The split is made of: ``scene_config.py`` (``SceneConfig``, the ``Scene`` span),
``splitter.py`` (``SceneSplitter``: frames in, final spans out, and where decoder
concealment or a gap of undecoded frames could fake or hide a cut), ``transitions.py`` (fades
and dissolves), ``cut_checks.py`` (what turns a detector cut into no cut, and a weak peak
into one), ``views.py`` (how alike two thumbnails are) and ``scene_rows.py`` (the rows kept per
frame and the spans cut from them). This module decodes a video and runs the split, and scores
boundaries for the benches.

Transition frames belong to no scene; they are reported as ``transition`` spans. Scenes
shorter than ``min_scene_s`` are reported as ``too_short``; scenes longer than
``max_scene_s`` are split into equal parts. A span is yielded once no later frame can change
it (about ``max_transition_s`` + 1 s later), so memory is bounded by the longest scene and
by ``2 x max_scene_s``: an open scene longer than that is cut into ``max_scene_s`` parts as
it goes.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Sequence
from pathlib import Path

import av
import numpy as np

from tasks.curate.decode import AnalysisConfig, AnalysisFrame, DecodeReport, analysis_frames
from tasks.curate.exact import ExactFrames
from tasks.curate.scene_config import Scene, SceneConfig, SpanKind
from tasks.curate.splitter import SceneSplitter
from tasks.curate.transitions import change_gap, find_transitions, frame_change
from tasks.video import DecodeError, SourceInfo, probe

__all__ = ["Scene", "SceneConfig", "SceneSplitter", "SpanKind", "boundaries", "change_gap", "cut_f1", "detect_scenes",
           "find_transitions", "frame_change", "scenes_of", "split_scenes"]


def split_scenes(frames: Iterable[AnalysisFrame], fps: float, config: SceneConfig = SceneConfig(),
                 keep_frames: bool = True,
                 exact: Callable[[list[int]], list[AnalysisFrame]] | None = None,
                 report: DecodeReport | None = None) -> Iterator[Scene]:
    """Spans in order (scenes, too_short and transition spans) from a stream of frames;
    ``exact`` decodes left-out frames on demand (see ``SceneSplitter``); ``report.smeared``
    gets the frames found smeared by concealment."""
    splitter = SceneSplitter(fps, config, keep_frames, exact)
    if report is not None:
        report.smeared = splitter.smeared
    for frame in frames:
        yield from splitter.push(frame)
    yield from splitter.finish()


def scenes_of(path: Path | str, config: SceneConfig = SceneConfig(), analysis: AnalysisConfig = AnalysisConfig(),
              report: DecodeReport | None = None, info: SourceInfo | None = None,
              keep_frames: bool = True) -> Iterator[Scene]:
    """Decode ``path`` once and yield its spans with their analysis frames."""
    info = info or probe(path)
    frames = analysis_frames(path, analysis, report, info)
    if not analysis.skip_unreferenced:
        try:
            yield from split_scenes(frames, info.fps, config, keep_frames, report=report)
        finally:
            frames.close()  # at once, also on an error: a decoder running ahead stops and lets go of the file
        return
    exact = ExactFrames(path, analysis, info)

    def refill(indices: list[int]) -> list[AnalysisFrame]:
        try:
            got = exact.get(indices)
        except (av.FFmpegError, DecodeError):
            return []
        return [AnalysisFrame(i, exact.time(i), got[i]) for i in sorted(got)]

    try:
        yield from split_scenes(frames, info.fps, config, keep_frames, refill, report)
    finally:
        frames.close()
        exact.close()


def detect_scenes(path: Path | str, config: SceneConfig = SceneConfig(), analysis: AnalysisConfig = AnalysisConfig(),
                  include_rejected: bool = False) -> list[Scene]:
    """Spans of ``path`` without frames (what ``worldline scenes VIDEO --json`` prints).

    Only kept scenes unless ``include_rejected`` (then also too_short and transition spans).
    """
    spans = scenes_of(path, config, analysis, keep_frames=False)
    return [s for s in spans if include_rejected or s.kind == "scene"]


def boundaries(spans: Sequence[Scene]) -> list[int | tuple[int, int]]:
    """Predicted boundaries for ``cut_f1``: the first frame after each cut, and each
    transition as (start, end). Splits of one long shot are not boundaries."""
    out: list[int | tuple[int, int]] = []
    for span in spans:
        if span.kind == "transition":
            out.append((span.start_frame, span.end_frame))
        elif span.cause == "cut":
            out.append(span.start_frame)
    return out


def cut_f1(predicted: Sequence[int | tuple[int, int]], truth_cuts: Sequence[int],
           truth_transitions: Sequence[tuple[int, int]], tolerance: int = 2) -> dict[str, float]:
    """Precision, recall and F1 of predicted boundaries against ground truth.

    A predicted cut c or transition (a, b) hits a true cut t when t is within ``tolerance``
    frames of [c, c] or [a, b]; it hits a true transition (s, e) when the two intervals,
    the true one widened by ``tolerance``, overlap. Matching is one to one, in order.
    """
    pred = sorted((int(p), int(p)) if isinstance(p, (int, np.integer)) else (int(p[0]), max(int(p[0]), int(p[1]) - 1))
                  for p in predicted)
    truth = sorted([(int(t), int(t)) for t in truth_cuts] + [(int(s), int(e) - 1) for s, e in truth_transitions])
    used = [False] * len(truth)
    hits = 0
    for a, b in pred:
        for j, (s, e) in enumerate(truth):
            if not used[j] and a <= e + tolerance and b >= s - tolerance:
                used[j] = True
                hits += 1
                break
    precision = hits / len(pred) if pred else 1.0
    recall = hits / len(truth) if truth else 1.0
    f1 = 2 * precision * recall / (precision + recall) if precision + recall else 0.0
    return {"precision": precision, "recall": recall, "f1": f1, "hits": hits,
            "predicted": len(pred), "truth": len(truth)}
