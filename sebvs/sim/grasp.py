"""Grasp executor: turns a pre-grasp pose into a physical grasp on the MuJoCo arm scene and
reports whether it held. The evaluation reuses it for the policies' predicted poses.

    result = execute_grasp(model, data, pose, handles, GraspConfig())   # handles: ArmHandles

Phases (each a joint-space target from damped least-squares IK on MuJoCo Jacobians, sent
to the arm's position actuators, then physics steps until the joints settle or the phase
times out):
  reach    the pre-grasp pose [x, y, z, roll, pitch, yaw] itself (gripper open)
  descend  straight down by the pose's clearance plus `grasp_depth`, so the fingertips
           straddle the cube's upper part
  close    gripper closed, arm held, `close_s` seconds
  lift     straight up by `lift`
  hold     `hold_s` seconds at the top
Success: the object rose by more than `success_lift` (m) over its start height and stayed
between the fingers (both finger pads in contact with it) through the whole hold.
The reason says which check failed: "bad_pose: ...", "ik_failed: <phase>", "not_grasped"
(the fingers closed on nothing), "dropped" (held, then lost before the hold ended and below
the success lift), "not_between_fingers" (lost during the hold, though still high),
"not_lifted", "diverged: ..." (with a stability monitor).

Orientation convention: R = Rz(yaw) Ry(pitch) Rx(roll) (extrinsic x-y-z), applied to the
end-effector site frame of the arm model.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

import mujoco

from .ik import dls_ik, rpy_to_mat  # rpy_to_mat: re-exported for callers of the executor


@dataclass
class GraspConfig:
    """Executor settings; lengths m, times s."""
    clearance: float = 0.10          # the pose's height above the cube top (the expert's)
    grasp_depth: float = 0.025       # how far below the cube top the fingertip centre goes
    lift: float = 0.12
    success_lift: float = 0.05       # N cm of the brief: object must rise more than this
    close_s: float = 0.8
    hold_s: float = 1.0
    phase_timeout_s: float = 3.0
    settle_tol: float = 0.01         # rad: joints within this of the target end a phase
    ik_tol: float = 0.005            # m: IK position residual accepted


@dataclass
class GraspResult:
    success: bool
    reason: str
    lift_m: float = 0.0              # object height gain at the end of the hold
    held_s: float = 0.0              # seconds the object stayed between the fingers
    phases: dict = field(default_factory=dict)   # phase -> seconds taken / IK residual

    def as_dict(self) -> dict:
        return {"success": self.success, "reason": self.reason, "lift_m": self.lift_m,
                "held_s": self.held_s, "phases": self.phases}


@dataclass
class ArmHandles:
    """Names in the arm model the executor drives and checks.

    ee_site: the end-effector site (its frame is what the pose sets); arm_joints: joints IK
    may move, in order; arm_actuators: position actuators of those joints (ctrl = joint
    target, same order); gripper_actuators with their open/closed ctrl values; finger_geoms:
    the two pads that must both touch the object; object_body: the cube to lift.
    A scene provides them through a method `grasp_handles(model) -> ArmHandles`.
    """
    ee_site: str
    arm_joints: list
    arm_actuators: list
    gripper_actuators: list
    gripper_open: list
    gripper_closed: list
    finger_geoms: tuple
    object_body: str


class _Rig:
    """Ids of the handles, and physics stepping with the arm's position targets."""

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData, h: ArmHandles,
                 monitor=None) -> None:
        self.m, self.d, self.h = model, data, h
        self.site = model.site(h.ee_site).id
        self.joints = np.array([model.joint(j).id for j in h.arm_joints])
        self.qadr = model.jnt_qposadr[self.joints]
        self.dofs = model.jnt_dofadr[self.joints]
        self.arm_act = np.array([model.actuator(a).id for a in h.arm_actuators])
        self.grip_act = np.array([model.actuator(a).id for a in h.gripper_actuators])
        self.fingers = [model.geom(g).id for g in h.finger_geoms]
        self.obj = model.body(h.object_body).id
        self.obj_geoms = set(np.nonzero(model.geom_bodyid == self.obj)[0].tolist())
        self.scratch = mujoco.MjData(model)
        self.monitor = monitor
        self.t_held = 0.0

    def obj_z(self) -> float:
        return float(self.d.xpos[self.obj][2])

    def between_fingers(self) -> bool:
        touching = set()
        for i in range(self.d.ncon):
            c = self.d.contact[i]
            for f in self.fingers:
                if (c.geom1 == f and c.geom2 in self.obj_geoms) or \
                        (c.geom2 == f and c.geom1 in self.obj_geoms):
                    touching.add(f)
        return len(touching) == len(self.fingers)

    def solve(self, pos, mat) -> tuple[np.ndarray, float, float]:
        self.scratch.qpos[:] = self.d.qpos
        return dls_ik(self.m, self.scratch, self.site, self.joints, pos, mat,
                      self.d.qpos[self.qadr].copy())

    def run(self, q_target, grip, seconds: float, settle_tol: float | None,
            track_hold: bool = False) -> tuple[float, str | None]:
        """Step with arm targets `q_target` and gripper ctrl `grip` for up to `seconds`
        (until settled when settle_tol is given). Returns (seconds used, divergence)."""
        m, d = self.m, self.d
        d.ctrl[self.arm_act] = q_target
        d.ctrl[self.grip_act] = grip
        n = max(1, int(round(seconds / m.opt.timestep)))
        for k in range(n):
            mujoco.mj_step(m, d)
            if self.monitor is not None:
                why = self.monitor.check(m, d)
                if why:
                    return (k + 1) * m.opt.timestep, why
            if track_hold:
                if self.between_fingers():
                    self.t_held += m.opt.timestep
                else:
                    return (k + 1) * m.opt.timestep, None
            if settle_tol is not None and k % 10 == 0 and \
                    np.abs(d.qpos[self.qadr] - q_target).max() < settle_tol and \
                    np.abs(d.qvel[self.dofs]).max() < 0.05:
                return (k + 1) * m.opt.timestep, None
        return n * m.opt.timestep, None


