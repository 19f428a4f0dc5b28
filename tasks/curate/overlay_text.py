"""Overlay-text filter: burned-in subtitles, captions, corner logos and running timestamps.

Text is found by a learned text detector (PP-OCRv4 detection, ``text_detector.py``) on a few
frames sampled across the scene; whether that text is burned in is decided by where it sits on
screen and how it persists:

1. **Placement**: overlays go in the top and bottom bands of the picture (timestamps, camera
   labels, channel logos in the top ``zone_top``; subtitles, captions and lower thirds in the
   bottom ``zone_bottom``): only boxes centred there count; text in the middle of the
   picture is taken for scene text. By default the detector sees only the two bands
   (``search``), which keeps its cost down.
2. **Detection**: each strip is upscaled ``detect_scale`` times (analysis frames are about
   256 px wide, where a caption's glyphs are 4 to 8 px tall; the detector needs about twice
   that) and its text boxes are kept when they look like a line of text: wider than
   ``line_aspect`` times their height, no taller than ``line_max_height`` of the picture.
   The middle sample is searched first, the other ``n_samples - 1`` only when it holds text,
   and then only in the rows around the boxes found so far (three text heights of context
   above and below: a box elsewhere could not persist); the search stops as soon as the
   samples seen make the verdict (two that agree, under the default 2-of-3 persistence).
   When the middle sample held text but the samples made no verdict, the search is run once
   more at ``closer_scale`` in the rows of what was seen: small glyphs on a busy ground (a
   caption's 1 px strokes among leaves or confetti of the same size) come out as fragments
   at 2x and as whole lines at 3x; clean footage rarely pays for this second look.
3. **Text-filled scenes**: an overlay is a few lines (a caption of one to three, a clock, a
   logo); a bookshelf, a shop front or a notice board shows many short words scattered over
   the picture. Boxes in one row closer than ``word_gap`` text heights are one line; a sample
   whose bands hold more than ``max_lines`` lines is taken for a text-filled scene, and there
   only lines ``long_line`` times as wide as tall (a caption, not a spine title) stay.
4. **Persistence**: a box counts when a box at the same screen position (same row, and the
   same left end, right end or centre, within ``same_place`` text heights) is found on at
   least ``persist`` of the samples. Scene text (a sign, a book spine, a T-shirt) moves with
   the camera or with whoever wears it and leaves its place; a caption stays, even while its
   words change (a centred line keeps its centre, a clock its left end).

Under a camera that does not move, scene text in the bands persists too; that case is not
told apart from an overlay (a sign on the top shelf of a locked-off shot is taken for one).

Drawn content (slides, test patterns, cartoons, as the video-type filter classifies them) is
not judged: its text is part of the content and the video-type filter's call (that check runs
only on a clip where overlay text was found). ``text_area`` is the screen area of the burned-in
boxes as a fraction of the picture; ``text_boxes`` how many there are; ``text_samples`` how
many frames the detector searched.
"""

from __future__ import annotations

import math
from typing import ClassVar, Literal

import cv2
import numpy as np

from tasks.curate import text_detector
from tasks.curate.filter_base import FilterConfig, Verdict, check_frames, sample_indices
from tasks.curate.video_type import VideoTypeConfig
from tasks.curate.video_type import judge as judge_type


class OverlayTextConfig(FilterConfig):
    stage: ClassVar[str] = "overlay_text"

    action: Literal["reject", "tag"] = "reject"
    n_samples: int = 3  # frames the detector may see, spread over the scene
    detect_scale: float = 2.0  # strips are upscaled this much for the detector
    closer_scale: float = 3.0  # text seen that made no verdict is searched again at this scale (0: never)
    threshold: float = 0.3  # detector: text probability of a text pixel (PP-OCR's default)
    box_score: float = 0.6  # detector: mean probability of a kept box (PP-OCR: 0.5)
    line_aspect: float = 1.5  # width / height of a text line
    line_max_height: float = 0.15  # of the picture height
    # A sample whose bands hold more than max_lines separate text lines shows a text-filled
    # scene (a bookshelf, a shop front): there only lines long_line x their height count.
    max_lines: int = 3
    long_line: float = 5.0
    word_gap: float = 1.5  # boxes in one row closer than this x their height are one line
    same_place: float = 0.6  # edge or centre tolerance, in text heights, of one box on two frames
    persist: float = 0.6  # of the searched samples
    # The overlay zones (fractions of the height): only there is text looked for.
    zone_top: float = 0.2
    zone_bottom: float = 0.3
    # "bands": the detector sees the two bands, each upscaled on its own (cheaper, and it found
    # the dev set's CCTV label); "frame": the whole frame (it needs context: a caption on a
    # very busy ground is found in the frame and missed in its band).
    search: Literal["bands", "frame"] = "bands"
    text_area_min: float = 0.001
    skip_drawn: bool = True  # leave text on slides and test patterns to the video-type filter

    def judge(self, frames: np.ndarray, times: np.ndarray) -> Verdict:
        return judge(frames, times, self)  # the module's judge below


