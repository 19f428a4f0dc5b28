"""Camera control, measured (issue 33, point 3): the camera's relative motion re-estimated from
two frames and scored against the true relative pose.

Conventions. Poses are OpenCV's: x right, y down, z forward, and a relative pose (R, t) maps
camera a's coordinates to camera b's, x_b = R x_a + t (t in metres when true; a unit vector
when estimated, since two frames fix the direction of travel but not its length). Pixels are
`tasks.world.geometry`'s: x = column, y = row, pixel centres at integers.

The estimate: point correspondences between the frames, then the essential matrix with the
known intrinsics (`cv2.findEssentialMat`, RANSAC) and its decomposition (`cv2.recoverPose`).
Frames are 64 x 64, so both matchers work on the frames upscaled to `MIN_SIDE` pixels and
contrast-stretched (dim scenes) and map their points back. Correspondences are KLT by default
(corners tracked by pyramidal Lucas-Kanade, kept when tracking back lands within a fraction of a
pixel of the start); ORB (`geometry.orb_matches`) is the alternative: its keypoints, found on
coarse pyramid levels, were less exact on 64 px aisle renders (2026-11-26: median rotation
error 0.6 against KLT's 0.2 degrees for yaws of 2-10 degrees, 30 degrees on some poses).
"""

from __future__ import annotations

import math
from collections import defaultdict
from dataclasses import dataclass

import cv2
import numpy as np

from tasks.world.geometry import PinholeCamera, orb_matches

MIN_SIDE = 256  # both matchers see the frames upscaled to this short side
STILL_PX = 0.3  # median flow below this (px of the frames): the camera did not move
MIN_TRANSLATION_M = 1e-3  # a true translation shorter than this has no direction to score
STEP_TURN_DEG = 15.0  # the most a rig turns between consecutive frames (300 deg/s at 20 fps)
FAILED_DIRECTION_DEG = 90.0  # the expected angle between a random direction and any other


@dataclass(frozen=True)
class Motion:
    """An estimated relative pose: R (3 x 3, camera a to camera b, OpenCV axes), t (unit vector of
    x_b = R x_a + t, or None when the frames show no motion), the matches found, the RANSAC
    inliers kept, and the median displacement of the matches (px of the input frames)."""

    R: np.ndarray
    t: np.ndarray | None
    matches: int
    inliers: int
    median_flow_px: float


def relative_pose(cam_a: PinholeCamera, cam_b: PinholeCamera) -> tuple[np.ndarray, np.ndarray]:
    """(R, t) with x_b = R x_a + t: camera a's OpenCV coordinates to camera b's, t in metres."""
    ra, ta = cam_a.extrinsics()
    rb, tb = cam_b.extrinsics()
    r = rb @ ra.T
    return r, tb - r @ ta


def _grey(img: np.ndarray, scale: float) -> np.ndarray:
    g = cv2.cvtColor(np.ascontiguousarray(img), cv2.COLOR_RGB2GRAY)
    g = cv2.normalize(g, None, 0, 255, cv2.NORM_MINMAX)
    return cv2.resize(g, None, fx=scale, fy=scale, interpolation=cv2.INTER_CUBIC) if scale > 1 else g


def klt_matches(img_a: np.ndarray, img_b: np.ndarray, corners: int = 400, fb_px: float = 0.25,
                min_side: int = MIN_SIDE) -> tuple[np.ndarray, np.ndarray]:
    """Shi-Tomasi corners of img_a tracked into img_b by pyramidal Lucas-Kanade: pixel coordinates
    ``N x 2`` each (of the input frames), kept where tracking back returns within `fb_px` (px of
    the input frames) of the corner. RGB uint8 frames, upscaled and stretched as `orb_matches` does."""
    scale = max(1.0, min_side / min(img_a.shape[:2]))
    ga, gb = _grey(img_a, scale), _grey(img_b, scale)
    pa = cv2.goodFeaturesToTrack(ga, corners, 0.01, 2 * scale)
    if pa is None:
        return np.zeros((0, 2)), np.zeros((0, 2))
    lk = dict(winSize=(21, 21), maxLevel=3, criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01))
    pb, ok, _ = cv2.calcOpticalFlowPyrLK(ga, gb, pa, None, **lk)
    back, ok_back, _ = cv2.calcOpticalFlowPyrLK(gb, ga, pb, None, **lk)
    good = (ok.ravel() == 1) & (ok_back.ravel() == 1) & (np.linalg.norm(back - pa, axis=2).ravel() < fb_px * scale)
    to_frame = lambda p: (p.reshape(-1, 2)[good] + 0.5) / scale - 0.5  # noqa: E731
    return to_frame(pa), to_frame(pb)


