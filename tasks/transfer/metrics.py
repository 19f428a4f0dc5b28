"""Does a transferred clip keep the source's structure and move its look? (issue 32 points 4, 5)

Pure functions on numpy arrays: clips are F x H x W x 3 uint8 RGB, edge maps F x H x W bool,
segmentations F x H x W integer labels. Each function's docstring gives its definition;
`bench/transfer.py` applies them to held-out simulator pairs (docs/transfer.md).

- Edges: `clip_edges` (Canny with the controls' threshold rule, one pair per clip, at the
  source's exposure), `outlines` (where the segmentation changes class: object outlines) and
  `edge_f` (boundary precision, recall and F with a one-to-one match within a tolerance, as
  the BSDS boundary benchmark counts them).
- Package position: `package_agreement` of two per-frame tracks
  (`tasks.panels.detect.track_package`).
- Colour clusters: `region_colour_score`, how well each segmentation region's own mean colour
  claims its pixels (balanced accuracy); and `colour_cluster_score`, the adjusted Rand index of
  a k-means of each frame's colours against the segmentation (near 0 even on the source on
  push_closeup, whose floor-and-wall class is two colours: reported, not judged).
- Flicker: `warp_error`, the frame-to-frame error after warping frame t - 1 onto t along the
  source's optical flow.
- Distance to a look: `colour_distance`, a Frechet distance (as FID) between per-frame colour
  moments.
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy import linalg
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import maximum_bipartite_matching
from scipy.spatial import cKDTree

from tasks.controls.video import canny_thresholds

EDGE_TOLERANCE_PX = 1.5  # Euclidean: an edge pixel matches one at most one pixel away, diagonals included


def _grey(frames: np.ndarray) -> np.ndarray:
    return np.stack([cv2.cvtColor(np.ascontiguousarray(f), cv2.COLOR_RGB2GRAY) for f in frames])


def grey_median(frames: np.ndarray) -> float:
    """The median grey level of a clip (F x H x W x 3 uint8): its exposure for `clip_edges`."""
    return float(np.median(_grey(frames)))


def clip_edges(frames: np.ndarray, median: float | None = None) -> np.ndarray:
    """F x H x W x 3 uint8 -> F x H x W bool: Canny on each grey frame with one pair of
    thresholds for the whole clip from its own median grey level
    (`tasks.controls.video.canny_thresholds`, the rule `frame_controls` uses).

    ``median``: first scale the clip's grey levels by one gain so that their median is this
    (the source's), so a darker look is judged at the source's exposure. Without it the
    rule's floor of 10 grey levels drops the edges of a dark clip whoever renders it: the true
    "very dim" render scored edge F 0.55 against its source, 0.86 at the source's exposure."""
    grey = _grey(frames)
    if median is not None:
        gain = median / max(1.0, float(np.median(grey)))
        grey = np.clip(grey * np.float32(gain) + 0.5, 0, 255).astype(np.uint8)
    low, high = canny_thresholds(grey)
    return np.stack([cv2.Canny(g, low, high) > 0 for g in grey])


def matched_edges(pred: np.ndarray, ref: np.ndarray, tolerance: float = EDGE_TOLERANCE_PX) -> int:
    """How many edge pixels of one H x W bool map ``pred`` pair with one of ``ref``: the size of
    a maximum one-to-one matching in which a pixel may pair with one at Euclidean distance
    ``tolerance`` or less (each pixel used at most once, as in the BSDS benchmark's
    correspondence)."""
    a, b = np.argwhere(pred), np.argwhere(ref)
    if not len(a) or not len(b):
        return 0
    near = cKDTree(a).query_ball_tree(cKDTree(b), tolerance)
    rows = np.repeat(np.arange(len(a)), [len(js) for js in near])
    cols = np.fromiter((j for js in near for j in js), int, count=len(rows))
    graph = csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(len(a), len(b)))
    return int((maximum_bipartite_matching(graph, perm_type="column") >= 0).sum())


def edge_f(pred: np.ndarray, ref: np.ndarray, tolerance: float = EDGE_TOLERANCE_PX) -> dict[str, float]:
    """Boundary agreement of edge maps ``pred`` and ``ref`` (F x H x W bool), counts summed
    over frames: matched = sum of `matched_edges` per frame; precision = matched / pred's edge
    pixels, recall = matched / ref's edge pixels, f = their harmonic mean. Two maps without
    any edge score 1; one without edges against one with them scores 0."""
    matched = sum(matched_edges(p, r, tolerance) for p, r in zip(pred, ref))
    n_pred, n_ref = int(pred.sum()), int(ref.sum())
    if n_pred == 0 and n_ref == 0:
        return {"precision": 1.0, "recall": 1.0, "f": 1.0, "matched": 0, "pred": 0, "ref": 0}
    return {"matched": matched, "pred": n_pred, "ref": n_ref, **f_from_counts(matched, n_pred, n_ref)}


