"""Overlay-text filter: burned-in subtitles, corner logos and running timestamps.

At analysis size (long side 256 px) overlay glyphs are 3-8 px tall, too small to read but
still a clear texture: a row of glyphs is a dense horizontal band of thin high-contrast
strokes (white top-hat response). Three cues separate that band from picture
content:

1. **Averaging**: each of ``n_windows`` short windows (``window_frames`` frames over
   ``window_s`` seconds) is averaged. Moving footage smears into a blur while text, fixed
   on screen, stays crisp; strokes are found on the average.
2. **Stability**: a band counts when its stroke pixels keep their grey level over the
   window (``stable_frac``), or are clearly steadier than the picture around them
   (``stable_margin``; a ticking clock changes a few digits, its surround changes more).
3. **Persistence**: overlays stay in place, so only screen area covered by bands in at
   least half of the windows (and at least two) counts; texture that happens to look like a
   band appears in a different place each time.

A band must also look like a row of glyphs rather than part of the scene: wider than tall
(``band_aspect``, relaxed to ``corner_aspect`` in the corners where logos sit), densely
filled, with upright strokes (``upright_min``: a lit rail or kerb is all horizontal edge),
not embedded in other steady strokes (``ring_strokes_max``: in a locked-off street
scene every fence bar is steady; an overlay stands alone, though the other line of a
two-line subtitle, or the other pieces of its own line, do not count against it), and
crossing several separate strokes along some pixel row (``glyph_runs_min``: a streak of
floor texture is one run).

Strokes are sought in luma and, with ``chroma_text``, in chroma (max minus min channel), where
coloured glyphs without a rim (a yellow clock over a pale sky) stand out although their luma
matches the ground.

Under a locked-off camera all still scene detail is as crisp and stable as an overlay, so
there a band must also sit near the top or bottom of the picture and be drawn at overlay
contrast (``locked_speed``; the camera's speed comes from phase correlation of the middle of
the picture, away from where overlays sit).

Windows in which nothing moves are skipped (a frozen shot gives no averaging cue), and
drawn content (slides, test patterns, cartoons, as the video-type filter classifies them)
is left alone: its text is part of the content and the video-type filter's call.
``text_area`` is the persistent band area as a fraction of the picture.
"""

from __future__ import annotations

import math
from typing import ClassVar, Literal

import cv2
import numpy as np

from tasks.curate.filters import FilterConfig, Verdict, check_frames, sample_indices
from tasks.curate.video_type import VideoTypeConfig
from tasks.curate.video_type import judge as judge_type

IMMERKAER = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)


class OverlayTextConfig(FilterConfig):
    stage: ClassVar[str] = "overlay_text"

    action: Literal["reject", "tag"] = "reject"
    n_windows: int = 6
    window_frames: int = 6
    window_s: float = 0.6
    still_change: int = 16  # grey levels; a window where almost nothing changes this much is skipped
    stroke_px: int = 5  # top-hat kernel: strokes thinner than this
    # Burned-in captions, clocks and logos are light glyphs with a dark rim; dark strokes
    # alone are common in textures (cracks, shadows), so they are opt-in.
    dark_text: bool = False
    stroke_min: float = 24.0  # top-hat grey levels of a stroke ...
    stroke_sigmas: float = 6.0  # ... and at least this many noise sigmas of the averaged frame
    gap_px: int = 3  # glyph gaps closed along a row
    ring_strokes_max: float = 0.05  # steady strokes around a band: it is part of a still scene
    # A row of glyphs crosses several separate strokes along some pixel row; a lone streak of
    # floor texture (a MuJoCo checker or speckle) is one run however text-like its box.
    glyph_runs_min: int = 3
    upright_min: float = 0.3  # |d/dx| over |d/dy| inside a band: glyphs have upright strokes, a rail has none
    band_max_height: float = 0.1  # of the picture height
    # A run of rows taller than that is cut at its weakest row while that row's stroke fill is
    # below this fraction of the run's peak: two subtitle lines joined by picture strokes
    # between them (at 256 px they are a few rows apart) read as one blob too tall for a row.
    row_split: float = 0.6
    band_aspect: float = 3.0  # width / height of a text row
    corner_aspect: float = 1.5  # in the picture corners (short logos)
    band_min_area: int = 60  # px
    band_fill: float = 0.45  # stroke pixels / band box
    stable_max: int = 24  # grey range over a window of a stable pixel
    stable_frac: float = 0.4
    stable_margin: float = 0.2
    text_area_min: float = 0.001
    # Coloured glyphs without a rim (a yellow clock over sky or concrete) have almost the luma of
    # their ground; in chroma (max - min channel) they still stand out as thin bright strokes.
    chroma_text: bool = True
    skip_drawn: bool = True  # leave text on slides and test patterns to the video-type filter
    # Under a locked-off camera every still object stays as crisp and as stable as an overlay,
    # so averaging and stability say nothing there (chaplin.mp4: a lit kerb beside the
    # pillarbox). In a window whose camera moves slower than ``locked_speed`` (picture long
    # sides per second), a band must also sit where overlays go, its centre within
    # ``locked_zone`` of the picture height from the top or bottom, and be drawn at overlay
    # contrast: a median stroke top-hat of at least ``locked_stroke_min`` (1.5 x stroke_min;
    # the kerb's is 28, and on the tuning seeds every overlay still passes with all windows locked).
    locked_speed: float = 0.01
    locked_zone: float = 1 / 3
    locked_stroke_min: float = 36.0