def estimate_motion(img_a: np.ndarray, img_b: np.ndarray, intrinsics: np.ndarray, matcher: str = "klt",
                    min_matches: int = 12, still_px: float = STILL_PX, threshold_px: float = 0.5,
                    rotation_share: float = 1.0, seed: int = 0, up: np.ndarray | None = None,
                    max_turn_deg: float = 45.0) -> Motion | None:
    """The camera's motion from frame a to frame b (RGB uint8, the same size), K the 3 x 3
    intrinsics of both. matcher: "klt" or "orb" (see the module docstring).

    None when fewer than `min_matches` correspondences (or RANSAC inliers) are found: a blank
    or unrelated frame. When the median match moves less than `still_px`, the frames show no
    motion: R = identity, t = None (a held frame says the camera stood still). Otherwise a
    pure rotation (R fitted alone, t = None) competes with the essential matrix and wins when it
    explains at least `rotation_share` times as many matches as the essential matrix's inliers:
    without parallax the essential matrix is degenerate (any t fits) and its R goes astray, and
    a small translation of a 64 px camera often leaves no parallax to see (its direction then
    counts as unknown). threshold_px is the inlier distance of both models in px of the input
    frames; `seed` fixes RANSAC's draws. With `up` (the rig's rotation axis in camera a's
    OpenCV coordinates) the motion is fitted as a rig's that turns only about it and moves across
    it (`planar_motion`) instead of by the general essential matrix.
    """
    if matcher not in ("klt", "orb"):
        raise ValueError(f"matcher: 'klt' or 'orb', not {matcher!r}")
    pa, pb = (klt_matches if matcher == "klt" else orb_matches)(img_a, img_b)
    if len(pa) < min_matches:
        return None
    flow = float(np.median(np.linalg.norm(pb - pa, axis=1)))
    if flow < still_px:
        return Motion(np.eye(3), None, len(pa), len(pa), flow)
    k = np.asarray(intrinsics, float)
    if up is not None:
        r, t, fits = planar_motion(pa, pb, k, up, threshold_px, max_turn_deg)
        return None if fits < min_matches else Motion(r, t, len(pa), fits, flow)
    r_only, fits_only = _rotation_only(pa, pb, k, threshold_px)
    cv2.setRNGSeed(seed)
    e, mask = cv2.findEssentialMat(pa, pb, k, cv2.RANSAC, 0.999, threshold_px)
    inliers = 0
    if e is not None and e.shape == (3, 3) and mask is not None and int(mask.sum()) >= min_matches:
        inliers, r, t, _ = cv2.recoverPose(e, pa, pb, k, mask=mask.copy())
    if fits_only >= max(min_matches, rotation_share * inliers):
        return Motion(r_only, None, len(pa), fits_only, flow)
    if inliers < min_matches:
        return None
    return Motion(r, t.ravel() / np.linalg.norm(t), len(pa), int(inliers), flow)


