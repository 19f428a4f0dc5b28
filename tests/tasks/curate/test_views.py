"""How alike two thumbnails are: the fast best-shift correlation against the loop over every shift."""

from __future__ import annotations

import cv2
import numpy as np

from tasks.curate.views import MOTION_SHIFT, best_shift


def _best_shift_by_loop(p, q, r):
    """The reference: Pearson correlation of the overlap at every shift, the first best kept."""
    h, w = p.shape
    best, shift = -1.0, 0
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            a = p[max(0, dy): h + min(0, dy), max(0, dx): w + min(0, dx)].ravel().astype(np.float64)
            b = q[max(0, -dy): h + min(0, -dy), max(0, -dx): w + min(0, -dx)].ravel().astype(np.float64)
            a, b = a - a.mean(), b - b.mean()
            norm = float(np.sqrt((a @ a) * (b @ b)))
            corr = float(a @ b) / norm if norm > 0 else 1.0
            if corr > best:
                best, shift = corr, max(abs(dy), abs(dx))
    return best, shift


def test_best_shift_equals_the_loop_over_every_shift():
    rng = np.random.default_rng(7)
    for trial in range(40):
        p = cv2.GaussianBlur((rng.random((36, 64)) * 255).astype(np.float32), (0, 0), rng.uniform(0.5, 4))
        q = np.roll(p, (int(rng.integers(-5, 6)), int(rng.integers(-5, 6))), (0, 1)) * rng.uniform(0.5, 2)
        q = (q + rng.normal(0, rng.uniform(0, 30), p.shape)).astype(np.float32)
        if trial % 4 == 0:  # flat regions: bars, a black frame
            p[:8], q[:, :20] = 0, 7
        got, want = best_shift(p, q), _best_shift_by_loop(p, q, MOTION_SHIFT)
        assert abs(got[0] - want[0]) < 1e-5 and got[1] == want[1]
    black = np.zeros((36, 64), np.float32)
    assert best_shift(black, black) == _best_shift_by_loop(black, black, MOTION_SHIFT)
