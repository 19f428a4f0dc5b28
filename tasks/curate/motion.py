"""Motion filter: reject static clips and erratic camera shake; tag pan and zoom.

Three measurements on small grey frames (long side ``size`` px, area-downscaled so sensor
noise averages out):

- ``motion_mean``: mean absolute grey difference (0-255) between frames ``gap_s`` seconds
  apart, so slow but real motion still counts while codec flicker does not;
- global camera translation per step from phase correlation on runs of consecutive frames,
  giving ``motion_global`` (median camera speed, frame long sides per second) and
  ``shake`` (RMS of the camera path minus its smoothed path, percent of the long side):
  a pan is a smooth path, shake is a jittering one;
- ``zoom`` (scale change per second) from Farneback flow fitted to a radial model on a few
  frame pairs.
"""

from __future__ import annotations

from typing import ClassVar

import cv2
import numpy as np

from tasks.curate.filters import FilterConfig, Verdict, check_frames, grey, palette_size, sample_indices
from tasks.curate.video_type import looks_drawn


class MotionConfig(FilterConfig):
    stage: ClassVar[str] = "motion"

    size: int = 128
    max_steps: int = 48  # consecutive pairs phase-correlated per scene, in runs
    run_length: int = 16
    gap_s: float = 0.5
    n_gaps: int = 8
    smooth_s: float = 0.25  # camera-path smoothing window: jitter faster than this is shake
    change_min: float = 6.0  # grey levels a pixel must change by to count as moving
    change_sigmas: float = 4.5  # ... or by this many noise sigmas of a frame difference
    # Static means nothing changes at all: a slide deck's pointer or a ticking counter (0.2 %
    # of the picture) already counts as content that moves, so the bound sits below that.
    static_max: float = 0.001  # moving_fraction at or below which the clip is static
    drawn_palette: float = 8.0  # filters.palette_size at or below: drawn, never "static"
    still_camera_max: float = 0.02  # motion_global (long sides / s) for the camera:still tag
    shake_min: float = 0.5  # shake (percent of long side) above which the clip is rejected
    shake_moving_min: float = 0.2  # ... when at least this fraction of the picture moves
    pan_min: float = 0.05  # motion_global for the camera:pan tag
    pan_consistency: float = 0.7  # |mean velocity| / mean |velocity| for a pan
    zoom_min: float = 0.05  # |zoom| (relative scale change per second) for a zoom tag
    n_zoom_pairs: int = 4
    zoom_size: int = 64
    min_response: float = 0.3  # phase-correlation peak below which a step's shift is unreliable


