"""Embodiments added to an `mujoco.MjSpec`: the built-in arm, an MJCF arm, a mobile base.

Every arm exposes the same handles: a body named `ee` whose frame is the flange/palm with
local -z along the approach direction (wrist cameras hang off it), a site `tcp` between the
fingertips, arm joints driven by position actuators, and one gripper command in [0, 1]
(0 open, 1 closed) mapped onto the robot's own gripper actuator range.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import mujoco
from tasks.sim.kinematics import solve_ik, yaw_quat

G = mujoco.mjtGeom
HINGE = mujoco.mjtJoint.mjJNT_HINGE
SLIDE = mujoco.mjtJoint.mjJNT_SLIDE

# Half sizes and link lengths of the built-in arm (metres). Shoulder sits at z=0.36 so the
# tcp reaches a bin floor at x=0.45 with the gripper pointing straight down.
PEDESTAL_TOP = 0.28
LINKS = (0.08, 0.32, 0.30, 0.05, 0.06)
FINGER_HALF = (0.022, 0.008, 0.045)
FINGER_OPEN, FINGER_CLOSED = 0.065, 0.010  # closed: 4 mm between the pads, so they never touch
TCP_DEPTH = 0.095  # palm to fingertip centre
MJCF_RISER = 0.3


@dataclass(frozen=True)
class ArmSpec:
    """Names the controller needs once the model is compiled (all prefixed as in the model)."""

    joints: tuple[str, ...]
    actuators: tuple[str, ...]
    gripper_actuators: tuple[str, ...]
    gripper_open: tuple[float, ...]
    gripper_closed: tuple[float, ...]
    home: tuple[float, ...]  # IK seed for the start pose (a second seed turns the base half a turn)
    link_bodies: tuple[str, ...]  # every body of the robot, for contact checks


def _capsule(body, a, b, r, rgba, name=None):
    return body.add_geom(name=name, type=G.mjGEOM_CAPSULE, fromto=[*a, *b], size=[r, 0, 0], rgba=rgba)


def add_builtin_arm(spec: mujoco.MjSpec, rgba=(0.85, 0.45, 0.1, 1.0)) -> ArmSpec:
    """A 6-hinge arm of capsules on a pedestal at the origin, with a two-finger slide gripper.

    Joints: yaw (z), shoulder, elbow and wrist pitch (y), wrist tilt (x), hand yaw (z). At
    zero the links point straight up; the hand frame is turned half a turn about y so that
    with the links pointing down and all yaws zero it is aligned with the world.
    """
    grey = (0.25, 0.25, 0.28, 1.0)
    wb = spec.worldbody
    wb.add_geom(name="pedestal", type=G.mjGEOM_CYLINDER, pos=[0, 0, PEDESTAL_TOP / 2],
                size=[0.07, PEDESTAL_TOP / 2, 0], rgba=grey)
    ranges = [(-3.1, 3.1), (-2.0, 2.0), (-0.3, 2.9), (-2.6, 2.6), (-1.6, 1.6), (-3.3, 3.3)]
    axes = [(0, 0, 1), (0, 1, 0), (0, 1, 0), (0, 1, 0), (1, 0, 0), (0, 0, 1)]
    offsets = [(0, 0, PEDESTAL_TOP), (0, 0, LINKS[0]), (0, 0, LINKS[1]), (0, 0, LINKS[2]),
               (0, 0, LINKS[3]), (0, 0, LINKS[4])]
    radii = [0.055, 0.042, 0.036, 0.03, 0.03]
    parent, names, bodies = wb, [], []
    for i in range(6):
        name = f"arm_link{i + 1}" if i < 5 else "ee"
        body = parent.add_body(name=name, pos=list(offsets[i]))
        if i == 5:
            body.quat = [0, 0, 1, 0]
        body.gravcomp = 1.0
        j = body.add_joint(name=f"arm_j{i + 1}", type=HINGE, axis=list(axes[i]), range=list(ranges[i]),
                           armature=0.05, damping=1.0)
        names.append(j.name)
        bodies.append(name)
        if i < 5:
            length = LINKS[i]
            if i == 0:
                body.add_geom(type=G.mjGEOM_CYLINDER, pos=[0, 0, LINKS[0] / 2], size=[radii[0], LINKS[0] / 2, 0], rgba=grey)
            else:
                _capsule(body, (0, 0, 0), (0, 0, length), radii[i], rgba if i in (1, 2) else grey)
        parent = body
    hand = parent
    hand.add_geom(name="palm", type=G.mjGEOM_BOX, size=[0.03, 0.08, 0.012], rgba=grey, mass=0.2)
    for side, sign in (("left", 1), ("right", -1)):
        finger = hand.add_body(name=f"finger_{side}")
        finger.gravcomp = 1.0
        finger.add_joint(name=f"finger_{side}_slide", type=SLIDE, axis=[0, sign, 0],
                         range=[FINGER_CLOSED, FINGER_OPEN], damping=2.0, armature=0.01)
        finger.add_geom(name=f"finger_{side}_pad", type=G.mjGEOM_BOX, pos=[0, 0, -0.012 - FINGER_HALF[2]],
                        size=list(FINGER_HALF), rgba=(0.15, 0.15, 0.15, 1), mass=0.05,
                        friction=[1.5, 0.01, 0.001], condim=4)
        bodies.append(finger.name)
    hand.add_site(name="tcp", pos=[0, 0, -TCP_DEPTH], size=[0.006, 0, 0], rgba=(1, 0, 0, 0))
    actuators = []
    for j in names:
        act = spec.add_actuator(name=f"act_{j}", target=j, trntype=mujoco.mjtTrn.mjTRN_JOINT)
        act.set_to_position(kp=600.0, dampratio=1.0)
        act.forcerange = [-150, 150]
        act.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
        actuators.append(act.name)
    grip = []
    for side in ("left", "right"):
        act = spec.add_actuator(name=f"act_finger_{side}", target=f"finger_{side}_slide",
                                trntype=mujoco.mjtTrn.mjTRN_JOINT)
        act.set_to_position(kp=300.0, dampratio=1.0)
        act.forcerange = [-12, 12]
        act.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
        grip.append(act.name)
    return ArmSpec(joints=tuple(names), actuators=tuple(actuators), gripper_actuators=tuple(grip),
                   gripper_open=(FINGER_OPEN, FINGER_OPEN), gripper_closed=(FINGER_CLOSED, FINGER_CLOSED),
                   home=(0.0, 0.25, 1.9, 0.99, 0.0, 0.0), link_bodies=tuple(bodies))


def add_mjcf_arm(spec: mujoco.MjSpec, arm_file: Path, gripper_file: Path | None) -> ArmSpec:
    """Attach an MJCF arm (e.g. Menagerie UR5e) at the origin, and a gripper at its flange.

    The arm needs a site named `attachment_site` at its flange whose +z points out of it (the
    Menagerie convention). A gripper MJCF (e.g. Robotiq 2F-85) is attached there; its
    actuators become the gripper command and its site `pinch` sets the tcp depth.
    """
    if not arm_file.is_file():
        raise FileNotFoundError(f"{arm_file}: robot MJCF not found")
    # On a riser like the built-in arm's, so a floor bin at x=0.45 is within comfortable reach.
    spec.worldbody.add_geom(name="pedestal", type=G.mjGEOM_CYLINDER, pos=[0, 0, MJCF_RISER / 2],
                            size=[0.08, MJCF_RISER / 2, 0], rgba=(0.25, 0.25, 0.28, 1.0))
    spec.attach(mujoco.MjSpec.from_file(str(arm_file)), prefix="robot_",
                frame=spec.worldbody.add_frame(pos=[0, 0, MJCF_RISER]))
    site = spec.site("robot_attachment_site")
    if site is None:
        raise ValueError(f"{arm_file}: no site named attachment_site at the flange")
    joints = [j.name for j in spec.joints if j.name.startswith("robot_") and j.type == HINGE][:6]
    by_joint = {a.target: a.name for a in spec.actuators if a.name.startswith("robot_")}
    if len(joints) < 6 or any(j not in by_joint for j in joints):
        raise ValueError(f"{arm_file}: need 6 hinge joints each driven by an actuator, found {joints}")
    flange, fpos, fquat = site.parent, np.array(site.pos, float), np.array(site.quat, float)
    # `ee` shares the flange origin with z flipped, so approach is local -z as for the built-in arm.
    flip = np.zeros(4)
    mujoco.mju_mulQuat(flip, fquat, np.array([0.0, 1.0, 0.0, 0.0]))
    ee = flange.add_body(name="ee", pos=list(fpos), quat=list(flip))
    depth, grip, g_open, g_closed = 0.0, [], [], []
    if gripper_file is not None and gripper_file.is_file():
        # Menagerie grippers are tuned for elliptic cones and impratio 10 (slip-free grasps).
        # Options only count on the top-level spec; copying the gripper's avoids a conflict warning.
        gspec = mujoco.MjSpec.from_file(str(gripper_file))
        spec.option.cone, spec.option.impratio = gspec.option.cone, gspec.option.impratio
        spec.attach(gspec, prefix="gripper_", frame=flange.add_frame(pos=list(fpos), quat=list(fquat)))
        pinch = spec.site("gripper_pinch")
        depth = float(np.linalg.norm(pinch.pos)) + 0.011 if pinch is not None else 0.15
        for act in spec.actuators:
            if act.name.startswith("gripper_"):
                grip.append(act.name)
                g_open.append(float(act.ctrlrange[0]))
                g_closed.append(float(act.ctrlrange[1]))
    ee.add_site(name="tcp", pos=[0, 0, -depth], size=[0.006, 0, 0], rgba=(1, 0, 0, 0))
    bodies = [b.name for b in spec.bodies if b.name.startswith(("robot_", "gripper_"))] + ["ee"]
    for body in spec.bodies:
        if body.name in bodies:
            body.gravcomp = 1.0  # Menagerie servos sag ~2 cm under gravity; the controller is kinematic
    return ArmSpec(joints=tuple(joints), actuators=tuple(by_joint[j] for j in joints),
                   gripper_actuators=tuple(grip), gripper_open=tuple(g_open), gripper_closed=tuple(g_closed),
                   home=(0.0, -1.57, 1.57, -1.57, -1.57, 0.0), link_bodies=tuple(bodies))


@dataclass(frozen=True)
class BaseSpec:
    joints: tuple[str, str]  # the planar slides (world x, y): where the base is
    actuators: tuple[str, str]
    link_bodies: tuple[str, ...]
    yaw_joint: str | None = None  # a base that turns (a twist action space)
    yaw_actuator: str | None = None


def add_mobile_base(spec: mujoco.MjSpec, rgba=(0.2, 0.35, 0.7, 1.0), turn: bool = False) -> BaseSpec:
    """A box chassis on x/y slide joints with velocity servos (a holonomic cart); with `turn`
    also a hinge about z after the slides, so the slides stay along world x and y and the chassis
    (with the cameras mounted on it) turns about its centre."""
    base = spec.worldbody.add_body(name="base", pos=[0, 0, 0.0])
    for axis, name in (((1, 0, 0), "base_x"), ((0, 1, 0), "base_y")):
        base.add_joint(name=name, type=SLIDE, axis=list(axis), damping=5.0)
    if turn:
        base.add_joint(name="base_yaw", type=mujoco.mjtJoint.mjJNT_HINGE, axis=[0, 0, 1], damping=2.0)
    base.add_geom(name="chassis", type=G.mjGEOM_BOX, pos=[0, 0, 0.2], size=[0.35, 0.25, 0.12], rgba=rgba, mass=40)
    base.add_geom(type=G.mjGEOM_BOX, pos=[0, 0, 0.42], size=[0.05, 0.18, 0.1], rgba=(0.2, 0.2, 0.2, 1), mass=1)
    for x in (-0.25, 0.25):
        for y in (-0.27, 0.27):
            base.add_geom(type=G.mjGEOM_CYLINDER, pos=[x, y, 0.08], quat=[0.7071068, 0.7071068, 0, 0],
                          size=[0.08, 0.03, 0], rgba=(0.05, 0.05, 0.05, 1), contype=0, conaffinity=0, mass=0.5)
    acts = []
    for j in ("base_x", "base_y", *(("base_yaw",) if turn else ())):
        act = spec.add_actuator(name=f"act_{j}", target=j, trntype=mujoco.mjtTrn.mjTRN_JOINT)
        act.set_to_velocity(kv=400.0 if j != "base_yaw" else 100.0)
        act.forcerange = [-600, 600]
        act.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
        acts.append(act.name)
    return BaseSpec(joints=("base_x", "base_y"), actuators=(acts[0], acts[1]), link_bodies=("base",),
                    yaw_joint="base_yaw" if turn else None, yaw_actuator=acts[2] if turn else None)


def fit_tcp_to_pads(model: mujoco.MjModel) -> float:
    """Move the tcp site to the middle of an MJCF gripper's pads; return their closing axis.

    Pads are the collision geoms of bodies named like left_pad / right_pad (Robotiq). Without
    them the tcp stays on the ee axis and the fingers are assumed to close along ee y.
    """
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    ee = model.body("ee").id
    sides = {}
    for side in ("left", "right"):
        geoms = [g for g in range(model.ngeom) if model.geom_contype[g] and side in model.body(model.geom_bodyid[g]).name
                 and "pad" in model.body(model.geom_bodyid[g]).name]
        if not geoms:
            return math.pi / 2
        world = data.geom_xpos[geoms].mean(axis=0)
        sides[side] = data.xmat[ee].reshape(3, 3).T @ (world - data.xpos[ee])
    mid = (sides["left"] + sides["right"]) / 2
    model.site_pos[model.site("tcp").id] = [0.0, 0.0, mid[2]]
    axis = sides["left"] - sides["right"]
    return math.atan2(axis[1], axis[0])


def initial_state(model: mujoco.MjModel, arm: ArmSpec | None, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(qpos, ctrl) to start from: the arm solved to a pose above `target`, gripper open."""
    qpos, ctrl = model.qpos0.copy(), np.zeros(model.nu)
    if arm is None:
        return qpos, ctrl
    qadr = np.array([model.jnt_qposadr[model.joint(j).id] for j in arm.joints])
    dofs = np.array([model.jnt_dofadr[model.joint(j).id] for j in arm.joints])
    qpos[qadr] = arm.home
    # Home: the tcp 0.25 m above and 0.15 m short of the target, pointing straight down.
    home = np.array([target[0] - 0.15, target[1] * 0.5, max(target[2], 0.1) + 0.25])
    # Two seeds, facing +x and -x (Menagerie arms face -x at zero pan): keep the exact solution
    # that moves the joints least from its seed, so the arm starts elbow-up and unwound.
    best, best_cost = None, np.inf
    for turn in (0.0, np.pi):
        seed_q = np.array(arm.home) + np.array([turn, 0, 0, 0, 0, 0])
        qpos[qadr] = seed_q
        q = solve_ik(model, qpos, model.site("tcp").id, qadr, dofs, home, yaw_quat(0.0))
        data = mujoco.MjData(model)
        data.qpos[:] = qpos
        data.qpos[qadr] = q
        mujoco.mj_kinematics(model, data)
        residual = float(np.linalg.norm(data.site_xpos[model.site("tcp").id] - home))
        cost = (residual > 1e-3) * 1e3 + float(np.abs(q - seed_q).sum())
        if cost < best_cost:
            best, best_cost = q, cost
    qpos[qadr] = best
    for name, q in zip(arm.actuators, qpos[qadr]):
        ctrl[model.actuator(name).id] = q
    for name, value in zip(arm.gripper_actuators, arm.gripper_open):
        ctrl[model.actuator(name).id] = value
        joint = model.actuator(name).trnid[0]
        if model.actuator_trntype[model.actuator(name).id] == mujoco.mjtTrn.mjTRN_JOINT:
            qpos[model.jnt_qposadr[joint]] = value
    return qpos, ctrl