def _axis_rotations(up: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """Rotations ``A x 3 x 3`` about the unit axis `up` by each angle (rad), Rodrigues' formula."""
    k = np.array([[0.0, -up[2], up[1]], [up[2], 0.0, -up[0]], [-up[1], up[0], 0.0]])
    s, c = np.sin(angles)[:, None, None], np.cos(angles)[:, None, None]
    return np.eye(3) + s * k + (1 - c) * (k @ k)


def _sampson_sq(f: np.ndarray, xa: np.ndarray, xb: np.ndarray) -> np.ndarray:
    """Squared Sampson distances ``H x N`` of homogeneous matches under fundamental matrices ``H x 3 x 3``."""
    fa, fb = xa @ f.transpose(0, 2, 1), xb @ f
    num = np.sum(xb * fa, axis=2) ** 2
    return num / np.maximum(fa[..., 0] ** 2 + fa[..., 1] ** 2 + fb[..., 0] ** 2 + fb[..., 1] ** 2, 1e-12)


def planar_motion(pa: np.ndarray, pb: np.ndarray, k: np.ndarray, up: np.ndarray, threshold_px: float = 0.5,
                  max_turn_deg: float = 45.0) -> tuple[np.ndarray, np.ndarray | None, int]:
    """The motion of a camera on a rig that turns only about `up` (its rotation axis in camera a's
    OpenCV coordinates, e.g. world z for a ground vehicle) and moves only across it: (R, unit t
    or None, the matches it explains). Two unknowns, the turn and the direction of travel,
    where the general essential matrix has five, so a few dozen matches on a 64 px frame fix
    them. Searched on a grid (turns of 0.5 degrees up to max_turn_deg, directions every
    2 degrees), refined on a finer one, scored by truncated Sampson distance; the sign of t by
    cheirality (the matches in front of both cameras). A pure turn competes (as in
    `estimate_motion`): when it explains at least as many matches, t is None."""
    up = np.asarray(up, float) / np.linalg.norm(up)
    e1 = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    kinv = np.linalg.inv(k)
    xa, xb = (np.column_stack([p, np.ones(len(p))]) for p in (pa, pb))
    tau = threshold_px ** 2

    def best(turns, dirs):
        rs = _axis_rotations(up, turns)
        ts = np.cos(dirs)[:, None] * e1 + np.sin(dirs)[:, None] * e2
        tx = np.zeros((len(ts), 3, 3))
        tx[:, 0, 1], tx[:, 0, 2], tx[:, 1, 2] = -ts[:, 2], ts[:, 1], -ts[:, 0]
        tx -= tx.transpose(0, 2, 1)
        f = (kinv.T @ (tx[:, None] @ rs[None]) @ kinv).reshape(-1, 3, 3)
        cost = np.minimum(_sampson_sq(f, xa, xb), tau).sum(axis=1)
        i = int(np.argmin(cost))
        return turns[i % len(turns)], dirs[i // len(turns)]

    limit = math.radians(max_turn_deg)
    turn, direction = best(np.arange(-limit, limit + 1e-9, math.radians(0.5)), np.radians(np.arange(0, 180, 2.0)))
    turn, direction = best(turn + np.radians(np.arange(-0.5, 0.51, 0.05)),
                           direction + np.radians(np.arange(-2.0, 2.01, 0.2)))
    r = _axis_rotations(up, np.array([turn]))[0]
    t = math.cos(direction) * e1 + math.sin(direction) * e2
    tx = np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])
    d = _sampson_sq((kinv.T @ tx @ r @ kinv)[None], xa, xb)[0]
    fits = int((d < tau).sum())
    # A pure turn about the same axis: the homography K R K^-1, its reprojection error.
    turns = np.arange(-limit, limit + 1e-9, math.radians(0.1))
    proj = (xa @ kinv.T) @ _axis_rotations(up, turns).transpose(0, 2, 1) @ k.T
    err = np.linalg.norm(proj[..., :2] / proj[..., 2:] - pb, axis=2)
    i = int(np.argmin(np.minimum(err ** 2, tau).sum(axis=1)))
    turned = int((err[i] < threshold_px).sum())
    if turned >= fits:
        return _axis_rotations(up, turns[i:i + 1])[0], None, turned
    # Cheirality: the sign of t that puts most inliers in front of both cameras (x_b ~ R x_a + t:
    # depths za, zb with za R ra - zb rb = -t, least squares per match).
    rays = np.stack([xa[d < tau] @ kinv.T @ r.T, -(xb[d < tau] @ kinv.T)], axis=2)
    depths = np.array([np.linalg.lstsq(m, -t, rcond=None)[0] for m in rays]).reshape(-1, 2)
    ahead = int((depths > 0).all(axis=1).sum())
    if 2 * ahead < len(depths):  # -t gives the depths negated: most are in front with it
        t = -t
    return r, t, fits


