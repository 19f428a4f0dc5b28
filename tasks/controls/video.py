"""Edge and blur controls of any video, simulated or curated, with OpenCV.

Edges: Canny on the grey frame (OpenCV's BT.601 weights), one pair of hysteresis thresholds
per video from the median grey level m of all its frames, ``(0.66 m, 1.33 m)`` (the usual
median rule), the lower kept at 10 or more and the upper 10 above it: one pair for the whole
video, so the edges do not flicker when a frame's median moves. Blur: a Gaussian of sigma a
32nd of the shorter side (2 px at 64 px, 11.25 px at 360 px), so a blur control means the
same at every resolution. Edges are stored losslessly (x264 at crf 0, read back thresholded),
the blur at the episodes' crf 20.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from schemas import paths
from tasks.video.read import display_frames, probe
from tasks.video.write import write_mp4

# Part of every controls stage's key: changed thresholds or blur make new control files.
CONTROLS_VERSION = 1
MEDIAN_LOW, MEDIAN_HIGH = 0.66, 1.33
MIN_LOW, MIN_GAP = 10.0, 10.0
BLUR_SIDE_FRACTION = 1 / 32
VIDEO_CONTROLS = ("edges", "blur")


def canny_thresholds(grey: np.ndarray) -> tuple[float, float]:
    """(low, high) hysteresis thresholds from the median of ``grey`` (any shape, uint8)."""
    median = float(np.median(grey))
    low = max(MIN_LOW, MEDIAN_LOW * median)
    return low, min(255.0, max(low + MIN_GAP, MEDIAN_HIGH * median))


def blur_sigma(height: int, width: int) -> float:
    return max(1.0, min(height, width) * BLUR_SIDE_FRACTION)


def frame_controls(frames: np.ndarray) -> dict[str, np.ndarray]:
    """frames F x H x W x 3 uint8 RGB -> edges F x H x W uint8 in {0, 255}, blur F x H x W x 3 uint8."""
    grey = np.stack([cv2.cvtColor(f, cv2.COLOR_RGB2GRAY) for f in frames])
    low, high = canny_thresholds(grey)
    sigma = blur_sigma(*frames.shape[1:3])
    return {"edges": np.stack([cv2.Canny(g, low, high) for g in grey]),
            "blur": np.stack([cv2.GaussianBlur(f, (0, 0), sigma) for f in frames])}


def video_controls(path: Path | str) -> dict[str, np.ndarray]:
    """The edge and blur controls of every frame of the video at ``path`` (display orientation);
    a file that is not a readable video raises tasks.video.read.DecodeError in one line."""
    probe(path)
    frames = np.stack(list(display_frames(Path(path))))
    return frame_controls(frames)


def write_video_controls(path: Path | str, folder: Path, name: str) -> dict[str, Path]:
    """``folder/{name}.edges.mp4`` and ``{name}.blur.mp4`` of the video at ``path``, at its fps."""
    fps = probe(path).fps
    made = video_controls(path)
    edges = np.repeat(made["edges"][..., None], 3, axis=-1)
    return {"edges": write_mp4(paths.control_file(folder, name, "edges"), edges, fps, crf=0),
            "blur": write_mp4(paths.control_file(folder, name, "blur"), made["blur"], fps)}


def read_edges(path: Path | str) -> np.ndarray:
    """An edges MP4 back as F x H x W uint8 in {0, 255} (exactly what was written)."""
    return np.stack([np.where(f[..., 0] >= 128, 255, 0).astype(np.uint8) for f in display_frames(Path(path))])
