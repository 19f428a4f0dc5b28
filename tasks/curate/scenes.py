"""Streaming scene split: hard cuts from PySceneDetect, gradual transitions from frame statistics.

Frames arrive one at a time (``AnalysisFrame``s from ``decode.analysis_frames``). Hard cuts
come from a PySceneDetect 0.7 detector (AdaptiveDetector by default, taking RGB frames through
``detectors.py``) fed frame by frame, with FrameTimecodes built from the frames' timestamps.
Gradual transitions are found on per-frame statistics (mean luma, gradient energy, and a
blurred 64-px grey thumbnail):

- a fade through black is a luma valley near black with monotone ramps either side
  (ThresholdDetector would give one cut mid-fade; the ramps are what must be excluded).
  A side that leaves black in one step of at least ``FADE_JUMP`` of its rise (a linear ramp
  of r frames climbs 1 / (r + 1) per step) is a hard cut into or out of black, not a ramp:
  a cut to black then a fade in is a cut, a too-short black span and a fade of the ramp
  frames; a fade out then a cut out of black is a fade, the black span and a cut;
- a dissolve is a span whose frames are well explained as blends (1-w) P + w Q of the
  frames P and Q either side, with w rising steadily. Candidates come from a dip of the
  gradient energy (a blend of unrelated shots is half as sharp mid-way) or from a peak of
  the change across a few frames. Camera motion leaves a large blend residual; a hard cut
  shows as a jump of w. Smooth real motion (handheld shake, a zoom, a head turning, auto-
  exposure) can still fit a blend on blurred thumbnails, so a candidate is also tested as
  motion: if its two ends are one view (correlation >= ``dissolve_same_view`` at the best
  shift of up to a tenth of the picture) and local motion plus a gain explains its middle
  frame about as well as the blend does (motion residual < ``dissolve_motion`` x blend
  residual, each of 4 x 4 blocks shifted on its own), it is motion, not a dissolve. A real
  dissolve's middle frame holds half of the other shot, which no shift of one end gives
  (ratio 2.4-21 on the corpus dissolves, 0.45-1.2 on the dev set's handheld false ones);
  two views of one place far apart still dissolve (ends unalike after a shift).

The analysis decode leaves out frames nothing predicts from (``skip_unreferenced``), which
stretches the detector's window and moves its ratio: on sintel.mp4 it lost three cuts a full
decode finds. Where the two decoded frames around such a gap differ by at least the
detector's own floor (``min_content_val``, measured with its HSV score), the frames between
them are decoded exactly (``exact.ExactFrames``) and pushed in order, and so are the gaps over
the next ``adaptive_window`` frames: every cut candidate is then scored on the frames a full
decode gives. Below that floor no cut can be hiding in the gap.

A detector cut where the view leaves and comes back is no cut: the frame after it is unlike the
frame before (best-shift correlation of the blurred thumbnails < ``cut_left_view``, the level of
unrelated pictures) while a frame within ``cut_return_s`` is that view again (>=
``cut_same_view``): a car or a hand passing right in front of the lens (caminandes.mp4 111:
0.46, then 0.97 two frames later; true cuts on the dev set never come back above 0.82). A
one-frame insert that only shares the layout (film leader cards, >= 0.86 across) stays a cut.
A detector cut whose two sides are one view moved (best-shift correlation >= ``cut_same_view``
at a shift of ``PAN_SHIFT`` px or more of the 64-px thumbnail) is a whip pan, not a cut
(armwrestle.mp4 206: 0.96 at 6 px); film leader cards match in place (shift 0-1 px).

A detector peak of ratio ``cut_weak_ratio`` (2) or more that stays under the threshold (3) is a
cut when the pictures either side are unrelated: best-shift correlation of the blurred
thumbnails below ``cut_unrelated`` (0.35), computed inside letterbox and pillarbox bars (border
rows and columns darker than ``BAR_DARK`` in every frame seen so far, less the row at each
bar's edge), since bars shared by both frames make any two pictures correlate. Fast motion on
both sides of a cut raises the neighbours' scores and so lowers the ratio (sintel.mp4 76 and
118: ratio 2-3, correlation 0.05-0.28 inside the bars); a weak peak within one view (an
exposure or keyframe quality pop: 0.9 and up) stays no cut. Two pictures of alike layout
(dark figures on snow either side of sintel.mp4 96: 0.68) are told apart by their edges: a
peak under ``cut_related`` (0.7) whose edge maps (gradient magnitude) correlate under
``cut_unrelated_edges`` (0.5; sintel 96: 0.42) is a cut too. Confirmed peaks keep the
detector's minimum gap to its cuts and pass the same checks as its cuts; for them the view
that comes back may be any of the ``cut_enter_s`` (1/8 s) before the peak, since a car
crossing the lens can fill both frames either side of it (caminandes.mp4 211). View checks
are made inside the bars.

A decoder that loses a slice conceals it by stretching rows into vertical streaks
(``tasks/curate/smear.py``) and often holds that picture until the next intra frame. Neither
the smeared frame nor the change where the picture comes back, right after it or after the
held copies of it, is a cut (armwrestle.mp4: smear at 229, held 231-267, back at 268); the
smeared frames are listed in the decode report and reject their clip (quality ``smeared``).

A source shorter than the detector's window (``1 + 2 adaptive_window`` frames, e.g. slides
one frame each) never has a frame judged by it: each pair of its frames is a cut where their
unblurred 64-px thumbnails are unrelated (best-shift correlation < ``cut_left_view``; slides.avi
0.14 and 0.20), with no minimum gap between cuts.

Transition frames belong to no scene; they are reported as ``transition`` spans. Scenes
shorter than ``min_scene_s`` are reported as ``too_short``; scenes longer than
``max_scene_s`` are split into equal parts. A span is yielded once no later frame can change
it (about ``max_transition_s`` + 1 s later), so memory is bounded by the longest scene and
by ``2 x max_scene_s``: an open scene longer than that is cut into ``max_scene_s`` parts as
it goes.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import Literal

import av
import cv2
import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from scenedetect.common import FrameTimecode, Timecode
from scenedetect.detector import FlashFilter

from tasks.curate.decode import AnalysisConfig, AnalysisFrame, DecodeReport, analysis_frames
from tasks.curate.exact import ExactFrames
from tasks.curate.detectors import RgbAdaptiveDetector, RgbContentDetector
from tasks.curate.filter_base import picture_box
from tasks.curate.smear import SMEAR_MIN, smear_fraction
from tasks.video import DecodeError, SourceInfo, probe

MICROSECOND = Fraction(1, 1_000_000)
THUMB_WIDTH = 64
MAX_FILL = 2  # undecoded frames in a row that get interpolated rows (see SceneSplitter.push)
MAX_REFILL = 16  # longest run of frames decoded on demand: H.264 allows at most 16 B-frames in a row
THUMB_BLUR = 2.0  # px of Gaussian blur on thumbnails: camera motion must not read as new content
Span = tuple[int, int, str]  # (start, end exclusive, kind) in frame positions
HELD_STEP = 0.5  # mean grey change (blurred thumbnail) under which a decoded frame repeats the one before
PAN_SHIFT = 3  # px of thumbnail shift (of 64) from which a view matched across a cut has moved: a pan
FADE_JUMP = 0.6  # share of a fade side's luma rise taken in one step that makes the side a hard cut


class SceneConfig(BaseModel):
    """Detector choice and thresholds. Luma values are on 0..255; times in seconds."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    detector: Literal["adaptive", "content"] = "adaptive"
    content_threshold: float = Field(27.0, gt=0, description="ContentDetector threshold")
    adaptive_threshold: float = Field(3.0, gt=0, description="AdaptiveDetector ratio threshold")
    adaptive_window: int = Field(2, ge=1, le=10)
    min_content_val: float = Field(15.0, ge=0, description="AdaptiveDetector minimum content score")
    min_cut_gap_s: float = Field(0.3, ge=0, description="detector's own minimum gap between cuts")
    min_scene_s: float = Field(2.0, ge=0)
    max_scene_s: float = Field(60.0, gt=0)
    transitions: bool = Field(True, description="find fades and dissolves and exclude their frames")
    max_transition_s: float = Field(2.0, gt=0)
    fade_black: float = Field(24.0, ge=0, le=255, description="mean luma of a faded-out frame")
    fade_step: float = Field(0.6, ge=0, description="smallest luma change per frame on a fade ramp")
    fade_depth: float = Field(20.0, ge=0, description="luma rise from the darkest frame to the brighter end")
    dissolve_dip: float = Field(0.7, gt=0, le=1, description="sharpness / its envelope mid-dissolve")
    dissolve_edge: float = Field(0.9, gt=0, le=1, description="dip level that bounds the span")
    dissolve_min_change: float = Field(15.0, ge=0, description="mean grey change across the span")
    dissolve_max_step: float = Field(0.35, gt=0, le=1, description="largest blend-weight step (else a cut)")
    dissolve_residual: float = Field(0.2, gt=0, description="blend residual / change")
    dissolve_motion: float = Field(1.5, ge=0, description="the middle frame's motion residual / its blend residual")
    cut_left_view: float = Field(0.5, le=1, description="best-shift correlation across a cut below which the view left")
    cut_same_view: float = Field(0.9, le=1, description="best-shift correlation of the view come back after a cut")
    cut_return_s: float = Field(0.33, ge=0, description="how long after a cut the view before may come back")
    cut_enter_s: float = Field(0.125, ge=0, description="how long before a cut the view that comes back may be seen")
    dissolve_same_view: float = Field(0.5, le=1, description="correlation of the ends, best shift, of one view")
    cut_weak_ratio: float = Field(2.0, gt=0, description="adaptive ratio from which a peak may be confirmed as a cut")
    cut_unrelated: float = Field(0.35, le=1, description="picture correlation, best shift, that confirms a weak peak")
    cut_unrelated_edges: float = Field(0.5, le=1, description="edge-map correlation, best shift, that confirms a "
                                       "weak peak whose picture correlation is under cut_related")
    cut_related: float = Field(0.7, le=1, description="picture correlation from which a weak peak is one view")


