"""Quality filter: blur, over- and under-exposure, and sensor noise.

Measured on ``n_samples`` frames spread over the scene, inside the letterbox (bars are
neither dark picture nor flat texture):

- ``sharpness``: at strong edges, the steepest grey slope divided by the local grey range
  (max - min in a ``range_px`` window). A step blurred by a Gaussian of sigma s has slope
  range / (s * sqrt(2 pi)), so the ratio measures edge width and does not depend on how much
  texture or contrast the footage has: clean low-texture footage with a few crisp edges stays
  sharp, while a busy but defocused scene does not. ``edge_fraction`` says how many edges
  were found; with almost none the blur score is not trusted.
- ``luma_mean``, ``luma_p01``, ``luma_p99``, ``clip_high``, ``clip_low``: exposure of the
  picture; overexposure is a bright mean, or a washed-out picture whose darkest 1 % is still
  light grey (blacks lifted, few pixels clipped); underexposure is judged by the 99th
  percentile (nothing in the shot is bright), which a dark slide with white text does not
  meet; exposure is only judged on footage, not on drawn content (a palette of a few colours,
  ``filter_base.palette_size``, or whatever the video-type filter's rules call drawn).
- ``noise``: sensor-noise sigma (grey levels) from consecutive frames aligned by phase
  correlation (``temporal_noise``): noise changes every frame, texture does not, so fine
  texture is not mistaken for noise the way a single-frame estimate would.
- ``frozen_s``: the longest run of identical consecutive frames (mean grey change below
  ``frozen_change``), in seconds, and ``frozen_motion``: the median grey change per frame
  everywhere else. A moving picture that stands exactly still for half a second and more has
  frozen (a decoder holding a broken frame, a stalled capture): real footage whose camera or
  scene moves that much between frames never repeats itself exactly, while a fixed camera on
  a quiet scene (a few grey levels per frame) may.
- ``smeared_frames``: frames a decoder patched over a lost slice by stretching rows into
  vertical streaks (``tasks/curate/smear.py``); the decoder does not flag them, so each
  frame is measured. One is enough to reject the clip as ``smeared``: it shows no scene.
"""

from __future__ import annotations

from typing import ClassVar

import cv2
import numpy as np

from tasks.curate.filter_base import (
    FilterConfig,
    Verdict,
    active_box,
    check_frames,
    palette_size,
    percentiles_of_histogram,
    sample_indices,
)
from tasks.curate.smear import SMEAR_MIN, smear_fraction
from tasks.curate.video_type import looks_drawn


class QualityConfig(FilterConfig):
    stage: ClassVar[str] = "quality"

    n_samples: int = 12
    range_px: int = 9
    edge_range_min: float = 40.0  # grey range for a pixel to sit on a real edge
    sharp_percentile: float = 90.0
    sharpness_min: float = 0.30  # below: "blur"
    drawn_palette: float = 8.0  # palette_size at or below: drawn content, exposure not judged
    overexposed_mean: float = 215.0  # luma_mean at or above: "overexposed"
    overexposed_clip: float = 0.4  # or this fraction of pixels clipped white
    moving_min: float = 0.05  # fraction of pixels changing between samples: a moving picture
    # Washed out: no shadows left anywhere (even the darkest 1 % is light grey) in a bright
    # picture. On the tuning seeds clean footage's 1st percentile reached 81 and washed-out
    # shots started at 103; 92 is between them.
    washed_p01: float = 92.0
    washed_mean: float = 160.0
    underexposed_p99: float = 64.0  # 99th luma percentile at or below: "underexposed"
    n_noise_pairs: int = 6
    noise_max: float = 3.5  # noise sigma (grey levels at analysis size) above: "noise"
    frozen_change: float = 0.5  # mean |grey change| below which two consecutive frames are identical
    frozen_min_s: float = 0.5  # identical frames for this long ...
    # ... in a picture that otherwise changes this much per frame: "frozen". On the real videos
    # in ../shared/data, the files that repeat frames for 0.5 s or more are fixed cameras on
    # quiet scenes and renders (0.7-3.4 grey levels per frame elsewhere; runs up to 1.8 s) and
    # armwrestle.mp4's decoder freeze (15-22); 7 is about their geometric midpoint. Handheld
    # footage measured 5.7-25 and never repeated a frame for long.
    frozen_motion: float = 7.0

    def judge(self, frames: np.ndarray, times: np.ndarray) -> Verdict:
        return judge(frames, times, self)  # the module's judge below


IMMERKAER = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)


