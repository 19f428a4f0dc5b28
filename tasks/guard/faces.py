"""Post-guard: find faces with OpenCV's Haar cascades and blur or pixelate them.

Frames are T x H x W x 3 uint8 RGB; boxes are (x, y, w, h) in pixels of the full frame.
Detection runs on a greyscale, histogram-equalised copy scaled by ``WINDOW / min_face``
(never up), so the smallest face that must be hidden still spans the cascades' 20 x 20
training window: min_face=40 detects at half size, four times fewer pixels. With
``detect_every`` N > 1, only every Nth frame (and the last) is searched, and a frame in
between gets the union of the boxes found either side of it; each box is padded by ``pad``
of its side so a face that moves a little between detections stays covered.

Only pixels inside the (padded) boxes change. The cascades ship in opencv-python-headless
up to 4.x (``cv2.data.haarcascades``); OpenCV 5 moved them to contrib, which is refused with
a clear error rather than guarding nothing.
"""

from __future__ import annotations

import threading
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from tasks.guard.config import GuardConfig

CASCADES = {"frontal": "haarcascade_frontalface_alt2.xml", "profile": "haarcascade_profileface.xml"}
WINDOW = 20  # both cascades were trained on 20 x 20 windows
SCALE_FACTOR = 1.1
MIN_NEIGHBOURS = 4
Box = tuple[int, int, int, int]


class FaceGuardError(RuntimeError):
    """The face guard cannot run (no Haar cascades in this OpenCV)."""


@dataclass(frozen=True, slots=True)
class FaceDecision:
    """One face box hidden in one frame; ``detected`` False when carried from neighbouring detections."""

    frame: int
    box: Box
    detected: bool = True


_local = threading.local()  # CascadeClassifier objects are not shared between threads


def _cascades() -> dict[str, "cv2.CascadeClassifier"]:
    loaded = getattr(_local, "cascades", None)
    if loaded is None:
        root = Path(getattr(getattr(cv2, "data", None), "haarcascades", "") or ".")
        missing = [name for name in CASCADES.values() if not (root / name).is_file()]
        if not hasattr(cv2, "CascadeClassifier") or missing:
            raise FaceGuardError(f"OpenCV {cv2.__version__} has no Haar face cascades (missing {missing or 'CascadeClassifier'}; "
                                 "OpenCV 5 moved them to contrib): install opencv-python-headless>=4.9,<5")
        loaded = {key: cv2.CascadeClassifier(str(root / name)) for key, name in CASCADES.items()}
        if any(c.empty() for c in loaded.values()):
            raise FaceGuardError(f"cannot load the Haar cascades under {root}")
        _local.cascades = loaded
    return loaded


