"""Scripted controllers with privileged state: bin pick and push for arms, aisle driving for bases.

Each control step a controller reads the simulator state, picks the next commanded pose (or
velocity), adds seeded noise, writes `data.ctrl` and returns the action it applied:
- ee_delta: [dx, dy, dz (m), dyaw (rad), grip in [0, 1]] change of the commanded tcp pose;
- velocity (arm): the same divided by the control period (m/s, rad/s), grip unchanged;
- joint_position: [6 joint targets (rad), grip];
- velocity (mobile base): [vx, vy] in m/s.
The commanded tcp pose becomes joint targets by differential IK (damped least squares on
mj_jacSite), converged from the measured joint angles on a scratch MjData.
"""

from __future__ import annotations

import math

import numpy as np

import mujoco
from tasks.sim.kinematics import solve_ik, yaw_quat
from tasks.sim.scene import Scene, rng_for
from tasks.sim.stressors import FORKLIFT_LENGTH

MAX_STEP = 0.012  # m per control step (0.6 m/s at 50 Hz)
PUSH_STEP = 0.005
MAX_YAW_STEP = 0.08
NOISE_STEP = 0.01  # m: per-step std of commanded-pose noise at controller_noise = 1
PUSH_HEIGHT = 0.025  # m above the rim at which closed fingers push the package
PRE_PUSH = 0.05  # m behind the contact point where a push starts (the approach's and realign's waypoint)
PUSH_LINE = 0.03  # m off the push line (and past the contact point) that a push still tolerates
PUSH_BAND = 0.02  # m above the push height within which an arm is taken to be pushing (ArmController.resync)
NOISE_AIM = 0.1  # m: std of the per-attempt aim error at controller_noise = 1
FINGER_REACH = 0.018  # closed fingers' half thickness along the push direction
STOP_GAP = 0.45 + 0.35 + 0.25  # forklift half width + base half length + margin (m)


def body_yaw(quat: np.ndarray) -> float:
    w, x, y, z = quat
    return math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


def _nearest_equivalent(angle: float, reference: float, period: float) -> float:
    return angle + period * round((reference - angle) / period)


