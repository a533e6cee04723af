"""Divergence detection beyond MuJoCo's own.

MuJoCo itself flags only NaN/inf or |qpos|, |qvel| > 1e10 (mjWARN_BADQPOS/BADQVEL/BADQACC,
after which it resets the data). A diverging sim usually shows much earlier as a body
flying out of the world, a joint spinning faster than anything physical, or total energy
jumping up within one step. `StabilityMonitor.check()` tests all of these with a handful
of vectorised numpy operations (a few microseconds), cheap enough for every step.

Use:
    mon = StabilityMonitor(model, Limits(bounds=(-10, 10, -10, 10, -1, 5), max_speed=5))
    mon.reset(data)                     # after each episode reset
    ...
    mujoco.mj_step(model, data)
    reason = mon.check(model, data)     # None, or a reason string: end the episode

The model needs energy enabled (Scene.configure does it) for the energy check; without it
the check is skipped.
"""
from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

# MuJoCo warnings that mean the state can no longer be trusted (or a buffer overflowed).
_FATAL_WARNINGS = {
    "BADQPOS": mujoco.mjtWarning.mjWARN_BADQPOS,
    "BADQVEL": mujoco.mjtWarning.mjWARN_BADQVEL,
    "BADQACC": mujoco.mjtWarning.mjWARN_BADQACC,
    "BADCTRL": mujoco.mjtWarning.mjWARN_BADCTRL,
    "CONTACTFULL": mujoco.mjtWarning.mjWARN_CONTACTFULL,
    "CNSTRFULL": mujoco.mjtWarning.mjWARN_CNSTRFULL,
}


@dataclass(frozen=True)
class Limits:
    """What counts as physical for one scene.

    bounds        (xmin, xmax, ymin, ymax, zmin, zmax) world box, m: every body (mocap
                  included) must stay inside
    max_speed     m/s, any translational dof (slide joints, free-joint translation)
    max_angular   rad/s, any rotational dof (hinge, ball, free-joint rotation)
    max_energy_jump  J: largest allowed rise of potential + kinetic energy in one check
                  (actuators add energy, so set it well above what they can add per step)
    """
    bounds: tuple[float, float, float, float, float, float] = (-50, 50, -50, 50, -10, 50)
    max_speed: float = 20.0
    max_angular: float = 200.0
    max_energy_jump: float = 1e3


class StabilityMonitor:
    """Per-sim checker; holds the dof masks and the last energy."""

    def __init__(self, model: mujoco.MjModel, limits: Limits) -> None:
        self.limits = limits
        jtype = model.jnt_type[model.dof_jntid]               # (nv,) joint type per dof
        free = mujoco.mjtJoint.mjJNT_FREE
        slide = mujoco.mjtJoint.mjJNT_SLIDE
        # Free joints: the first 3 of their 6 dofs translate, the last 3 rotate.
        first = np.zeros(model.nv, dtype=bool)
        for j in np.flatnonzero(model.jnt_type == free):
            a = model.jnt_dofadr[j]
            first[a:a + 3] = True
        self.linear = (jtype == slide) | ((jtype == free) & first)   # (nv,) bool
        self.angular = ~self.linear
        lo = np.array(limits.bounds[0::2], dtype=np.float64)
        hi = np.array(limits.bounds[1::2], dtype=np.float64)
        self.lo, self.hi = lo, hi
        self.energy_on = bool(model.opt.enableflags & mujoco.mjtEnableBit.mjENBL_ENERGY)
        self.last_energy: float | None = None
        self.warnings0 = {}

    def reset(self, data: mujoco.MjData) -> None:
        """Call after an episode reset (clears the energy reference and warning counts)."""
        self.last_energy = None
        self.warnings0 = {k: int(data.warning[w].number) for k, w in _FATAL_WARNINGS.items()}

    def check(self, model: mujoco.MjModel, data: mujoco.MjData) -> str | None:
        """None if the state looks physical, else a reason ("diverged: ...")."""
        for key, w in _FATAL_WARNINGS.items():
            if data.warning[w].number > self.warnings0.get(key, 0):
                return f"diverged: MuJoCo warning {key} at t={data.time:.4f}s"
        if not (np.isfinite(data.qpos).all() and np.isfinite(data.qvel).all()):
            return f"diverged: non-finite state at t={data.time:.4f}s"
        lim = self.limits
        qv = data.qvel
        if self.linear.any():
            v = float(np.abs(qv[self.linear]).max())
            if v > lim.max_speed:
                return f"diverged: speed {v:.3g} m/s > {lim.max_speed:g} at t={data.time:.4f}s"
        if self.angular.any():
            w = float(np.abs(qv[self.angular]).max())
            if w > lim.max_angular:
                return (f"diverged: angular speed {w:.3g} rad/s > {lim.max_angular:g} "
                        f"at t={data.time:.4f}s")
        # Bodies: xpos is from the last forward pass (one step behind after mj_step; fine).
        pos = data.xpos[1:]
        out = (pos < self.lo) | (pos > self.hi)
        if out.any():
            b = 1 + int(np.flatnonzero(out.any(axis=1))[0])
            name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, b) or f"#{b}"
            return (f"diverged: body {name!r} left the world bounds at "
                    f"{np.round(data.xpos[b], 3).tolist()} (t={data.time:.4f}s)")
        if self.energy_on:
            e = float(data.energy[0] + data.energy[1])
            if not np.isfinite(e):
                return f"diverged: non-finite energy at t={data.time:.4f}s"
            if self.last_energy is not None and e - self.last_energy > lim.max_energy_jump:
                return (f"diverged: energy jumped {e - self.last_energy:.3g} J in one check "
                        f"(> {lim.max_energy_jump:g}) at t={data.time:.4f}s")
            self.last_energy = e
        return None