def outlines(seg: np.ndarray, width: int = 2) -> np.ndarray:
    """F x H x W labels -> F x H x W bool: pixels within ``width`` px (a square window) of a
    pixel of another class, the objects' outlines. Edges inside one object (a texture, a
    checker) are not on them; `edge_f` of two edge maps both masked by them scores the
    structure a look keeps apart from the textures it adds or removes."""
    kernel = np.ones((2 * width + 1, 2 * width + 1), np.uint8)
    return np.stack([cv2.dilate(s, kernel) != cv2.erode(s, kernel) for s in seg.astype(np.uint8)])


def f_from_counts(matched: int, n_pred: int, n_ref: int) -> dict[str, float]:
    """precision, recall and F of ``matched`` pairs among ``n_pred`` and ``n_ref`` edge pixels
    (0 where a count is 0), so counts of several clips can be pooled before dividing."""
    precision = matched / n_pred if n_pred else 0.0
    recall = matched / n_ref if n_ref else 0.0
    f = 2 * precision * recall / (precision + recall) if precision + recall else 0.0
    return {"precision": precision, "recall": recall, "f": f}


def package_agreement(track: np.ndarray, reference: np.ndarray, within_px: float = 2.0) -> dict[str, float]:
    """Two per-frame package tracks, F x 2 pixel positions with NaN where the package was not
    seen: over the frames where ``reference`` saw it, the share where ``track`` saw it within
    ``within_px`` (Euclidean) of the reference's position; a frame ``track`` lost counts as a
    miss. Also the frames counted, those ``track`` lost, and the median distance where both saw it."""
    counted = ~np.isnan(reference).any(axis=1)
    seen = counted & ~np.isnan(track).any(axis=1)
    dist = np.linalg.norm(track[seen] - reference[seen], axis=1)
    n = int(counted.sum())
    return {"share": float((dist <= within_px).sum() / n) if n else float("nan"), "frames": n,
            "lost": int(n - seen.sum()), "median_px": float(np.median(dist)) if len(dist) else float("nan")}


def kmeans(points: np.ndarray, k: int, seed: int = 0, iterations: int = 25) -> np.ndarray:
    """Labels in [0, k) of N x D ``points`` by Lloyd's k-means from a k-means++ start drawn
    with ``seed`` (deterministic); fewer distinct points than k give fewer clusters."""
    points = points.astype(np.float64)
    rng = np.random.default_rng(seed)
    k = min(k, len(np.unique(points, axis=0)))
    centres = [points[rng.integers(len(points))]]
    for _ in range(1, k):
        d2 = np.min(((points[:, None] - np.array(centres)[None]) ** 2).sum(-1), axis=1)
        centres.append(points[rng.choice(len(points), p=d2 / d2.sum())])
    centres = np.array(centres)
    labels = np.zeros(len(points), int)
    for _ in range(iterations):
        labels = ((points[:, None] - centres[None]) ** 2).sum(-1).argmin(1)
        moved = np.array([points[labels == j].mean(0) if (labels == j).any() else centres[j] for j in range(k)])
        if np.allclose(moved, centres):
            break
        centres = moved
    return labels


def adjusted_rand_index(a: np.ndarray, b: np.ndarray) -> float:
    """Hubert and Arabie's adjusted Rand index of two labellings of the same items: 1 for the
    same partition (whatever the label names), about 0 for unrelated ones. 1 when both put
    every item in one cluster."""
    _, ai = np.unique(a.ravel(), return_inverse=True)
    _, bi = np.unique(b.ravel(), return_inverse=True)
    table = np.zeros((ai.max() + 1, bi.max() + 1))
    np.add.at(table, (ai, bi), 1)
    pairs = lambda x: (x * (x - 1) / 2).sum()  # noqa: E731
    index, rows, cols = pairs(table), pairs(table.sum(1)), pairs(table.sum(0))
    expected = rows * cols / pairs(np.array([float(ai.size)]))
    top = (rows + cols) / 2
    return 1.0 if top == expected else float((index - expected) / (top - expected))