def detect_in_strips(frame: np.ndarray, rows: list[tuple[int, int]], config: OverlayTextConfig,
                     scale: float | None = None) -> list[tuple[float, float, float, float]]:
    """(x, y, w, h) text-line boxes in an h x w x 3 uint8 RGB frame, searched in the row
    ranges ``rows`` only (upscaled ``scale``, default ``detect_scale``), in frame coordinates."""
    h, w = frame.shape[:2]
    scale = scale or config.detect_scale
    out = []
    for top, bottom in rows:
        # Strip heights at least 32 input px and a whole number of 32 px after scaling.
        need = max(32, math.ceil((bottom - top) * scale / 32) * 32)
        grow = need / scale - (bottom - top)
        top = max(0, int(top - grow / 2))
        bottom = min(h, top + math.ceil(need / scale))
        top = max(0, bottom - math.ceil(need / scale))
        strip = frame[top:bottom]
        probs = text_detector.probability(strip[None], int(round(max(strip.shape[:2]) * scale)))
        for b in text_detector.boxes(probs[0], strip.shape[:2], config.threshold, config.box_score):
            if b.w >= config.line_aspect * b.h and b.h <= config.line_max_height * h:
                out.append((b.x, b.y + top, b.w, b.h))
    return out


def in_zone(box: tuple[float, float, float, float], height: int, config: OverlayTextConfig) -> bool:
    """Whether an (x, y, w, h) box's centre lies in the top or bottom overlay band."""
    centre = box[1] + box[3] / 2
    return centre < config.zone_top * height or centre > (1 - config.zone_bottom) * height


def same_place(a: tuple[float, float, float, float], b: tuple[float, float, float, float],
               tolerance: float, width: float = math.inf) -> bool:
    """Whether two (x, y, w, h) text-line boxes from two frames sit at the same screen
    position: the same row (centres within ``tolerance`` x the taller height, heights within a
    factor of 2), overlapping, and the left edge, the right edge or the centre within
    ``tolerance`` x the taller height (left-aligned clocks, right-aligned logos, centred
    subtitles whose words change). Scene text under a moving camera shifts all three. An edge
    on the picture's border (x 0 or ``width``) is where the picture cut the text off, not where
    the text ends, so it says nothing."""
    tall = max(a[3], b[3])
    tol = max(2.0, tolerance * tall)
    if abs((a[1] + a[3] / 2) - (b[1] + b[3] / 2)) > tol or tall > 2 * min(a[3], b[3]):
        return False
    if min(a[0] + a[2], b[0] + b[2]) <= max(a[0], b[0]):
        return False
    cut_left = min(a[0], b[0]) <= 1
    cut_right = max(a[0] + a[2], b[0] + b[2]) >= width - 1
    return ((not cut_left and abs(a[0] - b[0]) <= tol)
            or (not cut_right and abs(a[0] + a[2] - b[0] - b[2]) <= tol)
            or (not (cut_left or cut_right) and abs(a[0] + a[2] / 2 - b[0] - b[2] / 2) <= tol))


def text_lines(boxes: list[tuple[float, float, float, float]], word_gap: float) -> int:
    """How many separate text lines the (x, y, w, h) boxes form: boxes in one row (centres
    within half the taller height, heights within a factor of 2) whose horizontal gap is under
    ``word_gap`` x the taller height are words of one line."""
    parent = list(range(len(boxes)))

    def root(i: int) -> int:
        while parent[i] != i:
            i = parent[i]
        return i

    for i, a in enumerate(boxes):
        for j in range(i):
            b = boxes[j]
            tall = max(a[3], b[3])
            gap = max(a[0], b[0]) - min(a[0] + a[2], b[0] + b[2])
            if (abs(a[1] + a[3] / 2 - b[1] - b[3] / 2) <= tall / 2 and tall <= 2 * min(a[3], b[3])
                    and gap <= word_gap * tall):
                parent[root(i)] = root(j)
    return len({root(i) for i in range(len(boxes))})


def overlay_candidates(boxes: list[tuple[float, float, float, float]], height: int,
                       config: OverlayTextConfig) -> list[tuple[float, float, float, float]]:
    """The boxes of one sample that may be burned in: those in the overlay bands; when the
    bands hold more than ``max_lines`` separate lines the scene itself is full of text (book
    spines, shop signs, a notice board: many short words scattered over the picture, where an
    overlay is a caption of one to three lines, a clock, a logo), and of those only lines at
    least ``long_line`` times as wide as tall (a caption) stay."""
    boxes = [b for b in boxes if in_zone(b, height, config)]
    if text_lines(boxes, config.word_gap) > config.max_lines:
        boxes = [b for b in boxes if b[2] >= config.long_line * b[3]]
    return boxes


