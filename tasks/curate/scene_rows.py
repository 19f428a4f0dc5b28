"""What the scene split keeps per source frame, and how spans are cut from it.

``frame_features`` measures an analysis frame once (mean luma, gradient energy, grey
thumbnails, the concealment smear, the HSV the cut detector scores); ``SceneRows`` stores
those rows for every frame position (filled-in rows for frames left undecoded carry no
picture), forgets rows that no later boundary can need, and makes ``Scene`` spans of stored
rows. ``splitter.SceneSplitter`` decides where the boundaries are.
"""

from __future__ import annotations

import cv2
import numpy as np

from tasks.curate.scene_config import Scene, SceneConfig, SpanKind
from tasks.curate.smear import smear_fraction

THUMB_WIDTH = 64
THUMB_BLUR = 2.0  # px of Gaussian blur on thumbnails: camera motion must not read as new content
MAX_FILL = 2  # undecoded frames in a row that get interpolated rows (see SceneSplitter.push)


def frame_features(image: np.ndarray) -> tuple[float, np.ndarray, float, np.ndarray, np.ndarray, float, np.ndarray]:
    """(mean luma, blurred 64-px grey thumbnail, mean squared gradient, half-size RGB frame,
    unblurred 64-px grey thumbnail, concealment smear share, the half-size frame in OpenCV's
    HSV) of an RGB analysis frame. Frames wider than 160 px are measured at half size: the same
    cuts and transitions on our corpus and on bikes.mp4, at a quarter of the cost. The HSV is
    made once here for the two that read it: the cut detector's score and the splitter's check
    across undecoded gaps (each converted the frame itself before)."""
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
    return (float(thumb.mean()), cv2.GaussianBlur(thumb, (0, 0), THUMB_BLUR), sharp, small, thumb, smear_fraction(grey),
            cv2.cvtColor(small, cv2.COLOR_RGB2HSV))


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


class SceneRows:
    """Rows of per-frame statistics at source frame positions (0 = the first frame pushed),
    the pictures of decoded frames, and the spans cut from them.

    Rows before ``base`` are forgotten, pictures before ``shown``. ``gap`` is the dissolve
    finder's change gap (``transitions.change_gap``): each row also holds the change across
    2 gap rows. ``fps`` is the source's average rate.
    """

    def __init__(self, fps: float, config: SceneConfig, keep_frames: bool, gap: int):
        self.config, self.fps, self.keep_frames = config, float(fps), keep_frames
        self.gap = gap
        self.base = 0  # position of the first stored row
        self.index: list[int] = []
        self.times: list[float] = []
        self.decoded: list[bool] = []  # False: a row filled in for a frame left undecoded
        self.images: list[np.ndarray | None] = []
        self.luma, self.sharp, self.change = _Rows(np.float64), _Rows(np.float64), _Rows(np.float64)
        self.thumbs: _Rows | None = None  # blurred grey thumbnails, shape set by the first frame
        self.raw: _Rows | None = None  # unblurred grey thumbnails
        self.shown = 0  # position of self.images[0]: frames before the open span are dropped
        self.pushed = 0  # rows

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

    def _forget_rows(self, shown: int, keep: int) -> bool:
        """Drop the pictures before position ``shown`` and the rows before ``keep``; whether any
        row was dropped."""
        del self.images[: shown - self.shown]
        self.shown = shown
        drop = keep - self.base
        if drop <= 0:
            return False
        for store in (self.index, self.times, self.decoded):
            del store[:drop]
        for rows in (self.luma, self.sharp, self.thumbs, self.change, self.raw):
            rows.drop(drop)
        self.base += drop
        return True

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
