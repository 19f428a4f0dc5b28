"""Continuous simulator footage of a manifest's scene, for the raw-footage corpus.

The controller runs its task on repeat (pick and put back, push there and back, drive up and
down the aisle) and the forklift comes round again, so a segment of any length keeps moving
with no cut inside it (a single episode would end holding still). An e-stop (a forklift lane
through the robot) still freezes the robot, as it would in an episode.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

import tasks.sim  # noqa: F401  (sets MUJOCO_GL before mujoco loads)
from schemas.manifest import ScenarioManifest
from tasks.sim.episode import Simulation, jitter_phases
from tasks.sim.render import MultiCameraRenderer, jitter_angles
from tasks.sim.scene import SimConfig, build_scene

MAX_SIDE = 4096


def sim_segment(manifest: ScenarioManifest, seed: int, n_frames: int, width: int, height: int,
                camera: str | None = None, fps: float = 30.0, render_width: int = 480,
                config: SimConfig = SimConfig(), start_s: float = 0.0) -> np.ndarray:
    """n_frames x height x width x 3 uint8 RGB of `camera` (default: the manifest's first).

    Frames are sampled every 1/fps s of simulated time from ``start_s`` (the simulation runs
    from 0 unrendered until then: a take from the middle of the task). They are rendered at most
    `render_width` wide (same aspect) and resized, so time and memory stay bounded whatever
    the output size. The same arguments give the same frames; every stressor in the
    manifest (camera jitter included) applies.
    """
    names = [c.name for c in manifest.cameras]
    name = camera or names[0]
    if name not in names:
        raise ValueError(f"manifest {manifest.name}: no camera {name!r} (has {names})")
    if n_frames < 0 or not (16 <= width <= MAX_SIDE and 16 <= height <= MAX_SIDE) or not 0 < fps <= 240 \
            or not 0 <= start_s <= 3600:
        raise ValueError(f"manifest {manifest.name}: bad segment {n_frames} frames of {width}x{height} at {fps} fps "
                         f"from {start_s} s")
    rw = max(16, min(render_width, width))
    rh = max(16, round(rw * height / width))
    scene = build_scene(manifest, seed, config)
    vis = scene.model.vis.global_
    vis.offwidth, vis.offheight = max(rw, vis.offwidth), max(rh, vis.offheight)
    sim = Simulation(scene, seed, repeat=True, cyclic_forklift=True)
    jitter = manifest.stressor("camera_jitter")
    phases = jitter_phases(scene)[name]
    out = np.zeros((n_frames, height, width, 3), np.uint8)
    state = {"next": 0}
    with MultiCameraRenderer(scene.model, {name: (rw, rh)}) as renderer:
        def capture(data) -> None:
            j = state["next"]
            if j < n_frames and data.time >= start_s + j / fps - 1e-9:
                angles = jitter_angles(jitter, phases, start_s + j / fps) if jitter else None
                frame = renderer.render(data, name, angles)
                out[j] = frame if (rh, rw) == (height, width) else cv2.resize(
                    frame, (width, height), interpolation=cv2.INTER_LINEAR)
                state["next"] = j + 1

        capture(sim.data)
        for _ in range(math.ceil((start_s + n_frames / fps) * scene.config.control_hz) + 1):
            if state["next"] >= n_frames:
                break
            sim.advance(capture)
    return out
