"""A rig's ego-motion, metric, from its views (issue 33 point 4): where the generated frames put
the vehicle, in centimetres.

One camera's frames give its motion only up to scale (`tasks.world.camera_motion`). Here the
scale comes from the scene: the reference frame of every view is a frame whose depth the
simulator rendered (the last context frame), so each corner found in it is a 3D point of the
scene. Tracked into a later frame of the same view (KLT, one hop), the points pin that frame's
pose; the rig is rigid and drives on the floor, so every view's points together fit one planar
motion (x, y, yaw about world z) by robust least squares on the reprojection error. No frame
of the later instant is rendered or read: the later frame can be a render, a reconstruction or
a generated picture, and only what it shows moves the estimate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import cv2
import numpy as np

from tasks.world.camera_motion import MIN_SIDE, _grey, klt_matches
from tasks.world.geometry import PinholeCamera

# Depths (m) that count as the scene: nearer is the rig's own body, farther the far plane.
MIN_DEPTH_M, MAX_DEPTH_M = 0.05, 20.0
# Starting points of the least squares (x, y in m): a stopped rig and a rig moved half a metre each way.
STARTS = ((0.0, 0.0), (0.5, 0.0), (-0.5, 0.0), (0.0, 0.5), (0.0, -0.5))
MIN_POINTS = 8


@dataclass(frozen=True)
class PlanarMotion:
    """A rigid motion of the floor plane: rotate by ``yaw`` (rad) about world z through the
    origin, then move by (``dx``, ``dy``) (m). ``points`` the correspondences it was fitted to."""

    dx: float
    dy: float
    yaw: float
    points: int = 0

    def apply(self, xyz: np.ndarray) -> np.ndarray:
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        return np.asarray(xyz, float) @ rz.T + np.array([self.dx, self.dy, 0.0])

    def move(self, camera: PinholeCamera) -> PinholeCamera:
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        return replace(camera, position=self.apply(camera.position), rotation=rz @ camera.rotation)


def true_motion(before: PinholeCamera, after: PinholeCamera) -> PlanarMotion:
    """The planar motion that takes a rig camera from ``before`` to ``after`` (both world poses)."""
    rz = after.rotation @ before.rotation.T
    yaw = math.atan2(rz[1, 0], rz[0, 0])
    moved = PlanarMotion(0.0, 0.0, yaw).apply(before.position)
    return PlanarMotion(float(after.position[0] - moved[0]), float(after.position[1] - moved[1]), yaw)


def commanded_motion(step_time: np.ndarray, action: np.ndarray, t0: float, t1: float,
                     centre: np.ndarray) -> PlanarMotion:
    """The planar motion the actions command between instants ``t0`` and ``t1`` (s): control step
    k holds ``action[k]`` from ``step_time[k]`` to the next step's start; its first two values
    are the base's velocity in the world frame (m/s) and a third, where there is one, its yaw
    rate (rad/s), about ``centre``, the rig's centre at ``t0``."""
    step_time, action = np.asarray(step_time, float), np.asarray(action, float)
    ends = np.append(step_time[1:], np.inf)
    held = np.clip(np.minimum(ends, t1) - np.maximum(step_time, t0), 0.0, None)
    dx, dy = held @ action[:, 0], held @ action[:, 1]
    yaw = float(held @ action[:, 2]) if action.shape[1] > 2 else 0.0
    turned = PlanarMotion(0.0, 0.0, yaw).apply(centre)
    return PlanarMotion(float(centre[0] + dx - turned[0]), float(centre[1] + dy - turned[1]), yaw)


