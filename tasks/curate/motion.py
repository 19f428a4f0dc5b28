"""Motion filter: reject static clips and erratic camera shake; tag pan and zoom.

Three measurements on small grey frames (long side ``size`` px, area-downscaled so sensor
noise averages out):

- ``motion_mean``: mean absolute grey difference (0-255) between frames ``gap_s`` seconds
  apart, so slow but real motion still counts while codec flicker does not; ``moving_fraction``
  the share of pixels that change by more than noise, and ``motion_visible`` the share that a
  one-pixel camera move would change as much (a clip is static only when that is large
  enough for stillness to be seen);
- global camera translation per step from phase correlation between frames resampled to
  ``jitter_hz`` per second (the frames nearest a regular time grid, so the measure does not
  depend on the frame rate or on frames the decoder left out), giving ``motion_global``
  (median camera speed, frame long sides per second) and the camera's jitter: the path and
  the velocity minus their smoothed versions (a local-linear fit with a Gaussian of
  ``smooth_s`` seconds, in time, so uneven steps are handled). ``jitter_amplitude`` is the
  RMS of the path residual (percent of the long side: how far the picture jumps about) and
  ``jitter_speed`` the median size of the velocity residual (percent of the long side per
  second: how fast it does). A pan is a smooth path and leaves both small; a hand tremor
  is fast but tiny; a slow sway is large but slow. ``shake`` is their product
  (percent squared per second), large only for jitter that is both large and fast;
- ``zoom`` (scale change per second) from Farneback flow fitted to a radial model on a few
  frame pairs.
"""

from __future__ import annotations

from typing import ClassVar

import cv2
import numpy as np

from tasks.curate.filter_base import FilterConfig, Verdict, check_frames, grey, palette_size, sample_indices
from tasks.curate.video_type import looks_drawn


class MotionConfig(FilterConfig):
    stage: ClassVar[str] = "motion"

    size: int = 128
    jitter_hz: float = 10.0  # camera path sampled at this rate (or every frame below it)
    max_steps: int = 80  # pairs phase-correlated per scene, in runs
    run_length: int = 40
    gap_s: float = 0.5
    n_gaps: int = 8
    smooth_s: float = 0.3  # camera-path smoothing (Gaussian sigma, s): jitter faster than this is shake
    change_min: float = 6.0  # grey levels a pixel must change by to count as moving
    change_sigmas: float = 4.5  # ... or by this many noise sigmas of a frame difference
    # Static means nothing changes at all: a slide deck's pointer or a ticking counter (0.2 %
    # of the picture) already counts as content that moves, so the bound sits below that.
    static_max: float = 0.001  # moving_fraction at or below which the clip is static ...
    # ... when a one-pixel camera move would have shown: at least ten times that share of the
    # picture has detail steep enough (motion_visible). A near-black or featureless picture
    # cannot be seen to stand still (corpus underexposed segment 415/0/1915: 0.005; corpus
    # static segments 0.012-0.57; real footage 0.024-0.45, ../shared/data 2026-11-25).
    visible_min: float = 0.01
    drawn_palette: float = 8.0  # filter_base.palette_size at or below: drawn, never "static"
    still_camera_max: float = 0.02  # motion_global (long sides / s) for the camera:still tag
    # Calibrated on real footage by a stated rule, not per file: the geometric midpoint between
    # the most jittery file labelled steady handheld and the least jittery file labelled shaky
    # (whole files of ../shared/data: basketball.mp4 8.7, fire2.mp4 16.1). Other handheld
    # footage measured 1.4-5.8, fixed cameras 0-1.5, a whip-panning phone selfie 310.
    shake_min: float = 11.8  # shake (jitter amplitude x speed) above which the clip is rejected
    shake_moving_min: float = 0.2  # ... when at least this fraction of the picture moves
    pan_min: float = 0.05  # motion_global for the camera:pan tag
    pan_consistency: float = 0.7  # |mean velocity| / mean |velocity| for a pan
    zoom_min: float = 0.05  # |zoom| (relative scale change per second) for a zoom tag
    n_zoom_pairs: int = 4
    zoom_size: int = 64
    min_response: float = 0.3  # phase-correlation peak below which a step's shift is unreliable

    def judge(self, frames: np.ndarray, times: np.ndarray) -> Verdict:
        return judge(frames, times, self)  # the module's judge below


