"""Video-type filter: physical footage versus animation, slides, screens and test patterns.

Camera footage and physically based renders share statistics that drawn content lacks:
shading gradients and texture make most pixels differ from their neighbours, colours are
many, and edges point every way. Drawn content is made of flat fills bounded by crisp
edges. Measured on ``n_samples`` frames inside the letterbox:

- ``flat``: fraction of pixels whose 5x5 neighbourhood spans at most ``flat_range`` grey
  levels in every channel (a fill; codec ringing is smoothed away first);
- ``colours``: how many 4-bit-per-channel colours cover 95 % of the picture;
- ``axis_edges``: share of strong gradient energy within 4 degrees of horizontal or
  vertical (bars, slides, windows);
- ``saturated``: fraction of strongly saturated pixels (colour bars);
- ``still``: fraction of pixels that never change over the sampled frames.

A small decision list maps these to a type; the allow/block lists say which types pass.
"""

from __future__ import annotations

from typing import ClassVar, Literal

import cv2
import numpy as np

from tasks.curate.filters import FilterConfig, Verdict, active_box, check_frames, sample_indices

VideoType = Literal["physical", "animation", "slides", "test_pattern", "screen"]


class VideoTypeConfig(FilterConfig):
    stage: ClassVar[str] = "video_type"

    allow: tuple[VideoType, ...] = ("physical",)
    block: tuple[VideoType, ...] = ()  # blocked even when allowed
    n_samples: int = 8
    flat_range: int = 3
    drawn_flat: float = 0.55  # flat above this: drawn content
    drawn_colours: int = 48  # ... or colours below this with flat above drawn_flat_low
    drawn_flat_low: float = 0.35
    pattern_axis: float = 0.7  # axis_edges above: bars, grids, slides or screens
    pattern_saturated: float = 0.3  # saturated above (with axis edges): test pattern
    slides_still: float = 0.9  # still above (with axis edges): slides


def frame_features(frame: np.ndarray, config: VideoTypeConfig) -> tuple[float, float, float, float]:
    """(flat, colours, axis_edges, saturated) of one h x w x 3 uint8 RGB frame."""
    soft = cv2.GaussianBlur(frame, (3, 3), 0)
    k = np.ones((5, 5), np.uint8)
    span = (cv2.dilate(soft, k).astype(np.int16) - cv2.erode(soft, k)).max(axis=2)
    flat = float((span <= config.flat_range).mean())
    q = (frame >> 4).astype(np.int32)
    counts = np.bincount(((q[..., 0] << 8) | (q[..., 1] << 4) | q[..., 2]).ravel(), minlength=4096)
    cover = np.cumsum(np.sort(counts)[::-1])
    colours = float(np.searchsorted(cover, 0.95 * cover[-1]) + 1)
    g = cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY).astype(np.float32)
    gx = cv2.Sobel(g, cv2.CV_32F, 1, 0)
    gy = cv2.Sobel(g, cv2.CV_32F, 0, 1)
    mag = np.sqrt(gx * gx + gy * gy)
    strong = mag > 80.0
    if strong.sum() >= 20:
        angle = np.degrees(np.arctan2(np.abs(gy[strong]), np.abs(gx[strong])))
        near = np.minimum(angle, 90.0 - angle) <= 4.0
        axis_edges = float((mag[strong] * near).sum() / mag[strong].sum())
    else:
        axis_edges = 0.0
    hsv = cv2.cvtColor(frame, cv2.COLOR_RGB2HSV)
    saturated = float(((hsv[..., 1] >= 160) & (hsv[..., 2] >= 100)).mean())
    return flat, colours, axis_edges, saturated


def classify(scores: dict[str, float], config: VideoTypeConfig) -> str:
    """The video type named by the features in ``scores`` (see the module docstring)."""
    drawn = scores["flat"] >= config.drawn_flat or (
        scores["flat"] >= config.drawn_flat_low and scores["colours"] <= config.drawn_colours)
    if not drawn:
        return "physical"
    if scores["axis_edges"] >= config.pattern_axis:
        if scores["saturated"] >= config.pattern_saturated:
            return "test_pattern"
        return "slides" if scores["still"] >= config.slides_still else "screen"
    return "animation"


def judge(frames: np.ndarray, times: np.ndarray, config: VideoTypeConfig) -> Verdict:
    """Judge the content type of one scene: frames T x h x w x 3 uint8 RGB, times T seconds."""
    if not config.enabled:
        return Verdict(keep=True)
    check_frames(frames, times)
    picked = frames[sample_indices(len(frames), config.n_samples)]
    top, bottom, left, right = active_box(picked)
    picked = picked[:, top:bottom, left:right]
    features = np.array([frame_features(f, config) for f in picked])
    grey = picked.max(axis=3)
    still = float(((grey.max(axis=0).astype(np.int16) - grey.min(axis=0)) <= 6).mean())
    scores = dict(zip(("flat", "colours", "axis_edges", "saturated"), map(float, np.median(features, axis=0))))
    scores["still"] = still
    kind = classify(scores, config)
    keep = kind in config.allow and kind not in config.block
    return Verdict(keep=keep, reason=None if keep else f"non_physical:{kind}",
                   scores={f"type_{k}": v for k, v in scores.items()}, tags=(f"type:{kind}",))