def backproject(camera: PinholeCamera, pixels: np.ndarray, depth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixels ``N x 2`` of a frame whose depth map (m along the optical axis, ``H x W``) is known
    -> world points ``N x 3`` and each pixel's depth (nearest depth sample)."""
    pixels = np.atleast_2d(np.asarray(pixels, float))
    ij = np.clip(np.round(pixels).astype(int), 0, [camera.width - 1, camera.height - 1])
    d = depth[ij[:, 1], ij[:, 0]]
    r, _ = camera.extrinsics()
    rays = np.linalg.solve(camera.intrinsics, np.column_stack([pixels, np.ones(len(pixels))]).T).T
    return camera.position + (rays * d[:, None]) @ r, d


def fit(views: list[tuple[PinholeCamera, np.ndarray, np.ndarray]], scale_px: float = 0.5) -> PlanarMotion | None:
    """The planar motion that best reprojects each view's world points ``N x 3`` onto their pixels
    ``N x 2`` in the later frame, the view's camera at the reference moved by it (soft-L1 loss,
    ``scale_px`` its knee; the best of `STARTS`). None with fewer than `MIN_POINTS` points."""
    from scipy.optimize import least_squares

    views = [(cam, x, p) for cam, x, p in views if len(x)]
    if sum(len(x) for _, x, _ in views) < MIN_POINTS:
        return None

    def residuals(params: np.ndarray) -> np.ndarray:
        motion = PlanarMotion(*params)
        out = [np.nan_to_num(motion.move(cam).project(x) - p, nan=50.0).ravel() for cam, x, p in views]
        return np.concatenate(out)

    best = None
    for x0, y0 in STARTS:
        found = least_squares(residuals, [x0, y0, 0.0], loss="soft_l1", f_scale=scale_px, x_scale=[0.1, 0.1, 0.05])
        if best is None or found.cost < best.cost:
            best = found
    return PlanarMotion(*map(float, best.x), points=int(sum(len(x) for _, x, _ in views)))


def track_hops(frames: list[np.ndarray], fb_px: float = 0.25) -> list[tuple[np.ndarray, np.ndarray]]:
    """Corners of ``frames[0]`` followed hop by hop through the later frames (pyramidal
    Lucas-Kanade, each hop checked forward and backward as `klt_matches` does): per later frame,
    pixel coordinates ``N x 2`` in the first frame and in that frame of the corners that survive
    every hop up to it."""
    pa, pb = klt_matches(frames[0], frames[1])
    hops = [(pa, pb)]
    for before, after in zip(frames[1:-1], frames[2:]):
        if len(pb):
            scale = max(1.0, MIN_SIDE / min(before.shape[:2]))
            ga, gb = _grey(before, scale), _grey(after, scale)
            start = ((pb + 0.5) * scale - 0.5).astype(np.float32).reshape(-1, 1, 2)
            lk = dict(winSize=(21, 21), maxLevel=3,
                      criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01))
            moved, ok, _ = cv2.calcOpticalFlowPyrLK(ga, gb, start, None, **lk)
            back, ok_back, _ = cv2.calcOpticalFlowPyrLK(gb, ga, moved, None, **lk)
            returned = np.linalg.norm(back - start, axis=2).ravel() < fb_px * scale
            good = (ok.ravel() == 1) & (ok_back.ravel() == 1) & returned
            pa, pb = pa[good], (moved.reshape(-1, 2)[good] + 0.5) / scale - 0.5
        hops.append((pa, pb))
    return hops


def track(frames: list[np.ndarray], fb_px: float = 0.25) -> tuple[np.ndarray, np.ndarray]:
    """The corners of ``frames[0]`` that `track_hops` follows all the way to ``frames[-1]``: their
    pixel coordinates ``N x 2`` in the first and in the last frame."""
    return track_hops(frames, fb_px)[-1]


Tracked = dict[str, tuple[PinholeCamera, np.ndarray, np.ndarray]]  # per view: camera, world points, later pixels


def correspondences_through(reference: dict[str, np.ndarray], laters: list[dict[str, np.ndarray]],
                            cameras: dict[str, PinholeCamera], depths: dict[str, np.ndarray]) -> list[Tracked]:
    """Per later instant, in order (each tracked through the ones before it: hops of a few frames
    keep a long motion trackable, and each hop is tracked once for all the instants after it),
    per view: corners of its reference frame (RGB uint8) lifted to 3D with the reference's depth;
    (the view's camera at the reference, sized as the frames, world points ``N x 3``, their pixels
    ``N x 2`` in that later frame)."""
    out: list[Tracked] = [{} for _ in laters]
    for name, before in (reference.items() if laters else ()):
        for k, (pa, pb) in enumerate(track_hops([before, *(v[name] for v in laters)])):
            if not len(pa):
                continue
            xyz, d = backproject(cameras[name], pa, depths[name])
            keep = (d > MIN_DEPTH_M) & (d < MAX_DEPTH_M)
            out[k][name] = (cameras[name], xyz[keep], pb[keep])
    return out


def correspondences(reference: dict[str, np.ndarray], later: dict[str, np.ndarray],
                    cameras: dict[str, PinholeCamera], depths: dict[str, np.ndarray],
                    via: list[dict[str, np.ndarray]] = ()) -> Tracked:
    """`correspondences_through` into ``later`` alone, through the frames of ``via``."""
    return correspondences_through(reference, [*via, later], cameras, depths)[-1]


def estimate(reference: dict[str, np.ndarray], later: dict[str, np.ndarray], cameras: dict[str, PinholeCamera],
             depths: dict[str, np.ndarray], via: list[dict[str, np.ndarray]] = ()) -> PlanarMotion | None:
    """The rig's motion from the reference instant to a later one: `fit` over every view's
    `correspondences`."""
    return fit(list(correspondences(reference, later, cameras, depths, via).values()))


def error_cm(estimated: PlanarMotion | None, truth: PlanarMotion, centre: np.ndarray) -> tuple[float, float]:
    """(cm, degrees): how far ``estimated`` puts the rig's ``centre`` from where ``truth`` puts
    it, and the yaw difference. NaN when nothing was estimated."""
    if estimated is None:
        return math.nan, math.nan
    cm = 100.0 * float(np.linalg.norm(estimated.apply(centre)[:2] - truth.apply(centre)[:2]))
    yaw = math.degrees(math.remainder(estimated.yaw - truth.yaw, 2 * math.pi))
    return cm, abs(yaw)
