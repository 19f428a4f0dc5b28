"""Stressors as real changes to an `mujoco.MjSpec`: forklift, occluder, distractors, appearance.

Dim light and camera jitter are applied where they act (light levels in `scene`, per-frame
camera rotation in `render`); everything here adds or recolours bodies before compiling.
"""

from __future__ import annotations

import numpy as np

import mujoco
from schemas.manifest import Appearance, Distractors, ForkliftCrossing, Occluder

G = mujoco.mjtGeom
FORKLIFT_YELLOW = (0.95, 0.72, 0.05, 1.0)
FORKLIFT_PARK_Y = -4.5  # off to the side of every workcell view until start_s
FORKLIFT_LENGTH = 2.4


def add_forklift(spec: mujoco.MjSpec, stressor: ForkliftCrossing, lane_x: float) -> None:
    """A forklift (chassis, cab, mast, forks) on a slide joint along the lane x=lane_x.

    It travels along +y (forks first) from start_s at speed_mps; the simulation overwrites
    its joint position and velocity every physics step (`forklift_position`), so the motion
    is exact. A 3 t joint body rather than a mocap body, because MuJoCo never collides mocap
    bodies with static geoms, and driving into the bin or pedestal must count as contact.
    """
    body = spec.worldbody.add_body(name="forklift", pos=[lane_x, 0.0, 0.0], quat=[0.7071068, 0, 0, 0.7071068])
    body.add_joint(name="forklift_slide", type=mujoco.mjtJoint.mjJNT_SLIDE, axis=[1, 0, 0])
    body.explicitinertial = True
    body.mass, body.ipos, body.inertia = 3000.0, [0, 0, 0.5], [1500.0, 3000.0, 3000.0]
    y, dark = FORKLIFT_YELLOW, (0.12, 0.12, 0.12, 1.0)
    solid = dict(contype=1, conaffinity=1, mass=0)
    body.add_geom(name="forklift_chassis", type=G.mjGEOM_BOX, pos=[-0.1, 0, 0.45], size=[0.75, 0.45, 0.3], rgba=y,
                  **solid)
    body.add_geom(name="forklift_counterweight", type=G.mjGEOM_BOX, pos=[-0.8, 0, 0.6], size=[0.12, 0.42, 0.3], rgba=dark, **solid)
    for px in (-0.6, 0.45):
        for py in (-0.4, 0.4):
            body.add_geom(type=G.mjGEOM_CAPSULE, fromto=[px, py, 0.75, px, py, 1.95], size=[0.03, 0, 0], rgba=dark, **solid)
    body.add_geom(name="forklift_roof", type=G.mjGEOM_BOX, pos=[-0.08, 0, 1.98], size=[0.6, 0.45, 0.03], rgba=dark, **solid)
    for py in (-0.3, 0.3):
        body.add_geom(type=G.mjGEOM_BOX, pos=[0.72, py, 1.2], size=[0.05, 0.05, 1.05], rgba=(0.3, 0.3, 0.3, 1), **solid)
        body.add_geom(type=G.mjGEOM_BOX, pos=[1.25, py * 0.8, 0.12], size=[0.5, 0.05, 0.02], rgba=(0.3, 0.3, 0.3, 1), **solid)
    for px in (-0.55, 0.45):
        for py in (-0.42, 0.42):
            body.add_geom(type=G.mjGEOM_CYLINDER, pos=[px, py, 0.2], quat=[0.7071068, 0.7071068, 0, 0],
                          size=[0.2, 0.09, 0], rgba=dark, contype=0, conaffinity=0, mass=0)


def forklift_position(stressor: ForkliftCrossing, t: float) -> tuple[float, float]:
    """(world y of the forklift origin in m, its speed in m/s) at time t: parked until start_s."""
    travelled = max(0.0, t - stressor.start_s) * stressor.speed_mps
    return FORKLIFT_PARK_Y + travelled, stressor.speed_mps if t >= stressor.start_s else 0.0


def _look_axes(forward: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    up = np.array([0.0, 0.0, 1.0])
    right = np.cross(forward, up)
    if np.linalg.norm(right) < 1e-6:
        right = np.cross(forward, np.array([1.0, 0.0, 0.0]))
    right /= np.linalg.norm(right)
    return right, np.cross(right, forward)


def add_occluder(spec: mujoco.MjSpec, stressor: Occluder, camera_pos: np.ndarray, target_pos: np.ndarray,
                 target_half: np.ndarray, target_yaw: float) -> None:
    """A board between the camera and the target hiding `coverage` of the target's width.

    The target box's corners are projected onto the plane facing the camera; the board
    spans the full projected height and the left `coverage` of the projected width, scaled
    to where it stands (a third of the way from target to camera). It is visual only, so
    it never changes the physics of the task it hides.
    """
    forward = target_pos - camera_pos
    dist = float(np.linalg.norm(forward))
    forward /= dist
    right, up = _look_axes(forward)
    c, s = np.cos(target_yaw), np.sin(target_yaw)
    rot = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    signs = np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)], float)
    corners = target_pos + (signs * target_half) @ rot.T
    # Perspective projection onto the plane through the target facing the camera.
    rel = corners - camera_pos
    depth = rel @ forward
    r = (rel @ right) * dist / depth
    u = (rel @ up) * dist / depth
    stand = min(1.0 / 3.0, 0.3 / dist)
    scale = 1.0 - stand  # board plane distance / target distance
    width = stressor.coverage * (r.max() - r.min())
    r_mid = r.min() + width / 2
    u_mid, height = (u.max() + u.min()) / 2, (u.max() - u.min()) * 1.3
    centre = camera_pos + forward * dist * scale + scale * (r_mid * right + u_mid * up)
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, np.column_stack([right, up, -forward]).ravel())
    # Matte: the board faces the camera head-on, where the headlight's specular glare peaks.
    spec.add_material(name="occluder_mat", rgba=[0.32, 0.3, 0.28, 1.0], specular=0.0, shininess=0.0)
    spec.worldbody.add_geom(name="occluder", type=G.mjGEOM_BOX, pos=list(centre), quat=list(quat),
                            size=[scale * width / 2, scale * height / 2, 0.004], material="occluder_mat",
                            contype=0, conaffinity=0)


