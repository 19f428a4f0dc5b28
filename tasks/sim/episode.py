"""Roll out a manifest's task in MuJoCo and judge it from simulator state.

`rollout(manifest, seed)` is pure: the same manifest, seed and config give bit-identical
arrays and frames (single-threaded MuJoCo, seeded streams, no wall clock). Cameras never touch
the physics: `rollout(..., record=())` (no episode videos, as policy collection and evaluation
roll out) gives the same arrays as a recorded rollout. Writing files and lineage lives in
`tasks.sim.files` and is re-exported here.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Callable, Protocol

import numpy as np

import tasks.sim  # noqa: F401  (sets MUJOCO_GL before mujoco loads)
import mujoco
from schemas.manifest import ScenarioManifest
from tasks.sim.control import make_controller
from tasks.sim.files import EpisodeFiles, episode_lineage, write_episode  # noqa: F401  (re-exported)
from tasks.sim.render import MultiCameraRenderer, jitter_angles
from tasks.sim.scene import Scene, SimConfig, build_scene, rng_for
from tasks.sim.stressors import FORKLIFT_LENGTH, FORKLIFT_PARK_Y, forklift_position


class Controller(Protocol):
    """What drives the robot: the scripted controllers (tasks.sim.control) or a policy's
    (tasks.policy). `step` reads the state, writes `data.ctrl` and returns the action applied."""

    def reset(self, data: mujoco.MjData) -> None: ...

    def step(self, data: mujoco.MjData) -> np.ndarray: ...

    def action_size(self) -> int: ...


ControllerFactory = Callable[[Scene, int], Controller]
"""(scene, seed) -> a controller for that scene; `Policy.controller` is one."""


@dataclass(frozen=True)
class Episode:
    """One rollout. T control steps (control_hz), F_c frames per camera (camera fps).

    time (T,) s at the start of each step; joint_pos / joint_vel (T, J) of the robot's joints
    (rad or m, rad/s or m/s) observed before the action; action (T, A) as applied (layout in
    tasks.sim.control); object_pose (T, N, 7) xyz + quaternion wxyz; success_flag (T,) the
    evaluation target holds at that step; estop (T,) an emergency stop has happened;
    frames[camera] F_c x H x W x 3 uint8 RGB with frame_time[camera] (F_c,) s, for the cameras
    recorded (every manifest camera unless `rollout` was told to record fewer).
    """

    manifest: ScenarioManifest
    seed: int
    control_hz: float
    joint_names: tuple[str, ...]
    object_names: tuple[str, ...]
    time: np.ndarray
    joint_pos: np.ndarray
    joint_vel: np.ndarray
    action: np.ndarray
    object_pose: np.ndarray
    success_flag: np.ndarray
    estop: np.ndarray
    frames: dict[str, np.ndarray]
    frame_time: dict[str, np.ndarray]
    success: bool
    reason: str
    stressor_values: dict = field(default_factory=dict)

    @property
    def steps(self) -> int:
        return int(self.time.shape[0])


class Simulation:
    """Physics, controller, forklift and e-stop for one scene; `advance` runs one control step.

    cyclic_forklift makes the forklift come round again (for long footage): it reappears at
    its parking spot, out of view, once it has driven as far past the lane as it started.
    controller: a factory used in place of the scripted controller (None: the scripted one).
    """

    def __init__(self, scene: Scene, seed: int, repeat: bool = False, cyclic_forklift: bool = False,
                 controller: ControllerFactory | None = None):
        self.scene, self.model = scene, scene.model
        self.data = mujoco.MjData(self.model)
        self.data.qpos[:] = scene.initial_qpos
        self.data.ctrl[:] = scene.initial_ctrl
        self.fork = scene.manifest.stressor("forklift_crossing")
        self.cyclic = cyclic_forklift
        if self.fork:
            joint = self.model.joint("forklift_slide")
            self.fork_q, self.fork_v = int(joint.qposadr[0]), int(joint.dofadr[0])
            self._drive_forklift()
        mujoco.mj_forward(self.model, self.data)
        self.controller = make_controller(scene, seed, repeat) if controller is None else controller(scene, seed)
        self.controller.reset(self.data)
        # The base's planar joints, for judging reach_goal whatever controller drives it.
        self.base_qadr = (self.model.jnt_qposadr[[self.model.joint(j).id for j in scene.base.joints]]
                          if scene.base is not None else None)
        self.substeps = max(1, round(1.0 / (scene.config.control_hz * scene.config.timestep)))
        self.fork_body = self.model.body("forklift").id if self.fork else -1
        self.estop_reason: str | None = None
        self.last_action = np.zeros(self.controller.action_size())

    def _fork_time(self, t: float) -> float:
        if not self.cyclic:
            return t
        period = (2 * abs(FORKLIFT_PARK_Y) + FORKLIFT_LENGTH) / self.fork.speed_mps + 1.0
        return self.fork.start_s + (t - self.fork.start_s) % period if t > self.fork.start_s else t

    def _drive_forklift(self) -> None:
        y, speed = forklift_position(self.fork, self._fork_time(self.data.time))
        self.data.qpos[self.fork_q], self.data.qvel[self.fork_v] = y, speed

    def _check_forklift(self) -> None:
        d, m = self.data, self.model
        if d.ncon == 0:
            return
        bodies = m.geom_bodyid[d.contact.geom[: d.ncon]]
        hit = np.any(bodies == self.fork_body, axis=1)
        floor = m.geom("floor").id
        for i in np.flatnonzero(hit):
            g1, g2 = d.contact.geom[i]
            other = g2 if bodies[i, 0] == self.fork_body else g1
            if other == floor:
                continue
            name = m.geom(other).name or m.body(m.geom_bodyid[other]).name or f"geom {other}"
            self.estop_reason = f"emergency stop: forklift contact with {name} at t={d.time:.3f}s"
            return

    def advance(self, on_substep: Callable[[mujoco.MjData], None] | None = None) -> np.ndarray:
        """One control step: act (or hold after an e-stop), then the physics substeps."""
        if self.estop_reason is None:
            self.last_action = self.controller.step(self.data)
        else:
            # Everything halts: the arm holds its joint targets, a base stops, the forklift brakes.
            if self.scene.base is not None:
                self.data.ctrl[:] = 0.0
            if self.scene.manifest.embodiment.action_space != "joint_position":
                self.last_action = np.zeros_like(self.last_action)
        for _ in range(self.substeps):
            if self.fork and self.estop_reason is None:
                self._drive_forklift()
            elif self.fork:
                self.data.qvel[self.fork_v] = 0.0
            mujoco.mj_step(self.model, self.data)
            if self.fork and self.estop_reason is None:
                self._check_forklift()
            if on_substep is not None:
                on_substep(self.data)
        return self.last_action.copy()


def _target_holds(sim: Simulation, rest_z: float) -> bool:
    scene, d, m = sim.scene, sim.data, sim.model
    ev = scene.manifest.evaluation
    if ev.target == "reach_goal":
        return float(np.linalg.norm(d.qpos[sim.base_qadr] - scene.goal[:2])) <= ev.goal_tolerance_m
    body = m.body(scene.objects[0]).id
    pos = d.xpos[body]
    if ev.target == "push_to_goal":
        return float(np.linalg.norm(pos[:2] - scene.goal[:2])) <= ev.goal_tolerance_m
    # lift_clear: lifted by lift_height_m, lowest corner above the rim, touching only the robot.
    corners = np.abs(d.xmat[body].reshape(3, 3)) @ scene.target_half
    if pos[2] - rest_z < ev.lift_height_m or pos[2] - corners[2] <= scene.rim_z:
        return False
    robot = {m.body(b).id for b in scene.arm.link_bodies}
    geoms = d.contact.geom[: d.ncon]
    bodies = m.geom_bodyid[geoms]
    for a, b in bodies:
        if body in (a, b) and (b if a == body else a) not in robot:
            return False
    return bool(d.ncon) and bool(np.any(bodies == body))


def jitter_phases(scene: Scene) -> dict[str, np.ndarray]:
    """(3, 2) phases per camera; cameras sharing a wrist or vehicle mount shake together."""
    rng = rng_for(scene.seed, "jitter")
    by_mount = {"wrist": rng.uniform(0, 2 * math.pi, (3, 2)), "vehicle": rng.uniform(0, 2 * math.pi, (3, 2))}
    return {c.name: by_mount.get(c.mount) if c.mount != "world" else rng.uniform(0, 2 * math.pi, (3, 2))
            for c in scene.manifest.cameras}


FrameHook = Callable[[Scene, MultiCameraRenderer, mujoco.MjData, str, "np.ndarray | None"], None]
"""(scene, renderer, data, camera, jitter angles or None), called after each RGB frame is rendered
(tasks.controls.render.Recorder renders depth and segmentation there)."""


def recorded_cameras(manifest: ScenarioManifest, record: Sequence[str] | None) -> tuple[str, ...]:
    """The manifest's cameras ``record`` names, in manifest order (None: all of them)."""
    names = tuple(c.name for c in manifest.cameras)
    if record is None:
        return names
    if isinstance(record, (str, bool)):
        raise TypeError(f"record: a sequence of camera names or None, not {record!r}")
    unknown = [n for n in record if n not in names]
    if unknown:
        raise ValueError(f"record: camera(s) {', '.join(unknown)} not in {manifest.name} (it has {', '.join(names)})")
    return tuple(n for n in names if n in record)


