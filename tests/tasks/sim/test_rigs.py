"""Rig videos (issue 33 point 4): views tiled into one picture and cut back out, and the
neighbouring views whose geometry a multi-view evaluation checks."""

import numpy as np
import pytest

from tasks.sim.rigs import ring_pairs, tile, untile

LAYOUT = (("front", "right"), ("left", "rear"))


def _views(frames=3, side=8):
    rng = np.random.default_rng(0)
    return {name: rng.integers(0, 256, (frames, side, side, 3), dtype=np.uint8) for row in LAYOUT for name in row}


def test_tiling_puts_each_view_in_its_place_and_untiling_gives_it_back():
    views = _views()
    tiled = tile(views, LAYOUT)
    assert tiled.shape == (3, 16, 16, 3)
    assert np.array_equal(tiled[:, :8, 8:], views["right"]) and np.array_equal(tiled[:, 8:, :8], views["left"])
    back = untile(tiled, LAYOUT)
    assert all(np.array_equal(back[name], views[name]) for name in views)
    # One frame as well as a stack.
    assert np.array_equal(untile(tiled[1], LAYOUT)["rear"], views["rear"][1])


def test_views_of_unequal_length_are_cut_to_the_shortest_and_a_missing_view_is_named():
    views = _views()
    views["rear"] = views["rear"][:2]
    assert tile(views, LAYOUT).shape[0] == 2
    del views["left"]
    with pytest.raises(ValueError, match="no frames of camera.s. left"):
        tile(views, LAYOUT)
    with pytest.raises(ValueError, match="does not split into 2 x 2"):
        untile(np.zeros((15, 16, 3), np.uint8), LAYOUT)


def test_neighbours_are_the_layouts_adjacent_views():
    assert ring_pairs(LAYOUT) == [("front", "right"), ("front", "left"), ("right", "rear"), ("left", "rear")]
    assert ring_pairs((("a", "b", "c"),)) == [("a", "b"), ("b", "c")]
