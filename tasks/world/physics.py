"""Physical alignment of world-model rollouts with the simulator (issue 8): where the package is.

Pure functions of frames: the package found by colour (a CIE Lab reference and a distance
threshold, both fitted per episode against the simulator's segmentation), mask IoU, per-frame
PSNR and SSIM, and the per-horizon table that sets a model's predictions beside the
tokenizer's reconstruction of the true future (the ceiling: what perfect codes would give)
and the last reconstructed context frame held still (the floor: copy-last-frame). Positions
are compared in pixels and, through the camera (`tasks.world.geometry`), in centimetres on
the plane of the package's top face.

Why a threshold fitted per episode: with the `appearance` stressor the package's colour is
random per seed and can sit close to the table's, the floor's or the orange arm's; one fixed
threshold either swallows those or misses the package. Why a separate fit for decoded
frames: the tokenizer shifts and blurs colours, and the model's predictions pass through the
same decoder, so the reconstruction is the honest place to fit the detector that reads them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np
import torch
import torch.nn.functional as F

from tasks.world.geometry import PinholeCamera

METHODS = ("model", "shuffled", "floor", "ceiling")
THRESHOLDS = tuple(float(t) for t in range(4, 42, 2))  # Lab distances tried when fitting a colour model
FULL_COVERAGE = 0.99
MIN_VISIBLE = 0.5  # decoded frames: colour models are fitted on frames showing at least half the package


# -- finding the package by colour --------------------------------------------------------
@dataclass(frozen=True)
class ColourModel:
    """Package pixels: Lab distance to `lab` below `threshold`, in a component of at most
    `max_area` pixels (a bigger blob is the arm or a wall, not the package), the largest
    such. `fit_iou`: its mean IoU with the segmentation on the frames it was fitted on."""

    lab: tuple[float, float, float]
    threshold: float
    max_area: int
    fit_iou: float


def to_lab(frames: np.ndarray) -> np.ndarray:
    """``... x H x W x 3`` uint8 RGB -> float32 CIE Lab (L in [0, 100])."""
    flat = frames.reshape(-1, *frames.shape[-3:]).astype(np.float32) / 255.0
    return np.stack([cv2.cvtColor(f, cv2.COLOR_RGB2Lab) for f in flat]).reshape(frames.shape)


def coverage(masks: np.ndarray, size: int) -> np.ndarray:
    """Full-resolution masks ``F x H x W`` bool -> the share of each pixel of the centre
    square resized to size x size that the mask covers: ``F x size x size`` float in [0, 1]
    (area interpolation, as `tasks.tokenize.data.square` resizes the frames)."""
    _, h, w = masks.shape
    side = min(h, w)
    top, left = (h - side) // 2, (w - side) // 2
    x = torch.from_numpy(np.ascontiguousarray(masks[:, top:top + side, left:left + side], dtype=np.float32))
    if side == size:
        return x.numpy()
    mode = "area" if side > size else "bilinear"
    return F.interpolate(x[:, None], size=(size, size), mode=mode).clamp(0, 1)[:, 0].numpy()


def _select(near: np.ndarray, max_area: int) -> np.ndarray:
    n, labels, stats, _ = cv2.connectedComponentsWithStats(near.astype(np.uint8), connectivity=8)
    area = stats[1:, cv2.CC_STAT_AREA].astype(np.int64)
    area[area > max_area] = -1
    if n <= 1 or area.max() <= 0:
        return np.zeros(near.shape, bool)
    return labels == 1 + int(np.argmax(area))


def locate(frames: np.ndarray, model: ColourModel, lab: np.ndarray | None = None) -> np.ndarray:
    """The package's mask in each frame ``F x H x W x 3`` uint8: ``F x H x W`` bool (empty where not found)."""
    lab = to_lab(frames) if lab is None else lab
    near = np.linalg.norm(lab - np.asarray(model.lab, np.float32), axis=-1) < model.threshold
    return np.stack([_select(m, model.max_area) for m in near])


def fit_colour_model(frames: np.ndarray, cover: np.ndarray, thresholds=THRESHOLDS,
                     min_visible: float = 0.0) -> ColourModel | None:
    """Fit the reference colour and threshold on frames ``F x H x W x 3`` whose package
    coverage ``F x H x W`` (`coverage`) is known; None if no pixel is fully the package.

    Reference: the mean Lab of fully covered pixels. Threshold: the one of `thresholds` with
    the best mean IoU against ``cover > 0.5`` over the frames where the package shows, or
    with ``min_visible`` where at least that share of it shows (its area against the largest
    in these frames). Decoded frames are fitted with `MIN_VISIBLE`: when the arm hides all
    but a sliver a pixel wide, a decoder keeps no sliver an IoU could score, and the fit
    would then say the colour does not set the package apart when it does.
    """
    lab = to_lab(frames)
    truth = cover > 0.5
    area = truth.reshape(len(truth), -1).sum(1)
    shown = (area > 0) & (area >= min_visible * area.max())
    full = (cover >= FULL_COVERAGE) & shown[:, None, None]  # the reference comes from the same frames
    if not full.any():
        return None
    ref = tuple(float(v) for v in lab[full].mean(0))
    max_area = int(3 * area.max())
    best = None
    for t in thresholds:
        model = ColourModel(ref, float(t), max_area, 0.0)
        found = locate(frames[shown], model, lab[shown])
        score = float(np.mean([mask_iou(a, b) for a, b in zip(found, truth[shown])]))
        if best is None or score > best.fit_iou + 1e-9:
            best = ColourModel(ref, float(t), max_area, score)
    return best