def rollout(manifest: ScenarioManifest, seed: int, config: SimConfig = SimConfig(),
            controller: ControllerFactory | None = None, on_frame: FrameHook | None = None,
            record: Sequence[str] | None = None) -> Episode:
    """Simulate the manifest's task for horizon_s and render each recorded camera at its own fps.
    controller: drive the robot with this instead of the scripted controller (a policy).
    on_frame: called after each recorded frame with the state and camera pose it was rendered from.
    record: the cameras whose frames the episode keeps (None: every camera; (): none, and no
    renderer is opened). The scene is always built from the whole manifest, so a policy's own
    renderer sees every camera at its real fps and resolution, and the physics is the same
    whatever is recorded."""
    recorded = recorded_cameras(manifest, record)
    scene = build_scene(manifest, seed, config)
    sim = Simulation(scene, seed, controller=controller)
    m, d = sim.model, sim.data
    steps = round(manifest.horizon_s * config.control_hz)
    # The robot's joints: every joint but the objects' free joints and the forklift's slide.
    joints = [j for j in range(m.njnt)
              if m.jnt_type[j] != mujoco.mjtJoint.mjJNT_FREE and m.joint(j).name != "forklift_slide"]
    qadr, vadr = m.jnt_qposadr[joints], m.jnt_dofadr[joints]
    objs = [m.body(o).id for o in scene.objects]
    rest_z = float(scene.initial_qpos[m.jnt_qposadr[m.body_jntadr[objs[0]]] + 2])
    jitter = manifest.stressor("camera_jitter")
    phases = jitter_phases(scene)
    cams = [c for c in manifest.cameras if c.name in recorded]
    n_frames = {c.name: int(math.floor(manifest.horizon_s * c.fps + 1e-9)) for c in cams}
    frames = {c.name: np.zeros((n_frames[c.name], c.resolution[1], c.resolution[0], 3), np.uint8) for c in cams}
    next_frame = {c.name: 0 for c in cams}
    out = {k: [] for k in ("time", "qpos", "qvel", "action", "pose", "flag", "estop")}

    opened = MultiCameraRenderer(m, {c.name: tuple(c.resolution) for c in cams}) if cams else contextlib.nullcontext()
    with opened as renderer:
        def capture(data: mujoco.MjData) -> None:
            for c in cams:
                j = next_frame[c.name]
                if j < n_frames[c.name] and data.time >= j / c.fps - 1e-9:
                    angles = jitter_angles(jitter, phases[c.name], j / c.fps) if jitter else None
                    frames[c.name][j] = renderer.render(data, c.name, angles)
                    next_frame[c.name] = j + 1
                    if on_frame is not None:
                        on_frame(scene, renderer, data, c.name, angles)

        capture(d)
        try:
            for k in range(steps):
                out["time"].append(k / config.control_hz)
                out["qpos"].append(d.qpos[qadr].copy())
                out["qvel"].append(d.qvel[vadr].copy())
                out["pose"].append(np.concatenate([d.xpos[objs], d.xquat[objs]], axis=1))
                out["flag"].append(_target_holds(sim, rest_z))
                out["estop"].append(sim.estop_reason is not None)
                out["action"].append(sim.advance(capture if cams else None))
        finally:
            close = getattr(sim.controller, "close", None)  # a vision policy's renderer
            if close is not None:
                close()
    flag = np.array(out["flag"], bool)
    success, reason = _verdict(sim, rest_z)
    return Episode(manifest=manifest, seed=seed, control_hz=config.control_hz,
                   joint_names=tuple(m.joint(j).name for j in joints), object_names=scene.objects,
                   time=np.array(out["time"]), joint_pos=np.array(out["qpos"]), joint_vel=np.array(out["qvel"]),
                   action=np.array(out["action"]), object_pose=np.array(out["pose"]), success_flag=flag,
                   estop=np.array(out["estop"], bool), frames=frames,
                   frame_time={c.name: np.arange(n_frames[c.name]) / c.fps for c in cams},
                   success=success, reason=reason, stressor_values=scene.stressor_values)


def _verdict(sim: Simulation, rest_z: float) -> tuple[bool, str]:
    """Success needs the target to hold after the last step and no e-stop at any time."""
    final = _target_holds(sim, rest_z)
    scene, ev = sim.scene, sim.scene.manifest.evaluation
    if sim.estop_reason is not None:
        return False, sim.estop_reason
    if final:
        return True, {"lift_clear": "package lifted clear of the bin", "push_to_goal": "package at goal",
                      "reach_goal": "base at goal"}[ev.target]
    d, m = sim.data, sim.model
    if ev.target == "lift_clear":
        pos = d.xpos[m.body(scene.objects[0]).id]
        return False, f"package not held clear: {pos[2] - rest_z:.3f} m above rest (need {ev.lift_height_m} m)"
    if ev.target == "push_to_goal":
        gap = float(np.linalg.norm(d.xpos[m.body(scene.objects[0]).id][:2] - scene.goal[:2]))
        return False, f"package {gap:.3f} m from goal (tolerance {ev.goal_tolerance_m} m)"
    gap = float(np.linalg.norm(d.qpos[sim.base_qadr] - scene.goal[:2]))
    return False, f"base {gap:.3f} m from goal (tolerance {ev.goal_tolerance_m} m)"
