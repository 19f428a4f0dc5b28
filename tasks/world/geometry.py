"""Pinhole geometry of MuJoCo cameras: intrinsics, projection, back-projection onto a plane,
the fundamental matrix of two known cameras, and Sampson error of ORB matches between views.

Conventions. MuJoCo cameras look along the -z axis of their frame with y up and x right
(`tasks.sim.scene.look_quat` builds exactly that frame); `fovy` is the vertical field of view
and pixels are square. Image coordinates here are OpenCV's: x = column, y = row, the centre
of pixel (0, 0) at (0, 0), so a mask's mean pixel index is its centroid in these units.
Cropping and resizing a frame (`square`) maps pixel centres affinely, so the camera of the
new frame is the same pinhole with its focal length and principal point mapped alike.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import cv2
import numpy as np

# MuJoCo camera axes (x right, y up, z backward) to OpenCV's (x right, y down, z forward).
_MJ_TO_CV = np.diag([1.0, -1.0, -1.0])


@dataclass(frozen=True)
class PinholeCamera:
    """A square-pixel pinhole camera of width x height pixels: focal length and principal point
    in pixels (OpenCV image coordinates), at `position` (world, m) with `rotation` (3 x 3, the
    camera's x, y, z axes in world coordinates as columns, MuJoCo's axes: x right, y up, looking along -z)."""

    width: int
    height: int
    focal_px: float
    cx: float
    cy: float
    position: np.ndarray
    rotation: np.ndarray

    @classmethod
    def from_fovy(cls, width: int, height: int, fovy_deg: float, position, rotation) -> "PinholeCamera":
        f = height / 2 / math.tan(math.radians(fovy_deg) / 2)
        return cls(int(width), int(height), f, width / 2 - 0.5, height / 2 - 0.5,
                   np.array(position, float), np.array(rotation, float).reshape(3, 3))  # copies: MuJoCo's
        # data.cam(name).xpos / xmat are views that the next step overwrites

    @classmethod
    def from_manifest(cls, camera) -> "PinholeCamera":
        """A world-mounted `schemas.manifest.Camera`, posed as the scene builder poses it."""
        if camera.mount != "world":
            raise ValueError(f"camera {camera.name!r} rides on the {camera.mount}: take its pose from the simulation")
        import mujoco

        from tasks.sim.scene import look_quat

        mat = np.zeros(9)
        mujoco.mju_quat2Mat(mat, look_quat(camera.position, camera.look_at))
        return cls.from_fovy(camera.resolution[0], camera.resolution[1], camera.fovy_deg, camera.position, mat)

    @classmethod
    def from_mujoco(cls, model, data, name: str, width: int, height: int) -> "PinholeCamera":
        """Camera `name` where it is in `data` (after mj_forward): any mount; render-time jitter aside."""
        return cls.from_fovy(width, height, float(model.camera(name).fovy[0]), data.cam(name).xpos,
                             data.cam(name).xmat)

    def square(self, size: int) -> "PinholeCamera":
        """The camera of frames centre-cropped to a square and resized to size x size
        (`tasks.tokenize.data.square`, which is how frames reach the tokenizer)."""
        side = min(self.width, self.height)
        top, left = (self.height - side) // 2, (self.width - side) // 2
        scale = size / side
        return replace(self, width=size, height=size, focal_px=self.focal_px * scale,
                       cx=(self.cx - left + 0.5) * scale - 0.5, cy=(self.cy - top + 0.5) * scale - 0.5)

    @property
    def intrinsics(self) -> np.ndarray:
        """K (3 x 3) in OpenCV pixel coordinates."""
        return np.array([[self.focal_px, 0.0, self.cx], [0.0, self.focal_px, self.cy], [0.0, 0.0, 1.0]])

    def extrinsics(self) -> tuple[np.ndarray, np.ndarray]:
        """(R, t) with x_cam = R x_world + t in OpenCV camera axes (x right, y down, z forward)."""
        r = _MJ_TO_CV @ self.rotation.T
        return r, -r @ self.position

    def project(self, points: np.ndarray) -> np.ndarray:
        """World points ``N x 3`` -> pixel coordinates ``N x 2`` (x, y); NaN behind the camera."""
        r, t = self.extrinsics()
        cam = np.atleast_2d(np.asarray(points, float)) @ r.T + t
        uvw = cam @ self.intrinsics.T
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = uvw[:, :2] / uvw[:, 2:]
        uv[cam[:, 2] <= 0] = np.nan
        return uv

    def to_plane(self, pixels: np.ndarray, z: float) -> np.ndarray:
        """Back-project pixels ``N x 2`` along their rays onto the world plane at height z:
        ``N x 3`` (NaN where the ray is parallel to the plane or meets it behind the camera)."""
        r, _ = self.extrinsics()
        pix = np.atleast_2d(np.asarray(pixels, float))
        rays = np.linalg.solve(self.intrinsics, np.column_stack([pix, np.ones(len(pix))]).T).T @ r
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (z - self.position[2]) / rays[:, 2]
        s[~(s > 0)] = np.nan
        return self.position + s[:, None] * rays


def fundamental_matrix(a: PinholeCamera, b: PinholeCamera) -> np.ndarray:
    """F with x_b^T F x_a = 0 for the images of one world point in cameras a and b."""
    ra, ta = a.extrinsics()
    rb, tb = b.extrinsics()
    r = rb @ ra.T  # camera a's axes to camera b's
    t = tb - r @ ta
    tx = np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])
    f = np.linalg.inv(b.intrinsics).T @ tx @ r @ np.linalg.inv(a.intrinsics)
    return f / np.linalg.norm(f)


def sampson_distances(f: np.ndarray, pa: np.ndarray, pb: np.ndarray) -> np.ndarray:
    """Sampson distance (px, the first-order geometric error) of each match pa[i] <-> pb[i]."""
    xa = np.column_stack([pa, np.ones(len(pa))])
    xb = np.column_stack([pb, np.ones(len(pb))])
    fa, fb = xa @ f.T, xb @ f
    num = np.sum(xb * fa, axis=1) ** 2
    den = fa[:, 0] ** 2 + fa[:, 1] ** 2 + fb[:, 0] ** 2 + fb[:, 1] ** 2
    return np.sqrt(num / np.maximum(den, 1e-12))


def orb_matches(img_a: np.ndarray, img_b: np.ndarray, features: int = 500, ratio: float = 0.8,
                min_side: int = 256) -> tuple[np.ndarray, np.ndarray]:
    """ORB matches (Lowe's ratio test) between two RGB uint8 images: pixel coordinates ``N x 2`` each.

    Small frames are upscaled (cubic) until their short side reaches `min_side`, since ORB's
    31-pixel patches leave almost nothing of a 64-pixel frame; the points are mapped back to
    the original pixel grid. Each image is stretched to its full grey range first, so a dim
    scene still gives corners.
    """
    pts = []
    grey = []
    scale = max(1.0, min_side / min(img_a.shape[:2]))
    for img in (img_a, img_b):
        g = cv2.cvtColor(np.ascontiguousarray(img), cv2.COLOR_RGB2GRAY)
        g = cv2.normalize(g, None, 0, 255, cv2.NORM_MINMAX)
        if scale > 1:
            g = cv2.resize(g, None, fx=scale, fy=scale, interpolation=cv2.INTER_CUBIC)
        grey.append(g)
    orb = cv2.ORB_create(nfeatures=features)
    (ka, da), (kb, db) = (orb.detectAndCompute(g, None) for g in grey)
    if da is None or db is None or len(ka) < 2 or len(kb) < 2:
        return np.zeros((0, 2)), np.zeros((0, 2))
    pairs = cv2.BFMatcher(cv2.NORM_HAMMING).knnMatch(da, db, k=2)
    good = [p[0] for p in pairs if len(p) == 2 and p[0].distance < ratio * p[1].distance]
    for keys, idx in ((ka, [m.queryIdx for m in good]), (kb, [m.trainIdx for m in good])):
        xy = np.array([keys[i].pt for i in idx], float).reshape(-1, 2)
        pts.append((xy + 0.5) / scale - 0.5)  # keypoint coordinates to the original pixel grid
    return pts[0], pts[1]


def sampson_error(img_a: np.ndarray, img_b: np.ndarray, cam_a: PinholeCamera, cam_b: PinholeCamera,
                  features: int = 500) -> dict:
    """Mean and median Sampson distance (px of these images) of ORB matches under the known geometry."""
    pa, pb = orb_matches(img_a, img_b, features)
    for cam, img in ((cam_a, img_a), (cam_b, img_b)):
        if (cam.height, cam.width) != img.shape[:2]:
            raise ValueError(f"a {cam.width}x{cam.height} camera for a {img.shape[1]}x{img.shape[0]} image")
    f = fundamental_matrix(cam_a, cam_b)
    d = sampson_distances(f, pa, pb) if len(pa) else np.zeros(0)
    return {"matches": int(len(d)), "mean_px": float(d.mean()) if len(d) else math.nan,
            "median_px": float(np.median(d)) if len(d) else math.nan}


def sampson_table(views: dict[str, list[tuple[np.ndarray, np.ndarray]]], cam_a: PinholeCamera, cam_b: PinholeCamera,
                  horizons: list[int]) -> list[dict]:
    """Per horizon and source (e.g. "simulator", "model"): the Sampson distances of the ORB
    matches between the two views, pooled over windows. views[source] lists, per window, the
    frames of camera a and of camera b, ``n x S x S x 3`` uint8 each, at the same instants."""
    size = next(iter(views.values()))[0][0].shape[1]
    f = fundamental_matrix(cam_a.square(size), cam_b.square(size))
    rows = []
    for h in horizons:
        for source, windows in views.items():
            d = [sampson_distances(f, *orb_matches(a[h - 1], b[h - 1])) for a, b in windows]
            d = np.concatenate(d) if d else np.zeros(0)
            rows.append({"horizon": h, "source": source, "matches": int(len(d)),
                         "mean_px": float(d.mean()) if len(d) else None,
                         "median_px": float(np.median(d)) if len(d) else None})
    return rows