SpanKind = Literal["scene", "too_short", "transition"]


@dataclass(frozen=True, slots=True)
class Scene:
    """A span of decoded frames [start_frame, end_frame) with its analysis frames.

    ``frames`` is T x h x w x 3 uint8 RGB, ``times`` T float64 seconds and ``indices`` their
    source frame numbers (T may be less than end_frame - start_frame when frames were left
    undecoded or lost); all three are None from ``detect_scenes``. ``start_frame`` is the span's first decoded frame and ``end_frame`` one
    past its last, so frames undecoded at a boundary belong to no span (but to one of two
    parts of a split shot). ``end_s`` is the time of frame ``end_frame``. ``cause``
    says what started the span: the video start, a cut, the end of a transition, or an
    equal split of a longer shot; ``detail`` is "fade"/"dissolve" for transitions.
    """

    kind: SpanKind
    start_frame: int
    end_frame: int
    start_s: float
    end_s: float
    cause: Literal["start", "cut", "transition", "split"] = "start"
    detail: str | None = None
    frames: np.ndarray | None = None
    times: np.ndarray | None = None
    indices: np.ndarray | None = None  # T int64 source frame numbers of ``frames``

    @property
    def duration(self) -> float:
        return self.end_s - self.start_s

    def summary(self) -> dict:
        """JSON-ready fields without the frames."""
        return {"kind": self.kind, "start_frame": self.start_frame, "end_frame": self.end_frame,
                "start_s": round(self.start_s, 6), "end_s": round(self.end_s, 6),
                "cause": self.cause, "detail": self.detail}