def _rotation_only(pa: np.ndarray, pb: np.ndarray, k: np.ndarray, threshold_px: float) -> tuple[np.ndarray, int]:
    """The rotation R with K R K^-1 pa ~ pb (no translation) by least squares on the bearing
    vectors (Kabsch), refitted twice on the matches it explains; and how many it explains
    within threshold_px."""
    rays = [np.column_stack([p, np.ones(len(p))]) @ np.linalg.inv(k).T for p in (pa, pb)]
    ua, ub = (r / np.linalg.norm(r, axis=1, keepdims=True) for r in rays)
    keep = np.ones(len(pa), bool)
    for _ in range(3):
        u, _, vt = np.linalg.svd(ub[keep].T @ ua[keep])
        r = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
        proj = ua @ r.T @ k.T
        err = np.linalg.norm(proj[:, :2] / proj[:, 2:] - pb, axis=1)
        keep = err < max(threshold_px, np.median(err)) if keep.sum() >= 3 else keep
    return r, int((err < threshold_px).sum())


def rotation_error_deg(r_est: np.ndarray, r_true: np.ndarray) -> float:
    """Angle (degrees, [0, 180]) of the rotation r_est @ r_true.T that takes the truth to the estimate."""
    d = np.asarray(r_est, float) @ np.asarray(r_true, float).T
    sine = np.linalg.norm([d[2, 1] - d[1, 2], d[0, 2] - d[2, 0], d[1, 0] - d[0, 1]]) / 2
    return math.degrees(math.atan2(sine, (np.trace(d) - 1) / 2))  # exact near 0, unlike acos


def direction_error_deg(t_est: np.ndarray | None, t_true: np.ndarray | None,
                        min_norm: float = MIN_TRANSLATION_M) -> float:
    """Angle (degrees, [0, 180]) between two translation directions; NaN when either is None or
    the true translation is shorter than min_norm (no direction to score)."""
    if t_est is None or t_true is None or np.linalg.norm(t_true) < min_norm or not np.linalg.norm(t_est) > 0:
        return math.nan
    a, b = np.asarray(t_est, float), np.asarray(t_true, float)
    c = a @ b / (np.linalg.norm(a) * np.linalg.norm(b))
    return math.degrees(math.acos(float(np.clip(c, -1.0, 1.0))))


def motion_errors(img_a: np.ndarray, img_b: np.ndarray, cam_a: PinholeCamera, cam_b: PinholeCamera,
                  planar: bool = False, **options) -> dict:
    """One pair of frames scored against the true motion between the cameras that (should have)
    taken them; options go to `estimate_motion` (cam_a's intrinsics are used for both frames);
    `planar`: fit the motion of a ground rig turning about world z (`planar_motion`).

    rotation_deg: angle between estimated and true rotation; direction_deg: angle between the
    estimated and true translation directions (NaN when the camera truly did not move; when
    it did but the estimate saw no motion, 90). When no motion could be estimated at all
    (estimate_motion gave None; "estimated" is False) the failure counts as seeing no motion:
    rotation_deg is the true rotation angle and direction_deg is 90 degrees, the expected angle
    of a random direction. Also true_rotation_deg, true_translation_m and matches."""
    r_true, t_true = relative_pose(cam_a, cam_b)
    moved = float(np.linalg.norm(t_true)) >= MIN_TRANSLATION_M
    if planar:  # a ground rig: it turns about world z, which camera a's mount puts at this axis
        options["up"] = cam_a.extrinsics()[0] @ np.array([0.0, 0.0, 1.0])
    motion = estimate_motion(img_a, img_b, cam_a.intrinsics, **options)
    r_est = np.eye(3) if motion is None else motion.R
    if not moved:
        direction = math.nan
    elif motion is None or motion.t is None:
        direction = FAILED_DIRECTION_DEG
    else:
        direction = direction_error_deg(motion.t, t_true)
    return {"rotation_deg": rotation_error_deg(r_est, r_true), "direction_deg": direction,
            "true_rotation_deg": rotation_error_deg(r_true, np.eye(3)),
            "true_translation_m": float(np.linalg.norm(t_true)),
            "matches": 0 if motion is None else motion.matches, "estimated": motion is not None}