class ArmController:
    """Bin pick (approach, descend, close, lift, hold) or push (align, descend, push, retreat).

    With `repeat`, the task cycles (put the package back, push it back) so long footage keeps
    moving; episodes use repeat=False and end holding the result.
    """

    def __init__(self, scene: Scene, seed: int, repeat: bool = False, noise: float | None = None):
        m, arm = scene.model, scene.arm
        self.scene, self.model, self.repeat = scene, m, repeat
        self.task = scene.manifest.task.kind
        self.space = scene.manifest.embodiment.action_space
        # noise None: the manifest's controller_noise (a policy may run the same task noisier).
        self.noise = scene.manifest.task.controller_noise if noise is None else noise
        self.rng = rng_for(seed, "controller")
        self.dt = 1.0 / scene.config.control_hz
        self.site = m.site("tcp").id
        jids = [m.joint(j).id for j in arm.joints]
        self.qadr = m.jnt_qposadr[jids]
        self.dofs = m.jnt_dofadr[jids]
        self.acts = np.array([m.actuator(a).id for a in arm.actuators])
        self.grip_acts = np.array([m.actuator(a).id for a in arm.gripper_actuators], int)
        self.grip_open = np.array(arm.gripper_open)
        self.grip_closed = np.array(arm.gripper_closed)
        self.body = m.body(scene.objects[0]).id
        self.scratch = mujoco.MjData(m)
        self.phase, self.phase_t, self.grip = "approach", 0.0, 0.0
        self.bias = self._aim()
        self.goal_xy = scene.goal[:2].copy()
        self.start_xy: np.ndarray | None = None
        self.target_pos = np.zeros(3)
        self.target_yaw = 0.0

    def _aim(self) -> np.ndarray:
        return self.rng.normal(0.0, self.noise * NOISE_AIM, 2) if self.noise else np.zeros(2)

    def reset(self, data: mujoco.MjData) -> None:
        self.target_pos = data.site_xpos[self.site].copy()
        quat = np.zeros(4)
        mujoco.mju_mat2Quat(quat, data.site_xmat[self.site])
        self.target_yaw = body_yaw(quat)
        self.start_xy = data.xpos[self.body][:2].copy()

    def _go(self, phase: str) -> None:
        self.phase, self.phase_t = phase, 0.0

    def _near(self, data, goal, tol) -> bool:
        return float(np.linalg.norm(data.site_xpos[self.site] - goal)) < tol

    def _bin_pick(self, data) -> tuple[np.ndarray, float, float, float]:
        pkg = data.xpos[self.body]
        # Close across the box's short side (its y axis): ee yaw + grip_axis = box yaw + 90 deg.
        yaw = _nearest_equivalent(body_yaw(data.xquat[self.body]) + math.pi / 2 - self.scene.grip_axis,
                                  self.target_yaw, math.pi)
        aim = pkg[:2] + self.bias
        rest_z = self.scene.initial_qpos[self.model.jnt_qposadr[self.model.body_jntadr[self.body]] + 2]
        lift_z = self.scene.rim_z + self.scene.manifest.evaluation.lift_height_m + 0.2
        p, step = self.phase, MAX_STEP
        if p == "approach":
            goal, grip = np.array([*aim, pkg[2] + 0.15]), 0.0
            if self._near(data, goal, 0.012) and abs(yaw - self.target_yaw) < 0.05:
                self._go("descend")
        elif p == "descend":
            goal, grip, step = np.array([*aim, pkg[2] - 0.005]), 0.0, 0.008
            if self._near(data, goal, 0.006) or self.phase_t > 1.5:
                self._go("close")
        elif p == "close":
            goal, grip = self.target_pos.copy(), 1.0
            if self.phase_t >= 0.35:
                self._go("lift")
        elif p in ("lift", "hold"):
            goal, grip, yaw = np.array([*self.target_pos[:2], lift_z]), 1.0, self.target_yaw
            if data.site_xpos[self.site][2] > self.scene.rim_z + 0.1 and pkg[2] < data.site_xpos[self.site][2] - 0.06:
                self.bias = self._aim()  # dropped it: try again
                self._go("approach")
            elif p == "lift" and self._near(data, goal, 0.02):
                self._go("hold")
            elif p == "hold" and self.repeat and self.phase_t > 0.6:
                self._go("lower")
        elif p == "lower":
            goal, grip, yaw = np.array([*self.scene.goal[:2], rest_z + 0.01]), 1.0, self.target_yaw
            if self._near(data, goal, 0.01) or self.phase_t > 2.0:
                self._go("release")
        else:  # release, then retreat and start over
            goal, grip, yaw = np.array([*self.target_pos[:2], rest_z + 0.2]), 0.0, self.target_yaw
            if self.phase_t > 0.8:
                self.bias = self._aim()
                self._go("approach")
        return goal, yaw, grip, step

    def _push_geometry(self, data) -> tuple[float, np.ndarray, np.ndarray, np.ndarray, float]:
        """(package's distance to the goal, unit direction u to it, the contact point behind the
        package, the tcp, the tcp's distance sideways from the push line through the contact)."""
        pkg = data.xpos[self.body][:2]
        to_goal = self.goal_xy - pkg
        dist = float(np.linalg.norm(to_goal))
        u = to_goal / max(dist, 1e-9)
        box_yaw = body_yaw(data.xquat[self.body])
        half = self.scene.target_half
        reach = abs(half[0] * math.cos(box_yaw - math.atan2(u[1], u[0]))) + abs(half[1] * math.sin(box_yaw - math.atan2(u[1], u[0])))
        contact = pkg - u * (reach + FINGER_REACH + 0.004) + self.bias * 0.3
        tcp = data.site_xpos[self.site]
        offset = tcp[:2] - contact
        lateral = abs(float(u[0] * offset[1] - u[1] * offset[0]))  # 2-D cross product
        return dist, u, contact, tcp, lateral

    def _push(self, data) -> tuple[np.ndarray, float, float, float]:
        dist, u, contact, tcp, lateral = self._push_geometry(data)
        # Closed fingers make a paddle wide across their closing axis: point that axis along u.
        yaw = _nearest_equivalent(math.atan2(u[1], u[0]) - self.scene.grip_axis, self.target_yaw, math.pi)
        low, high = self.scene.rim_z + PUSH_HEIGHT, self.scene.rim_z + 0.14
        p, step, grip = self.phase, MAX_STEP, 1.0
        if p == "approach":
            goal = np.array([*(contact - u * PRE_PUSH), high])
            if self._near(data, goal, 0.015) and abs(yaw - self.target_yaw) < 0.08:
                self._go("descend")
        elif p == "descend":
            goal = np.array([*(contact - u * PRE_PUSH), low])
            if self._near(data, goal, 0.008):
                self._go("push")
        elif p == "push":
            goal, step = np.array([*(contact + u * 0.03), low]), PUSH_STEP
            if dist < 0.3 * self.scene.manifest.evaluation.goal_tolerance_m:
                self._go("retreat")
            elif lateral > PUSH_LINE:
                self._go("realign")
        elif p == "realign":
            goal = np.array([*(contact - u * PRE_PUSH), low])
            if self._near(data, goal, 0.01):
                self._go("push")
            elif self.phase_t > 1.0:
                self._go("approach")
        else:  # retreat: lift clear; with repeat, push it back where it came from
            goal, yaw = np.array([*tcp[:2], high]), self.target_yaw
            if self.repeat and self.phase_t > 0.5:
                self.goal_xy, self.start_xy = self.start_xy, self.goal_xy
                self.bias = self._aim()
                self._go("approach")
        return goal, yaw, grip, step

    def resync(self, data: mujoco.MjData) -> None:
        """Take the push's phase from the state alone: where the arm, the package and the goal
        are, not which of this controller's waypoints the arm passed. An expert labelling
        another's states (DAgger) needs it: a learner that pushes from a few millimetres off
        the path never reaches the approach or descend waypoint, and a controller waiting
        for them labels every step of a good push with a move back. Low (within PUSH_BAND of
        the push height), across the package from the goal and in line with it (as the push
        phase itself allows, 0.03 m): push; low otherwise, behind the package: realign; low
        past it, or high: approach, or descend within 0.03 m of above the pre-push point. A pick keeps
        its phase (its phases also follow the grip and the lift, not read here). A package
        already at the goal: retreat, as the push itself decides."""
        if self.task != "push" or self.phase == "retreat":
            return
        dist, u, contact, tcp, lateral = self._push_geometry(data)
        if dist < 0.3 * self.scene.manifest.evaluation.goal_tolerance_m:
            self._go("retreat")  # the package is there: lift clear
            return
        along = float(u @ (tcp[:2] - contact))  # < 0: on the far side of the contact point from the goal
        if tcp[2] < self.scene.rim_z + PUSH_HEIGHT + PUSH_BAND:
            phase = "push" if lateral <= PUSH_LINE and along <= PUSH_LINE else "realign" if along < 0 else "approach"
        else:
            above = float(np.linalg.norm(tcp[:2] - (contact - u * PRE_PUSH))) <= 0.03
            phase = "descend" if above else "approach"
        if phase != self.phase:
            self._go(phase)

    def plan(self, data: mujoco.MjData) -> tuple[np.ndarray, float, float]:
        """The noiseless move from the commanded pose: (delta, dyaw, grip); advances the phase.
        An expert labelling a learner's states (DAgger) sets ``target_pos``, ``target_yaw``
        and ``grip`` to the learner's, then asks for this."""
        goal, yaw, grip, step = self._bin_pick(data) if self.task == "bin_pick" else self._push(data)
        self.phase_t += self.dt
        delta = goal - self.target_pos
        norm = float(np.linalg.norm(delta))
        if norm > step:
            delta *= step / norm
        return delta, float(np.clip(yaw - self.target_yaw, -MAX_YAW_STEP, MAX_YAW_STEP)), grip

    def step(self, data: mujoco.MjData) -> np.ndarray:
        """Choose, noise and apply one control step's action; returns the action applied."""
        delta, dyaw, grip = self.plan(data)
        if self.noise and self.space != "joint_position":
            delta = delta + self.rng.normal(0.0, self.noise * NOISE_STEP, 3)
            dyaw += float(self.rng.normal(0.0, self.noise * NOISE_STEP * 5))
        return self.apply(data, delta, dyaw, grip)

    def apply(self, data: mujoco.MjData, delta: np.ndarray, dyaw: float, grip: float) -> np.ndarray:
        """Move the commanded tcp pose by (delta, dyaw), set the grip, and write the joint
        targets (differential IK); returns the action in this controller's action space.
        A learned policy acts through this too (tasks/policy)."""
        self.target_pos = self.target_pos + delta
        self.target_yaw += dyaw
        self.grip = grip
        q = solve_ik(self.model, data.qpos, self.site, self.qadr, self.dofs, self.target_pos,
                     yaw_quat(self.target_yaw), iters=6, scratch=self.scratch)
        if self.space == "joint_position":
            if self.noise:
                q = q + self.rng.normal(0.0, self.noise * 0.05, q.shape)
            action = np.concatenate([q, [grip]])
        elif self.space == "velocity":
            action = np.concatenate([delta / self.dt, [dyaw / self.dt, grip]])
        else:
            action = np.concatenate([delta, [dyaw, grip]])
        data.ctrl[self.acts] = q
        if len(self.grip_acts):
            data.ctrl[self.grip_acts] = self.grip_open + grip * (self.grip_closed - self.grip_open)
        return action

    def action_size(self) -> int:
        return 7 if self.space == "joint_position" else 5