def _detector(config: SceneConfig):
    if config.detector == "content":
        return RgbContentDetector(threshold=config.content_threshold, min_scene_len=config.min_cut_gap_s,
                                  filter_mode=FlashFilter.Mode.SUPPRESS)
    return RgbAdaptiveDetector(adaptive_threshold=config.adaptive_threshold, min_scene_len=config.min_cut_gap_s,
                               window_width=config.adaptive_window, min_content_val=config.min_content_val,
                               weak_threshold=config.cut_weak_ratio if config.cut_weak_ratio < config.adaptive_threshold
                               else None)


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """[start, end) of each run of True."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(np.int8), [0]])))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist()))


def _fades(luma: np.ndarray, h: int, max_len: int, config: SceneConfig, ended: bool) -> list[Span]:
    """Fades through black: the darkest frame within h either side, near black, with luma
    ramps (at least two frames) out to shots at least ``fade_depth`` brighter."""
    n = len(luma)
    found = []
    for v in np.flatnonzero(luma <= config.fade_black):
        lo, hi = max(0, v - h), min(n, v + h + 1)
        if luma[v] > luma[lo:hi].min() or np.any(luma[lo:v] <= luma[v]) or (v + h >= n and not ended):
            continue  # not the first darkest frame around, or not yet seen in full
        floor = luma[v] + 2.0

        def out(t: int, nxt: int) -> bool:  # is frame nxt one step further out along a ramp?
            # A ramp climbs about (luma - floor) / distance per frame; content drifting in
            # the shot next to the fade climbs far slower.
            slope = (luma[nxt] - floor) / (abs(nxt - v) + 1)
            return luma[nxt] <= floor or luma[nxt] - luma[t] > max(config.fade_step, 0.015 * luma[nxt], 0.25 * slope)

        a = b = int(v)
        while a > 0 and b - a < max_len and out(a, a - 1):
            a -= 1
        while b < n - 1 and b - a < max_len and out(b, b + 1):
            b += 1
        if b - a > max_len or (b == n - 1 and not ended):
            continue
        ramps = b - a - 1 - int(np.sum(luma[a + 1: b] <= floor))
        if ramps < 2 or max(luma[a], luma[b]) < luma[v] + config.fade_depth:
            continue  # a dark shot between hard cuts, not a fade
        end = b + 1 if b == n - 1 and out(b - 1, b) else b
        # A side reached in one step of most of its rise is a hard cut into or out of black,
        # not a ramp (a linear ramp of r frames climbs 1 / (r + 1) of the rise per step).
        cut_in = a < v and luma[a] - luma[a + 1] >= FADE_JUMP * (luma[a] - luma[v])
        cut_out = end == b and b > v and luma[b] - luma[b - 1] >= FADE_JUMP * (luma[b] - luma[v])
        if cut_in and cut_out:
            continue
        if cut_in:  # the cut at the first black frame; the fade starts where luma leaves black
            start = a + 1
            while start < end and luma[start] <= floor:
                start += 1
            found += [(a + 1, a + 1, "cut"), (start, end, "fade")]
        elif cut_out:  # the fade ends at the first black frame; the cut at the new shot's first
            stop = b - 1
            while stop > a + 1 and luma[stop - 1] <= floor:
                stop -= 1
            found += [(a + 1, stop, "fade"), (b, b, "cut")]
        else:
            found.append((a + 1, end, "fade"))
    return found


def _blend_fit(thumbs: np.ndarray, a: int, b: int) -> tuple[float, float, float, float] | None:
    """How well frames a..b-1 are blends (1-w) P + w Q of P = thumbs[a-1] and Q = thumbs[b].

    Returns (mean |Q - P|, mean residual / mean |Q - P|, correlation of w with time, largest
    step of w, ends included).
    """
    p, q = thumbs[a - 1].ravel(), thumbs[b].ravel()
    inner = thumbs[a:b].reshape(b - a, -1)
    direction = q - p
    norm = float(direction @ direction)
    if norm <= 0:
        return None
    w = (inner - p) @ direction / norm
    change = float(np.abs(direction).mean())
    residual = float(np.abs(inner - p - w[:, None] * direction).mean()) / change
    order = float(np.corrcoef(w, np.arange(len(w)))[0, 1]) if np.ptp(w) > 0 else 0.0
    jump = float(np.abs(np.diff(np.concatenate([[0.0], w, [1.0]]))).max())
    return change, residual, order, jump


MOTION_SHIFT = 6  # px of shift per block at thumbnail size (64 px wide): about a tenth of the picture
MOTION_BLOCKS = 4  # blocks per side, each free to take its own shift


def _motion_residual(x: np.ndarray, m: np.ndarray) -> float:
    """Mean |m - x'| where x' is x with one gain and offset fitted to m, each of
    MOTION_BLOCKS x MOTION_BLOCKS blocks then shifted by up to MOTION_SHIFT px to fit best:
    how well local motion (a pan, a shake, a head turning) and an exposure change of x
    explain m."""
    gain, offset = np.polyfit(x.ravel(), m.ravel(), 1) if np.ptp(x) > 0 else (1.0, float(m.mean() - x.mean()))
    r = MOTION_SHIFT
    padded = cv2.copyMakeBorder((gain * x + offset).astype(np.float32), r, r, r, r, cv2.BORDER_REPLICATE)
    h, w = m.shape
    ys = np.linspace(0, h, MOTION_BLOCKS + 1).astype(int)[:-1]
    xs = np.linspace(0, w, MOTION_BLOCKS + 1).astype(int)[:-1]
    best = np.full((len(ys), len(xs)), np.inf)
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            err = np.abs(m - padded[r + dy: r + dy + h, r + dx: r + dx + w])
            best = np.minimum(best, np.add.reduceat(np.add.reduceat(err, ys, axis=0), xs, axis=1))
    return float(best.sum()) / m.size


def _motion_vs_blend(thumbs: np.ndarray, a: int, b: int) -> float:
    """The middle frame of a..b-1: its residual as local motion of either end over its
    residual as a blend of the two (> 1: the blend explains it better)."""
    p, q, m = thumbs[a - 1], thumbs[b], thumbs[(a + b) // 2]
    d = q - p
    w = float(((m - p) * d).sum() / max(float((d * d).sum()), 1e-9))
    blend = float(np.abs(m - p - w * d).mean())
    return min(_motion_residual(p, m), _motion_residual(q, m)) / max(blend, 1e-6)


def _best_shift(p: np.ndarray, q: np.ndarray) -> tuple[float, int]:
    """(correlation, shift) of two thumbnails' overlap at the best shift up to MOTION_SHIFT px;
    shift is the larger of its two components, in px (the first best in row order of (dy, dx)).

    The Pearson correlation of each shift's overlap, from six cross-correlations (OpenCV's
    ``matchTemplate``) of the zero-padded pictures and their masks: the overlap's count, sums,
    sums of squares and sum of products. Equal to looping over the 169 shifts to within 1e-6,
    and 18 times faster; an overlap with no variance counts as correlation 1.
    """
    r, (h, w) = MOTION_SHIFT, p.shape
    p = np.asarray(p, np.float32) - np.float32(np.mean(p))  # centred: float32 sums keep their precision
    q = np.asarray(q, np.float32) - np.float32(np.mean(q))
    ones = np.ones((h, w), np.float32)
    pp = cv2.copyMakeBorder(p, r, r, r, r, cv2.BORDER_CONSTANT, value=0)
    mask = cv2.copyMakeBorder(ones, r, r, r, r, cv2.BORDER_CONSTANT, value=0)

    def corr(image: np.ndarray, template: np.ndarray) -> np.ndarray:
        return cv2.matchTemplate(image, template, cv2.TM_CCORR).astype(np.float64)

    n, sa, sb = corr(mask, ones), corr(pp, ones), corr(mask, q)
    saa, sbb, sab = corr(pp * pp, ones), corr(mask, q * q), corr(pp, q)
    cov = sab - sa * sb / n
    norm = np.sqrt(np.maximum(saa - sa * sa / n, 0) * np.maximum(sbb - sb * sb / n, 0))
    flat = norm <= 1e-6 * (n + saa)  # no variance, up to float32 rounding
    values = np.where(flat, 1.0, cov / np.where(flat, 1.0, norm))
    k = int(np.argmax(values))
    dy, dx = divmod(k, 2 * r + 1)
    return float(values.flat[k]), max(abs(dy - r), abs(dx - r))


def _same_view(p: np.ndarray, q: np.ndarray) -> float:
    """Correlation of two thumbnails' overlap at the best shift up to MOTION_SHIFT px: near 1
    for two moments of one shot (gain and offset do not matter), near 0 for unrelated shots."""
    return _best_shift(p, q)[0]


def _edges(thumb: np.ndarray) -> np.ndarray:
    """Gradient magnitude of an unblurred grey thumbnail, blurred by 1 px: where its edges are."""
    gx = cv2.Sobel(thumb, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(thumb, cv2.CV_32F, 0, 1, ksize=3)
    return cv2.GaussianBlur(cv2.magnitude(gx, gy), (0, 0), 1.0)


def change_gap(max_len: int) -> int:
    """k of the dissolve finder's change across 2k frames, for transitions up to ``max_len``."""
    return max(2, (max_len // 2 + 2) // 3)


def frame_change(thumbs: np.ndarray, gap: int) -> np.ndarray:
    """N float64: change[i] = mean |thumbs[i] - thumbs[i - 2 gap]| of N x th x tw float32
    thumbnails (0 for the first 2 gap frames). Each value depends only on its two frames, so
    a stream can append one per frame instead of measuring every window again."""
    change = np.zeros(len(thumbs))
    change[2 * gap:] = np.abs(thumbs[2 * gap:] - thumbs[: len(thumbs) - 2 * gap]).mean(axis=(1, 2))
    return change


def _dissolves(sharp: np.ndarray, thumbs: np.ndarray, h: int, max_len: int, config: SceneConfig,
               ended: bool, cache: dict, offset: int, change: np.ndarray | None) -> list[Span]:
    """Dissolves: for each candidate centre, the best-fitting blend span of a few widths."""
    n = len(sharp)
    pad = np.full(h, -np.inf)
    windows = np.lib.stride_tricks.sliding_window_view(np.concatenate([pad, sharp, pad]), h + 1)
    with np.errstate(invalid="ignore", divide="ignore"):
        dip = np.nan_to_num(sharp / np.minimum(windows[:n].max(axis=1), windows[h: h + n].max(axis=1)), nan=1.0)
    centres = {(r0 + r1) // 2: (r0, r1) for r0, r1 in _runs(dip < config.dissolve_edge)
               if r1 - r0 <= max_len + 2 and dip[r0:r1].min() <= config.dissolve_dip}
    # Shots of unequal sharpness need not dip: also try where the change across 2k frames
    # peaks at 1.5 times its level 3k frames either side.
    k = change_gap(max_len)
    if n > 8 * k:
        dk = np.zeros(n)
        dk[k: n - k] = (frame_change(thumbs, k) if change is None else change)[2 * k:]
        c = np.arange(4 * k, n - 4 * k)
        peak = ((dk[c] >= config.dissolve_min_change) & (dk[c] >= dk[c - 1]) & (dk[c] > dk[c + 1])
                & (dk[c] >= 1.5 * np.minimum(dk[c - 3 * k], dk[c + 3 * k])))
        for centre in c[peak].tolist():
            centres.setdefault(centre, (centre - k // 2, centre + k // 2 + 1))
    found = []
    for c, (r0, r1) in sorted(centres.items()):
        if c + max_len // 2 + h >= n and not ended:
            continue
        best = None
        for a, b in {(r0, r1)} | {(c - m, c + m + 1) for m in (k // 2, k, 3 * k // 2, 2 * k)}:
            a, b = max(a, 1), min(b, n - 1)
            if b - a < 3 or b - a > max_len:
                continue
            key = (a + offset, b + offset)
            if key not in cache:
                cache[key] = _blend_fit(thumbs, a, b)
            fit = cache[key]
            if (fit is not None and fit[0] >= config.dissolve_min_change and fit[1] <= config.dissolve_residual
                    and fit[2] >= 0.8 and fit[3] <= config.dissolve_max_step and (best is None or fit[1] < best[0])):
                # Two moments of one shot (ends alike after a shift) whose middle frame local
                # motion explains about as well as a blend does: camera or subject motion.
                if key + ("motion",) not in cache:
                    cache[key + ("motion",)] = (_motion_vs_blend(thumbs, a, b) >= config.dissolve_motion
                                                or _same_view(thumbs[a - 1], thumbs[b]) < config.dissolve_same_view)
                if cache[key + ("motion",)]:
                    best = (fit[1], a, b)
        if best is not None:
            found.append((best[1], best[2], "dissolve"))
    return found


def find_transitions(luma: np.ndarray, sharp: np.ndarray, thumbs: np.ndarray, max_len: int,
                     config: SceneConfig, ended: bool = False, cache: dict | None = None,
                     offset: int = 0, change: np.ndarray | None = None) -> list[Span]:
    """Gradual transitions in N frames, as sorted, disjoint (start, end exclusive, kind), and
    (c, c, "cut") for a hard cut into or out of black that borders a fade.

    luma: N mean luma (0..255); sharp: N mean squared grey gradient; thumbs: N x th x tw
    float32 blurred grey thumbnails. Unless the video has ``ended``, candidates that later
    frames could still change are left out. ``cache`` (with ``offset`` added to keys) keeps
    blend fits between calls on overlapping windows. ``change`` is
    ``frame_change(thumbs, change_gap(max_len))`` when the caller keeps it already (the first
    2 gap values are not read).
    """
    h = max_len // 2 + 2
    fades = _fades(luma, h, max_len, config, ended)
    dissolves = _dissolves(sharp, thumbs, h, max_len, config, ended, {} if cache is None else cache, offset,
                           change)
    # A fade is also a blend (with black); its luma ramps bound it better than a blend fit.
    found = sorted(fades + [d for d in dissolves if not any(d[0] < b and a < d[1] for a, b, _ in fades)])
    cuts = [span for span in found if span[2] == "cut"]
    merged: list[Span] = []
    for a, b, kind in (span for span in found if span[2] != "cut"):
        if merged and a <= merged[-1][1]:
            pa, pb, pkind = merged[-1]
            merged[-1] = (pa, max(pb, b), "fade" if "fade" in (kind, pkind) else kind)
        else:
            merged.append((a, b, kind))
    return sorted(merged + [c for c in cuts if not any(a < c[0] < b for a, b, _ in merged)])


def _features(image: np.ndarray) -> tuple[float, np.ndarray, float, np.ndarray, np.ndarray, float]:
    """(mean luma, blurred 64-px grey thumbnail, mean squared gradient, half-size RGB frame,
    unblurred 64-px grey thumbnail, concealment smear share) of an RGB analysis frame. Frames wider than 160 px are measured at half size: the same
    cuts and transitions on our corpus and on bikes.mp4, at a quarter of the cost."""
    h, w = image.shape[:2]
    small = image if w <= 160 else cv2.resize(image, (w // 2, h // 2), interpolation=cv2.INTER_AREA)
    grey = cv2.cvtColor(small, cv2.COLOR_RGB2GRAY)
    h, w = grey.shape
    size = (THUMB_WIDTH, max(1, round(h * THUMB_WIDTH / w))) if w > THUMB_WIDTH else (w, h)
    thumb = cv2.resize(grey, size, interpolation=cv2.INTER_AREA).astype(np.float32)
    gx = cv2.Sobel(grey, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(grey, cv2.CV_32F, 0, 1, ksize=3)
    sharp = float(cv2.mean(gx * gx + gy * gy)[0])
    # Blurred so that sub-pixel camera motion does not read as a change of content.
    return float(thumb.mean()), cv2.GaussianBlur(thumb, (0, 0), THUMB_BLUR), sharp, small, thumb, smear_fraction(grey)


BAR_DARK = 24  # grey level under which a border row or column of every frame is a bar (filter_base.active_box)


def _picture_box(peak: np.ndarray) -> tuple[int, int, int, int]:
    """(top, bottom, left, right) of the picture inside bars, from the running maximum of
    the unblurred thumbnails: border rows (columns) darker than BAR_DARK in every frame seen
    (98th percentile, as ``filter_base.active_box``). A crop that leaves less than half is no bar."""
    h, w = peak.shape
    top, bottom, left, right = picture_box(peak, BAR_DARK)
    # A row (column) at a bar's edge is part bar in both frames, which makes them look alike.
    return top + (top > 0), bottom - (bottom < h), left + (left > 0), right - (right < w)


class _Rows:
    """A growable array of equal-shaped rows: append at the end, drop from the front."""

    def __init__(self, dtype=np.float32, shape: tuple[int, ...] = ()):
        self.data = np.empty((256, *shape), dtype)
        self.start = self.stop = 0

    def append(self, row) -> None:
        if self.stop == len(self.data):
            kept = self.data[self.start: self.stop]
            grown = np.empty((max(256, 2 * len(kept)), *self.data.shape[1:]), self.data.dtype)
            grown[: len(kept)] = kept
            self.data, self.start, self.stop = grown, 0, len(kept)
        self.data[self.stop] = row
        self.stop += 1

    def drop(self, count: int) -> None:
        self.start = min(self.stop, self.start + count)

    def view(self, lo: int = 0) -> np.ndarray:
        return self.data[self.start + lo: self.stop]


class SceneSplitter:
    """Push analysis frames in order; get spans back as soon as they are final.

    ``for f in frames: handle(splitter.push(f))`` then ``handle(splitter.finish())``. Spans
    come out in order and tile the pushed frames: kept ``scene``s, ``too_short`` shots and
    ``transition``s. ``fps`` is the source's average rate (it sizes windows in frames).
    """

    def __init__(self, fps: float, config: SceneConfig = SceneConfig(), keep_frames: bool = True,
                 exact: Callable[[list[int]], list[AnalysisFrame]] | None = None):
        self.config, self.fps, self.keep_frames = config, float(fps), keep_frames
        # Frames a fast decode left out, decoded exactly on demand (``exact.ExactFrames``):
        # asked for where the two decoded frames around them suggest a boundary.
        self.exact = exact
        self.refilled = 0  # frames pushed from ``exact``
        self.exact_until = -1  # frames up to this index are all decoded
        self.last_small: np.ndarray | None = None
        self.max_len = max(3, round(config.max_transition_s * fps))
        # Frames after which no boundary can change, and context kept before the open span.
        self.lag = self.max_len + 2 * (self.max_len // 2 + 2) + config.adaptive_window + 2
        self.absorb = max(2, round(0.25 * fps))  # a detector cut this near a transition is it
        self.detector = _detector(config)
        self.rate = Fraction(self.fps).limit_denominator(1001)
        self.base = 0  # position of the first stored row
        self.index: list[int] = []
        self.times: list[float] = []
        self.decoded: list[bool] = []  # False: a row filled in for a frame left undecoded
        self.images: list[np.ndarray | None] = []
        self.luma, self.sharp, self.change = _Rows(np.float64), _Rows(np.float64), _Rows(np.float64)
        self.gap = change_gap(self.max_len)
        self.thumbs: _Rows | None = None  # blurred grey thumbnails, shape set by the first frame
        self.cuts: list[int] = []  # positions of first frames after a hard cut
        self.head: list[np.ndarray] = []  # unblurred thumbnails of the first frames (see finish)
        self.cut_checks: dict[int, bool] = {}  # cut position: rejected by _view_returns
        self.weak: list[int] = []  # positions of detector peaks below its threshold (see _unrelated)
        self.weak_checks: dict[int, bool] = {}  # weak peak position: confirmed by _unrelated
        self.raw: _Rows | None = None  # unblurred grey thumbnails
        self.peak: np.ndarray | None = None  # their running maximum over decoded frames (letterbox bars)
        self.fits: dict = {}
        self.by_pts: dict[int, int] = {}
        self.open = 0  # position where the open span starts
        self.shown = 0  # position of self.images[0]: frames before the open span are dropped
        self.open_cause = "start"
        self.checked = 0  # frontier of the previous settle
        self.pushed = 0  # rows
        self.settled = -16  # rows at the previous settle, less one
        self.last: tuple | None = None  # (index, time, luma, thumb, sharp) of the last decoded frame
        self.smeared: list[int] = []  # source frame numbers of concealment-smeared frames (tasks/curate/smear.py)
        self.last_smear = -1  # position of the last smeared frame
        self.held_from = 0  # position where the current run of unchanged decoded frames starts
        self.recovered: set[int] = set()  # positions where a smeared or held-after-smear picture ends

    def push(self, frame: AnalysisFrame) -> list[Scene]:
        """Take the next frame (in decoded order); return the spans that became final.

        Positions count source frames: when one or two frame numbers were skipped (the
        analysis pass leaves out frames nothing predicts from), each gets a row whose
        statistics are interpolated between its neighbours, so every window of the transition
        finder spans the same time whichever frames were decoded. The rows carry no picture:
        spans hold only decoded frames. Longer gaps (frames lost to errors) are not filled.
        """
        features = _features(frame.image)
        out: list[Scene] = []
        if self.exact is not None and self.last is not None and 1 < frame.index - self.last[0] <= MAX_REFILL + 1 \
                and self.last_small is not None and self.last_small.shape == features[3].shape:
            # A cut between the two decoded frames changes the picture across the gap at least
            # about as much as it does between its own two frames, and the detector never cuts
            # below min_content_val: under that, the frames left out cannot hold a cut.
            # The frames after one are decoded too, as far as the detector's window reaches,
            # so that the candidate's ratio is measured against neighbours one frame apart.
            change = cv2.absdiff(cv2.cvtColor(features[3], cv2.COLOR_RGB2HSV),
                                 cv2.cvtColor(self.last_small, cv2.COLOR_RGB2HSV))
            if frame.index <= self.exact_until or float(np.mean(change)) >= self.config.min_content_val:
                if frame.index > self.exact_until:
                    self.exact_until = frame.index + self.config.adaptive_window + 1
                for extra in self.exact(list(range(self.last[0] + 1, frame.index))):
                    if self.last[0] < extra.index < frame.index:
                        self.refilled += 1
                        out += self._push(extra, _features(extra.image))
        self.last_small = features[3]
        return out + self._push(frame, features)

    def _push(self, frame: AnalysisFrame, features) -> list[Scene]:
        luma, thumb, sharp, small, raw, smear = features
        held = self.last is not None and float(np.abs(thumb - self.last[3]).mean()) < HELD_STEP
        if self.last is not None and 1 < frame.index - self.last[0] <= MAX_FILL + 1:
            i0, t0, l0, th0, s0, r0 = self.last
            steps = frame.index - i0
            for k in range(1, steps):
                w = k / steps
                self._row(i0 + k, t0 + w * (frame.time - t0), (1 - w) * l0 + w * luma, (1 - w) * th0 + w * thumb,
                          (1 - w) * s0 + w * sharp, None, decoded=False, raw=(1 - w) * r0 + w * raw)
        gap = frame.index - self.last[0] if self.last is not None else 1
        self.last = (frame.index, frame.time, luma, thumb, sharp, raw)
        pos = self._row(frame.index, frame.time, luma, thumb, sharp, frame.image, decoded=True, raw=raw)
        self._corruption(pos, frame.index, smear, held)
        self.peak = raw.copy() if self.peak is None or self.peak.shape != raw.shape else np.maximum(self.peak, raw)
        if pos < 2 * self.config.adaptive_window and pos == len(self.head):
            self.head.append(raw)
        pts = round(frame.time / MICROSECOND)
        self.by_pts[pts] = pos
        code = FrameTimecode(Timecode(pts=pts, time_base=MICROSECOND), fps=self.rate)
        for cut in self.detector.process_frame(code, small, gap):
            self.cuts.append(self.by_pts.get(cut.pts, pos))
        weak = getattr(self.detector, "weak", None)  # peaks below the threshold (see _unrelated)
        if weak:
            self.weak += [self.by_pts.get(cut.pts, pos) for cut in weak]
            weak.clear()
        if len(self.by_pts) > 64:
            del self.by_pts[next(iter(self.by_pts))]
        if pos - self.settled < 16:
            return []
        self.settled = pos
        return self._settle(pos + 1 - self.lag)

    def _corruption(self, pos: int, index: int, smear: float, held: bool) -> None:
        """Mark where a decoder's concealment ends. A smeared frame (``smear.SMEAR_MIN``) is the
        stream breaking, not a new shot, and decoders often hold the broken picture until the
        next intra frame: the change where the picture comes back, right after the smear or
        after the held copies of it (each changing less than ``HELD_STEP`` from the one before),
        is the stream recovering, not a cut. Neither marks a cut (armwrestle.mp4: smear at 229,
        held 231-267, the picture back at 268)."""
        if smear >= SMEAR_MIN:
            self.smeared.append(index)
            self.last_smear = pos
            self.recovered.add(pos)
        elif not held and self.last_smear >= max(0, self.held_from - 2):
            self.recovered.add(pos)
        if not held:
            self.held_from = pos

    def _row(self, index: int, time: float, luma: float, thumb: np.ndarray, sharp: float,
             image: np.ndarray | None, decoded: bool, raw: np.ndarray | None = None) -> int:
        pos = self.pushed
        self.pushed += 1
        self.index.append(index)
        self.times.append(time)
        self.decoded.append(decoded)
        self.images.append(image if self.keep_frames else None)  # from position self.shown
        if self.thumbs is None:
            self.thumbs = _Rows(np.float32, thumb.shape)
            self.raw = _Rows(np.float32, thumb.shape)
        self.raw.append(thumb if raw is None else raw)
        self.luma.append(luma)
        self.thumbs.append(thumb)
        self.sharp.append(sharp)
        # The dissolve finder's change across 2 gap frames, measured once per frame rather than
        # over every overlapping search window (that was most of the transition search's time).
        back = pos - 2 * self.gap - self.base
        self.change.append(np.abs(thumb - self.thumbs.view(back)[0]).mean() if back >= 0 else 0.0)
        return pos

    def finish(self) -> list[Scene]:
        """The remaining spans, once the last frame has been pushed."""
        if self.pushed < 1 + 2 * self.config.adaptive_window and self.config.detector == "adaptive":
            # The detector's window never filled: no frame was judged. Each pair of frames is
            # judged on the pictures instead (slides one frame each).
            for pos in range(1, len(self.head)):
                if _best_shift(self.head[pos - 1], self.head[pos])[0] < self.config.cut_left_view:
                    self.cuts.append(pos)
        out = self._settle(self.pushed, final=True)
        out += self._close(self.open, self.pushed, self.open_cause)
        self.open = self.pushed
        return out

    def _boundaries(self, final: bool) -> list[Span]:
        spans: list[Span] = []
        if self.config.transitions and self.pushed > self.base:
            # Search only where a new boundary can still start, with `lag` frames of context
            # before it (spans nearer the window's edge could be artefacts of the edge).
            start = max(self.open, self.checked - self.max_len)
            lo = max(self.base, start - self.lag)
            found = find_transitions(self.luma.view(lo - self.base), self.sharp.view(lo - self.base),
                                     self.thumbs.view(lo - self.base), self.max_len, self.config,
                                     ended=final, cache=self.fits, offset=lo, change=self.change.view(lo - self.base))
            spans = [(a + lo, b + lo, kind) for a, b, kind in found if a + lo >= start]
        near = self.absorb
        found = sorted(self.cuts)
        gap = max(1, round(self.config.min_cut_gap_s * self.fps))
        for c in sorted(self.weak):
            if not any(abs(c - k) < gap for k in found) and self._unrelated(c):
                found = sorted(found + [c])
        cuts = [(c, c, "cut") for c in found if not any(a - near <= c < b + near for a, b, _ in spans)
                and c not in self.recovered and not self._view_returns(c, final)]
        return sorted(s for s in spans + cuts if s[0] > self.open or (s[2] != "cut" and s[1] > self.open))

    def _unrelated(self, cut: int) -> bool:
        """Whether the pictures either side of a weak detector peak are unrelated: best-shift
        correlation of their blurred thumbnails, letterbox and pillarbox bars cut off (bars
        seen so far, as dark border rows and columns of every decoded frame), below
        ``cut_unrelated``."""
        if cut not in self.weak_checks:
            if cut - 1 < self.base:
                return False
            top, bottom, left, right = _picture_box(self.peak)
            p, q = (np.ascontiguousarray(t[top:bottom, left:right]) for t in self.raw.view(cut - 1 - self.base)[:2])
            picture = _same_view(*(cv2.GaussianBlur(x, (0, 0), THUMB_BLUR) for x in (p, q)))
            self.weak_checks[cut] = picture < self.config.cut_unrelated or (
                picture < self.config.cut_related and _same_view(_edges(p), _edges(q)) < self.config.cut_unrelated_edges)
        return self.weak_checks[cut]

    def _view_returns(self, cut: int, final: bool) -> bool:
        """Whether the view before a detector cut leaves and comes back: the frame after the cut
        is unlike the frame before it (best-shift correlation < ``cut_left_view``), but one of
        the next ``cut_return_s`` is the same view again (>= ``cut_same_view``) as that frame or
        one of the ``cut_enter_s`` before it (the thing may already be entering the frame before
        the peak; the frame after a weak peak confirmed by ``_unrelated`` has left the view). Something passed right in front of the lens (a car, a hand): the same shot
        goes on."""
        if cut in self.cut_checks:
            return self.cut_checks[cut]
        last = cut + max(1, round(self.config.cut_return_s * self.fps))
        if cut - 1 < self.base or (last >= self.pushed and not final):
            return False  # (not yet decided: a cut is only used max_len frames after it)
        back = min(round(self.config.cut_enter_s * self.fps), cut - 1 - self.base)
        top, bottom, left, right = _picture_box(self.peak)  # bars shared by both make any two alike
        thumbs = self.thumbs.view(cut - 1 - back - self.base)[:, top:bottom, left:right]
        before, after = thumbs[back], range(back + 1, min(last, self.pushed - 1) - cut + back + 2)
        # A weak peak already had unrelated pictures either side (``_unrelated``).
        left = cut in self.weak_checks or _same_view(before, thumbs[back + 1]) < self.config.cut_left_view
        returns = left and any(_same_view(thumbs[i], thumbs[j]) >= self.config.cut_same_view
                               for i in range(back, -1, -1) for j in after)
        across, shift = _best_shift(before, thumbs[back + 1])
        self.cut_checks[cut] = returns or (across >= self.config.cut_same_view and shift >= PAN_SHIFT)
        return self.cut_checks[cut]

    def _settle(self, frontier: int, final: bool = False) -> list[Scene]:
        out: list[Scene] = []
        for a, b, kind in self._boundaries(final):
            if not final and (b > frontier or (kind == "cut" and a + self.max_len > frontier)):
                break  # a transition found later may still swallow a recent cut
            a = max(a, self.open)
            out += self._close(self.open, a, self.open_cause)
            if kind == "cut":
                self.open, self.open_cause = a, "cut"
            else:
                out.append(self._span("transition", a, b, "cut" if a > self.open else self.open_cause, kind))
                self.open, self.open_cause = b, "transition"
        if not final:
            out += self._trim_long(frontier)
            self.checked = max(self.checked, frontier)
            if len(self.fits) > 4096:  # fits far behind the frontier are never asked for again
                self.fits = {key: fit for key, fit in self.fits.items() if key[0] > frontier - 2 * self.lag}
        self._forget()
        return out

    def _trim_long(self, frontier: int) -> list[Scene]:
        start_time = self._time(self.open)
        if frontier <= self.open or self._time(frontier) - start_time <= 2 * self.config.max_scene_s:
            return []
        times = np.asarray(self.times[self.open - self.base: frontier - self.base])
        end = self.open + int(np.searchsorted(times, start_time + self.config.max_scene_s))
        part = self._span("scene", self.open, end, self.open_cause, split_after=True)
        self.open, self.open_cause = end, "split"
        return [part]

    def _close(self, start: int, end: int, cause: str) -> list[Scene]:
        """The shot [start, end): too short, one scene, or equal parts no longer than max."""
        if end <= start:
            return []
        duration = self._time(end) - self._time(start)
        if duration < self.config.min_scene_s:
            return [self._span("too_short", start, end, cause)]
        parts = max(1, int(np.ceil(duration / self.config.max_scene_s - 1e-9)))
        times = np.asarray(self.times[start - self.base: end - self.base])
        edges = [start] + [start + int(np.searchsorted(times, times[0] + duration * j / parts))
                           for j in range(1, parts)] + [end]
        return [self._span("scene", s, e, cause if j == 0 else "split", split_after=j < parts - 1)
                for j, (s, e) in enumerate(zip(edges[:-1], edges[1:], strict=True))]

    def _time(self, pos: int) -> float:
        if pos < self.pushed:
            return self.times[pos - self.base]
        return self.times[-1] + self._step()  # the end of the last frame

    def _step(self) -> float:
        """A typical source frame's duration, from the last few rows."""
        steps = np.diff(self.times[-9:]) / np.diff(self.index[-9:])
        return float(np.median(steps)) if len(steps) else 1.0 / self.fps

    def _span(self, kind: SpanKind, start: int, end: int, cause: str, detail: str | None = None,
              split_after: bool = False) -> Scene:
        lo, hi = start - self.base, end - self.base
        real = [k for k in range(lo, hi) if self.decoded[k]]
        frames = times = indices = None
        if self.keep_frames and real:  # (a span of filled rows only is at most MAX_FILL frames)
            frames = np.stack([self.images[k + self.base - self.shown] for k in real])
            times = np.asarray([self.times[k] for k in real], np.float64)
            indices = np.asarray([self.index[k] for k in real], np.int64)
        real = real or list(range(lo, hi))
        # Source frames between this span's last decoded frame and the next span's first (left
        # undecoded, or lost) may belong to either side of a cut: they go to neither. Only the
        # equal parts of one long shot share them.
        last = real[-1]
        after = next((k for k in range(hi, len(self.index)) if self.decoded[k]), None) if split_after else last + 1
        if after is not None and after < len(self.index) and (split_after or self.index[after] == self.index[last] + 1):
            end_frame, end_s = self.index[after], self.times[after]
        else:  # the end of the video, or frames lost after the span
            end_frame, end_s = self.index[last] + 1, self.times[last] + self._step()
        return Scene(kind=kind, start_frame=self.index[real[0]], end_frame=end_frame, start_s=self.times[real[0]],
                     end_s=end_s, cause=cause, detail=detail, frames=frames, times=times, indices=indices)

    def _forget(self) -> None:
        del self.images[: self.open - self.shown]
        self.shown = self.open
        drop = self.open - self.lag - self.base
        if drop <= 0:
            return
        for store in (self.index, self.times, self.decoded):
            del store[:drop]
        for rows in (self.luma, self.sharp, self.thumbs, self.change, self.raw):
            rows.drop(drop)
        self.base += drop
        self.cuts = [c for c in self.cuts if c >= self.base]
        self.weak = [c for c in self.weak if c >= self.base]
        self.recovered = {c for c in self.recovered if c >= self.base}
        self.fits = {key: fit for key, fit in self.fits.items() if key[0] > self.base}


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
        yield from split_scenes(frames, info.fps, config, keep_frames, report=report)
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