def colour_cluster_score(frames: np.ndarray, seg: np.ndarray, seed: int = 0) -> float:
    """Do the segmentation's regions keep their colour clusters? Per frame: k-means (`kmeans`,
    RGB, k = the number of segmentation classes present in the frame) of the frame's pixel
    colours, scored by `adjusted_rand_index` against the segmentation; the mean over frames."""
    scores = []
    for frame, labels in zip(frames, seg):
        k = len(np.unique(labels))
        scores.append(adjusted_rand_index(kmeans(frame.reshape(-1, 3), k, seed), labels))
    return float(np.mean(scores))


def region_colour_score(frames: np.ndarray, seg: np.ndarray) -> float:
    """Do the segmentation's regions keep their colour clusters? Per frame: each region's
    mean RGB colour in that frame is a centre, every pixel goes to the nearest centre, and the
    score is the balanced accuracy of that assignment against the segmentation (the share of
    each region's pixels that went to its own centre, averaged over the regions present, so a
    small package counts as much as the table); the mean over frames. 1 when every region's
    colours are nearer its own mean than any other's; a uniform scaling of the colours (dim
    light) leaves it unchanged."""
    scores = []
    for frame, labels in zip(frames, seg):
        pixels, labels = frame.reshape(-1, 3).astype(np.float64), labels.ravel()
        classes = np.unique(labels)
        centres = np.stack([pixels[labels == c].mean(0) for c in classes])
        nearest = classes[((pixels[:, None] - centres[None]) ** 2).sum(-1).argmin(1)]
        scores.append(np.mean([(nearest[labels == c] == c).mean() for c in classes]))
    return float(np.mean(scores))


def backward_flows(source: np.ndarray) -> np.ndarray:
    """(F - 1) x H x W x 2: Farneback optical flow from source frame t to t - 1 (t = 1..F-1),
    grey frames, OpenCV's usual parameters (pyramid 0.5, 3 levels, window 15, 3 iterations,
    poly_n 5, sigma 1.2): pixel (x, y) of frame t shows what frame t - 1 has at (x, y) + flow."""
    grey = _grey(source)
    return np.stack([cv2.calcOpticalFlowFarneback(grey[t], grey[t - 1], None, 0.5, 3, 15, 3, 5, 1.2, 0)
                     for t in range(1, len(grey))])


def warp_error(frames: np.ndarray, flows: np.ndarray) -> float:
    """Temporal flicker of a clip along given motion: frame t - 1 warped onto frame t by
    ``flows`` (`backward_flows` of the source clip, bilinear, borders replicated), the mean
    absolute difference from frame t over pixels and channels (0-255 units), averaged over
    t = 1..F-1. A static clip scores 0; a clip that follows the flow exactly scores about 0."""
    h, w = frames.shape[1:3]
    grid = np.stack(np.meshgrid(np.arange(w), np.arange(h)), -1).astype(np.float32)
    errors = []
    for t in range(1, len(frames)):
        maps = grid + flows[t - 1]
        warped = cv2.remap(frames[t - 1], maps[..., 0], maps[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        errors.append(np.abs(frames[t].astype(np.float32) - warped.astype(np.float32)).mean())
    return float(np.mean(errors)) if errors else 0.0


def colour_features(frames: np.ndarray) -> np.ndarray:
    """F x 6 colour moments: each frame's mean and standard deviation of R, G and B in [0, 1]."""
    x = frames.reshape(len(frames), -1, 3).astype(np.float64) / 255
    return np.concatenate([x.mean(1), x.std(1)], 1)


def frechet_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Frechet distance of Gaussians fitted to the rows of ``a`` and ``b`` (N x D each), as FID
    computes it: |mu_a - mu_b|^2 + tr(S_a + S_b - 2 (S_a S_b)^(1/2)), a squared distance."""
    mu_a, mu_b = a.mean(0), b.mean(0)
    s_a, s_b = np.atleast_2d(np.cov(a, rowvar=False)), np.atleast_2d(np.cov(b, rowvar=False))
    root = linalg.sqrtm(s_a @ s_b)
    if not np.isfinite(root).all():  # singular product: regularise as the FID reference code does
        eps = np.eye(len(s_a)) * 1e-8
        root = linalg.sqrtm((s_a + eps) @ (s_b + eps))
    d = float(((mu_a - mu_b) ** 2).sum() + np.trace(s_a + s_b - 2 * np.real(root)))
    return max(d, 0.0)


def colour_distance(frames: np.ndarray, target: np.ndarray) -> float:
    """Distance of a set of frames to a look: `frechet_distance` of their `colour_features`
    (each set's frames pooled over its clips, K x H x W x 3)."""
    return frechet_distance(colour_features(frames), colour_features(target))