def persistent(found: list[list[tuple[float, float, float, float]]], config: OverlayTextConfig,
               width: float = math.inf, samples: int | None = None) -> list:
    """Boxes of ``found`` (one list per searched sample) with a box at the same place on at
    least ``persist`` of ``samples`` samples (default: those in ``found``; their own included,
    and never fewer than two)."""
    need = max(2, math.ceil(config.persist * (samples or len(found))))
    out = []
    for i, boxes in enumerate(found):
        for box in boxes:
            seen = 1 + sum(any(same_place(box, other, config.same_place, width) for other in found[j])
                           for j in range(len(found)) if j != i)
            if seen >= need:
                out.append(box)
    return out


def rows_around(boxes: list[tuple[float, float, float, float]], height: int) -> list[tuple[int, int]]:
    """Row ranges covering each (x, y, w, h) box with three text heights above and below, merged."""
    spans = sorted((max(0, math.floor(y - 3 * bh)), min(height, math.ceil(y + 4 * bh))) for _, y, _, bh in boxes)
    out: list[tuple[int, int]] = []
    for top, bottom in spans:
        if out and top <= out[-1][1]:
            out[-1] = (out[-1][0], max(out[-1][1], bottom))
        else:
            out.append((top, bottom))
    return out


def box_area(boxes: list[tuple[float, float, float, float]], height: int, width: int) -> float:
    """Fraction of an height x width picture the (x, y, w, h) boxes cover."""
    mask = np.zeros((height, width), bool)
    for x, y, bw, bh in boxes:
        mask[int(y):int(math.ceil(y + bh)), int(x):int(math.ceil(x + bw))] = True
    return float(mask.mean())


def search_samples(frames: np.ndarray, order: list[int], rows: list[tuple[int, int]], scale: float,
                   config: OverlayTextConfig) -> tuple[list[list], list]:
    """Candidate boxes of the samples ``order`` searched (see the module docstring, 2), and
    the persistent ones among them."""
    t, h, w = frames.shape[:3]
    found: list[list] = []
    overlay: list = []
    for i in order:
        found.append(overlay_candidates(detect_in_strips(frames[i], rows, config, scale), h, config))
        if not found[0]:
            break
        overlay = persistent(found, config, w, len(order)) if len(found) > 1 else []
        if box_area(overlay, h, w) >= config.text_area_min:
            break
        rows = rows_around([b for boxes in found for b in boxes], h)
    return found, overlay


def judge(frames: np.ndarray, times: np.ndarray, config: OverlayTextConfig) -> Verdict:
    """Judge burned-in text in one scene: frames T x h x w x 3 uint8 RGB, times T seconds."""
    if not config.enabled:
        return Verdict(keep=True)
    check_frames(frames, times)
    times = np.asarray(times, np.float64)
    t, h, w = frames.shape[:3]
    rows = [(0, round(config.zone_top * h)), (round((1 - config.zone_bottom) * h), h)]
    if config.search == "frame" or rows[0][1] >= rows[1][0]:
        rows = [(0, h)]
    picks = sample_indices(t, config.n_samples)
    # The middle sample first: the others are searched only when it shows text, and only in the
    # rows where the samples before found some (a box elsewhere could not persist); the search
    # stops as soon as the samples seen already make the verdict.
    order = sorted(picks.tolist(), key=lambda i: abs(i - (t - 1) / 2))
    found, overlay = search_samples(frames, order, rows, config.detect_scale, config)
    if found and found[0] and box_area(overlay, h, w) < config.text_area_min and config.closer_scale:
        # Text was seen but did not make the verdict: look again, closer, where it was.
        rows = rows_around([b for boxes in found for b in boxes], h)
        found, overlay = search_samples(frames, order, rows, config.closer_scale, config)
    text_area = box_area(overlay, h, w)
    scores = {"text_area": text_area, "text_boxes": float(len(overlay)), "text_samples": float(len(found))}
    has_text = text_area >= config.text_area_min
    if has_text and config.skip_drawn:
        kind = judge_type(frames, times, VideoTypeConfig())
        if not kind.keep:
            return Verdict(keep=True, scores={**scores, "text_area": 0.0}, tags=("overlay:not_judged",))
    reason = "overlay_text" if has_text and config.action == "reject" else None
    return Verdict(keep=reason is None, reason=reason, scores=scores, tags=("overlay:text",) if has_text else ())
