"""Overlay-text filter: burned-in subtitles, corner logos and running timestamps.

Text laid over footage has two properties natural content rarely has together:

- character structure: thin high-contrast strokes (a white or black top-hat response) that
  group into rows of several similar-sized blobs;
- a fixed position on screen: the stroke pixels keep their place and their grey level while
  the picture under them changes.

The scene is looked at through ``n_windows`` short windows of ``window_frames`` frames each
(subtitles change every few seconds, so stability is judged within a window, not across
the scene). In each window a pixel is a *stable stroke* when it is a stroke in every frame
and its grey level barely changes; stable strokes are merged into word boxes and kept when
the box looks like text. A running timestamp or counter is the opposite case: a small
text-like box whose strokes change while the rest of the picture stays put, or a box of
stable strokes (the date, the colons) next to it. ``text_area`` is the median over windows of
the picture fraction covered by text-like boxes; ``text_windows`` the fraction of windows
that found any. Stable strokes only mean something when the rest of the picture changes: in
windows where it does not, only boxes with clear character rows count.
"""

from __future__ import annotations

from typing import ClassVar, Literal

import cv2
import numpy as np

from tasks.curate.filters import FilterConfig, Verdict, check_frames, sample_indices


class OverlayTextConfig(FilterConfig):
    stage: ClassVar[str] = "overlay_text"

    action: Literal["reject", "tag"] = "reject"
    n_windows: int = 4
    window_frames: int = 5
    window_s: float = 1.0
    stroke_px: int = 7  # top-hat kernel: strokes thinner than this count
    stroke_min: float = 40.0  # top-hat grey levels of a stroke
    stable_max: float = 24.0  # grey range over a window of a stable pixel
    aspect_min: float = 1.2
    fill_min: float = 0.15
    fill_max: float = 0.75
    strokes_per_height: float = 1.0
    gap_px: int = 5  # widest gap between glyphs of one word
    ring_changed_min: float = 0.3  # fixed text: changed fraction of the picture around it
    ring_still_max: float = 0.1  # running text: changed fraction around it
    text_area_min: float = 0.002  # text_area above which the clip has overlay text
    text_windows_min: float = 0.5


def stroke_map(g: np.ndarray, config: OverlayTextConfig) -> np.ndarray:
    """h x w bool: thin bright or dark strokes of an h x w uint8 grey frame."""
    k = cv2.getStructuringElement(cv2.MORPH_RECT, (config.stroke_px, config.stroke_px))
    white = cv2.morphologyEx(g, cv2.MORPH_TOPHAT, k)
    black = cv2.morphologyEx(g, cv2.MORPH_BLACKHAT, k)
    return np.maximum(white, black) >= config.stroke_min


def text_boxes(mask: np.ndarray, config: OverlayTextConfig) -> list[tuple[int, int, int, int]]:
    """(x, y, w, h) boxes of text-like rows of strokes in an h x w bool mask.

    Glyphs often touch at analysis size, so instead of counting blobs a row counts when a
    horizontal line through it crosses many strokes: at least ``strokes_per_height`` stroke
    starts per box height of width, the rhythm of letters.
    """
    m = mask.astype(np.uint8)
    h, w = m.shape
    n, labels, stats, _ = cv2.connectedComponentsWithStats(m, connectivity=8)
    sizes = stats[1:]
    small = (sizes[:, 3] <= h // 5) & (sizes[:, 2] <= w // 3) & (sizes[:, 4] >= 3)
    keep = np.zeros(n, bool)
    keep[1:] = small
    glyphs = keep[labels].astype(np.uint8)
    words = cv2.dilate(glyphs, cv2.getStructuringElement(cv2.MORPH_RECT, (config.gap_px, 1)))
    nw, word_labels, wstats, _ = cv2.connectedComponentsWithStats(words, connectivity=8)
    boxes = []
    for i in range(1, nw):
        x, y, bw, bh, _ = wstats[i]
        if bh < 4 or bh > h // 5 or bw < config.aspect_min * bh:
            continue
        inner = glyphs[y: y + bh, x: x + bw] * (word_labels[y: y + bh, x: x + bw] == i)
        fill = float(inner.mean())
        rows = inner[bh // 5: bh - bh // 5 or None].astype(np.int8)
        starts = (np.diff(rows, axis=1) == 1).sum(axis=1)
        rhythm = float(np.median(starts)) * bh / bw
        if config.fill_min <= fill <= config.fill_max and rhythm >= config.strokes_per_height:
            boxes.append((int(x), int(y), int(bw), int(bh)))
    return boxes


def ring_change(box: tuple[int, int, int, int], changed: np.ndarray) -> float:
    """Fraction of changed pixels in a ring one box-height wide around an (x, y, w, h) box."""
    x, y, bw, bh = box
    h, w = changed.shape
    x0, y0, x1, y1 = max(0, x - bh), max(0, y - bh), min(w, x + bw + bh), min(h, y + 2 * bh)
    outer = changed[y0:y1, x0:x1]
    inner = changed[y:y + bh, x:x + bw]
    n = outer.size - inner.size
    return float((outer.sum() - inner.sum()) / n) if n > 0 else 0.0


def window_score(greys: np.ndarray, config: OverlayTextConfig) -> tuple[float, float]:
    """(fixed text area, changing text area) as picture fractions for W x h x w uint8 frames.

    Fixed text: rows of stable strokes with a changing picture around them. Changing text:
    rows of strokes that change in place (a running clock) inside a still surround.
    """
    strokes = np.stack([stroke_map(g, config) for g in greys])
    changed = (greys.max(axis=0).astype(np.int16) - greys.min(axis=0)) > config.stable_max
    area = greys.shape[1] * greys.shape[2]
    fixed = [b for b in text_boxes(strokes.all(axis=0) & ~changed, config)
             if ring_change(b, changed) >= config.ring_changed_min]
    running = [b for b in text_boxes(strokes.any(axis=0) & changed, config)
               if ring_change(b, changed) <= config.ring_still_max]
    return (sum(b[2] * b[3] for b in fixed) / area, sum(b[2] * b[3] for b in running) / area)


def judge(frames: np.ndarray, times: np.ndarray, config: OverlayTextConfig) -> Verdict:
    """Judge burned-in text in one scene: frames T x h x w x 3 uint8 RGB, times T seconds."""
    if not config.enabled:
        return Verdict(keep=True)
    check_frames(frames, times)
    times = np.asarray(times, np.float64)
    span = min(config.window_s, float(times[-1] - times[0]))
    last_start = int(np.searchsorted(times, times[-1] - span, side="right")) - 1
    areas, changing = [], []
    for start in sample_indices(max(1, last_start + 1), config.n_windows):
        stop = int(np.searchsorted(times, times[start] + span, side="right"))
        idx = start + sample_indices(max(2, stop - start), config.window_frames)
        idx = idx[idx < len(frames)]
        greys = np.stack([cv2.cvtColor(frames[i], cv2.COLOR_RGB2GRAY) for i in idx])
        a, c = window_score(greys, config)
        areas.append(a)
        changing.append(c)
    found = [max(a, c) > config.text_area_min for a, c in zip(areas, changing)]
    scores = {
        "text_area": float(np.median(np.maximum(areas, changing))),
        "text_windows": float(np.mean(found)),
        "text_changing_area": float(np.median(changing)),
    }
    has_text = scores["text_windows"] >= config.text_windows_min
    reason = "overlay_text" if has_text and config.action == "reject" else None
    tags = ("overlay:text",) if has_text else ()
    return Verdict(keep=reason is None, reason=reason, scores=scores, tags=tags)
