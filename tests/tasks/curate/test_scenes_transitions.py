"""Transition checks on generated frames: what a dissolve or fade is, and what only looks like one."""

from __future__ import annotations

import cv2
import numpy as np

from tasks.curate.decode import AnalysisFrame
from tasks.curate.scenes import split_scenes

from .test_scenes import FPS, H, W, plane


def spans_of(frames):
    return [(s.start_frame, s.end_frame, s.detail or s.cause)
            for s in split_scenes((AnalysisFrame(i, i / FPS, f) for i, f in enumerate(frames)), FPS, keep_frames=False)
            if s.kind == "transition" or s.cause == "cut"]


def zoom(seed: int, scales, gains):
    big = plane(seed, W + 400, H + 100)
    centre = (big.shape[1] / 2, big.shape[0] / 2)
    out = []
    for scale, gain in zip(scales, gains, strict=True):
        m = cv2.getRotationMatrix2D(centre, 0, scale)
        m[:, 2] += [W / 2 - centre[0], H / 2 - centre[1]]
        frame = gain * cv2.warpAffine(big, m, (W, H), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
        out.append(np.clip(frame, 0, 255).astype(np.uint8))
    return out


def test_a_zoom_with_an_exposure_change_is_not_a_dissolve():
    # Blurred thumbnails of a quick zoom while auto-exposure darkens the frame change
    # smoothly and almost linearly, as a blend would: the middle frame is a shifted, darker
    # copy of an end, which local motion with a gain explains better than a blend does.
    n = 12
    scales = [1.0] * 60 + list(np.linspace(1, 1.3, n)) + [1.3] * 60
    gains = [1.0] * 60 + list(np.linspace(1, 0.6, n)) + [0.6] * 60
    assert spans_of(zoom(5, scales, gains)) == []


def test_a_dissolve_between_views_of_one_place_is_still_a_dissolve():
    # Two views of the same texture, far enough apart that no local shift maps one on the other.
    a, b = zoom(5, [1.0] * 70, [1.0] * 70), zoom(5, [2.2] * 70, [1.0] * 70)
    mix = [np.clip((1 - w) * a[0].astype(np.float32) + w * b[0], 0, 255).astype(np.uint8)
           for w in np.linspace(0, 1, 14)[1:-1]]
    found = spans_of(a + mix + b)
    # (Still shots either side read as blends with weight 0 or 1, so the span may reach into them.)
    assert len(found) == 1 and found[0][2] == "dissolve" and found[0][0] <= 70 and found[0][1] >= 82
