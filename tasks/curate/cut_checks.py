"""Checks on a cut candidate of the scene split, made on grey thumbnails (``views.py``).

A detector cut where the view leaves and comes back is no cut: the frame after it is unlike the
frame before (best-shift correlation of the blurred thumbnails < ``cut_left_view``, the level of
unrelated pictures) while a frame within ``cut_return_s`` is that view again (>=
``cut_same_view``): a car or a hand passing right in front of the lens (caminandes.mp4 111:
0.46, then 0.97 two frames later; true cuts on the dev set never come back above 0.82). A
one-frame insert that only shares the layout (film leader cards, >= 0.86 across) stays a cut.
A detector cut whose two sides are one view moved (best-shift correlation >= ``cut_same_view``
at a shift of ``PAN_SHIFT`` px or more of the 64-px thumbnail) is a whip pan, not a cut
(armwrestle.mp4 206: 0.96 at 6 px); film leader cards match in place (shift 0-1 px).

A detector peak of ratio ``cut_weak_ratio`` (2) or more that stays under the threshold (3) is a
cut when the pictures either side are unrelated: best-shift correlation of the blurred
thumbnails below ``cut_unrelated`` (0.35), computed inside letterbox and pillarbox bars (border
rows and columns darker than ``BAR_DARK`` in every frame seen so far, less the row at each
bar's edge), since bars shared by both frames make any two pictures correlate. Fast motion on
both sides of a cut raises the neighbours' scores and so lowers the ratio (sintel.mp4 76 and
118: ratio 2-3, correlation 0.05-0.28 inside the bars); a weak peak within one view (an
exposure or keyframe quality pop: 0.9 and up) stays no cut. Two pictures of alike layout
(dark figures on snow either side of sintel.mp4 96: 0.68) are told apart by their edges: a
peak under ``cut_related`` (0.7) whose edge maps (gradient magnitude) correlate under
``cut_unrelated_edges`` (0.5; sintel 96: 0.42) is a cut too. Confirmed peaks keep the
detector's minimum gap to its cuts and pass the same checks as its cuts; for them the view
that comes back may be any of the ``cut_enter_s`` (1/8 s) before the peak, since a car
crossing the lens can fill both frames either side of it (caminandes.mp4 211). View checks
are made inside the bars.

A source shorter than the detector's window (``1 + 2 adaptive_window`` frames, e.g. slides
one frame each) never has a frame judged by it: each pair of its frames is a cut where their
unblurred 64-px thumbnails are unrelated (best-shift correlation < ``cut_left_view``; slides.avi
0.14 and 0.20), with no minimum gap between cuts.
"""

from __future__ import annotations

import cv2
import numpy as np

from tasks.curate.filter_base import picture_box
from tasks.curate.scene_config import SceneConfig
from tasks.curate.scene_rows import THUMB_BLUR
from tasks.curate.views import best_shift, edges, same_view

PAN_SHIFT = 3  # px of thumbnail shift (of 64) from which a view matched across a cut has moved: a pan
BAR_DARK = 24  # grey level under which a border row or column of every frame is a bar (filter_base.active_box)


def inner_box(peak: np.ndarray) -> tuple[int, int, int, int]:
    """(top, bottom, left, right) of the picture inside bars, from the running maximum of
    the unblurred thumbnails: border rows (columns) darker than BAR_DARK in every frame seen
    (98th percentile, as ``filter_base.active_box``). A crop that leaves less than half is no bar."""
    h, w = peak.shape
    top, bottom, left, right = picture_box(peak, BAR_DARK)
    # A row (column) at a bar's edge is part bar in both frames, which makes them look alike.
    return top + (top > 0), bottom - (bottom < h), left + (left > 0), right - (right < w)


def unrelated(before: np.ndarray, after: np.ndarray, peak: np.ndarray, config: SceneConfig) -> bool:
    """Whether the pictures either side of a weak detector peak are unrelated: best-shift
    correlation of their blurred thumbnails, letterbox and pillarbox bars cut off (bars
    seen so far, as dark border rows and columns of every decoded frame), below
    ``cut_unrelated``. ``before``, ``after``: the unblurred thumbnails either side; ``peak``
    their running maximum over the frames seen."""
    top, bottom, left, right = inner_box(peak)
    p, q = (np.ascontiguousarray(t[top:bottom, left:right]) for t in (before, after))
    picture = same_view(*(cv2.GaussianBlur(x, (0, 0), THUMB_BLUR) for x in (p, q)))
    return picture < config.cut_unrelated or (
        picture < config.cut_related and same_view(edges(p), edges(q)) < config.cut_unrelated_edges)


def view_returns(thumbs: np.ndarray, back: int, until: int, peak: np.ndarray, weak: bool,
                 config: SceneConfig) -> bool:
    """Whether the view before a detector cut leaves and comes back: the frame after the cut
    is unlike the frame before it (best-shift correlation < ``cut_left_view``), but one of
    the next ``cut_return_s`` is the same view again (>= ``cut_same_view``) as that frame or,
    for a ``weak`` peak, one of the ``cut_enter_s`` before it (the thing may already be
    entering the frame before the peak; the frame after a weak peak confirmed by ``unrelated``
    has left the view).
    Something passed right in front of the lens (a car, a hand): the same shot goes on. Or
    the two sides are one view moved: a whip pan.

    ``thumbs``: blurred thumbnails from ``back`` frames before the frame before the cut;
    frames ``back + 1`` to ``until - 1`` of it are those that may show the view again.
    """
    top, bottom, left, right = inner_box(peak)  # bars shared by both make any two alike
    thumbs = thumbs[:, top:bottom, left:right]
    before, after = thumbs[back], range(back + 1, until)
    across, shift = best_shift(before, thumbs[back + 1])
    # A weak peak already had unrelated pictures either side (``unrelated``).
    left = weak or across < config.cut_left_view
    views = range(back, -1, -1) if weak else (back,)
    returns = left and any(same_view(thumbs[i], thumbs[j]) >= config.cut_same_view for i in views for j in after)
    return returns or (across >= config.cut_same_view and shift >= PAN_SHIFT)


def picture_cuts(head: list[np.ndarray], config: SceneConfig) -> list[int]:
    """Cuts of a source too short for the detector's window: each pair of its frames whose
    unblurred thumbnails ``head`` are unrelated (best-shift correlation < ``cut_left_view``)."""
    return [pos for pos in range(1, len(head)) if best_shift(head[pos - 1], head[pos])[0] < config.cut_left_view]
