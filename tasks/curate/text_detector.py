"""Text boxes in a picture, from the PP-OCRv4 detection network that ``rapidocr-onnxruntime``
ships (``tasks.weights.TEXT_DETECTOR``), run with onnxruntime.

Only the network's weights come from that package; the little of its pipeline the filter
needs is rebuilt here with numpy and OpenCV (``rapidocr_onnxruntime/ch_ppocr_det``: the input
is BGR scaled to [-1, 1], mean 0.5 and std 0.5 per channel; its sides are multiples of 32).
The network outputs a text-probability map at input resolution. Its DB post-processing is
kept in the simple form that horizontal overlay text needs: the map above ``threshold`` is cut
into connected regions, a region's score is its mean probability, regions scoring below
``box_score`` are dropped, and each kept region's bounding box is grown by the DB "unclip"
offset (area x ``unclip`` / perimeter), since the network marks a shrunken core of each line.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from tasks.weights import TEXT_DETECTOR, session


@dataclass(frozen=True, slots=True)
class TextBox:
    """One detected text region in the coordinates of the picture it was found in."""

    x: float
    y: float
    w: float
    h: float
    score: float

    @property
    def area(self) -> float:
        return self.w * self.h


def input_size(h: int, w: int, long_side: int) -> tuple[int, int]:
    """(height, width) of the network input for an h x w picture scaled so its long side is
    ``long_side`` (up or down), each side rounded to a multiple of 32 (at least 32)."""
    k = long_side / max(h, w)
    return max(32, int(round(h * k / 32)) * 32), max(32, int(round(w * k / 32)) * 32)


def probability(images: np.ndarray, long_side: int, threads: int = 1) -> np.ndarray:
    """N x H x W float32 text probability of N x h x w x 3 uint8 RGB pictures of one size, each
    resized to the network input (see ``input_size``); one batched run of the network."""
    n, h, w, _ = images.shape
    ih, iw = input_size(h, w, long_side)
    batch = np.empty((n, 3, ih, iw), np.float32)
    for i, image in enumerate(images):
        resized = cv2.resize(image, (iw, ih), interpolation=cv2.INTER_LINEAR if ih > h else cv2.INTER_AREA)
        # BGR as the network was trained on, (v / 255 - 0.5) / 0.5
        batch[i] = resized[..., ::-1].transpose(2, 0, 1) * np.float32(2 / 255) - np.float32(1)
    return session(TEXT_DETECTOR, threads).run(None, {"x": batch})[0][:, 0]


def boxes(prob: np.ndarray, shape: tuple[int, int], threshold: float = 0.3, box_score: float = 0.5,
          unclip: float = 1.6, min_side: int = 3) -> list[TextBox]:
    """Text boxes of one H x W probability map, in the coordinates of an h x w (``shape``)
    picture the map was computed from."""
    ph, pw = prob.shape
    h, w = shape
    sx, sy = w / pw, h / ph
    mask = (prob > threshold).astype(np.uint8)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    out = []
    for i in range(1, n):
        x, y, bw, bh, area = (int(v) for v in stats[i])
        if min(bw, bh) < min_side:
            continue
        region = labels[y:y + bh, x:x + bw] == i
        score = float(prob[y:y + bh, x:x + bw][region].mean())
        if score < box_score:
            continue
        d = bw * bh * unclip / (2 * (bw + bh))
        x0, y0 = max(0.0, x - d), max(0.0, y - d)
        x1, y1 = min(float(pw), x + bw + d), min(float(ph), y + bh + d)
        out.append(TextBox(x0 * sx, y0 * sy, (x1 - x0) * sx, (y1 - y0) * sy, score))
    return out


def detect(images: np.ndarray, long_side: int, threshold: float = 0.3, box_score: float = 0.5,
           unclip: float = 1.6, threads: int = 1) -> list[list[TextBox]]:
    """Text boxes of each of N x h x w x 3 uint8 RGB pictures, detected at ``long_side``."""
    probs = probability(images, long_side, threads)
    return [boxes(p, images.shape[1:3], threshold, box_score, unclip) for p in probs]
