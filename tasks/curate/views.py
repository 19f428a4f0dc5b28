"""How alike two grey thumbnails are: correlation at the best shift, local motion, edges.

The scene split compares pictures this way to tell a dissolve from camera motion
(``transitions.py``) and a cut from something passing in front of the lens or a whip pan
(``cut_checks.py``). Thumbnails are 64 px wide float32 grey pictures.
"""

from __future__ import annotations

import cv2
import numpy as np

MOTION_SHIFT = 6  # px of shift per block at thumbnail size (64 px wide): about a tenth of the picture
MOTION_BLOCKS = 4  # blocks per side, each free to take its own shift


def motion_residual(x: np.ndarray, m: np.ndarray) -> float:
    """Mean |m - x'| where x' is x with one gain and offset fitted to m, each of
    MOTION_BLOCKS x MOTION_BLOCKS blocks then shifted by up to MOTION_SHIFT px to fit best:
    how well local motion (a pan, a shake, a head turning) and an exposure change of x
    explain m."""
    gain, offset = np.polyfit(x.ravel(), m.ravel(), 1) if np.ptp(x) > 0 else (1.0, float(m.mean() - x.mean()))
    r = MOTION_SHIFT
    padded = cv2.copyMakeBorder((gain * x + offset).astype(np.float32), r, r, r, r, cv2.BORDER_REPLICATE)
    h, w = m.shape
    ys = np.linspace(0, h, MOTION_BLOCKS + 1).astype(int)[:-1]
    xs = np.linspace(0, w, MOTION_BLOCKS + 1).astype(int)[:-1]
    best = np.full((len(ys), len(xs)), np.inf)
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            err = np.abs(m - padded[r + dy: r + dy + h, r + dx: r + dx + w])
            best = np.minimum(best, np.add.reduceat(np.add.reduceat(err, ys, axis=0), xs, axis=1))
    return float(best.sum()) / m.size


def best_shift(p: np.ndarray, q: np.ndarray) -> tuple[float, int]:
    """(correlation, shift) of two thumbnails' overlap at the best shift up to MOTION_SHIFT px;
    shift is the larger of its two components, in px (the first best in row order of (dy, dx)).

    The Pearson correlation of each shift's overlap, from six cross-correlations (OpenCV's
    ``matchTemplate``) of the zero-padded pictures and their masks: the overlap's count, sums,
    sums of squares and sum of products. Equal to looping over the 169 shifts to within 1e-6,
    and 18 times faster; an overlap with no variance counts as correlation 1.
    """
    r, (h, w) = MOTION_SHIFT, p.shape
    p = np.asarray(p, np.float32) - np.float32(np.mean(p))  # centred: float32 sums keep their precision
    q = np.asarray(q, np.float32) - np.float32(np.mean(q))
    ones = np.ones((h, w), np.float32)
    pp = cv2.copyMakeBorder(p, r, r, r, r, cv2.BORDER_CONSTANT, value=0)
    mask = cv2.copyMakeBorder(ones, r, r, r, r, cv2.BORDER_CONSTANT, value=0)

    def corr(image: np.ndarray, template: np.ndarray) -> np.ndarray:
        return cv2.matchTemplate(image, template, cv2.TM_CCORR).astype(np.float64)

    n, sa, sb = corr(mask, ones), corr(pp, ones), corr(mask, q)
    saa, sbb, sab = corr(pp * pp, ones), corr(mask, q * q), corr(pp, q)
    cov = sab - sa * sb / n
    norm = np.sqrt(np.maximum(saa - sa * sa / n, 0) * np.maximum(sbb - sb * sb / n, 0))
    flat = norm <= 1e-6 * (n + saa)  # no variance, up to float32 rounding
    values = np.where(flat, 1.0, cov / np.where(flat, 1.0, norm))
    k = int(np.argmax(values))
    dy, dx = divmod(k, 2 * r + 1)
    return float(values.flat[k]), max(abs(dy - r), abs(dx - r))


def same_view(p: np.ndarray, q: np.ndarray) -> float:
    """Correlation of two thumbnails' overlap at the best shift up to MOTION_SHIFT px: near 1
    for two moments of one shot (gain and offset do not matter), near 0 for unrelated shots."""
    return best_shift(p, q)[0]


def edges(thumb: np.ndarray) -> np.ndarray:
    """Gradient magnitude of an unblurred grey thumbnail, blurred by 1 px: where its edges are."""
    gx = cv2.Sobel(thumb, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(thumb, cv2.CV_32F, 0, 1, ksize=3)
    return cv2.GaussianBlur(cv2.magnitude(gx, gy), (0, 0), 1.0)
