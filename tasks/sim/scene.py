"""Build the MuJoCo model of a ScenarioManifest in code (mujoco.MjSpec), from a seed.

Layout (metres, world z up, robot base at the origin facing +x):
- bin_pick: a bin centred at (0.45, 0) on the floor, packages inside it.
- push: a conveyor-like table centred at (0.45, 0), top at z=0.10; the package starts near
  y=-0.14 and the green goal marker lies near y=+0.13.
- drive: an aisle along +x between two runs of racks; the goal is 6 m ahead, or the last of the
  task's waypoints (which stay inside the aisle: schemas.manifest.AISLE_X_M, AISLE_HALF_WIDTH_M).
A forklift lane runs along y at x = lane_m (distance from the robot base). Every random
choice draws from a stream named after its purpose, so adding one stressor never shifts
the draws of another.
"""

from __future__ import annotations

import math
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

import mujoco
from pydantic import Field

from schemas.manifest import AISLE_HALF_WIDTH_M, AISLE_X_M, Camera, Frozen, ScenarioManifest, object_body_name
from schemas.settings import Settings
from tasks.sim import mjcf, robots, stressors
from tasks.sim.kinematics import yaw_quat

G = mujoco.mjtGeom
BIN_CENTRE = np.array([0.45, 0.0])
BIN_INNER, BIN_WALL, BIN_HEIGHT, BIN_FLOOR = 0.13, 0.012, 0.10, 0.01
TABLE_TOP = 0.10
PACKAGE_HALF = np.array([0.04, 0.03, 0.03])
AISLE_GOAL_X = 6.0
NORMAL_LUX = 500.0


class SimConfig(Frozen):
    """Physics and asset settings that are not part of a manifest's meaning."""

    timestep: float = 0.002
    control_hz: float = 50.0
    # WORLDLINE_ROBOTS_ROOT, as the process had it when it made this config (the functions'
    # default configs: when this module was imported).
    robots_root: Path = Field(default_factory=lambda: Settings().robots_root)
    gripper_mjcf: str | None = "robotiq_2f85/2f85.xml"


def check_assets(manifest: ScenarioManifest, config: SimConfig | None = None) -> None:
    """FileNotFoundError naming the field and the path when an MJCF the scene needs is missing,
    or it (or a file it makes MuJoCo read) lies outside the robots root: `mjcf.check_mjcf`.

    Here rather than in manifest validation: the root is a setting of the machine, and a
    manifest's validity, like its hash, may not depend on where it is read."""
    if manifest.embodiment.kind != "arm" or not manifest.embodiment.mjcf:
        return
    config = config or SimConfig()
    root = Path(config.robots_root)
    wanted = [("embodiment.mjcf", manifest.embodiment.mjcf)]
    if config.gripper_mjcf:
        wanted.append(("gripper", config.gripper_mjcf))
    for field_name, relative in wanted:
        if not (root / relative).is_file():
            raise FileNotFoundError(f"{field_name} {relative!r}: no robot MJCF at {root / relative} "
                                    f"(MJCF paths resolve under WORLDLINE_ROBOTS_ROOT, now {root})")
        try:
            mjcf.check_mjcf(root / relative, root)
        except mjcf.RobotFileError as exc:
            raise mjcf.RobotFileError(f"{field_name} {relative!r}: {exc}") from None


@dataclass(frozen=True)
class Scene:
    """A compiled model plus the handles and layout facts the controller and judge need."""

    model: mujoco.MjModel
    manifest: ScenarioManifest
    seed: int
    config: SimConfig
    arm: robots.ArmSpec | None
    base: robots.BaseSpec | None
    objects: tuple[str, ...]  # free bodies whose poses are recorded; objects[0] is the target
    target_half: np.ndarray  # (3,) half sizes of the target box
    goal: np.ndarray  # (3,) push goal or drive goal; for bin_pick the lift point above the bin
    rim_z: float  # top of the bin walls (bin_pick) or table top (push)
    lane_x: float | None  # forklift lane, None without a forklift
    initial_qpos: np.ndarray
    initial_ctrl: np.ndarray
    stressor_values: dict = field(default_factory=dict)
    grip_axis: float = math.pi / 2  # direction the fingers close along, as an angle in the ee x-y plane
    path: np.ndarray | None = None  # a drive task's waypoints as this seed drives them (drive_path); None: straight