def centroids(masks: np.ndarray) -> np.ndarray:
    """``F x H x W`` bool -> ``F x 2`` (x = column, y = row) mean pixel of each mask; NaN where empty."""
    out = np.full((len(masks), 2), np.nan)
    for i, m in enumerate(masks):
        ys, xs = np.nonzero(m)
        if len(xs):
            out[i] = xs.mean(), ys.mean()
    return out


def mask_iou(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two bool masks; NaN when both are empty."""
    union = np.logical_or(a, b).sum()
    return float(np.logical_and(a, b).sum() / union) if union else math.nan


# -- image similarity ----------------------------------------------------------------------
def psnr_frames(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """PSNR (dB) of each frame pair of ``F x H x W x 3`` uint8 arrays: ``F``."""
    mse = ((a.astype(np.float64) - b.astype(np.float64)) ** 2).reshape(len(a), -1).mean(1)
    return 10 * np.log10(255.0 ** 2 / np.maximum(mse, 1e-10))


def ssim_frames(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """SSIM of each frame pair (Wang et al. 2004: 11 x 11 Gaussian, sigma 1.5, mean over RGB):
    ``F`` values (bench/tokenizer.py reports their mean)."""
    def planes(v):
        return torch.from_numpy(v).float().permute(0, 3, 1, 2).reshape(-1, 1, *v.shape[1:3])
    x, y = planes(a), planes(b)
    g = torch.exp(-(torch.arange(11) - 5.0) ** 2 / (2 * 1.5 ** 2))
    w = (g / g.sum()).outer(g / g.sum())[None, None]
    mu_x, mu_y = F.conv2d(x, w), F.conv2d(y, w)
    sxx = F.conv2d(x * x, w) - mu_x ** 2
    syy = F.conv2d(y * y, w) - mu_y ** 2
    sxy = F.conv2d(x * y, w) - mu_x * mu_y
    c1, c2 = (0.01 * 255) ** 2, (0.03 * 255) ** 2
    s = ((2 * mu_x * mu_y + c1) * (2 * sxy + c2)) / ((mu_x ** 2 + mu_y ** 2 + c1) * (sxx + syy + c2))
    return s.reshape(len(a), -1).mean(1).numpy().astype(np.float64)


# -- the per-horizon table -------------------------------------------------------------------
@dataclass(frozen=True)
class Window:
    """One prediction window: horizons 1..n after the last context frame.

    true ``n x S x S x 3`` uint8 simulator frames; outputs: "model", "shuffled" and "ceiling"
    (the tokenizer's reconstruction of `true`) ``n x S x S x 3`` uint8; context_last ``S x S x
    3`` the reconstructed last context frame (the floor holds it). true_colour fits `true`
    frames, decoded_colour decoded ones (None: the package could not be found reliably, so the
    window counts for PSNR and SSIM only). camera: the camera of these S x S frames; plane_z
    the height (m) of the package's top face; moved: the package moved in the true future.
    """

    key: str
    true: np.ndarray
    outputs: dict[str, np.ndarray]
    context_last: np.ndarray
    camera: PinholeCamera | None = None
    plane_z: float = 0.0
    moved: bool = False
    true_colour: ColourModel | None = None
    decoded_colour: ColourModel | None = None
    info: dict = field(default_factory=dict)

    def frames(self, method: str) -> np.ndarray:
        if method == "floor":
            return np.repeat(self.context_last[None], len(self.true), axis=0)
        return self.outputs[method]

    @property
    def tracked(self) -> bool:
        return self.moved and self.true_colour is not None and self.decoded_colour is not None


def _nanmean(values) -> float | None:
    v = np.asarray([x for x in values if x is not None and not math.isnan(x)], float)
    return float(v.mean()) if len(v) else None


def horizon_table(windows: list[Window], methods=METHODS) -> list[dict]:
    """One row per horizon h (1..n video frames) and method: mean PSNR and SSIM over all
    windows; over the windows where the package moved (and is found by colour in the true
    frame): position error in px and cm (where the method's frame shows it too), mask IoU
    (0 where it does not) and the share of frames where it was found."""
    if not windows:
        return []
    n = min(len(w.true) for w in windows)
    per: dict[tuple[int, str], dict[str, list]] = {}
    for w in windows:
        true_masks = locate(w.true, w.true_colour) if w.tracked else None
        true_xy = centroids(true_masks) if w.tracked else None
        true_cm = w.camera.to_plane(true_xy, w.plane_z) if w.tracked and w.camera is not None else None
        for method in methods:
            frames = w.frames(method)[:n]
            psnr, ssim = psnr_frames(w.true[:n], frames), ssim_frames(w.true[:n], frames)
            masks = locate(frames, w.decoded_colour) if w.tracked else None
            xy = centroids(masks) if w.tracked else None
            cm = w.camera.to_plane(xy, w.plane_z) if w.tracked and w.camera is not None else None
            for h in range(n):
                acc = per.setdefault((h + 1, method), {k: [] for k in ("psnr", "ssim", "px", "cm", "iou", "found")})
                acc["psnr"].append(psnr[h])
                acc["ssim"].append(ssim[h])
                if not w.tracked or np.isnan(true_xy[h, 0]):
                    continue
                acc["iou"].append(mask_iou(masks[h], true_masks[h]))
                acc["found"].append(float(not np.isnan(xy[h, 0])))
                if not np.isnan(xy[h, 0]):
                    acc["px"].append(float(np.linalg.norm(xy[h] - true_xy[h])))
                    if cm is not None:
                        acc["cm"].append(100 * float(np.linalg.norm(cm[h, :2] - true_cm[h, :2])))
    rows = []
    for (h, method), acc in sorted(per.items(), key=lambda kv: (kv[0][0], methods.index(kv[0][1]))):
        rows.append({"horizon": h, "method": method, "psnr": _nanmean(acc["psnr"]), "ssim": _nanmean(acc["ssim"]),
                     "pos_err_px": _nanmean(acc["px"]), "pos_err_cm": _nanmean(acc["cm"]),
                     "iou": _nanmean(acc["iou"]), "found": _nanmean(acc["found"]),
                     "windows": len(acc["psnr"]), "tracked": len(acc["iou"])})
    return rows


def shuffle_actions(actions: np.ndarray, first_row: int, seed: int = 0) -> np.ndarray:
    """Actions ``N x R x F`` with rows ``first_row..`` (the ones leading into predicted
    frames) taken from another window: a random derangement over windows, so no window keeps
    its own. One window alone gets its rows in reverse order."""
    out = actions.copy()
    n = len(actions)
    if n == 1:
        out[0, first_row:] = actions[0, first_row:][::-1]
        return out
    rng = np.random.default_rng(seed)
    while True:
        perm = rng.permutation(n)
        if np.all(perm != np.arange(n)):
            break
    out[:, first_row:] = actions[perm, first_row:]
    return out


# -- quality gates (recorded, never asserted) ---------------------------------------------------
def _by(rows: list[dict], method: str, key: str, min_h: int) -> dict[int, float]:
    return {r["horizon"]: r[key] for r in rows
            if r["method"] == method and r["horizon"] >= min_h and r[key] is not None}


def check_beats_floor(rows: list[dict], min_h: int = 4, every: int = 4) -> dict:
    """Position error below copy-last-frame's at every reported horizon >= min_h."""
    model, floor = _by(rows, "model", "pos_err_px", min_h), _by(rows, "floor", "pos_err_px", min_h)
    hs = [h for h in sorted(model) if h % every == 0 and h in floor]
    return {"passed": bool(hs) and all(model[h] < floor[h] for h in hs), "horizons": hs,
            "margin_px": [floor[h] - model[h] for h in hs]}


def check_actions_matter(rows: list[dict], min_h: int = 4, ratio: float = 0.9) -> dict:
    """True actions clearly better than shuffled ones: mean position error over horizons >=
    min_h at most `ratio` times the shuffled-action model's."""
    model, shuffled = _by(rows, "model", "pos_err_px", min_h), _by(rows, "shuffled", "pos_err_px", min_h)
    hs = [h for h in model if h in shuffled]
    if not hs:
        return {"passed": False, "ratio": None, "needed": ratio}
    got = np.mean([model[h] for h in hs]) / max(np.mean([shuffled[h] for h in hs]), 1e-9)
    return {"passed": bool(got <= ratio), "ratio": float(got), "needed": ratio}


def check_psnr_between(rows: list[dict], every: int = 4) -> dict:
    """The model's PSNR between the floor's and the ceiling's at every reported horizon."""
    model, floor, ceiling = (_by(rows, m, "psnr", 1) for m in ("model", "floor", "ceiling"))
    hs = [h for h in sorted(model) if h % every == 0]
    inside = [floor[h] <= model[h] <= ceiling[h] for h in hs]
    return {"passed": bool(hs) and all(inside), "horizons": hs, "inside": inside}