def execute_grasp(model: mujoco.MjModel, data: mujoco.MjData, pose, handles: ArmHandles,
                  cfg: GraspConfig | None = None, monitor=None) -> GraspResult:
    """Run reach, descend, close, lift, hold from the current state of `data` (it is stepped
    in place) for `pose` [x, y, z m, roll, pitch, yaw rad] and report the outcome.

    monitor: an optional sebvs.sim.stability.StabilityMonitor checked after every step.
    A scene supplies `handles` (e.g. `scene.grasp_handles(model)`).
    """
    cfg = cfg or GraspConfig()
    pose = np.asarray(pose, dtype=np.float64).reshape(6)
    if not np.isfinite(pose).all():
        return GraspResult(False, "bad_pose: not finite")
    rig = _Rig(model, data, handles, monitor)
    mat = rpy_to_mat(*pose[3:])
    top = pose[:3]
    low = top - np.array([0.0, 0.0, cfg.clearance + cfg.grasp_depth])
    up = low + np.array([0.0, 0.0, cfg.lift])
    z0 = rig.obj_z()
    phases: dict = {}
    opened, closed = np.asarray(handles.gripper_open), np.asarray(handles.gripper_closed)
    for name, target in (("reach", top), ("descend", low)):
        q, perr, rerr = rig.solve(target, mat)
        phases[name] = {"ik_pos_m": perr, "ik_rot_rad": rerr}
        if perr > cfg.ik_tol or rerr > 0.05:
            return GraspResult(False, f"ik_failed: {name} (residual {perr * 1e3:.1f} mm, "
                               f"{math.degrees(rerr):.1f} deg)", phases=phases)
        t, why = rig.run(q, opened, cfg.phase_timeout_s, cfg.settle_tol)
        phases[name]["s"] = t
        if why:
            return GraspResult(False, why, phases=phases)
    t, why = rig.run(q, closed, cfg.close_s, None)
    phases["close"] = {"s": t}
    if why:
        return GraspResult(False, why, phases=phases)
    if not rig.between_fingers():
        return GraspResult(False, "not_grasped", lift_m=rig.obj_z() - z0, phases=phases)
    q_up, perr, rerr = rig.solve(up, mat)
    phases["lift"] = {"ik_pos_m": perr, "ik_rot_rad": rerr}
    if perr > cfg.ik_tol:
        return GraspResult(False, "ik_failed: lift", phases=phases)
    t, why = rig.run(q_up, closed, cfg.phase_timeout_s, cfg.settle_tol)
    phases["lift"]["s"] = t
    if why:
        return GraspResult(False, why, phases=phases)
    rig.t_held = 0.0
    t, why = rig.run(q_up, closed, cfg.hold_s, None, track_hold=True)
    phases["hold"] = {"s": t}
    lift = rig.obj_z() - z0
    if why:
        return GraspResult(False, why, lift_m=lift, held_s=rig.t_held, phases=phases)
    if rig.t_held < cfg.hold_s - 2 * model.opt.timestep:
        reason = "dropped" if lift < cfg.success_lift else "not_between_fingers"
        return GraspResult(False, reason, lift_m=lift, held_s=rig.t_held, phases=phases)
    if lift <= cfg.success_lift:
        return GraspResult(False, "not_lifted", lift_m=lift, held_s=rig.t_held, phases=phases)
    return GraspResult(True, "lifted_and_held", lift_m=lift, held_s=rig.t_held, phases=phases)
