"""Headless multi-camera rendering: one EGL context, one scene, a viewport per camera.

Shadows and reflections are off (they cost several times the frame time on this CPU).
Camera jitter is a small rotation of the GL camera applied at render time, so it moves the
picture without touching physics.
"""

from __future__ import annotations

import math

import numpy as np

import tasks.sim  # noqa: F401  (sets MUJOCO_GL before mujoco loads)
import mujoco
from schemas.manifest import CameraJitter


def jitter_angles(jitter: CameraJitter, phases: np.ndarray, t: float) -> np.ndarray:
    """(yaw, pitch, roll) radians at time t: two incommensurate sines per axis, seeded phases.

    phases: (3, 2) in [0, 2 pi). The second sine runs at 1.7 x frequency so the shake does
    not repeat every period; the peak never exceeds amplitude_deg.
    """
    amp = math.radians(jitter.amplitude_deg)
    w = 2 * math.pi * jitter.frequency_hz * t
    out = 0.6 * np.sin(w + phases[:, 0]) + 0.4 * np.sin(1.7 * w + phases[:, 1])
    return amp * out * np.array([1.0, 1.0, 0.5])


def _rotate(vec: np.ndarray, axis: np.ndarray, angle: float) -> np.ndarray:
    axis = axis / np.linalg.norm(axis)
    return (vec * math.cos(angle) + np.cross(axis, vec) * math.sin(angle)
            + axis * np.dot(axis, vec) * (1 - math.cos(angle)))


class MultiCameraRenderer:
    """Renders named model cameras at their own sizes. Close it (or use `with`) when done."""

    def __init__(self, model: mujoco.MjModel, sizes: dict[str, tuple[int, int]]):
        """sizes: camera name -> (width, height) in pixels; each must fit the offscreen buffer."""
        self._model = model
        self._sizes = dict(sizes)
        width = max(w for w, _ in sizes.values())
        height = max(h for _, h in sizes.values())
        if width > model.vis.global_.offwidth or height > model.vis.global_.offheight:
            raise ValueError(f"camera size {width}x{height} exceeds the model's offscreen buffer "
                             f"{model.vis.global_.offwidth}x{model.vis.global_.offheight}")
        self._cam_ids = {}
        for name in sizes:
            cid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, name)
            if cid < 0:
                raise ValueError(f"camera {name!r} is not in the model")
            self._cam_ids[name] = cid
        self._gl = mujoco.GLContext(width, height)
        self._gl.make_current()
        self._ctx = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_100)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._ctx)
        self._scene = mujoco.MjvScene(model, maxgeom=4000)
        self._scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = False
        self._scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = False
        self._option = mujoco.MjvOption()
        self._camera = mujoco.MjvCamera()
        self._camera.type = mujoco.mjtCamera.mjCAMERA_FIXED

    def _update(self, data: mujoco.MjData, name: str, angles: np.ndarray | None) -> mujoco.MjrRect:
        self._gl.make_current()
        self._camera.fixedcamid = self._cam_ids[name]
        mujoco.mjv_updateScene(self._model, data, self._option, None, self._camera,
                               mujoco.mjtCatBit.mjCAT_ALL, self._scene)
        if angles is not None and np.any(angles):
            for glcam in self._scene.camera:
                fwd = np.array(glcam.forward, float)
                up = np.array(glcam.up, float)
                right = np.cross(fwd, up)
                fwd, up = _rotate(fwd, up, angles[0]), up
                fwd, up = _rotate(fwd, right, angles[1]), _rotate(up, right, angles[1])
                up = _rotate(up, fwd, angles[2])
                glcam.forward, glcam.up = fwd, up
        w, h = self._sizes[name]
        return mujoco.MjrRect(0, 0, w, h)

    def render(self, data: mujoco.MjData, name: str, angles: np.ndarray | None = None) -> np.ndarray:
        """H x W x 3 uint8 RGB of camera `name`, rotated by (yaw, pitch, roll) radians if given."""
        rect = self._update(data, name, angles)
        mujoco.mjr_render(rect, self._scene, self._ctx)
        out = np.empty((rect.height, rect.width, 3), np.uint8)
        mujoco.mjr_readPixels(out, None, rect, self._ctx)
        return out[::-1].copy()  # GL rows run bottom-up

    def depth(self, data: mujoco.MjData, name: str, angles: np.ndarray | None = None) -> np.ndarray:
        """H x W float64 depth in metres along camera `name`'s optical axis (as `render` places it,
        jitter included), 0 where nothing is nearer than the far plane."""
        rect = self._update(data, name, angles)
        mujoco.mjr_render(rect, self._scene, self._ctx)
        raw = np.empty((rect.height, rect.width), np.float32)
        mapping = self._ctx.readDepthMap
        self._ctx.readDepthMap = mujoco.mjtDepthMap.mjDEPTH_ZEROFAR  # reversed z: precision where it is near
        try:
            mujoco.mjr_readPixels(None, raw, rect, self._ctx)
        finally:
            self._ctx.readDepthMap = mapping
        extent = self._model.stat.extent
        near, far = self._model.vis.map.znear * extent, self._model.vis.map.zfar * extent
        raw = raw[::-1].astype(np.float64)
        # Perspective depth buffer, zero at the far plane (MuJoCo's renderer_test.py): d = n (f - z) / (z (f - n)).
        metres = near * far / (near + raw * (far - near))
        metres[raw <= 0] = 0.0
        return metres

    def segment(self, data: mujoco.MjData, name: str, angles: np.ndarray | None = None) -> np.ndarray:
        """H x W int32 geom id seen at each pixel of camera `name` (rotated as `render` does),
        -1 where nothing is."""
        rect = self._update(data, name, angles)
        flags = self._scene.flags
        flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = True
        flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = True
        try:
            mujoco.mjr_render(rect, self._scene, self._ctx)
            rgb = np.empty((rect.height, rect.width, 3), np.uint8)
            mujoco.mjr_readPixels(rgb, None, rect, self._ctx)
        finally:
            flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = False
            flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = False
        seg = rgb[::-1].astype(np.int64)
        seg = seg[..., 0] + seg[..., 1] * 256 + seg[..., 2] * 65536  # segid + 1; 0 is background
        lookup = np.full(self._scene.ngeom + 1, -1, np.int32)
        for i in range(self._scene.ngeom):
            geom = self._scene.geoms[i]
            if geom.segid >= 0 and geom.objtype == mujoco.mjtObj.mjOBJ_GEOM:
                lookup[geom.segid + 1] = geom.objid
        return lookup[np.clip(seg, 0, self._scene.ngeom)]

    def close(self) -> None:
        if self._ctx is not None:
            self._gl.make_current()
            self._ctx.free()
            self._ctx = None
        if self._gl is not None:
            self._gl.free()
            self._gl = None

    def __enter__(self) -> "MultiCameraRenderer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