def add_distractors(spec: mujoco.MjSpec, stressor: Distractors, rng: np.random.Generator,
                    region: tuple[float, float, float, float], z: float, keep_out: list[tuple[float, float, float]]) -> list[str]:
    """`count` free bodies of random shape, size and colour in the x/y box `region` at height z.

    Positions avoid the discs in `keep_out` (x, y, radius) and each other; returns body names.
    """
    x0, x1, y0, y1 = region
    placed: list[tuple[float, float, float]] = []
    names = []
    for i in range(stressor.count):
        half = float(rng.uniform(0.015, 0.035))
        for _ in range(200):
            x, y = float(rng.uniform(x0, x1)), float(rng.uniform(y0, y1))
            if all(np.hypot(x - a, y - b) > r + half for a, b, r in keep_out + placed):
                break
        placed.append((x, y, half + 0.01))
        kind = int(rng.integers(3))
        rgba = [*rng.uniform(0.1, 0.95, 3), 1.0]
        body = spec.worldbody.add_body(name=f"distractor_{i}", pos=[x, y, z + half],
                                       quat=list(_yaw(float(rng.uniform(-np.pi, np.pi)))))
        body.add_freejoint()
        shape = [G.mjGEOM_BOX, G.mjGEOM_CYLINDER, G.mjGEOM_ELLIPSOID][kind]
        size = [half, half * float(rng.uniform(0.6, 1.4)), half] if kind != 1 else [half, half, 0]
        body.add_geom(type=shape, size=size, rgba=rgba, mass=0.08)
        names.append(body.name)
    return names


def _yaw(yaw: float) -> np.ndarray:
    return np.array([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)])


def add_material(spec: mujoco.MjSpec, name: str, rgb: tuple[float, float, float], rng: np.random.Generator | None,
                 appearance: Appearance | None, repeat: tuple[float, float] = (1.0, 1.0), checker: bool = False) -> str:
    """A material named `name`: base colour `rgb`, jittered and textured when `appearance` is set.

    Without appearance the look is fixed (a plain colour, or a two-tone checker if `checker`);
    with it, each channel moves by up to +-colour_jitter and, if texture, a random builtin
    texture (checker or gradient with noise dots) replaces the plain surface.
    """
    base = np.array(rgb, float)
    if appearance is not None and rng is not None:
        base = np.clip(base + rng.uniform(-appearance.colour_jitter, appearance.colour_jitter, 3), 0.02, 1.0)
    textured = checker or (appearance is not None and appearance.texture)
    mat = spec.add_material(name=name, rgba=[*base, 1.0], specular=0.1, shininess=0.1)
    if not textured:
        return name
    tex = spec.add_texture(name=f"{name}_tex", type=mujoco.mjtTexture.mjTEXTURE_2D, width=64, height=64)
    if appearance is not None and appearance.texture and rng is not None:
        tex.builtin = [mujoco.mjtBuiltin.mjBUILTIN_CHECKER, mujoco.mjtBuiltin.mjBUILTIN_GRADIENT][int(rng.integers(2))]
        tex.rgb1 = list(base)
        tex.rgb2 = list(np.clip(base * rng.uniform(0.4, 1.0), 0, 1))
        tex.mark = mujoco.mjtMark.mjMARK_RANDOM
        tex.random = float(rng.uniform(0.01, 0.1))
        tex.markrgb = list(rng.uniform(0, 1, 3))
        repeat = tuple(float(r * rng.uniform(0.5, 2.0)) for r in repeat)
    else:
        tex.builtin = mujoco.mjtBuiltin.mjBUILTIN_CHECKER
        tex.rgb1, tex.rgb2 = list(base), list(base * 0.8)
    mat.rgba = [1.0, 1.0, 1.0, 1.0]
    mat.texrepeat = list(repeat)
    roles = [""] * len(mat.textures)
    roles[mujoco.mjtTextureRole.mjTEXROLE_RGB] = tex.name
    mat.textures = roles
    return name