def _runs(n_steps: int, max_steps: int, run_length: int) -> list[tuple[int, int]]:
    """(start, stop) position ranges of runs of consecutive samples, spread evenly, covering
    at most ``max_steps`` steps."""
    if n_steps <= max_steps:
        return [(0, n_steps + 1)]
    n_runs = max(1, max_steps // run_length)
    starts = np.linspace(0, n_steps - run_length, n_runs).round().astype(int)
    return [(int(s), int(s) + run_length + 1) for s in starts]


def resample(times: np.ndarray, hz: float) -> np.ndarray:
    """Indices of the frames nearest a regular grid of ``hz`` per second (unique, ascending)."""
    grid = np.arange(times[0], times[-1] + 0.5 / hz, 1.0 / hz)
    right = np.clip(np.searchsorted(times, grid), 1, len(times) - 1)
    nearest = np.where(grid - times[right - 1] <= times[right] - grid, right - 1, right)
    return np.unique(nearest)


def smooth_in_time(t: np.ndarray, x: np.ndarray, sigma: float) -> np.ndarray:
    """Local-linear smoothing of x (n or n x k) sampled at times t (s) with a Gaussian of
    ``sigma`` s: a straight path (a steady pan) is reproduced exactly, ends included."""
    d = t[None, :] - t[:, None]  # row i: offsets from sample i
    w = np.exp(-0.5 * (d / sigma) ** 2)
    s0, s1, s2 = w.sum(1), (w * d).sum(1), (w * d * d).sum(1)
    det = s0 * s2 - s1 * s1
    # Weights of the local-linear estimate at each sample's own time.
    lw = w * (s2[:, None] - s1[:, None] * d) / np.where(np.abs(det) > 1e-12, det, np.inf)[:, None]
    lw = np.where(np.abs(det)[:, None] > 1e-12, lw, w / s0[:, None])
    return lw @ x


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
    # Where a one-pixel move of the camera would change a pixel by more than the threshold:
    # on a picture with almost no such detail (near black, heavily blurred) nothing can be
    # seen to move, so "static" cannot be told from a moving camera.
    gy, gx = np.gradient(small(int(starts[0])))
    visible = float((np.hypot(gx, gy) >= threshold).mean())

    # Global camera path from phase correlation, sampled at jitter_hz.
    picked = resample(times, config.jitter_hz)
    velocities, amplitudes, speeds, weights = [], [], [], []
    for start, stop in _runs(len(picked) - 1, config.max_steps, config.run_length):
        run = picked[start:stop]
        shifts, response = camera_path({int(i): small(int(i)) for i in run}, run, config.min_response)
        t = times[run]
        dt = np.maximum(np.diff(t), 1e-6)
        vel = shifts / dt[:, None] / long_side
        velocities.append(vel)
        weights.append(response)
        if len(run) < 4:
            continue
        path = np.vstack([np.zeros((1, 2)), np.cumsum(shifts, axis=0)]) / long_side * 100
        residual = np.linalg.norm(path - smooth_in_time(t, path, config.smooth_s), axis=1)
        amplitudes.append(residual ** 2)
        v = vel * 100
        tv = 0.5 * (t[1:] + t[:-1])
        jitter = np.linalg.norm(v - smooth_in_time(tv, v, config.smooth_s), axis=1)
        speeds.append(jitter[response >= config.min_response])
    vel = np.concatenate(velocities)
    speed = np.linalg.norm(vel, axis=1)
    motion_global = float(np.median(speed))
    amplitude = float(np.sqrt(np.mean(np.concatenate(amplitudes)))) if amplitudes else 0.0
    jitter_speed = np.concatenate(speeds) if speeds else np.zeros(0)
    jitter_speed = float(np.median(jitter_speed)) if jitter_speed.size else 0.0
    shake = amplitude * jitter_speed
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
        "motion_visible": visible,
        "motion_global": motion_global,
        "shake": shake,
        "jitter_amplitude": amplitude,
        "jitter_speed": jitter_speed,
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
    elif (moving_fraction <= config.static_max and visible >= config.visible_min and palette_size(frames[n // 2]) > config.drawn_palette
          and not looks_drawn(frames, times)):
        # A still drawn page (a slide held on screen) is the video-type filter's call, not a
        # locked-off camera; footage has far more than a handful of colours.
        reason = "static"
    return Verdict(keep=reason is None, reason=reason, scores=scores, tags=tuple(tags))
