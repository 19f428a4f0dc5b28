"""What a dedup signature measures: the picture inside letterbox and pillarbox bars."""

from __future__ import annotations

import numpy as np

from tasks.curate.dedup_signature import content_box


def test_a_dark_edge_on_one_side_is_picture_but_bars_in_pairs_are_cut():
    rng = np.random.default_rng(7)
    frames = rng.integers(60, 200, (3, 72, 128)).astype(np.uint8)
    one_side = frames.copy()
    one_side[:, :4], one_side[:, :, :6] = 14, 14  # a dim top and left border: no letterbox
    assert content_box(one_side, 24) == (0, 72, 0, 128)
    boxed = frames.copy()
    boxed[:, :9], boxed[:, -8:] = 0, 0  # bars top and bottom: cut to the narrower
    assert content_box(boxed, 24) == (8, 64, 0, 128)
