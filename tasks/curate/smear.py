"""Decoder concealment smear: frames a damaged stream was patched into.

When an H.264 slice is lost, the decoder conceals it by stretching the last good rows
downwards: the picture turns into vertical streaks, each column one colour over a long
run while neighbouring columns differ. The decoder does not flag such a frame corrupt, so
the frame itself is measured: the share of the picture in streaks, that is pixels whose
vertical step is at most ``FLAT_STEP`` grey levels and horizontal step at least
``EDGE_STEP``, over ``RUN`` rows in a row, at a width of ``WIDTH`` pixels.

On the 26 real videos of ``../shared/data`` (2026-11-25) the two concealment frames score
0.155 and 0.163; every other frame is under 0.04 (the highest: SMPTE colour bars, whose
vertical edges are streaks of one pixel column each, 0.039; then a film leader, 0.026).
``SMEAR_MIN`` sits at their geometric middle, 0.08: a frame needs about twice the streaked
area of a full-screen bar chart to count.
"""

from __future__ import annotations

import cv2
import numpy as np

WIDTH = 160
RUN = 17  # rows (at WIDTH) a streak runs down unchanged: about a tenth of a 16:9 picture
FLAT_STEP = 2
EDGE_STEP = 6
SMEAR_MIN = 0.08

_KERNEL = np.ones((RUN, 1), np.uint8)


def smear_fraction(grey: np.ndarray) -> float:
    """Share of an h x w uint8 grey frame covered by vertical concealment streaks (0..1).

    The steps are ``cv2.absdiff`` of neighbouring rows and columns in uint8 (the last row and
    column step 0, as if the picture were repeated one pixel further), and the share is the
    count of eroded streak pixels over the frame's size: the same figure as the int16 steps
    and mean it replaced, at about half the cost (it runs on every analysed frame twice: in
    the scene split and in the quality filter)."""
    h, w = grey.shape
    if w != WIDTH:
        grey = cv2.resize(grey, (WIDTH, max(1, round(h * WIDTH / w))), interpolation=cv2.INTER_AREA)
    if grey.shape[0] < RUN:
        return 0.0
    dx = np.zeros_like(grey)
    cv2.absdiff(grey[:, 1:], grey[:, :-1], dst=dx[:, :-1])
    dy = np.zeros_like(grey)
    cv2.absdiff(grey[1:], grey[:-1], dst=dy[:-1])
    streak = ((dy <= FLAT_STEP) & (dx >= EDGE_STEP)).view(np.uint8)
    return cv2.countNonZero(cv2.erode(streak, _KERNEL)) / streak.size


def smeared(grey: np.ndarray) -> bool:
    return smear_fraction(grey) >= SMEAR_MIN