def detect_faces(frame: np.ndarray, config: GuardConfig = GuardConfig()) -> list[Box]:
    """Faces of at least ``min_face`` px in one H x W x 3 uint8 RGB frame (unpadded boxes)."""
    cascades = _cascades()
    grey = cv2.cvtColor(np.ascontiguousarray(frame), cv2.COLOR_RGB2GRAY)
    scale = min(1.0, WINDOW / config.min_face)
    if scale < 1.0:
        grey = cv2.resize(grey, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    grey = cv2.equalizeHist(grey)
    width = grey.shape[1]
    found = []
    args = dict(scaleFactor=SCALE_FACTOR, minNeighbors=MIN_NEIGHBOURS, minSize=(WINDOW, WINDOW))
    found += [tuple(b) for b in cascades["frontal"].detectMultiScale(grey, **args)]
    if config.profile:
        found += [tuple(b) for b in cascades["profile"].detectMultiScale(grey, **args)]
        # The profile cascade knows one direction only: search the mirror image for the other.
        found += [(width - x - w, y, w, h) for x, y, w, h in cascades["profile"].detectMultiScale(grey[:, ::-1].copy(), **args)]
    return [tuple(int(round(v / scale)) for v in box) for box in found]


def pad_box(box: Box, shape: tuple[int, ...], pad: float) -> Box:
    """The box grown by ``pad`` of its side each way, clipped to an H x W frame."""
    x, y, w, h = box
    dx, dy = int(round(w * pad)), int(round(h * pad))
    x0, y0 = max(0, x - dx), max(0, y - dy)
    x1, y1 = min(shape[1], x + w + dx), min(shape[0], y + h + dy)
    return x0, y0, x1 - x0, y1 - y0


def hide(frame: np.ndarray, boxes: Iterable[Box], config: GuardConfig = GuardConfig()) -> np.ndarray:
    """A copy of the frame with each box blurred or pixelated; nothing outside the boxes changes."""
    out = frame.copy()
    for x, y, w, h in boxes:
        if w < 2 or h < 2:
            continue
        roi = out[y:y + h, x:x + w]
        if config.method == "pixelate":
            cols = min(w, config.pixel_blocks)
            rows = max(1, min(h, round(config.pixel_blocks * h / w)))
            small = cv2.resize(roi, (cols, rows), interpolation=cv2.INTER_AREA)
            out[y:y + h, x:x + w] = cv2.resize(small, (w, h), interpolation=cv2.INTER_NEAREST)
        else:
            # A Gaussian of sigma a quarter of the box leaves no eyes, nose or mouth for a detector
            # (sigma 1/12 did: the astronaut's face was found again); it runs on a copy shrunk to
            # at most ~64 px so big faces cost no more than small ones.
            factor = max(1, max(w, h) // 64)
            small = cv2.resize(roi, (max(1, w // factor), max(1, h // factor)), interpolation=cv2.INTER_AREA)
            sigma = max(small.shape[:2]) / 4
            small = cv2.GaussianBlur(small, (0, 0), sigma, borderType=cv2.BORDER_REPLICATE)
            out[y:y + h, x:x + w] = cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)
    return out


def guard_stream(frames: Iterable[np.ndarray], config: GuardConfig = GuardConfig()
                 ) -> Iterator[tuple[np.ndarray, list[FaceDecision]]]:
    """(guarded frame, its decisions) for each H x W x 3 uint8 RGB frame, in order. Holds at
    most ``detect_every`` frames, so a long video streams through."""
    if not config.enabled:
        for frame in frames:
            yield frame, []
        return
    every = config.detect_every
    pending: list[tuple[int, np.ndarray]] = []
    before: list[Box] = []

    def search(frame: np.ndarray) -> list[Box]:
        return [pad_box(b, frame.shape, config.pad) for b in detect_faces(frame, config)]

    def flush(after: list[Box]) -> Iterator[tuple[np.ndarray, list[FaceDecision]]]:
        carried = list(dict.fromkeys(before + after))
        for j, held in pending:
            yield hide(held, carried, config), [FaceDecision(j, b, False) for b in carried]
        pending.clear()

    i = -1
    for i, frame in enumerate(frames):
        if i % every:
            pending.append((i, frame))
            continue
        boxes = search(frame)
        yield from flush(boxes)
        yield hide(frame, boxes, config), [FaceDecision(i, b) for b in boxes]
        before = boxes
    if pending:  # the tail: search its last frame so every held frame has detections on both sides
        last_index, last = pending.pop()
        boxes = search(last)
        yield from flush(boxes)
        yield hide(last, boxes, config), [FaceDecision(last_index, b) for b in boxes]


def guard_frames(frames: np.ndarray, config: GuardConfig = GuardConfig()) -> tuple[np.ndarray, list[FaceDecision]]:
    """frames: T x H x W x 3 uint8 RGB. Returns the guarded frames (a new array) and every decision."""
    frames = np.asarray(frames)
    if frames.ndim != 4 or frames.shape[-1] != 3 or frames.dtype != np.uint8:
        raise ValueError(f"frames must be T x H x W x 3 uint8, not {frames.shape} {frames.dtype}")
    out = np.empty_like(frames)
    decisions: list[FaceDecision] = []
    for i, (frame, made) in enumerate(guard_stream(frames, config)):
        out[i] = frame
        decisions.extend(made)
    return out, decisions