def rng_for(seed: int, purpose: str) -> np.random.Generator:
    return np.random.default_rng([seed, zlib.crc32(purpose.encode())])


def look_quat(position, look_at, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Quaternion of a MuJoCo camera (looks along its -z, y up) at position facing look_at."""
    fwd = np.asarray(look_at, float) - np.asarray(position, float)
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, up)
    if np.linalg.norm(right) < 1e-6:  # looking along `up`: let image-up point along +x
        right = np.cross(fwd, (1.0, 0.0, 0.0))
    right /= np.linalg.norm(right)
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, np.column_stack([right, np.cross(-fwd, right), -fwd]).ravel())
    return quat


def _add_cameras(spec: mujoco.MjSpec, cameras: tuple[Camera, ...], where: str) -> None:
    for cam in cameras:
        if cam.mount == "world":
            parent = spec.worldbody
        else:
            parent = spec.body("ee" if cam.mount == "wrist" else "base")
            if parent is None:
                raise ValueError(f"{where}: camera {cam.name!r} is mounted on the {cam.mount}, "
                                 f"which this embodiment does not have")
        parent.add_camera(name=cam.name, pos=list(cam.position), quat=list(look_quat(cam.position, cam.look_at)),
                          fovy=cam.fovy_deg, resolution=list(cam.resolution))


def drive_path(manifest: ScenarioManifest, seed: int | None = None) -> np.ndarray:
    """(K, 2) the points a drive task's base drives through from its start at the origin, the
    last its goal: the manifest's waypoints, or straight down the aisle to AISLE_GOAL_X. With
    `task.waypoint_jitter_m` and a seed, each waypoint moved by up to that much in x and y
    (uniform, from the seed's own stream, so nothing else the seed draws changes), kept in
    the aisle."""
    if not manifest.task.waypoints:
        return np.array([[AISLE_GOAL_X, 0.0]])
    path = np.array(manifest.task.waypoints, float)
    jitter = manifest.task.waypoint_jitter_m
    if jitter and seed is not None:
        path = path + rng_for(seed, "waypoints").uniform(-jitter, jitter, path.shape)
        path[:, 0] = path[:, 0].clip(*AISLE_X_M)
        path[:, 1] = path[:, 1].clip(-AISLE_HALF_WIDTH_M, AISLE_HALF_WIDTH_M)
    return path


def _along(points: np.ndarray, spacing: float) -> list[np.ndarray]:
    """Points every `spacing` metres along the polyline through `points` (both ends included)."""
    out = [points[0]]
    for a, b in zip(points[:-1], points[1:]):
        n = max(1, int(math.ceil(float(np.linalg.norm(b - a)) / spacing)))
        out += [a + (b - a) * k / n for k in range(1, n + 1)]
    return out


def _box(body, name, pos, half, material=None, rgba=None):
    # An explicit rgba would override the material's colour, so pass one only without material.
    geom = body.add_geom(name=name, type=G.mjGEOM_BOX, pos=list(pos), size=list(half))
    if material:
        geom.material = material
    else:
        geom.rgba = list(rgba)
    return geom


def _add_bin(spec, material):
    wb, (cx, cy) = spec.worldbody, BIN_CENTRE
    outer = BIN_INNER + BIN_WALL
    _box(wb, "bin_floor", (cx, cy, BIN_FLOOR / 2), (outer, outer, BIN_FLOOR / 2), material)
    h = BIN_HEIGHT / 2
    for name, pos, half in (("bin_wall_px", (cx + outer - BIN_WALL / 2, cy, h), (BIN_WALL / 2, outer, h)),
                            ("bin_wall_nx", (cx - outer + BIN_WALL / 2, cy, h), (BIN_WALL / 2, outer, h)),
                            ("bin_wall_py", (cx, cy + outer - BIN_WALL / 2, h), (outer, BIN_WALL / 2, h)),
                            ("bin_wall_ny", (cx, cy - outer + BIN_WALL / 2, h), (outer, BIN_WALL / 2, h))):
        _box(wb, name, pos, half, material)


def _add_racks(spec, material, x_ranges, y):
    """Warehouse racks: uprights and three shelves per run, on both sides (|y|) of an aisle."""
    for i, (x0, x1) in enumerate(x_ranges):
        for side in (-1, 1):
            cx, cy = (x0 + x1) / 2, side * y
            for level in (0.05, 0.75, 1.45):
                _box(spec.worldbody, None, (cx, cy, level), ((x1 - x0) / 2, 0.4, 0.025), material)
            for ux in np.arange(x0, x1 + 1e-6, 1.5):
                _box(spec.worldbody, None, (ux, cy, 1.0), (0.04, 0.4, 1.0), None, (0.2, 0.3, 0.6, 1))


def _add_package(spec, name, pos, yaw, half, material):
    body = spec.worldbody.add_body(name=name, pos=list(pos), quat=list(yaw_quat(yaw)))
    body.add_freejoint()
    body.add_geom(name=f"{name}_geom", type=G.mjGEOM_BOX, size=list(half), material=material,
                  mass=0.15, friction=[1.0, 0.01, 0.001], condim=4)
    return body.name


def build_scene(manifest: ScenarioManifest, seed: int, config: SimConfig = SimConfig()) -> Scene:
    """Compile the manifest's scene for this seed (same inputs, same model, bit for bit)."""
    where = f"manifest {manifest.name}"
    kind, task = manifest.embodiment.kind, manifest.task.kind
    if kind == "vehicle":
        raise ValueError(f"{where}: embodiment kind 'vehicle' is not simulated; use 'arm' or 'mobile'")
    if (kind == "mobile") != (task == "drive"):
        raise ValueError(f"{where}: task {task!r} does not fit embodiment {kind!r} (drive needs mobile)")
    spec = mujoco.MjSpec()
    spec.compiler.degree = False
    spec.option.timestep = config.timestep
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    spec.visual.global_.offwidth = max(c.resolution[0] for c in manifest.cameras)
    spec.visual.global_.offheight = max(c.resolution[1] for c in manifest.cameras)
    # Clip planes are fractions of the model extent (~7-12 m here); the default near plane
    # (7+ cm) would hide a package held just below the wrist camera.
    spec.visual.map.znear, spec.visual.map.zfar = 0.0005, 8.0
    spec.visual.quality.offsamples = 0  # multisample resolve costs more than the render on llvmpipe
    look = manifest.stressor("appearance")
    arng = rng_for(seed, "appearance") if look else None
    layout = rng_for(seed, "layout")
    values = {s.kind: s.model_dump(exclude={"kind"}) for s in manifest.stressors}

    floor = stressors.add_material(spec, "floor_mat", (0.42, 0.42, 0.4), arng, look, (12, 12), checker=True)
    # A plane's third size is its render grid spacing: 0.1 m meant 57,600 quads and 3x slower frames.
    spec.worldbody.add_geom(name="floor", type=G.mjGEOM_PLANE, size=[12, 12, 1.5], material=floor)
    spec.worldbody.add_light(name="sun", type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL, pos=[0.5, 0.5, 4],
                             dir=[-0.3, -0.2, -1], diffuse=[0.6] * 3, ambient=[0.25] * 3, specular=[0.1] * 3,
                             castshadow=False)
    spec.visual.headlight.ambient = [0.15] * 3
    spec.visual.headlight.diffuse = [0.3] * 3
    package_mat = stressors.add_material(spec, "package_mat", (0.62, 0.45, 0.26), arng, look, (2, 2))
    names = [object_body_name(o, i) for i, o in enumerate(manifest.task.objects)]
    arm = base = None
    if kind == "arm":
        if manifest.embodiment.mjcf:
            check_assets(manifest, config)
            root = Path(config.robots_root)
            gripper = root / config.gripper_mjcf if config.gripper_mjcf else None
            arm = robots.add_mjcf_arm(spec, root / manifest.embodiment.mjcf, gripper)
        else:
            arm = robots.add_builtin_arm(spec)
    else:
        base = robots.add_mobile_base(spec, turn=manifest.embodiment.action_space == "twist")

    keep_out: list[tuple[float, float, float]] = [(0.0, 0.0, 0.2)]
    if task == "bin_pick":
        _add_bin(spec, stressors.add_material(spec, "bin_mat", (0.15, 0.3, 0.65), arng, look))
        start = BIN_CENTRE + layout.uniform(-0.03, 0.03, 2)
        rest_z = BIN_FLOOR + PACKAGE_HALF[2] + 0.001
        yaw = float(layout.uniform(-0.5, 0.5))
        rim_z = BIN_HEIGHT
        goal = np.array([*BIN_CENTRE, rim_z + 0.25])
        extra_xy = [BIN_CENTRE + np.array([0.0, 0.3]), BIN_CENTRE + np.array([0.0, -0.3]), BIN_CENTRE + np.array([0.3, 0.0])]
        extra_z = PACKAGE_HALF[2]
        region, dz = (0.2, 0.95, -0.65, 0.65), 0.0
        keep_out.append((*BIN_CENTRE, BIN_INNER * 1.5 + 0.03))
    elif task == "push":
        table = stressors.add_material(spec, "table_mat", (0.22, 0.22, 0.24), arng, look, (4, 6), checker=True)
        _box(spec.worldbody, "table", (0.45, 0.0, TABLE_TOP / 2), (0.2, 0.35, TABLE_TOP / 2), table)
        start = np.array([0.45, -0.14]) + layout.uniform(-0.02, 0.02, 2)
        rest_z = TABLE_TOP + PACKAGE_HALF[2] + 0.001
        yaw = float(layout.uniform(-0.2, 0.2))
        rim_z = TABLE_TOP
        goal = np.array([0.45 + layout.uniform(-0.03, 0.03), 0.13 + layout.uniform(-0.02, 0.02), TABLE_TOP])
        spec.worldbody.add_geom(name="goal_marker", type=G.mjGEOM_CYLINDER, pos=[*goal[:2], TABLE_TOP + 0.0005],
                                size=[manifest.evaluation.goal_tolerance_m, 0.0005, 0], rgba=[0.1, 0.8, 0.2, 1],
                                contype=0, conaffinity=0)
        extra_xy = [np.array([0.3, -0.25]), np.array([0.6, -0.25]), np.array([0.3, 0.28])]
        extra_z = TABLE_TOP + PACKAGE_HALF[2]
        region, dz = (0.27, 0.63, -0.32, 0.32), TABLE_TOP
        # Clear of the package, the goal, the path between them and where the pusher lands behind it.
        keep_out += [(*start, 0.08), (*goal[:2], 0.08), ((start[0] + goal[0]) / 2, 0.0, 0.08),
                     (start[0], start[1] - 0.13, 0.07)]
    else:
        lane = manifest.stressor("forklift_crossing")
        gap = (lane.lane_m - 1.6, lane.lane_m + 1.6) if lane else (99.0, 99.0)
        runs = [(x0, x1) for x0, x1 in ((-2.0, min(gap[0], 8.0)), (max(gap[1], -2.0), 8.0)) if x1 - x0 > 0.5]
        _add_racks(spec, stressors.add_material(spec, "rack_mat", (0.85, 0.5, 0.1), arng, look), runs, 1.4)
        path = drive_path(manifest, seed)
        goal = np.array([*path[-1], 0.0])
        # Across the aisle at the end of the default straight drive; a square at a waypoint goal.
        mark = [0.05, 0.9, 0.001] if not manifest.task.waypoints else [0.15, 0.15, 0.001]
        spec.worldbody.add_geom(name="goal_marker", type=G.mjGEOM_BOX, pos=[*goal[:2], 0.001],
                                size=mark, rgba=[0.1, 0.8, 0.2, 1], contype=0, conaffinity=0)
        shelf = 0.775  # top of the middle shelf
        start, yaw, rest_z, rim_z = np.array([1.0, 1.4]), 0.0, shelf + PACKAGE_HALF[2] + 0.001, 0.0
        extra_xy = [np.array([x, -1.4]) for x in (0.0, 5.5, 7.0)]
        extra_z = shelf + PACKAGE_HALF[2]
        region, dz = (0.5, 5.5, -0.95, 0.95), 0.0
        if manifest.task.waypoints:  # distractors stay off the commanded path
            keep_out = [(*xy, 0.45) for xy in _along(np.vstack([[0.0, 0.0], path]), 0.5)]
        else:
            keep_out = [(x, 0.0, 0.45) for x in np.arange(-0.5, AISLE_GOAL_X + 0.6, 0.5)]
    target_pos = np.array([*start, rest_z])
    objects = [_add_package(spec, names[0], target_pos, yaw, PACKAGE_HALF, package_mat)]
    for i, name in enumerate(names[1:]):
        xy = extra_xy[i % len(extra_xy)] + layout.uniform(-0.02, 0.02, 2)
        objects.append(_add_package(spec, name, (*xy, extra_z + 0.001), float(layout.uniform(-1, 1)), PACKAGE_HALF, package_mat))

    fork = manifest.stressor("forklift_crossing")
    if fork:
        stressors.add_forklift(spec, fork, fork.lane_m)
    if manifest.stressor("occluder"):
        primary = next((c for c in manifest.cameras if c.mount == "world"), manifest.cameras[0])
        cam_pos = np.array(primary.position) if primary.mount == "world" else target_pos + np.array([0.6, 0.0, 0.6])
        stressors.add_occluder(spec, manifest.stressor("occluder"), cam_pos, target_pos, PACKAGE_HALF, yaw)
    if manifest.stressor("distractors"):
        objects += stressors.add_distractors(spec, manifest.stressor("distractors"), rng_for(seed, "distractors"),
                                             region, dz, keep_out)
    _add_cameras(spec, manifest.cameras, where)
    dim = manifest.stressor("dim_light")
    _scale_lights(spec, (dim.lux if dim else NORMAL_LUX) / NORMAL_LUX)
    model = spec.compile()
    grip_axis = robots.fit_tcp_to_pads(model) if arm is not None and manifest.embodiment.mjcf else math.pi / 2
    qpos, ctrl = robots.initial_state(model, arm, target_pos)
    if fork:
        qpos[model.joint("forklift_slide").qposadr[0]] = stressors.FORKLIFT_PARK_Y
    return Scene(model=model, manifest=manifest, seed=seed, config=config, arm=arm, base=base,
                 objects=tuple(objects), target_half=PACKAGE_HALF.copy(), goal=goal, rim_z=rim_z,
                 lane_x=fork.lane_m if fork else None, initial_qpos=qpos, initial_ctrl=ctrl, stressor_values=values,
                 grip_axis=grip_axis, path=path if task == "drive" and manifest.task.waypoints else None)


def _scale_lights(spec: mujoco.MjSpec, scale: float) -> None:
    # Lux maps linearly onto light colour: 500 lux (a lit warehouse) is the nominal rig.
    scale = float(np.clip(scale, 0.0, 3.0))
    for light in spec.lights:
        light.diffuse = list(np.asarray(light.diffuse) * scale)
        light.ambient = list(np.asarray(light.ambient) * scale)
        light.specular = list(np.asarray(light.specular) * scale)
    head = spec.visual.headlight
    head.ambient = list(np.asarray(head.ambient) * scale)
    head.diffuse = list(np.asarray(head.diffuse) * scale)