class DriveController:
    """Drives the base along the aisle to the goal, holding at a stop line while a forklift crosses.

    With the task's waypoints it drives through them in order on straight legs, slowing to
    CORNER_SPEED to turn at each (within WAYPOINT_REACH), and comes to rest at the last; with `repeat` it then drives the
    path back to where it started, and again. The action is [vx, vy] (world frame), the base
    carrying its cameras without turning, so it is their velocity too: a camera-control action.
    A base that turns (the twist action space) also turns to face where it drives, within
    MAX_TURN of the aisle's direction, and the action is [vx, vy, wz] (rad/s about world z):
    the cameras' translation and rotation rates.
    """

    VMAX, ACCEL = 1.5, 1.5  # m/s, m/s^2
    WAYPOINT_REACH = 0.15  # m: close enough to a waypoint to head for the next one
    CORNER_SPEED = 0.3  # m/s: speed through a waypoint on the way
    GAIN = 1.0  # 1/s: wanted speed per metre to the waypoint; GAIN * VMAX stays within ACCEL
    WMAX, ALPHA, YAW_GAIN = 0.5, 1.5, 2.0  # rad/s, rad/s^2, 1/s: a turning base's yaw rate servo
    MAX_TURN = 0.6  # rad: the most a turning base faces away from the aisle's direction
    FACE_SPEED = 0.2  # m/s: slower than this, a turning base keeps the heading it has

    def __init__(self, scene: Scene, seed: int, repeat: bool = False, noise: float | None = None):
        m = scene.model
        self.scene, self.model, self.repeat = scene, m, repeat
        self.noise = scene.manifest.task.controller_noise if noise is None else noise
        self.rng = rng_for(seed, "controller")
        self.dt = 1.0 / scene.config.control_hz
        self.qadr = m.jnt_qposadr[[m.joint(j).id for j in scene.base.joints]]
        self.acts = np.array([m.actuator(a).id for a in scene.base.actuators])
        self.goal_x, self.home_x = float(scene.goal[0]), 0.0
        self.fork = scene.manifest.stressor("forklift_crossing")
        self.fork_y: float | None = None
        self.v = np.zeros(2)
        self.path = [] if scene.path is None else [np.array(w, float) for w in scene.path]
        self.leg = 0  # index of the waypoint being driven to
        base = scene.base
        self.yaw_q = int(m.jnt_qposadr[m.joint(base.yaw_joint).id]) if base.yaw_joint else -1
        self.yaw_act = m.actuator(base.yaw_actuator).id if base.yaw_actuator else -1
        self.w, self.face = 0.0, 0.0

    def reset(self, data: mujoco.MjData) -> None:
        self.home_x = float(data.qpos[self.qadr[0]])
        self.home = data.qpos[self.qadr].astype(float)
        self.fork_q = int(self.model.joint("forklift_slide").qposadr[0]) if self.fork else -1
        self.fork_y = float(data.qpos[self.fork_q]) if self.fork else None

    def _crossing_soon(self, data, x: float, heading: float) -> bool:
        """True while the forklift is in, or within a second of, the aisle ahead of the base."""
        if not self.fork:
            return False
        fy = float(data.qpos[self.fork_q])
        speed = (fy - self.fork_y) / self.dt
        self.fork_y = fy
        # World y span of the forklift (forks lead along +y), projected one second ahead.
        front, rear = fy + FORKLIFT_LENGTH * 0.73 + max(speed, 0.0) * 1.0, fy - FORKLIFT_LENGTH * 0.42
        gap = heading * (self.scene.lane_x - x)  # distance to the lane along the direction of travel
        return STOP_GAP - 0.25 < gap < 4.0 and front > -1.0 and rear < 1.0

    def _follow(self, x: float, y: float) -> tuple[np.ndarray, float]:
        """Wanted velocity and heading along x on the waypoint path."""
        here = np.array([x, y])
        last = len(self.path) - 1
        while self.leg < last and np.linalg.norm(self.path[self.leg] - here) < self.WAYPOINT_REACH:
            self.leg += 1
        if self.repeat and self.leg == last and np.linalg.norm(self.path[last] - here) < 0.1:
            # Back the way it came, to where it started: [.., w1, w0, home].
            back = self.path[-2::-1] + [self.home]
            self.home, self.path, self.leg = self.path[-1], back, 0
        to = self.path[self.leg] - here
        gap = float(np.linalg.norm(to))
        # Slow to CORNER_SPEED into a waypoint on the way (so the turn stays tight), to rest at the last.
        speed = min(self.VMAX, self.GAIN * gap + (self.CORNER_SPEED if self.leg < last else 0.0))
        want = to / gap * speed if gap > 1e-9 else np.zeros(2)
        return want, 1.0 if to[0] >= 0 else -1.0

    def step(self, data: mujoco.MjData) -> np.ndarray:
        x, y = (float(v) for v in data.qpos[self.qadr])
        if self.path:
            want, heading = self._follow(x, y)
        else:
            if self.repeat and abs(self.goal_x - x) < 0.1:
                self.goal_x, self.home_x = self.home_x, self.goal_x
            want = np.array([np.clip(1.5 * (self.goal_x - x), -self.VMAX, self.VMAX), -2.0 * y])
            heading = 1.0 if self.goal_x >= x else -1.0
        if self._crossing_soon(data, x, heading):
            room = heading * (self.scene.lane_x - x) - STOP_GAP  # how far to the stop line
            want[0] = heading * min(heading * want[0], max(0.0, 2.0 * room))
        self.v = self.v + np.clip(want - self.v, -self.ACCEL * self.dt, self.ACCEL * self.dt)
        action = self.v + (self.rng.normal(0.0, self.noise * 0.3, 2) if self.noise else 0.0)
        data.ctrl[self.acts] = action
        if self.yaw_q < 0:
            return np.asarray(action, float)
        return np.append(action, self._turn(data, heading))

    def _turn(self, data: mujoco.MjData, heading: float) -> float:
        """A turning base's yaw rate: towards facing along its velocity (backwards along the
        aisle it faces +x still), rate- and acceleration-limited; written to its servo."""
        if np.linalg.norm(self.v) >= self.FACE_SPEED:
            self.face = float(np.clip(math.atan2(heading * self.v[1], heading * self.v[0]),
                                      -self.MAX_TURN, self.MAX_TURN))
        want = float(np.clip(self.YAW_GAIN * (self.face - data.qpos[self.yaw_q]), -self.WMAX, self.WMAX))
        self.w += float(np.clip(want - self.w, -self.ALPHA * self.dt, self.ALPHA * self.dt))
        w = self.w + (float(self.rng.normal(0.0, self.noise * 0.3)) if self.noise else 0.0)
        data.ctrl[self.yaw_act] = w
        return w

    def action_size(self) -> int:
        return 2 if self.yaw_q < 0 else 3


def make_controller(scene: Scene, seed: int, repeat: bool = False,
                    noise: float | None = None) -> ArmController | DriveController:
    """The scripted controller for the scene's embodiment; noise None is the manifest's."""
    kind = ArmController if scene.arm is not None else DriveController
    return kind(scene, seed, repeat, noise)
