"""The physics evaluation's error plot, drawn with matplotlib: an RGB picture with a line per
method, the same bytes for the same rows, and "no data" panels when a metric is missing."""

from __future__ import annotations

import numpy as np

from tasks.world.plots import COLOURS, error_plot

ROWS = [dict(horizon=h, method=m, pos_err_px=h * k, iou=1 - h * 0.02 * k, psnr=None if m == "ceiling" else 30 - h * k)
        for h in range(1, 17) for k, m in enumerate(COLOURS, 1)]


def test_every_method_is_drawn_in_its_colour():
    pixels = np.asarray(error_plot(ROWS))
    assert pixels.ndim == 3 and pixels.shape[2] == 3 and pixels.shape[1] == 560
    for colour in COLOURS.values():
        assert (np.abs(pixels.astype(int) - colour).sum(axis=-1) < 30).sum() > 200, colour


def test_same_rows_same_picture_and_no_rows_is_not_an_error():
    assert error_plot(ROWS).tobytes() == error_plot(ROWS).tobytes()
    empty = np.asarray(error_plot([]))
    assert empty.shape == np.asarray(error_plot(ROWS)).shape and empty.std() > 0  # axes and "no data"
