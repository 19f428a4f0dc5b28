"""Depth and segmentation of every camera frame of a rollout, rendered with the RGB frame's pose.

`Recorder` is the hook `tasks.sim.episode.rollout(on_frame=...)` calls after each RGB frame:
it renders that camera again, with the same jitter angles, for depth (metres along the optical
axis, kept as uint16 millimetres) and for the geom at each pixel, mapped to an object id of
the scene's legend.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

import tasks.sim  # noqa: F401  (sets MUJOCO_GL before mujoco loads)
import mujoco
from tasks.sim.render import MultiCameraRenderer
from tasks.sim.scene import Scene

BACKGROUND = "background"
# World-body geoms by name; anything else attached to the world is part of the robot (its pedestal).
WORLD_GEOMS = {"goal_marker": "goal", "table": "table", "floor": "floor", "occluder": "occluder"}
MAX_DEPTH_M = 65.535  # uint16 millimetres


@dataclass(frozen=True)
class Rendered:
    """Per camera: depth_mm F x H x W uint16 (0: nothing within the far plane), ids F x H x W
    uint8 indexing ``legend`` (0 is background)."""

    depth_mm: dict[str, np.ndarray]
    ids: dict[str, np.ndarray]
    legend: tuple[str, ...]


def object_label(model: mujoco.MjModel, geom: int, scene: Scene) -> str:
    """The object a geom belongs to: the task's first object is `package`, the other task objects,
    distractors and the forklift by their body names, world geoms by WORLD_GEOMS (bin walls and
    floor as `bin`), and everything else (arm, hand, mobile base, pedestal) `robot`."""
    body = int(model.geom_bodyid[geom])
    if body == 0:
        name = model.geom(geom).name
        return "bin" if name.startswith("bin_") else WORLD_GEOMS.get(name, "robot")
    root = model.body(int(model.body_rootid[body])).name
    if root == scene.objects[0]:
        return "package"
    if root in scene.objects or root == "forklift":
        return root
    return "robot"


def legend_of(model: mujoco.MjModel, scene: Scene) -> tuple[tuple[str, ...], np.ndarray]:
    """(legend: object names, background first; lookup: geom id + 1 -> legend index)."""
    labels = [object_label(model, g, scene) for g in range(model.ngeom)]
    legend = (BACKGROUND, *sorted(set(labels), key=lambda n: (n != "package", n)))
    lookup = np.array([0] + [legend.index(label) for label in labels], np.uint8)
    return legend, lookup


def to_millimetres(metres: np.ndarray) -> np.ndarray:
    """Depth in metres -> uint16 millimetres, rounded (0 stays 0: nothing there)."""
    return np.rint(np.clip(metres, 0.0, MAX_DEPTH_M) * 1000.0).astype(np.uint16)


class Recorder:
    """Collects depth and segmentation of every frame `rollout` renders; `rendered()` when done."""

    def __init__(self) -> None:
        self._depth: dict[str, list[np.ndarray]] = {}
        self._ids: dict[str, list[np.ndarray]] = {}
        self._lookup: np.ndarray | None = None
        self._legend: tuple[str, ...] = (BACKGROUND,)

    def __call__(self, scene: Scene, renderer: MultiCameraRenderer, data: mujoco.MjData, camera: str,
                 angles: np.ndarray | None) -> None:
        """Frame after frame of ``camera``, in the order rollout renders them."""
        if self._lookup is None:
            self._legend, self._lookup = legend_of(scene.model, scene)
        self._depth.setdefault(camera, []).append(to_millimetres(renderer.depth(data, camera, angles)))
        self._ids.setdefault(camera, []).append(self._lookup[renderer.segment(data, camera, angles) + 1])

    def rendered(self) -> Rendered:
        return Rendered(depth_mm={c: np.stack(v) for c, v in self._depth.items()},
                        ids={c: np.stack(v) for c, v in self._ids.items()}, legend=self._legend)