def frame_measures(g: np.ndarray, config: QualityConfig) -> tuple[float, float]:
    """(sharpness, edge_fraction) of one h x w uint8 grey frame."""
    gf = g.astype(np.float32)
    # Grey range from a lightly smoothed copy: smoothing leaves a step's range alone but keeps
    # noise from inflating it (which would read as blur).
    soft = cv2.GaussianBlur(gf, (0, 0), 1.0)
    k = np.ones((config.range_px, config.range_px), np.uint8)
    local_range = cv2.dilate(soft, k) - cv2.erode(soft, k)
    gx = cv2.Sobel(gf, cv2.CV_32F, 1, 0, ksize=3) / 8.0
    gy = cv2.Sobel(gf, cv2.CV_32F, 0, 1, ksize=3) / 8.0
    slope = np.sqrt(gx * gx + gy * gy)
    # Measure on the ridge of each edge (local slope maxima), not on its flanks.
    ridge = slope >= cv2.dilate(slope, np.ones((3, 3), np.uint8))
    edges = ridge & (local_range >= config.edge_range_min) & (slope >= 0.1 * local_range)
    edge_fraction = float(edges.mean())
    if edges.sum() >= 20:
        ratio = slope[edges] / local_range[edges]
        # The steeper edges in the frame: a sharp frame has some, however few.
        sharpness = float(np.percentile(ratio, config.sharp_percentile))
    else:
        sharpness = float("nan")
    return sharpness, edge_fraction


