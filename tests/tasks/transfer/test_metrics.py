"""Transfer metrics (tasks/transfer/metrics.py): each scores a perfect copy as perfect and a
damaged one worse."""

import cv2
import numpy as np
import pytest

from tasks.transfer.metrics import (adjusted_rand_index, grey_median, backward_flows, clip_edges, colour_cluster_score,
                                    colour_distance, edge_f, frechet_distance, kmeans, matched_edges,
                                    outlines, package_agreement, region_colour_score, warp_error)


def scene(frames: int = 6, size: int = 32, step: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """A grey table with a red box moving right ``step`` px a frame and a fixed blue bar:
    (frames F x H x W x 3 uint8, segmentation F x H x W: 0 table, 1 box, 2 bar)."""
    clip = np.full((frames, size, size, 3), (120, 120, 110), np.uint8)
    seg = np.zeros((frames, size, size), np.uint8)
    for t in range(frames):
        x = 4 + step * t
        clip[t, 10:18, x:x + 8] = (200, 40, 30)
        seg[t, 10:18, x:x + 8] = 1
        clip[t, 24:28, 4:28] = (30, 40, 180)
        seg[t, 24:28, 4:28] = 2
    return clip, seg


def test_edge_f_of_a_clip_with_itself_is_one_and_falls_when_shifted():
    clip, _ = scene()
    edges = clip_edges(clip)
    assert edges.any()
    assert edge_f(edges, edges)["f"] == 1.0
    one = edge_f(np.roll(edges, 1, axis=2), edges)  # a 1 px shift is inside the tolerance
    assert one["f"] > 0.95
    along = edge_f(np.roll(edges, 3, axis=2), edges)  # horizontal edges slide along themselves
    assert 0.5 < along["f"] < 0.9
    far = edge_f(np.roll(edges, (3, 3), axis=(1, 2)), edges)
    assert far["f"] < 0.5  # only crossings of shifted and unshifted outlines still match
    assert edge_f(np.zeros_like(edges), edges)["f"] == 0.0


def test_edges_on_the_outlines_ignore_a_texture_inside_an_object():
    clip, seg = scene()
    textured = clip.copy()
    textured[:, :7, ::4] = (60, 60, 50)  # stripes on the table above the objects
    mask = outlines(seg)
    assert mask.any() and not mask[:, :7].any()  # only where the classes meet
    src, out = clip_edges(clip), clip_edges(textured)
    assert edge_f(out, src)["f"] < 0.8  # every stripe is an edge the source lacks
    assert edge_f(out & mask, src & mask)["f"] == pytest.approx(1.0)  # the objects' outlines are all kept
    moved = np.roll(textured, (2, 2), axis=(1, 2))
    assert edge_f(clip_edges(moved) & mask, src & mask)["f"] < 0.5  # outlines moved: structure lost


def test_edge_matching_is_one_to_one():
    """Two predicted pixels next to one true pixel: only one of them matches it."""
    ref = np.zeros((5, 5), bool)
    ref[2, 2] = True
    pred = np.zeros((5, 5), bool)
    pred[2, 1] = pred[2, 3] = True
    assert matched_edges(pred, ref) == 1
    assert matched_edges(pred, ref, tolerance=0.5) == 0
    diagonal = np.zeros((5, 5), bool)
    diagonal[3, 3] = True
    assert matched_edges(diagonal, ref) == 1  # sqrt(2) is within 1.5 px


def test_clip_edges_use_one_threshold_pair_for_the_clip():
    """A darker copy of a frame in the same clip loses edges a per-frame threshold would keep."""
    clip, _ = scene(frames=2)
    dim = clip.copy()
    dim[1] = (clip[1] * 0.15).astype(np.uint8)
    edges = clip_edges(dim)
    assert edges[0].sum() > edges[1].sum()


def test_clip_edges_at_the_sources_exposure_find_a_dark_copys_edges():
    clip, _ = scene(frames=2)
    dark = (clip * 0.06).astype(np.uint8)  # steps of at most 12 grey levels: near the rule's floor of 10
    source = clip_edges(clip)
    median = grey_median(clip)
    assert np.array_equal(clip_edges(clip, median), source)  # the source itself: gain 1
    plain, matched = edge_f(clip_edges(dark), source)["f"], edge_f(clip_edges(dark, median), source)["f"]
    assert matched > 0.8 and matched > plain + 0.2, (plain, matched)


def test_package_agreement_counts_lost_and_far_frames_as_misses():
    ref = np.array([[10.0, 10], [11, 10], [12, 10], [np.nan, np.nan]])
    assert package_agreement(ref, ref) == {"share": 1.0, "frames": 3, "lost": 0, "median_px": 0.0}
    track = np.array([[10.0, 11.5], [np.nan, np.nan], [15, 10], [0, 0]])
    got = package_agreement(track, ref)
    assert got["share"] == pytest.approx(1 / 3) and got["lost"] == 1 and got["frames"] == 3


def test_adjusted_rand_index_ignores_label_names_and_scores_noise_near_zero():
    a = np.repeat([0, 1, 2], 50)
    assert adjusted_rand_index(a, (a + 1) % 3 + 7) == pytest.approx(1.0)
    rng = np.random.default_rng(0)
    assert abs(adjusted_rand_index(a, rng.integers(0, 3, a.size))) < 0.05
    assert adjusted_rand_index(a, np.where(a == 2, 1, a)) < 0.7  # two segments merged


def test_kmeans_separates_distinct_colours():
    points = np.concatenate([np.full((30, 3), 10.0), np.full((20, 3), 200.0), np.full((10, 3), (200.0, 0, 0))])
    labels = kmeans(points, 3)
    assert adjusted_rand_index(labels, np.repeat([0, 1, 2], [30, 20, 10])) == 1.0


def test_colour_clusters_are_kept_by_a_recolouring_and_lost_by_noise():
    clip, seg = scene()
    assert colour_cluster_score(clip, seg) == pytest.approx(1.0)
    recoloured = clip[..., ::-1].copy() // 2  # other colours, darker: same regions
    assert colour_cluster_score(recoloured, seg) == pytest.approx(1.0)
    rng = np.random.default_rng(0)
    noisy = np.clip(clip + rng.normal(0, 60, clip.shape), 0, 255).astype(np.uint8)
    assert colour_cluster_score(noisy, seg) < 0.6


def test_flicker_of_a_static_clip_is_zero_and_a_flickering_output_scores_worse():
    still = np.repeat(scene(frames=1)[0], 5, axis=0)
    assert warp_error(still, backward_flows(still)) == 0.0
    clip, _ = scene(frames=8)
    flows = backward_flows(clip)
    steady = warp_error(clip, flows)
    flicker = clip.astype(np.int16)
    flicker[1::2] += 25  # every other frame brighter
    flickering = np.clip(flicker, 0, 255).astype(np.uint8)
    assert warp_error(flickering, flows) > 3 * steady + 10


def test_warping_along_the_flow_beats_no_warp():
    clip, _ = scene(frames=6, step=2)
    flows = backward_flows(clip)
    still = np.zeros_like(flows)
    assert warp_error(clip, flows) < 0.5 * warp_error(clip, still)


def test_colour_distance_of_a_set_with_itself_is_zero_and_grows_with_the_change():
    clip, _ = scene(frames=12)
    rng = np.random.default_rng(1)
    clip = np.clip(clip + rng.normal(0, 8, clip.shape), 0, 255).astype(np.uint8)  # frames differ a little
    assert colour_distance(clip, clip) == pytest.approx(0.0, abs=1e-9)
    dim = (clip * 0.6).astype(np.uint8)
    dimmer = (clip * 0.3).astype(np.uint8)
    assert 0 < colour_distance(dim, clip) < colour_distance(dimmer, clip)
    assert colour_distance(dim, dimmer) < colour_distance(clip, dimmer)


def test_frechet_distance_of_shifted_gaussians_is_the_squared_shift():
    rng = np.random.default_rng(2)
    a = rng.normal(size=(4000, 3))
    assert frechet_distance(a, a + (3.0, 0, 0)) == pytest.approx(9.0, rel=1e-6)


def test_region_colours_are_kept_by_a_recolouring_and_lost_by_blur_and_noise():
    clip, seg = scene()
    assert region_colour_score(clip, seg) == 1.0
    assert region_colour_score(clip[..., ::-1].copy() // 3, seg) == 1.0  # other colours, dim: same regions
    blurred = np.stack([cv2.GaussianBlur(f, (0, 0), 3) for f in clip])
    assert region_colour_score(blurred, seg) < 0.97  # the box's rim goes to the table
    rng = np.random.default_rng(0)
    noisy = np.clip(clip + rng.normal(0, 60, clip.shape), 0, 255).astype(np.uint8)
    assert region_colour_score(noisy, seg) < region_colour_score(blurred, seg)
