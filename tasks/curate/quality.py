"""Quality filter: blur, over- and under-exposure, and sensor noise.

Measured on ``n_samples`` frames spread over the scene, inside the letterbox (bars are
neither dark picture nor flat texture):

- ``sharpness``: at strong edges, the steepest grey slope divided by the local grey range
  (max - min in a ``range_px`` window). A step blurred by a Gaussian of sigma s has slope
  range / (s * sqrt(2 pi)), so the ratio measures edge width and does not depend on how much
  texture or contrast the footage has: clean low-texture footage with a few crisp edges stays
  sharp, while a busy but defocused scene does not. ``edge_fraction`` says how many edges
  were found; with almost none the blur score is not trusted.
- ``luma_mean``, ``clip_high``, ``clip_low``: mean luma and fractions of clipped pixels.
- ``noise``: Immerkaer's noise sigma (grey levels) measured in the flattest half of the
  picture, where texture cannot masquerade as noise.
"""

from __future__ import annotations

from typing import ClassVar

import cv2
import numpy as np

from tasks.curate.filters import FilterConfig, Verdict, active_box, check_frames, sample_indices


class QualityConfig(FilterConfig):
    stage: ClassVar[str] = "quality"

    n_samples: int = 12
    range_px: int = 9
    edge_range_min: float = 40.0  # grey range for a pixel to sit on a real edge
    min_edge_fraction: float = 0.002  # below this the blur score is not trusted
    sharp_percentile: float = 90.0
    sharpness_min: float = 0.16  # below: "blur"
    overexposed_clip: float = 0.20  # clip_high above: "overexposed"
    overexposed_mean: float = 205.0  # or luma_mean above
    underexposed_mean: float = 40.0  # luma_mean below: "underexposed"
    noise_max: float = 6.0  # noise above: "noise"


IMMERKAER = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)


def frame_measures(g: np.ndarray, config: QualityConfig) -> tuple[float, float, float]:
    """(sharpness, edge_fraction, noise) of one h x w uint8 grey frame."""
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
    # Immerkaer's Laplacian-difference kernel cancels planes and ramps, leaving noise; it is
    # read only in the flattest half of the picture so texture does not count as noise.
    residual = np.abs(cv2.filter2D(gf, -1, IMMERKAER))[1:-1, 1:-1]
    flat = local_range[1:-1, 1:-1] <= np.median(local_range)
    noise = float(np.sqrt(np.pi / 2) / 6.0 * residual[flat].mean()) if flat.any() else 0.0
    return sharpness, edge_fraction, noise


def judge(frames: np.ndarray, times: np.ndarray, config: QualityConfig) -> Verdict:
    """Judge the picture quality of one scene: frames T x h x w x 3 uint8 RGB, times T seconds."""
    if not config.enabled:
        return Verdict(keep=True)
    check_frames(frames, times)
    picked = frames[sample_indices(len(frames), config.n_samples)]
    top, bottom, left, right = active_box(picked)
    sharp, edge_frac, noise, means, highs, lows = [], [], [], [], [], []
    for frame in picked:
        g = cv2.cvtColor(frame[top:bottom, left:right], cv2.COLOR_RGB2GRAY)
        s, e, n = frame_measures(g, config)
        sharp.append(s)
        edge_frac.append(e)
        noise.append(n)
        means.append(float(g.mean()))
        highs.append(float((g >= 250).mean()))
        lows.append(float((g <= 5).mean()))
    valid = [s for s in sharp if s == s]
    scores = {
        "sharpness": float(np.median(valid)) if valid else float("nan"),
        "edge_fraction": float(np.median(edge_frac)),
        "luma_mean": float(np.mean(means)),
        "clip_high": float(np.mean(highs)),
        "clip_low": float(np.mean(lows)),
        "noise": float(np.median(noise)),
    }
    reason = None
    if scores["clip_high"] > config.overexposed_clip or scores["luma_mean"] > config.overexposed_mean:
        reason = "overexposed"
    elif scores["luma_mean"] < config.underexposed_mean:
        reason = "underexposed"
    elif scores["noise"] > config.noise_max:
        reason = "noise"
    elif (
        scores["edge_fraction"] >= config.min_edge_fraction
        and valid
        and scores["sharpness"] < config.sharpness_min
    ):
        reason = "blur"
    exposure = "bright" if scores["luma_mean"] > 170 else "dark" if scores["luma_mean"] < 70 else "normal"
    tags = (f"exposure:{exposure}",)
    return Verdict(keep=reason is None, reason=reason, scores=scores, tags=tags)
