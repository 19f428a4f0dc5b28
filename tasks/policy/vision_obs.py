"""What a vision policy observes: named cameras and the robot's own state, nothing else.

Frames: each named camera rendered by MuJoCo's offscreen renderer at the manifest's
resolution (with the cell's camera jitter, light and appearance, as the recorded videos
show them), then downscaled to ``image_size`` square by area averaging. A camera delivers a
new frame at its own fps; between frames the policy sees the latest one, as a robot would.

Proprioception: the arm's joint angles and velocities, the commanded grip, the tcp position
(forward kinematics of the joint angles), the commanded tcp pose relative to it, and the time
since the episode began. Never an object pose, the goal, or anything else only the simulator
knows: the package and the goal marker have to be found in the frames.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from pydantic import BaseModel, ConfigDict, Field

import tasks.sim  # noqa: F401  (sets MUJOCO_GL before mujoco loads)
import mujoco
from schemas.manifest import ScenarioManifest
from tasks.sim.control import ArmController
from tasks.sim.episode import jitter_phases
from tasks.sim.render import MultiCameraRenderer, jitter_angles
from tasks.sim.scene import Scene

PROPRIO_VERSION = 1


class ObservationSpec(BaseModel):
    """Saved in every vision checkpoint; a panel whose cameras differ is refused by it."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    cameras: tuple[str, ...] = Field(min_length=1, max_length=8)
    image_size: int = Field(64, ge=16, le=256)
    proprio_version: int = PROPRIO_VERSION

    def mismatch(self, manifest: ScenarioManifest) -> str | None:
        """What differs between this spec and the manifest's cameras, in words; None if nothing."""
        cams = {c.name: c for c in manifest.cameras}
        missing = [c for c in self.cameras if c not in cams]
        if missing:
            return (f"the policy observes camera(s) {', '.join(missing)}, which {manifest.name} does not have "
                    f"(it has {', '.join(cams)})")
        small = [f"{c} is {cams[c].resolution[0]}x{cams[c].resolution[1]}" for c in self.cameras
                 if min(cams[c].resolution) < self.image_size]
        if small:
            return f"the policy needs {self.image_size} px frames; in {manifest.name} {', '.join(small)}"
        if self.proprio_version != PROPRIO_VERSION:
            return f"proprioception version {self.proprio_version} is not this build's {PROPRIO_VERSION}"
        return None


def parse_cameras(text: str) -> tuple[str, ...]:
    """``front_left,wrist`` -> ("front_left", "wrist"); duplicates and blanks refused."""
    names = tuple(n.strip() for n in text.split(","))
    if not names or any(not n for n in names) or len(set(names)) != len(names):
        raise ValueError(f"--observe {text!r}: name one or more distinct cameras, comma-separated")
    return names


def proprio_size(arm: ArmController) -> int:
    return 2 * len(arm.qadr) + 1 + 3 + 3 + 2 + 1


def proprio(data: mujoco.MjData, arm: ArmController) -> np.ndarray:
    """(proprio_size,) float32 read before the step acts."""
    tcp = data.site_xpos[arm.site]
    parts = [data.qpos[arm.qadr], data.qvel[arm.dofs], [arm.grip], tcp, arm.target_pos - tcp,
             [math.sin(arm.target_yaw), math.cos(arm.target_yaw)], [data.time / arm.scene.manifest.horizon_s]]
    return np.concatenate([np.asarray(p, np.float64).ravel() for p in parts]).astype(np.float32)


class Observer:
    """Frames of the spec's cameras for one episode of ``scene``: C x 3 x S x S uint8."""

    def __init__(self, scene: Scene, spec: ObservationSpec):
        manifest = scene.manifest
        problem = spec.mismatch(manifest)
        if problem:
            raise ValueError(problem)
        self.spec, self.cams = spec, [next(c for c in manifest.cameras if c.name == n) for n in spec.cameras]
        self.renderer = MultiCameraRenderer(scene.model, {c.name: tuple(c.resolution) for c in self.cams})
        self.jitter = manifest.stressor("camera_jitter")
        self.phases = jitter_phases(scene)
        self.latest = np.zeros((len(self.cams), 3, spec.image_size, spec.image_size), np.uint8)
        self.next_frame = [0] * len(self.cams)

    def frames(self, data: mujoco.MjData) -> np.ndarray:
        """The latest frame of each camera at ``data.time`` (rendered when a new one is due)."""
        size = self.spec.image_size
        for i, cam in enumerate(self.cams):
            j = self.next_frame[i]
            if data.time >= j / cam.fps - 1e-9:
                t = math.floor(data.time * cam.fps + 1e-9) / cam.fps
                angles = jitter_angles(self.jitter, self.phases[cam.name], t) if self.jitter else None
                rgb = self.renderer.render(data, cam.name, angles)
                if rgb.shape[:2] != (size, size):
                    rgb = cv2.resize(rgb, (size, size), interpolation=cv2.INTER_AREA)
                self.latest[i] = rgb.transpose(2, 0, 1)
                self.next_frame[i] = math.floor(data.time * cam.fps + 1e-9) + 1
        return self.latest.copy()

    def close(self) -> None:
        self.renderer.close()