def stroke_map(mean: np.ndarray, config: OverlayTextConfig) -> np.ndarray:
    """h x w bool map of thin bright (and, with ``dark_text``, dark) strokes of an h x w
    uint8 averaged grey frame; the threshold rises with the frame's own noise level."""
    hat, threshold = _top_hat(mean, config)
    return hat >= threshold


def _top_hat(mean: np.ndarray, config: OverlayTextConfig) -> tuple[np.ndarray, float]:
    """(h x w uint8 stroke strength, the strength a stroke needs) of an averaged grey frame."""
    k = cv2.getStructuringElement(cv2.MORPH_RECT, (config.stroke_px, config.stroke_px))
    sigma = np.sqrt(np.pi / 2) / 6.0 * float(np.median(np.abs(cv2.filter2D(mean.astype(np.float32), -1, IMMERKAER))))
    hat = cv2.morphologyEx(mean, cv2.MORPH_TOPHAT, k)
    if config.dark_text:
        hat = np.maximum(hat, cv2.morphologyEx(mean, cv2.MORPH_BLACKHAT, k))
    return hat, max(config.stroke_min, config.stroke_sigmas * sigma)


def camera_speed(first: np.ndarray, last: np.ndarray, seconds: float) -> float:
    """Camera speed (picture long sides per second) between two h x w uint8 grey frames
    ``seconds`` apart, by phase correlation of their middle half: the top and bottom quarters,
    where overlays sit, are left out so that a fixed caption cannot pin the shift to zero."""
    h, w = first.shape
    if seconds <= 0:
        return math.inf
    a, b = (g[h // 4: h - h // 4].astype(np.float32) for g in (first, last))
    window = cv2.createHanningWindow(a.shape[::-1], cv2.CV_32F)
    (dx, dy), _ = cv2.phaseCorrelate(a * window, b * window)
    return float(np.hypot(dx, dy)) / max(h, w) / seconds


def bands(strokes: np.ndarray, config: OverlayTextConfig) -> list[tuple[int, int, int, int]]:
    """(x, y, w, h) boxes of text-row-like bands in an h x w bool stroke map.

    Two subtitle lines often touch through a descender, their backing box or strokes of the
    picture between them, so each blob is first cut into rows where its stroke fill drops.
    """
    h, w = strokes.shape
    closed = cv2.morphologyEx(strokes.astype(np.uint8), cv2.MORPH_CLOSE,
                              cv2.getStructuringElement(cv2.MORPH_RECT, (config.gap_px, 1)))
    n, labels, stats, _ = cv2.connectedComponentsWithStats(closed, connectivity=4)
    out = []
    for i, (x, y, bw, bh, area) in enumerate(stats[1:], start=1):
        if bh < 3 or bh > h // 3 or area < config.band_min_area * config.band_fill:
            continue
        blob = labels[y:y + bh, x:x + bw] == i
        for start, stop in _text_rows(blob.mean(axis=1), config.band_max_height * h, config.row_split):
            cols = np.flatnonzero(blob[start:stop].any(axis=0))
            box = (int(x + cols[0]), int(y + start), int(cols[-1] - cols[0] + 1), stop - start)
            if _is_band(box, int(blob[start:stop, cols[0]:cols[-1] + 1].sum()), (h, w), config):
                out.append(box)
    return out


def _text_rows(fill: np.ndarray, max_height: float, split: float) -> list[tuple[int, int]]:
    """[start, stop) row runs of a blob from its per-row stroke fill: the runs above 0.3 x the
    peak fill, and a run taller than ``max_height`` cut at its weakest row (at least 3 rows
    from either end) while that row's fill is below ``split`` x the run's peak."""
    rows = np.concatenate([[False], fill >= 0.3 * fill.max(), [False]])
    edges = np.flatnonzero(rows[1:] != rows[:-1])
    runs, out = list(zip(edges[::2].tolist(), edges[1::2].tolist())), []
    while runs:
        start, stop = runs.pop()
        if stop - start > max_height and stop - start >= 7:
            cut = start + 3 + int(np.argmin(fill[start + 3: stop - 3]))
            if fill[cut] < split * fill[start:stop].max():
                runs += [(start, cut), (cut + 1, stop)]
                continue
        out.append((start, stop))
    return sorted(out)


def _is_band(box: tuple[int, int, int, int], area: int, shape: tuple[int, int], config: OverlayTextConfig) -> bool:
    x, y, bw, bh = box
    h, w = shape
    corner = (x + bw <= 0.3 * w or x >= 0.7 * w) and (y + bh <= 0.3 * h or y >= 0.7 * h)
    aspect = config.corner_aspect if corner else config.band_aspect
    return (3 <= bh <= config.band_max_height * h and bw >= aspect * bh and bw * bh >= config.band_min_area
            and area >= config.band_fill * bw * bh)


def _ring_mean(mask: np.ndarray, box: tuple[int, int, int, int]) -> float:
    """Mean of a bool mask in a ring one box-height wide around an (x, y, w, h) box."""
    x, y, bw, bh = box
    h, w = mask.shape
    x0, y0, x1, y1 = max(0, x - bh), max(0, y - bh), min(w, x + bw + bh), min(h, y + 2 * bh)
    n = (y1 - y0) * (x1 - x0) - bw * bh
    return float((mask[y0:y1, x0:x1].sum() - mask[y:y + bh, x:x + bw].sum()) / n) if n > 0 else 0.0


def chroma_frames(frames: np.ndarray) -> np.ndarray:
    """N x h x w uint8 chroma (max minus min channel) of N x h x w x 3 uint8 RGB frames."""
    n, h, w, _ = frames.shape
    # Channel planes in OpenCV: numpy reduces over a 3-wide last axis, or on strided channel
    # views, several times slower; the values are the same.
    r, g, b = cv2.split(np.ascontiguousarray(frames).reshape(n * h, w, 3))
    return cv2.subtract(cv2.max(cv2.max(r, g), b), cv2.min(cv2.min(r, g), b)).reshape(n, h, w)


def glyph_runs(strokes: np.ndarray, box: tuple[int, int, int, int]) -> int:
    """Most separate stroke runs along any pixel row of an (x, y, w, h) box of a bool map."""
    x, y, bw, bh = box
    sub = strokes[y:y + bh, x:x + bw].astype(np.int8)
    return int(((np.diff(sub, axis=1) == 1).sum(axis=1) + sub[:, 0]).max())


def _without_stacked(mask: np.ndarray, box: tuple[int, int, int, int], rows: list) -> np.ndarray:
    """A bool mask with the other glyph rows stacked above or below an (x, y, w, h) box, or
    beside it on the same line, cleared: the second line of a two-line subtitle, or the rest of
    a line that broke into pieces, is not scene around it."""
    x, y, bw, bh = box
    out = mask
    for ox, oy, ow, oh in rows:
        overlap = min(x + bw, ox + ow) - max(x, ox)
        stacked = overlap >= 0.5 * min(bw, ow) and abs(oy - y) <= 2.5 * max(bh, oh)
        same_line = min(y + bh, oy + oh) - max(y, oy) >= 0.5 * min(bh, oh) and -overlap <= 2 * max(bh, oh)
        if (ox, oy) != (x, y) and (stacked or same_line):
            out = out.copy() if out is mask else out
            out[oy:oy + oh, ox:ox + ow] = False
    return out


def window_mask(greys: np.ndarray, config: OverlayTextConfig, check_still: bool = True,
                locked: bool = False) -> np.ndarray | None:
    """h x w bool screen area of stable text bands in W x h x w uint8 grey (or chroma) frames;
    None when the picture does not move (nothing to average away). ``check_still=False`` skips
    that test, for a chroma window whose grey twin was already found moving. ``locked``: the
    camera stood still over the window (see ``OverlayTextConfig.locked_speed``)."""
    span = greys.max(axis=0).astype(np.int16) - greys.min(axis=0)
    if check_still and (span > config.still_change).mean() < 0.002:
        return None
    mean = np.clip(greys.mean(axis=0, dtype=np.float32) + 0.5, 0, 255).astype(np.uint8)
    hat, threshold = _top_hat(mean, config)
    strokes = hat >= threshold
    stable = span <= config.stable_max
    mf = mean.astype(np.float32)
    gx = np.abs(cv2.Sobel(mf, cv2.CV_32F, 1, 0))
    gy = np.abs(cv2.Sobel(mf, cv2.CV_32F, 0, 1))
    mask = np.zeros(mean.shape, bool)
    rows = [(x, y, bw, bh) for x, y, bw, bh in bands(strokes, config)
            if glyph_runs(strokes, (x, y, bw, bh)) >= config.glyph_runs_min
            and gx[y:y + bh, x:x + bw].sum() >= config.upright_min * gy[y:y + bh, x:x + bw].sum()]
    steady = strokes & stable
    h = mean.shape[0]
    for x, y, bw, bh in rows:
        if _ring_mean(_without_stacked(steady, (x, y, bw, bh), rows), (x, y, bw, bh)) > config.ring_strokes_max:
            continue
        if locked and (config.locked_zone * h < y + bh / 2 < (1 - config.locked_zone) * h
                       or np.median(hat[y:y + bh, x:x + bw][strokes[y:y + bh, x:x + bw]]) < config.locked_stroke_min):
            continue
        inside = stable[y:y + bh, x:x + bw][strokes[y:y + bh, x:x + bw]].mean()
        if inside >= config.stable_frac or inside - _ring_mean(stable, (x, y, bw, bh)) >= config.stable_margin:
            mask[y:y + bh, x:x + bw] = True
    return mask


def judge(frames: np.ndarray, times: np.ndarray, config: OverlayTextConfig) -> Verdict:
    """Judge burned-in text in one scene: frames T x h x w x 3 uint8 RGB, times T seconds."""
    if not config.enabled:
        return Verdict(keep=True)
    check_frames(frames, times)
    times = np.asarray(times, np.float64)
    if config.skip_drawn:
        kind = judge_type(frames, times, VideoTypeConfig(n_samples=3))
        if not kind.keep:
            return Verdict(keep=True, scores={"text_area": 0.0, "text_windows": 0.0}, tags=("overlay:not_judged",))
    span = min(config.window_s, float(times[-1] - times[0]))
    last_start = int(np.searchsorted(times, times[-1] - span, side="right")) - 1
    masks = []
    for start in sample_indices(max(1, last_start + 1), config.n_windows):
        stop = int(np.searchsorted(times, times[start] + span, side="right"))
        idx = start + sample_indices(max(2, stop - start), config.window_frames)
        idx = idx[idx < len(frames)]
        picked = frames[idx]
        greys = np.stack([cv2.cvtColor(f, cv2.COLOR_RGB2GRAY) for f in picked])
        locked = camera_speed(greys[0], greys[-1], float(times[idx[-1]] - times[idx[0]])) < config.locked_speed
        mask = window_mask(greys, config, locked=locked)
        if mask is not None and config.chroma_text:
            chroma = window_mask(chroma_frames(picked), config, check_still=False, locked=locked)
            mask = mask | chroma if chroma is not None else mask
        if mask is not None:
            masks.append(mask)
    if masks:
        count = np.sum(masks, axis=0)
        text_area = float((count >= max(2, math.ceil(0.5 * len(masks)))).mean())
        windows = float(np.mean([m.any() for m in masks]))
    else:
        text_area = windows = 0.0
    scores = {"text_area": text_area, "text_windows": windows}
    has_text = text_area >= config.text_area_min
    reason = "overlay_text" if has_text and config.action == "reject" else None
    return Verdict(keep=reason is None, reason=reason, scores=scores, tags=("overlay:text",) if has_text else ())
