"""Concealment smear on generated frames and on the real concealment in armwrestle.mp4."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from tasks.curate.smear import SMEAR_MIN, smear_fraction

from .test_scenes import H, W, plane


def streaked(frame: np.ndarray, top: int) -> np.ndarray:
    """``frame`` with every row from ``top`` down replaced by row ``top - 1``: what a decoder
    does when it conceals the lost slices of the lower picture."""
    out = frame.copy()
    out[top:] = out[top - 1]
    return out


def grey(frame: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(np.clip(frame, 0, 255).astype(np.uint8), cv2.COLOR_RGB2GRAY)


def textured(seed: int) -> np.ndarray:
    """A grey picture with fine detail (foliage, gravel): smooth noise plus pixel noise."""
    rng = np.random.default_rng(seed)
    return grey(plane(seed)[:H, :W] + rng.normal(0, 12, (H, W, 1)))


def test_rows_stretched_down_a_textured_picture_are_smear():
    picture = textured(4)
    assert smear_fraction(picture) < SMEAR_MIN / 4
    assert smear_fraction(streaked(picture, H // 2)) >= SMEAR_MIN


def test_smooth_pictures_with_a_stretched_row_are_below_the_line():
    # Without detail across the stretched row, neighbouring columns differ by under EDGE_STEP:
    # the measure needs the streaks it names, not just a still lower half.
    picture = grey(plane(4)[:H, :W])
    assert smear_fraction(streaked(picture, H // 2)) < SMEAR_MIN


def test_colour_bars_and_flat_or_dark_pictures_are_not_smear():
    bars = np.zeros((H, W), np.uint8)
    for k, level in enumerate((235, 210, 180, 150, 120, 90, 60, 16)):
        bars[:, k * W // 8:(k + 1) * W // 8] = level
    assert smear_fraction(bars) < SMEAR_MIN  # each edge is one streak column (7 of 160), not a field of them
    assert smear_fraction(np.full((H, W), 128, np.uint8)) == 0.0
    assert smear_fraction(np.zeros((8, W), np.uint8)) == 0.0  # shorter than a streak


def test_the_real_concealment_frame_is_the_only_smeared_one():
    from tasks.curate.decode import analysis_frames
    from tests.support import SHARED_DATA

    path = SHARED_DATA / "videos-dev" / "armwrestle.mp4"
    if not path.is_file():
        pytest.skip("../shared/data is absent")
    found = [f.index for f in analysis_frames(path) if smear_fraction(grey(f.image)) >= SMEAR_MIN]
    assert found == [229]


def _reference(picture: np.ndarray) -> float:
    """The measure as first written: int16 steps, a boolean mask and its mean."""
    from tasks.curate.smear import _KERNEL, EDGE_STEP, FLAT_STEP, RUN, WIDTH

    h, w = picture.shape
    if w != WIDTH:
        picture = cv2.resize(picture, (WIDTH, max(1, round(h * WIDTH / w))), interpolation=cv2.INTER_AREA)
    g = picture.astype(np.int16)
    dx = np.abs(np.diff(g, axis=1, append=g[:, -1:]))
    dy = np.abs(np.diff(g, axis=0, append=g[-1:, :]))
    streak = ((dy <= FLAT_STEP) & (dx >= EDGE_STEP)).astype(np.uint8)
    if streak.shape[0] < RUN:
        return 0.0
    return float(cv2.erode(streak, _KERNEL).mean())


@pytest.mark.parametrize("width", [128, 160, 170, 256, 321])
def test_the_uint8_steps_give_the_figure_of_the_int16_ones(width):
    rng = np.random.default_rng(width)
    pictures = [textured(5), streaked(textured(6), H // 3), rng.integers(0, 256, (90, 160), np.uint8),
                np.repeat(rng.integers(0, 256, (1, 160), np.uint8), 90, axis=0)]
    for picture in pictures:
        h, w = picture.shape
        picture = cv2.resize(picture, (width, max(1, round(h * width / w))), interpolation=cv2.INTER_AREA)
        assert smear_fraction(picture) == _reference(picture)
        crop = picture[3:-3, 5:-5]  # a view with a row stride wider than its rows (160 wide from 170)
        assert smear_fraction(crop) == _reference(crop)
