"""What a learned arm policy observes: the state the scripted controller acts on.

Everything is relative to the target package, so a policy generalises across layouts:
tcp and commanded tcp pose, the goal, the package's height and yaw, the angle the fingers
must turn to line up (for pushing and for grasping; yaw is pi-periodic for a box), the arm's
joint angles and the commanded grip. Needs the commanded pose, so it reads an
`ArmController`, whose `apply` a learned policy acts through.
"""

from __future__ import annotations

import math

import numpy as np

import tasks.sim  # noqa: F401  (sets MUJOCO_GL before mujoco loads)
import mujoco
from tasks.sim.control import ArmController, body_yaw

FEATURES_VERSION = 1


def _angle(value: float) -> list[float]:
    return [math.sin(value), math.cos(value)]


def obs_size(arm: ArmController) -> int:
    return 24 + len(arm.qadr)


def arm_features(data: mujoco.MjData, arm: ArmController) -> np.ndarray:
    """(obs_size,) float32 for one control step, read before the step acts."""
    scene = arm.scene
    tcp = data.site_xpos[arm.site]
    pkg = data.xpos[arm.body]
    pkg_yaw = body_yaw(data.xquat[arm.body])
    to_goal = scene.goal[:2] - pkg[:2]
    push_dir = math.atan2(to_goal[1], to_goal[0])
    parts = [
        tcp - pkg, arm.target_pos - pkg, arm.target_pos - tcp, scene.goal - pkg,
        [pkg[2] - scene.rim_z, float(np.linalg.norm(to_goal)), scene.manifest.evaluation.goal_tolerance_m],
        _angle(arm.target_yaw), _angle(2 * pkg_yaw),
        _angle(2 * (push_dir - scene.grip_axis - arm.target_yaw)),
        _angle(2 * (pkg_yaw + math.pi / 2 - scene.grip_axis - arm.target_yaw)),
        data.qpos[arm.qadr], [arm.grip],
    ]
    return np.concatenate([np.asarray(p, np.float64).ravel() for p in parts]).astype(np.float32)