def _blocks(a: np.ndarray, size: int = 8) -> np.ndarray:
    """Means of the non-overlapping size x size blocks of a 2-D array, flattened."""
    h, w = a.shape
    return a[: h // size * size, : w // size * size].reshape(h // size, size, w // size, size).mean(axis=(1, 3)).ravel()


def temporal_noise(a: np.ndarray, b: np.ndarray, quantile: float = 25.0) -> float:
    """Noise sigma (grey levels) from two consecutive h x w uint8 grey frames.

    Sensor noise is new in every frame while texture moves with the camera: after aligning b
    to a (phase correlation), the Immerkaer residuals of texture cancel and those of noise do
    not. A low quantile over 8x8 blocks keeps the blocks where alignment worked, and blocks
    near black or white are skipped because clipping hides noise there.
    """
    fa, fb = a.astype(np.float32), b.astype(np.float32)
    window = cv2.createHanningWindow(fa.shape[::-1], cv2.CV_32F)
    # Windowed copies: cv2.phaseCorrelate(a, b, window) would window a and b in place.
    (dx, dy), _ = cv2.phaseCorrelate(fa * window, fb * window)
    # Whole-pixel shift only: interpolating b would smooth its noise away.
    sx, sy = int(round(dx)), int(round(dy))
    h, w = fa.shape
    pad = max(abs(sx), abs(sy)) + 2
    if 2 * pad >= min(h, w) - 16:
        return float("nan")
    ra = cv2.filter2D(fa, -1, IMMERKAER)[pad:h - pad, pad:w - pad]
    rb = cv2.filter2D(fb, -1, IMMERKAER)[pad + sy:h - pad + sy, pad + sx:w - pad + sx]
    blocks = _blocks(np.abs(ra - rb))
    level = _blocks(fa[pad:h - pad, pad:w - pad])
    usable = (level > 24) & (level < 230)
    if usable.sum() < 10:
        return float("nan")
    # Mean |difference of two independent Immerkaer residuals| is 6 sqrt(2) sqrt(2/pi) sigma.
    return float(np.sqrt(np.pi / 2) / (6.0 * np.sqrt(2.0)) * np.percentile(blocks[usable], quantile))


def frozen_run(frames: np.ndarray, times: np.ndarray, config: QualityConfig,
               greys: list[np.ndarray] | None = None) -> tuple[float, float]:
    """(longest run of identical consecutive frames in s, median grey change per frame outside
    such runs) of T x h x w x 3 uint8 RGB frames at times T seconds."""
    greys = greys if greys is not None else [cv2.cvtColor(f, cv2.COLOR_RGB2GRAY) for f in frames]
    change = np.array([cv2.absdiff(a, b).mean() for a, b in zip(greys[:-1], greys[1:])])
    same = change < config.frozen_change
    longest, start = 0.0, None
    for k, s in enumerate(same):
        if s:
            start = k if start is None else start
            longest = max(longest, float(times[k + 1] - times[start]))
        else:
            start = None
    moving = change[~same]
    return longest, float(np.median(moving)) if moving.size else 0.0


def judge(frames: np.ndarray, times: np.ndarray, config: QualityConfig) -> Verdict:
    """Judge the picture quality of one scene: frames T x h x w x 3 uint8 RGB, times T seconds."""
    if not config.enabled:
        return Verdict(keep=True)
    check_frames(frames, times)
    picked = frames[sample_indices(len(frames), config.n_samples)]
    top, bottom, left, right = active_box(picked)
    picked = picked[:, top:bottom, left:right]
    sharp, edge_frac, greys = [], [], []
    for frame in picked:
        g = cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY)
        s, e = frame_measures(g, config)
        sharp.append(s)
        edge_frac.append(e)
        greys.append(g)
    noise = []
    for i in sample_indices(len(frames) - 1, config.n_noise_pairs):
        a, b = (cv2.cvtColor(frames[j, top:bottom, left:right], cv2.COLOR_RGB2GRAY) for j in (i, i + 1))
        noise.append(temporal_noise(a, b))
    noise = [n for n in noise if n == n]
    pixels = sum(g.size for g in greys)
    changed = [np.count_nonzero(cv2.absdiff(a, b) > 6) / a.size for a, b in zip(greys[:-1], greys[1:])]
    moving = float(np.median(changed)) if changed else 0.0
    # Exposure statistics from the grey-level histogram: the same numbers as the mean and
    # percentiles of the stacked greys (integer sums, exact order statistics), without sorting.
    hist = sum(np.bincount(g.ravel(), minlength=256) for g in greys)
    p99, p01 = percentiles_of_histogram(hist, (99, 1))
    valid = [s for s in sharp if s == s]
    scores = {
        "sharpness": float(np.median(valid)) if valid else float("nan"),
        "edge_fraction": float(np.median(edge_frac)),
        "luma_mean": float(np.float64(hist @ np.arange(256)) / pixels),
        "luma_p99": float(p99),
        "luma_p01": float(p01),
        "clip_high": float(hist[250:].sum() / pixels),
        "clip_low": float(hist[:6].sum() / pixels),
        "noise": float(np.median(noise)) if noise else 0.0,
        "palette": float(np.median([palette_size(f) for f in picked[:: max(1, len(picked) // 3)]])),
        "luma_change": moving,
    }
    every = [cv2.cvtColor(f, cv2.COLOR_RGB2GRAY) for f in frames]
    scores["frozen_s"], scores["frozen_motion"] = frozen_run(frames, times, config, every)
    scores["smeared_frames"] = float(sum(smear_fraction(g) >= SMEAR_MIN for g in every))
    # A drawn page (slides, cartoons, bars) has a chosen palette, not an exposure: a white
    # slide is not an overexposed shot. Only footage with a real palette is judged for it.
    # Drawn is the video-type filter's call (its default rules, a few samples), so a white
    # slide is judged the same way by both filters.
    # Asked only when the exposure would be rejected: the video-type pass costs as much as
    # the rest of this filter.
    def footage() -> bool:
        return scores["palette"] > config.drawn_palette and not looks_drawn(frames, times)

    # A blown-out shot can clip to a few flat tones and look drawn (or keep dark areas that
    # hold its mean down): much of it clipped white while the picture moves is overexposure
    # whatever its palette, while a still checkerboard with as much white is not.
    blown = scores["clip_high"] >= config.overexposed_clip and moving >= config.moving_min
    reason = "smeared" if scores["smeared_frames"] else None
    washed = scores["luma_p01"] >= config.washed_p01 and scores["luma_mean"] >= config.washed_mean
    if reason:
        pass
    elif blown or ((scores["luma_mean"] >= config.overexposed_mean or washed) and footage()):
        reason = "overexposed"
    elif scores["luma_p99"] <= config.underexposed_p99 and footage():
        reason = "underexposed"
    elif (scores["frozen_s"] >= config.frozen_min_s and scores["frozen_motion"] >= config.frozen_motion
          and scores["palette"] > config.drawn_palette and not looks_drawn(frames, times)):
        # A held slide between page turns is the video-type filter's call, not a freeze.
        reason = "frozen"
    elif scores["noise"] > config.noise_max:
        reason = "noise"
    elif valid and scores["sharpness"] < config.sharpness_min:
        reason = "blur"
    exposure = "bright" if scores["luma_mean"] > 170 else "dark" if scores["luma_mean"] < 70 else "normal"
    return Verdict(keep=reason is None, reason=reason, scores=scores, tags=(f"exposure:{exposure}",))
