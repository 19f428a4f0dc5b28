"""Differential inverse kinematics for the `tcp` site: damped least squares on mj_jacSite."""

from __future__ import annotations

import numpy as np

import mujoco


def yaw_quat(yaw: float) -> np.ndarray:
    """Quaternion (w, x, y, z) of a rotation by `yaw` radians about world z."""
    return np.array([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)])


def site_pose(model: mujoco.MjModel, data: mujoco.MjData, site: int) -> tuple[np.ndarray, np.ndarray]:
    """World position (3,) and quaternion (4,) of a site, from the last mj_kinematics."""
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, data.site_xmat[site])
    return data.site_xpos[site].copy(), quat


def pose_error(pos: np.ndarray, quat: np.ndarray, target_pos: np.ndarray, target_quat: np.ndarray) -> np.ndarray:
    """6-vector: position error (m) then rotation error as an angular velocity over 1 s (rad)."""
    err = np.zeros(6)
    err[:3] = target_pos - pos
    conj, diff = np.zeros(4), np.zeros(4)
    mujoco.mju_negQuat(conj, quat)
    mujoco.mju_mulQuat(diff, target_quat, conj)
    mujoco.mju_quat2Vel(err[3:], diff, 1.0)
    return err


def ik_step(model: mujoco.MjModel, data: mujoco.MjData, site: int, dofs: np.ndarray, err: np.ndarray,
            damping: float = 0.05, rot_weight: float = 0.5) -> np.ndarray:
    """Joint displacement (len(dofs),) that reduces `err` at the site, by damped least squares.

    Rotation rows are weighted down so position wins when both cannot be met (near the edge
    of the workspace), which keeps the gripper on target rather than perfectly vertical.
    """
    jacp = np.zeros((3, model.nv))
    jacr = np.zeros((3, model.nv))
    mujoco.mj_jacSite(model, data, jacp, jacr, site)
    jac = np.vstack([jacp[:, dofs], rot_weight * jacr[:, dofs]])
    e = np.concatenate([err[:3], rot_weight * err[3:]])
    lhs = jac @ jac.T + (damping**2) * np.eye(6)
    return jac.T @ np.linalg.solve(lhs, e)


def solve_ik(model: mujoco.MjModel, qpos: np.ndarray, site: int, qadr: np.ndarray, dofs: np.ndarray,
             target_pos: np.ndarray, target_quat: np.ndarray, iters: int = 200,
             scratch: mujoco.MjData | None = None) -> np.ndarray:
    """Joint angles reaching the target pose from `qpos`, iterating ik_step on a scratch MjData.

    Only kinematics run on the scratch data, so the simulation's own MjData is never touched.
    """
    data = scratch if scratch is not None else mujoco.MjData(model)
    data.qpos[:] = qpos
    lo, hi = model.jnt_range[model.dof_jntid[dofs]].T
    for _ in range(iters):
        mujoco.mj_kinematics(model, data)
        mujoco.mj_comPos(model, data)
        pos, quat = site_pose(model, data, site)
        err = pose_error(pos, quat, target_pos, target_quat)
        if np.linalg.norm(err) < 1e-5:
            break
        data.qpos[qadr] = np.clip(data.qpos[qadr] + ik_step(model, data, site, dofs, err), lo, hi)
    return data.qpos[qadr].copy()