def _runs(n_frames: int, max_steps: int, run_length: int) -> list[np.ndarray]:
    """Index runs of consecutive frames, spread evenly, covering at most ``max_steps`` steps."""
    if n_frames - 1 <= max_steps:
        return [np.arange(n_frames)]
    n_runs = max(1, max_steps // run_length)
    starts = np.linspace(0, n_frames - run_length - 1, n_runs).round().astype(int)
    return [np.arange(s, s + run_length + 1) for s in starts]


def _smooth(x: np.ndarray, width: int) -> np.ndarray:
    """Moving average of a 1-D series with reflected ends (same length)."""
    if width < 3 or x.size < 3:
        return x.copy()
    pad = min(width // 2, x.size - 1)
    # Odd reflection continues a linear trend, so a steady pan leaves no residual at the ends.
    xp = np.pad(x, pad, mode="reflect", reflect_type="odd")
    return np.convolve(xp, np.ones(width) / width, mode="same")[pad: pad + x.size]


def camera_path(
    small: dict[int, np.ndarray], run: np.ndarray, min_response: float = 0.3
) -> tuple[np.ndarray, np.ndarray]:
    """Per-step global shift (dx, dy) in px and phase-correlation response along one run.

    small: frame index -> h x w float32 grey frame; run: consecutive frame indices.
    """
    h, w = small[int(run[0])].shape
    window = cv2.createHanningWindow((w, h), cv2.CV_32F)
    shifts, responses = [], []
    for a, b in zip(run[:-1], run[1:]):
        # The window is applied here: cv2.phaseCorrelate(a, b, window) windows its inputs in place.
        (dx, dy), response = cv2.phaseCorrelate(small[int(a)] * window, small[int(b)] * window)
        shifts.append((dx, dy))
        responses.append(response)
    shifts, responses = np.asarray(shifts, np.float64).reshape(-1, 2), np.asarray(responses)
    # A weak correlation peak (a foreground object crossing, a blur smear) gives an arbitrary
    # shift; fill those steps from their reliable neighbours instead of calling them shake.
    good = responses >= min_response
    if good.any() and not good.all():
        steps = np.arange(len(shifts))
        for k in range(2):
            shifts[~good, k] = np.interp(steps[~good], steps[good], shifts[good, k])
    return shifts, responses


def zoom_rate(a: np.ndarray, b: np.ndarray) -> float:
    """Relative scale change from grey frame a to b (>0: zoom in), from dense flow."""
    flow = cv2.calcOpticalFlowFarneback(a, b, None, 0.5, 2, 9, 3, 5, 1.1, 0)
    h, w = a.shape
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    x -= (w - 1) / 2
    y -= (h - 1) / 2
    u = flow[..., 0] - flow[..., 0].mean()
    v = flow[..., 1] - flow[..., 1].mean()
    return float((u * x + v * y).sum() / ((x * x + y * y).sum() + 1e-9))


def noise_sigma(g: np.ndarray) -> float:
    """Immerkaer's fast noise estimate (grey levels) of an h x w grey image.

    Texture also raises it, which only makes the moving-pixel threshold more conservative.
    """
    kernel = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)
    r = cv2.filter2D(g.astype(np.float32), -1, kernel)[1:-1, 1:-1]
    return float(np.sqrt(np.pi / 2) * np.abs(r).mean() / 6.0)


def judge(frames: np.ndarray, times: np.ndarray, config: MotionConfig) -> Verdict:
    """Judge the motion of one scene: frames T x h x w x 3 uint8 RGB, times T seconds."""
    if not config.enabled:
        return Verdict(keep=True)
    check_frames(frames, times)
    times = np.asarray(times, np.float64)
    n = len(frames)
    cache: dict[int, np.ndarray] = {}

    def small(i: int) -> np.ndarray:
        if i not in cache:
            cache[i] = grey(frames[i], config.size).astype(np.float32)
        return cache[i]

    long_side = max(small(0).shape)

    # Frame differences over a fixed time gap.
    duration = times[-1] - times[0]
    gap = min(config.gap_s, duration)
    starts = sample_indices(int(np.searchsorted(times, times[-1] - gap, side="right")), config.n_gaps)
    # A pixel "moves" when it changes by more than sensor noise could explain; the noise level
    # comes from the frame itself so a grainy locked-off shot still counts as static.
    sigma = noise_sigma(small(0))
    threshold = max(config.change_min, config.change_sigmas * np.sqrt(2.0) * sigma)
    diffs, moving = [], []
    for i in starts:
        j = min(n - 1, int(np.searchsorted(times, times[i] + gap)))
        j = max(j, i + 1)
        d = np.abs(small(j) - small(int(i)))
        diffs.append(float(d.mean()))
        moving.append(float((d > threshold).mean()))
    motion_mean = float(np.mean(diffs))
    moving_fraction = float(np.mean(moving))

    # Global camera path from phase correlation.
    velocities, residuals, weights = [], [], []
    for run in _runs(n, config.max_steps, config.run_length):
        shifts, response = camera_path({int(i): small(int(i)) for i in run}, run, config.min_response)
        dt = np.diff(times[run])
        velocities.append(shifts / dt[:, None] / long_side)
        path = np.cumsum(shifts, axis=0) / long_side * 100
        # Odd width: an even moving average is off by half a step, which a pan turns into shake.
        width = 2 * int(round(config.smooth_s / float(np.median(dt)) / 2)) + 1
        smooth = np.stack([_smooth(path[:, k], width) for k in range(2)], axis=1)
        residuals.append(np.sqrt(((path - smooth) ** 2).sum(axis=1)))
        weights.append(response)
    vel = np.concatenate(velocities)
    speed = np.linalg.norm(vel, axis=1)
    motion_global = float(np.median(speed))
    # Median-based RMS: one bad step must not look like a shaking camera.
    shake = float(1.4826 * np.median(np.concatenate(residuals)))
    reliable = float(np.mean(np.concatenate(weights) >= config.min_response))
    mean_vel = vel.mean(axis=0)
    consistency = float(np.linalg.norm(mean_vel) / (speed.mean() + 1e-9))

    # Zoom from a few pairs about 0.2 s apart.
    zooms = []
    for i in sample_indices(max(1, n - 1), config.n_zoom_pairs):
        j = min(n - 1, max(int(i) + 1, int(np.searchsorted(times, times[i] + 0.2))))
        if j <= i:
            continue
        a, b = (grey(frames[k], config.zoom_size) for k in (int(i), j))
        zooms.append(zoom_rate(a, b) / (times[j] - times[i]))
    zoom = float(np.median(zooms)) if zooms else 0.0

    scores = {
        "motion_mean": motion_mean,
        "moving_fraction": moving_fraction,
        "motion_global": motion_global,
        "shake": shake,
        "pan_consistency": consistency,
        "motion_reliable": reliable,
        "zoom": zoom,
    }
    tags = []
    if motion_global >= config.pan_min and consistency >= config.pan_consistency:
        dx, dy = mean_vel
        tags.append("camera:pan_" + (("right" if dx < 0 else "left") if abs(dx) >= abs(dy) else ("down" if dy < 0 else "up")))
    if abs(zoom) >= config.zoom_min:
        tags.append("camera:zoom_in" if zoom > 0 else "camera:zoom_out")
    if motion_global < config.still_camera_max and not tags:
        tags.append("camera:still")
    reason = None
    # A shaking camera moves the whole picture; on a flat backdrop the correlation peak can
    # follow a few bouncing objects instead, which is not camera shake.
    if shake >= config.shake_min and moving_fraction >= config.shake_moving_min:
        reason = "shake"
        tags.append("camera:shake")
    elif (moving_fraction <= config.static_max and palette_size(frames[n // 2]) > config.drawn_palette
          and not looks_drawn(frames, times)):
        # A still drawn page (a slide held on screen) is the video-type filter's call, not a
        # locked-off camera; footage has far more than a handful of colours.
        reason = "static"
    return Verdict(keep=reason is None, reason=reason, scores=scores, tags=tuple(tags))
