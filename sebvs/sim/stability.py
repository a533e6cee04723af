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
    solid_boxes   names of static box geoms (a belt, a table) that nothing passes through
    free_bodies   names of the bodies whose centre must not stay inside one of them for
                  sink_s seconds: a body that tunnelled or sank is at rest, so no speed or
                  energy limit sees it. (MuJoCo's soft contacts let a hard impact push a
                  centre below a surface for a few milliseconds; the contact pushes it
                  back out, hence the persistence.)
    sink_s        s, see free_bodies
    passive_rise  m: how far one of the free_bodies may rise while nothing but static
                  geoms and other free bodies touches it. A passive body cannot climb; a
                  stiff contact (time constant below two timesteps) makes resting bodies
                  chatter and hop, slowly, under every speed and energy limit above. The
                  reference height is the body's at the episode start, at its last touch by
                  the robot (any other non-static geom; plus the ballistic rise v_z^2 / 2g
                  a touch may have launched it into), or after it rested for rest_s; it
                  never moves up otherwise. (Height, not energy: an integrator's energy
                  drift in free fall would be mistaken for a gain at large timesteps.)
    rest_s        s of rest (speed < 1 mm/s, spin < 0.01 rad/s) that reset the reference
    Both free-body checks are slow phenomena and cost more than the rest together, so they
    run every FREE_BODY_PERIOD_S of simulated time, not every step.
    """
    bounds: tuple[float, float, float, float, float, float] = (-50, 50, -50, 50, -10, 50)
    max_speed: float = 20.0
    max_angular: float = 200.0
    max_energy_jump: float = 1e3
    max_kinetic: float = math.inf
    solid_boxes: tuple[str, ...] = ()
    free_bodies: tuple[str, ...] = ()
    sink_s: float = 0.05
    passive_rise: float = math.inf
    rest_s: float = 0.02


FREE_BODY_PERIOD_S = 0.005      # cadence of the free-body checks (sinking, climbing)


class _FreeBodyWatch:
    """The free-body checks of Limits: sinking into solid boxes, climbing while untouched.

    Keeps a per-body timer (centre inside a box since) and reference height. `check`
    returns a reason (without the "diverged: " prefix) or None."""

    def __init__(self, model: mujoco.MjModel, limits: Limits) -> None:
        self.limits = limits
        self.model = model
        self.names = limits.free_bodies
        self.free = np.array([model.body(n).id for n in limits.free_bodies], dtype=int)
        boxes = np.array([model.geom(n).id for n in limits.solid_boxes], dtype=int)
        self.sinking = bool(boxes.size)
        if self.sinking:       # static boxes: centre, rotation, half sizes never change
            d = mujoco.MjData(model)
            mujoco.mj_kinematics(model, d)
            self.box_pos = d.geom_xpos[boxes].copy()                 # (B, 3)
            self.box_rot = d.geom_xmat[boxes].reshape(-1, 3, 3)      # (B, 3, 3)
            self.box_half = model.geom_size[boxes].copy()            # (B, 3)
        self.climbing = math.isfinite(limits.passive_rise)
        self.dof = model.jnt_dofadr[model.body_jntadr[self.free]]   # (F,) free-joint dofs
        static = model.body_weldid[model.geom_bodyid] == 0           # (ngeom,)
        self.robot_geom = ~static & ~np.isin(model.geom_bodyid, self.free)  # may lift a body
        self.g = float(np.linalg.norm(model.opt.gravity))
        self.every = max(1, round(FREE_BODY_PERIOD_S / model.opt.timestep))
        self.calls = 0

    def reset(self, data: mujoco.MjData) -> None:
        mujoco.mj_kinematics(self.model, data)
        self.z_ref = data.xpos[self.free, 2].copy()
        self.rest_since = np.full(self.free.size, np.nan)
        self.inside_since = np.full(self.free.size, np.nan)
        self.calls = 0

    def check(self, data: mujoco.MjData) -> str | None:
        self.calls += 1
        if self.calls % self.every:
            return None
        t = float(data.time)
        if self.sinking:
            p = data.xpos[self.free]                                          # (F, 3)
            local = np.einsum("bji,fbj->fbi", self.box_rot, p[:, None] - self.box_pos[None])
            inside = (np.abs(local) < self.box_half[None]).all(axis=2)        # (F, B)
            now = inside.any(axis=1)
            self.inside_since = np.where(now, np.fmin(self.inside_since, t), np.nan)
            sunk = now & (t - self.inside_since >= self.limits.sink_s)
            if sunk.any():
                f = int(np.flatnonzero(sunk)[0])
                b = int(np.flatnonzero(inside[f])[0])
                return (f"body {self.names[f]!r} sank into {self.limits.solid_boxes[b]!r} at "
                        f"{np.round(p[f], 3).tolist()} for {t - self.inside_since[f]:.3f} s "
                        f"(t={t:.4f}s)")
        if self.climbing:
            z = data.xpos[self.free, 2]
            v = data.qvel[self.dof[:, None] + np.arange(6)]                   # (F, 6)
            touched = np.zeros(self.free.size, dtype=bool)
            if data.ncon:
                geoms = data.contact.geom[:data.ncon]                         # (ncon, 2)
                robot = self.robot_geom[geoms]
                bodies = self.model.geom_bodyid[geoms]
                touched = np.isin(self.free, np.concatenate([bodies[robot[:, 0], 1],
                                                             bodies[robot[:, 1], 0]]))
            still = (np.abs(v[:, :3]).max(1) < 1e-3) & (np.abs(v[:, 3:]).max(1) < 1e-2)
            self.rest_since = np.where(still, np.fmin(self.rest_since, t), np.nan)
            rested = still & (t - self.rest_since >= self.limits.rest_s)
            apex = z + np.maximum(v[:, 2], 0.0) ** 2 / (2 * self.g)   # where a launch peaks
            self.z_ref = np.where(touched, apex, np.where(rested, z, self.z_ref))
            rise = z - self.z_ref
            if (rise > self.limits.passive_rise).any():
                f = int(np.argmax(rise))
                return (f"body {self.names[f]!r} rose {rise[f]:.3g} m with nothing but "
                        f"static geoms or other free bodies touching it "
                        f"(> {self.limits.passive_rise:g}) at t={t:.4f}s")
        return None


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
        watched = limits.free_bodies and (limits.solid_boxes
                                          or math.isfinite(limits.passive_rise))
        self.bodies = _FreeBodyWatch(model, limits) if watched else None

    def reset(self, data: mujoco.MjData) -> None:
        """Call after an episode reset (clears the energy reference and warning counts)."""
        self.last_energy = None
        if self.bodies is not None:
            self.bodies.reset(data)
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
        if not ok:
            return self._diagnose(model, data, qv, pos, e, jump)
        self.last_energy = e
        why = self.bodies.check(data) if self.bodies is not None else None
        return f"diverged: {why}" if why else None

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