def trajectory_errors(frames: list[np.ndarray] | np.ndarray, cams: list[PinholeCamera], planar: bool = True,
                      steps: dict | None = None, keys: list | None = None, **options) -> list[dict]:
    """The camera's trajectory re-estimated along a clip (visual odometry) and scored at every
    frame against the truth: frames[0] is the reference, frames[h] the frame h steps later,
    cams[h] the camera that (should have) taken it. Each step's motion is estimated between
    consecutive frames (`estimate_motion`, planar as in `motion_errors`) and composed, so
    large motions over many frames, which no single pair of 64 px frames keeps enough matches
    across, are followed in small steps. Two frames fix a step's direction, not its length:
    the composed translation takes every moving step as equally long (a rig whose speed
    changes little over the clip); a step that saw no motion, or a turn only, adds none, and a
    failed step counts as no motion. Returns, for h = 1 .. len(frames) - 1, the keys of
    `motion_errors` (estimated: every step up to h was).

    ``steps``, with ``keys`` (one hashable per frame), keeps each step's estimate under
    ``(keys[h - 1], keys[h])`` across calls, so clips that share frames (overlapping windows of
    one episode's true frames) estimate each step once; the options must not change between
    calls that share it."""
    r_acc, t_acc, ok, out = np.eye(3), np.zeros(3), True, []
    for h in range(1, len(frames)):
        a, b = cams[h - 1], cams[h]
        # Consecutive frames: a turn of more than STEP_TURN_DEG between them is not a rig's.
        opts = dict({"max_turn_deg": STEP_TURN_DEG, **options},
                    up=a.extrinsics()[0] @ np.array([0.0, 0.0, 1.0])) if planar else options
        key = None if steps is None or keys is None else (keys[h - 1], keys[h])
        if key is not None and key in steps:
            step = steps[key]
        else:
            step = estimate_motion(frames[h - 1], frames[h], a.intrinsics, **opts)
            if key is not None:
                steps[key] = step
        ok = ok and step is not None
        r_step = np.eye(3) if step is None else step.R
        t_step = np.zeros(3) if step is None or step.t is None else step.t
        r_acc, t_acc = r_step @ r_acc, r_step @ t_acc + t_step
        r_true, t_true = relative_pose(cams[0], b)
        moved = float(np.linalg.norm(t_true)) >= MIN_TRANSLATION_M
        if not moved:
            direction = math.nan
        elif np.linalg.norm(t_acc) < 1e-9:
            direction = FAILED_DIRECTION_DEG
        else:
            direction = direction_error_deg(t_acc, t_true)
        out.append({"rotation_deg": rotation_error_deg(r_acc, r_true), "direction_deg": direction,
                    "true_rotation_deg": rotation_error_deg(r_true, np.eye(3)),
                    "true_translation_m": float(np.linalg.norm(t_true)),
                    "matches": 0 if step is None else step.matches, "estimated": ok})
    return out


def motion_table(rows: list[dict]) -> list[dict]:
    """Per (horizon, source), sorted: pairs, mean and median rotation_deg, the mean true rotation, mean and median
    direction_deg (over pairs with a true translation; None when none has), and failures
    (pairs not "estimated"). rows: `motion_errors` dicts with "horizon" and "source" added."""
    groups: dict[tuple[int, str], list[dict]] = defaultdict(list)
    for row in rows:
        groups[(int(row["horizon"]), str(row["source"]))].append(row)
    out = []
    for (horizon, source), group in sorted(groups.items()):
        rot = np.array([r["rotation_deg"] for r in group], float)
        dirs = np.array([r["direction_deg"] for r in group], float)
        dirs = dirs[~np.isnan(dirs)]
        out.append({"horizon": horizon, "source": source, "pairs": len(group),
                    "rotation_mean_deg": float(rot.mean()), "rotation_median_deg": float(np.median(rot)),
                    "true_rotation_mean_deg": float(np.mean([r["true_rotation_deg"] for r in group])),
                    "direction_mean_deg": float(dirs.mean()) if len(dirs) else None,
                    "direction_median_deg": float(np.median(dirs)) if len(dirs) else None,
                    "failures": sum(not r["estimated"] for r in group)})
    return out
