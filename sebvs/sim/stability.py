"""Divergence detection beyond MuJoCo's own.

MuJoCo itself flags only NaN/inf or |qpos|, |qvel| > 1e10 (mjWARN_BADQPOS/BADQVEL/BADQACC,
after which it resets the data). A diverging sim usually shows much earlier as a body
flying out of the world, a joint spinning faster than anything physical, or total energy
jumping up within one step. `StabilityMonitor.check()` tests all of these with a handful
of vectorised numpy operations (~13 us), cheap enough for every step.

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

import math

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
    max_kinetic   J: ceiling on the total kinetic energy; catches a slow pump (a stiff
                  contact feeding energy in small steps) that stays under the speed and
                  jump limits
    """
    bounds: tuple[float, float, float, float, float, float] = (-50, 50, -50, 50, -10, 50)
    max_speed: float = 20.0
    max_angular: float = 200.0
    max_energy_jump: float = 1e3
    max_kinetic: float = math.inf


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
        self.n_lin, self.n_ang = int(self.linear.sum()), int(self.angular.sum())
        self.energy_on = bool(model.opt.enableflags & mujoco.mjtEnableBit.mjENBL_ENERGY)
        self.last_energy: float | None = None
        self.warn_idx = np.array([int(w) for w in _FATAL_WARNINGS.values()])
        self.warnings0 = np.zeros(len(self.warn_idx), np.int64)

    def reset(self, data: mujoco.MjData) -> None:
        """Call after an episode reset (clears the energy reference and warning counts)."""
        self.last_energy = None
        self.warnings0 = np.array(data.warning.number, dtype=np.int64)[self.warn_idx]

    def check(self, model: mujoco.MjModel, data: mujoco.MjData) -> str | None:
        """None if the state looks physical, else a reason ("diverged: ...").

        Fast path first: every comparison is written so that a NaN fails it too; the
        slower diagnosis runs only once something failed. ~13 us on this machine (numpy's
        per-call overhead on tiny arrays; a nav mj_step is ~3 us): the sim actor's
        check_every trades it off, but at 500 Hz it is < 1% of real time anyway.
        """
        lim = self.limits
        qv = np.abs(data.qvel)
        pos = data.xpos[1:]       # from the last forward pass (one step behind after mj_step)
        e = float(data.energy[0] + data.energy[1]) if self.energy_on else 0.0
        jump = e - self.last_energy if self.last_energy is not None else 0.0
        ok = (data.warning.number[self.warn_idx] <= self.warnings0).all() \
            and (not self.n_lin or qv[self.linear].max() <= lim.max_speed) \
            and (not self.n_ang or qv[self.angular].max() <= lim.max_angular) \
            and (pos >= self.lo).all() and (pos <= self.hi).all() \
            and np.isfinite(data.qpos).all() and jump <= lim.max_energy_jump \
            and (not self.energy_on or data.energy[1] <= lim.max_kinetic)
        if ok:
            self.last_energy = e
            return None
        return self._diagnose(model, data, qv, pos, e, jump)

    def _diagnose(self, model, data, qv, pos, e, jump) -> str:
        lim, t = self.limits, f"t={data.time:.4f}s"
        counts = data.warning.number[self.warn_idx]
        for key, n, n0 in zip(_FATAL_WARNINGS, counts, self.warnings0):
            if n > n0:
                return f"diverged: MuJoCo warning {key} at {t}"
        if not (np.isfinite(data.qpos).all() and np.isfinite(data.qvel).all()):
            return f"diverged: non-finite state at {t}"
        if self.n_lin and not qv[self.linear].max() <= lim.max_speed:
            v = float(qv[self.linear].max())
            return f"diverged: speed {v:.3g} m/s > {lim.max_speed:g} at {t}"
        if self.n_ang and not qv[self.angular].max() <= lim.max_angular:
            w = float(qv[self.angular].max())
            return f"diverged: angular speed {w:.3g} rad/s > {lim.max_angular:g} at {t}"
        out = ~((pos >= self.lo) & (pos <= self.hi))
        if out.any():
            b = 1 + int(np.flatnonzero(out.any(axis=1))[0])
            name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, b) or f"#{b}"
            return (f"diverged: body {name!r} left the world bounds at "
                    f"{np.round(data.xpos[b], 3).tolist()} ({t})")
        if not np.isfinite(e):
            return f"diverged: non-finite energy at {t}"
        if not jump <= lim.max_energy_jump:
            return (f"diverged: energy jumped {jump:.3g} J in one check "
                    f"(> {lim.max_energy_jump:g}) at {t}")
        return (f"diverged: kinetic energy {float(data.energy[1]):.3g} J > "
                f"{lim.max_kinetic:g} at {t}")
