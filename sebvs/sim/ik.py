"""Orientation helpers and damped least-squares inverse kinematics on MuJoCo Jacobians.

Shared by the arm scene (its HOME joint configuration) and the grasp executor (every arm
motion), so both agree on what a pose [x, y, z, roll, pitch, yaw] means.

Orientation convention: R = Rz(yaw) Ry(pitch) Rx(roll) (extrinsic x-y-z), applied to an
end-effector site frame.
"""
from __future__ import annotations

import math

import mujoco
import numpy as np


def rpy_to_mat(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """3x3 rotation R = Rz(yaw) Ry(pitch) Rx(roll)."""
    cr, sr, cp, sp, cy, sy = (math.cos(roll), math.sin(roll), math.cos(pitch),
                              math.sin(pitch), math.cos(yaw), math.sin(yaw))
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


def mat_to_rpy(R: np.ndarray) -> tuple[float, float, float]:
    """Inverse of rpy_to_mat: (roll, pitch, yaw) with pitch in [-pi/2, pi/2]."""
    R = np.asarray(R, dtype=np.float64).reshape(3, 3)
    pitch = math.asin(max(-1.0, min(1.0, -R[2, 0])))
    if abs(R[2, 0]) < 1 - 1e-9:
        roll = math.atan2(R[2, 1], R[2, 2])
        yaw = math.atan2(R[1, 0], R[0, 0])
    else:   # gimbal lock: only roll - yaw (or roll + yaw) is defined; put it all in roll
        roll, yaw = math.atan2(-R[1, 2], R[1, 1]), 0.0
    return roll, pitch, yaw


def dls_ik(model: mujoco.MjModel, data: mujoco.MjData, site: int, joints: np.ndarray,
           target_pos: np.ndarray, target_mat: np.ndarray, q0: np.ndarray, *,
           damping: float = 0.05, iters: int = 300, rot_weight: float = 0.3,
           tol: float = 1e-4) -> tuple[np.ndarray, float, float]:
    """Damped least squares on MuJoCo's site Jacobian.

    Positions of `joints` (ids of hinge or slide joints, (n,)) that put site `site` at
    target_pos (3,) m with orientation target_mat (3, 3), starting from q0 (n,). Uses `data`
    as scratch (its qpos changes; other joints keep their values). Joint ranges are
    respected where the model limits them. Returns (q (n,), position residual m, rotation
    residual rad).

    The rotation error is 0.5 sum_i R_i x T_i over the frames' axes: it vanishes for a half
    turn as well as for none, so start within a quarter turn of the target orientation
    (callers step from the current configuration, which keeps every motion small).
    """
    joints = np.asarray(joints)
    qadr = model.jnt_qposadr[joints]
    dofs = model.jnt_dofadr[joints]
    limited = model.jnt_limited[joints].astype(bool)
    lo, hi = model.jnt_range[joints, 0], model.jnt_range[joints, 1]
    q = np.array(q0, dtype=np.float64)
    jacp, jacr = np.zeros((3, model.nv)), np.zeros((3, model.nv))
    eye = np.eye(6)

    def residual():
        data.qpos[qadr] = q
        mujoco.mj_kinematics(model, data)
        R = data.site_xmat[site].reshape(3, 3)
        ep = target_pos - data.site_xpos[site]
        er = 0.5 * (np.cross(R[:, 0], target_mat[:, 0]) + np.cross(R[:, 1], target_mat[:, 1])
                    + np.cross(R[:, 2], target_mat[:, 2]))
        return ep, er

    for _ in range(iters):
        ep, er = residual()
        if np.linalg.norm(ep) < tol and np.linalg.norm(er) < 10 * tol:
            break
        mujoco.mj_comPos(model, data)
        mujoco.mj_jacSite(model, data, jacp, jacr, site)
        J = np.vstack([jacp[:, dofs], rot_weight * jacr[:, dofs]])
        e = np.concatenate([ep, rot_weight * er])
        q = q + J.T @ np.linalg.solve(J @ J.T + damping ** 2 * eye, e)
        q = np.where(limited, np.clip(q, lo, hi), q)
    ep, er = residual()
    return q, float(np.linalg.norm(ep)), float(np.linalg.norm(er))
