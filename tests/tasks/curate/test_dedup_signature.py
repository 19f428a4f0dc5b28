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


def test_the_stacked_phash_is_imagehash_bit_for_bit():
    import cv2

    from tasks.curate.dedup_signature import _phash64, _phash64_many, _phash_input

    rng = np.random.default_rng(7)
    pictures = [rng.integers(0, 256, (144, 256), np.uint8),
                cv2.GaussianBlur(rng.integers(0, 256, (120, 200), np.uint8), (0, 0), 5),
                np.full((90, 160), 77, np.uint8),  # flat: every coefficient but the first is 0
                np.tile(np.arange(256, dtype=np.uint8), (144, 1)),
                np.ascontiguousarray(rng.integers(0, 256, (144, 256), np.uint8)[10:130, 20:230])]
    many = _phash64_many(np.stack([_phash_input(p) for p in pictures]))
    assert many.dtype == np.uint64
    assert list(many) == [_phash64(p) for p in pictures]
