"""The filter contract and the pixels every curation filter measures the same way.

A filter is a frozen config class (``FilterConfig``: ``enabled``, its thresholds, and a
``stage`` class variable naming it) whose ``judge(frames, times) -> Verdict`` keeps a scene
or drops it with a reason, scores and tags, where

- ``frames`` is T x h x w x 3 uint8 RGB: the analysis frames of ONE scene, downscaled so the
  long side is about 256 px;
- ``times`` is T float64 seconds, strictly increasing (variable frame rate is allowed).

Each filter module (motion, quality, overlay_text, video_type) imports this one and nothing
imports them back from here: ``filters.run_filters`` calls the configs' ``judge``. The shared
helpers below (grey conversion, sampling, letterbox crop, palette) exist so the four filters
measure the same pixels.
"""

from __future__ import annotations

import functools
import threading
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from typing import ClassVar

import cv2
import numpy as np
from pydantic import BaseModel, ConfigDict



class Verdict(BaseModel):
    """keep, or drop with a reason; scores are named floats, tags short ``kind:value`` strings.

    ``stage`` names the filter that produced the verdict (for a merged verdict: the first
    rejecting stage, or None when the clip is kept).
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    keep: bool
    reason: str | None = None
    scores: dict[str, float] = {}
    tags: tuple[str, ...] = ()
    stage: str | None = None


class FilterConfig(BaseModel):
    """Base of every filter config: frozen, strict, and switchable."""

    model_config = ConfigDict(frozen=True, extra="forbid")
    stage: ClassVar[str] = ""

    enabled: bool = True

    def judge(self, frames: np.ndarray, times: np.ndarray) -> Verdict:
        """Keep this scene, or drop it with a reason; scores and tags either way."""
        raise NotImplementedError(f"{type(self).__name__}: a filter defines judge")


_scope = threading.local()  # .verdicts: (judge, frames, times, config, verdict) of the open scope


@contextmanager
def one_scene() -> Iterator[None]:
    """While open (``filters.run_filters`` opens it around one scene's filters), a judge marked
    ``@judged_once`` returns its first verdict when it is asked again about the same ``frames``
    and ``times`` objects with an equal config: the motion, quality and overlay text filters
    each ask the video-type rules whether a scene is drawn, and the video-type filter itself
    judges it again. The scope holds the arrays, so they are the ones judged (no filter writes
    into them). Per thread: the curate flow judges several sources at once."""
    outer = getattr(_scope, "verdicts", None)
    _scope.verdicts = []
    try:
        yield
    finally:
        _scope.verdicts = outer


def judged_once(judge: Callable[..., Verdict]) -> Callable[..., Verdict]:
    """``judge(frames, times, config)`` with its verdicts kept for the open ``one_scene``."""

    @functools.wraps(judge)
    def once(frames: np.ndarray, times: np.ndarray, config) -> Verdict:
        verdicts = getattr(_scope, "verdicts", None)
        if verdicts is None:
            return judge(frames, times, config)
        for fn, f, t, c, verdict in verdicts:
            if fn is judge and f is frames and t is times and c == config:
                return verdict
        verdict = judge(frames, times, config)
        verdicts.append((judge, frames, times, config, verdict))
        return verdict

    return once


def check_frames(frames: np.ndarray, times: np.ndarray) -> None:
    """Raise ValueError naming the problem when frames/times break the filter contract."""
    if not isinstance(frames, np.ndarray) or frames.dtype != np.uint8:
        raise ValueError(f"frames: expected a uint8 numpy array, got {type(frames).__name__} "
                         f"{getattr(frames, 'dtype', '')}")
    if frames.ndim != 4 or frames.shape[-1] != 3:
        raise ValueError(f"frames: expected T x h x w x 3 RGB, got shape {frames.shape}")
    if frames.shape[0] < 2 or min(frames.shape[1:3]) < 16:
        raise ValueError(f"frames: need at least 2 frames of at least 16x16 px, got {frames.shape}")
    times = np.asarray(times)
    if times.shape != (frames.shape[0],):
        raise ValueError(f"times: expected shape ({frames.shape[0]},), got {times.shape}")
    if not np.all(np.diff(times) > 0):
        raise ValueError("times: must be strictly increasing seconds")


def sample_indices(n_frames: int, n_samples: int) -> np.ndarray:
    """At most ``n_samples`` frame indices spread evenly over 0..n_frames-1 (ends included)."""
    if n_frames <= n_samples:
        return np.arange(n_frames)
    return np.unique(np.linspace(0, n_frames - 1, n_samples).round().astype(np.int64))


def grey(frame: np.ndarray, long_side: int | None = None) -> np.ndarray:
    """h x w x 3 uint8 RGB -> uint8 luma, area-downscaled to ``long_side`` when it is smaller."""
    g = cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY)
    h, w = g.shape
    if long_side is not None and max(h, w) > long_side:
        k = long_side / max(h, w)
        g = cv2.resize(g, (max(8, round(w * k)), max(8, round(h * k))), interpolation=cv2.INTER_AREA)
    return g


def active_box(frames: np.ndarray, dark: int = 24) -> tuple[int, int, int, int]:
    """(top, bottom, left, right) of the picture inside letterbox or pillarbox bars.

    A bar is a run of border rows (columns) that stays darker than ``dark`` in every given
    frame; bars count neither as flat nor as underexposed picture. frames: N x h x w x 3 uint8.
    """
    peak = frames.max(axis=0)  # over frames first: numpy reduces a 3-wide last axis slowly
    return picture_box(np.maximum(np.maximum(peak[..., 0], peak[..., 1]), peak[..., 2]), dark)


def picture_box(peak: np.ndarray, dark: int = 24) -> tuple[int, int, int, int]:
    """``active_box`` of an h x w brightest-seen picture (each pixel's maximum over the frames):
    border rows (columns) whose 98th percentile stays under ``dark`` are bars."""
    h, w = peak.shape
    rows = np.flatnonzero(np.percentile(peak, 98, axis=1) >= dark)
    cols = np.flatnonzero(np.percentile(peak, 98, axis=0) >= dark)
    if rows.size == 0 or cols.size == 0:
        return 0, h, 0, w
    top, bottom, left, right = int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1
    # Only trust a crop that leaves most of the picture: a dark scene is not a letterbox.
    if (bottom - top) < h // 2 or (right - left) < w // 2:
        return 0, h, 0, w
    return top, bottom, left, right


def palette_size(frame: np.ndarray, cover: float = 0.95) -> float:
    """How many 4-bit-per-channel colours cover ``cover`` of an h x w x 3 uint8 RGB frame.

    The frame is first stretched so its 1-99 % range fills 0-255: a dark or washed-out shot
    keeps its many shades, while drawn content (slides, cartoons, bars) stays at a handful.
    Clipped pixels (black or white in every channel) are left out when at least a tenth of
    the picture remains, so a blown-out shot is judged by what is left of it.

    Computed from histograms (grey levels, then colours) rather than by sorting pixels: the
    same number as the sorting reference in test_filters, about ten times faster.
    """
    h, w = frame.shape[:2]
    frame = np.ascontiguousarray(frame)
    planes = cv2.split(frame)
    lum = cv2.add(cv2.max(cv2.max(planes[0], planes[1]), planes[2]),
                  cv2.min(cv2.min(planes[0], planes[1]), planes[2]), dtype=cv2.CV_16S)
    clipped = (lum <= 12) | (lum >= 498)
    n_clipped = int(np.count_nonzero(clipped))
    drop = n_clipped > 0 and (h * w - n_clipped) / (h * w) >= 0.1
    if frame.size < 1 << 24:  # calcHist counts in float32: exact below 2^24
        hist = cv2.calcHist([frame.reshape(h, w * 3)], [0], None, [256], [0, 256]).ravel().astype(np.int64)
    else:
        hist = np.bincount(frame.ravel(), minlength=256)
    if drop:
        hist -= np.bincount(frame[clipped].ravel(), minlength=256)
    lo, hi = percentiles_of_histogram(hist, (1, 99))
    # The stretch of the reference, applied once per grey level (float64, as numpy promotes
    # a float32 array minus a float64 scalar) and looked up per pixel.
    stretch = np.clip((np.arange(256, dtype=np.float32) - lo) * (255.0 / max(16.0, hi - lo)), 0, 255)
    lut = stretch.astype(np.uint8) >> 4
    q = [cv2.LUT(p, lut) for p in planes]
    codes = (q[0].astype(np.uint16) << 8) | (q[1].astype(np.uint16) << 4) | q[2]
    counts = np.bincount(codes.ravel(), minlength=4096)
    if drop:
        counts -= np.bincount(codes[clipped], minlength=4096)
    total = np.cumsum(np.sort(counts)[::-1])
    return float(np.searchsorted(total, cover * total[-1]) + 1)


def percentiles_of_histogram(hist: np.ndarray, qs: Sequence[float]) -> list[np.float64]:
    """``np.percentile(values, qs)`` (linear method) of the integer values counted in ``hist``
    (hist[v] = how many values equal v), bit for bit: the same virtual index, the two order
    statistics around it from the cumulative counts, and numpy's own interpolation steps."""
    cum = np.cumsum(hist)
    n = int(cum[-1])
    out = []
    for q in qs:
        virtual = (n - 1) * (np.float64(q) / 100)
        below = np.floor(virtual)
        top = virtual >= n - 1
        a = int(np.searchsorted(cum, n - 1 if top else int(below), side="right"))
        b = a if top else int(np.searchsorted(cum, int(below) + 1, side="right"))
        gamma = virtual - below
        step = b - a
        # numpy's _lerp: a + step * gamma, or from the upper end when gamma >= 0.5.
        out.append(np.float64(b) - step * (1 - gamma) if gamma >= 0.5 else np.float64(a) + step * gamma)
    return out
