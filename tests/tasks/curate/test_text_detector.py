"""The PP-OCRv4 text detector (tasks/curate/text_detector.py) on rendered pictures: a line of
text drawn at a known place is found there, and a picture without text gives no box."""

from __future__ import annotations

import cv2
import numpy as np

from tasks.curate import text_detector


def test_a_rendered_text_line_is_found_where_it_was_drawn():
    img = np.full((160, 640, 3), 200, np.uint8)
    text, org, scale = "the boats were already gone", (40, 100), 1.0
    (tw, th), base = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, 2)
    cv2.putText(img, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, (20, 20, 20), 2, cv2.LINE_AA)
    found = text_detector.detect(img[None], 640)[0]
    assert found
    # Drawn box: x 40..40+tw, y 100-th..100+base. The boxes found cover it and little else.
    x0, y0 = min(b.x for b in found), min(b.y for b in found)
    x1, y1 = max(b.x + b.w for b in found), max(b.y + b.h for b in found)
    assert abs(x0 - org[0]) <= 8 and abs(x1 - (org[0] + tw)) <= 8, (x0, x1, tw)
    assert y0 <= org[1] - th + 4 and y1 >= org[1] and y1 - y0 <= 2.5 * (th + base), (y0, y1, th)
    assert all(b.score >= 0.5 for b in found)


def test_no_text_on_a_flat_or_a_natural_looking_picture():
    flat = np.full((160, 480, 3), 128, np.uint8)
    rng = np.random.default_rng(0)
    noise = cv2.resize(rng.random((20, 60, 3)).astype(np.float32), (480, 160), interpolation=cv2.INTER_CUBIC)
    noise += 0.15 * rng.random((160, 480, 3)).astype(np.float32)  # grain over smooth shading
    natural = np.clip(noise * 160 + 30, 0, 255).astype(np.uint8)
    assert text_detector.detect(np.stack([flat, natural]), 480) == [[], []]


def test_input_size_rounds_to_multiples_of_32():
    assert text_detector.input_size(144, 256, 512) == (288, 512)
    assert text_detector.input_size(10, 10, 20) == (32, 32)
