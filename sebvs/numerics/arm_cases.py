"""The stability sweep's arm kind: the real arm scene under one stiff knob at a time, and
its own plausibility test (ArmPlausibility), built from what the scene can physically do
rather than from the monitor's checks. stability.py runs it beside the other kinds.
"""
from __future__ import annotations

import itertools
import math

import numpy as np

from sebvs.sim import make_scene
from sebvs.sim.arm import HOME_POSE
from sebvs.sim.arm_model import CONVEYOR_SOLIDS

import mujoco  # noqa: E402

G = 9.81            # m/s^2
ARM_TICK_S = 0.1    # s, the arm's control period (10 Hz, as its topologies run)


def arm_config(params: dict) -> dict:
    """Scene config (sebvs.sim.arm) of an `arm` case: objects 3, the knobs the case sets.

    params: timestep s, integrator, and any of servo_gain (x the UR5 gains), ratio
    (contact solref time constant / timestep, refsafe off; 0 = MuJoCo's default),
    belt_speed m/s (conveyor "moving"), drop_height m."""
    dt = params["timestep"]
    config = {"integrator": params["integrator"], "timestep": dt, "objects": 3,
              "servo_gain": params.get("servo_gain", 1.0),
              "drop_height": params.get("drop_height", 0.002)}
    if params.get("ratio", 0.0) > 0:
        config["contact_timeconst"] = params["ratio"] * dt
    if "belt_speed" in params:
        config.update(conveyor="moving", belt_speed=params["belt_speed"])
    return config


class ArmPlausibility:
    """What the arm scene can physically do, stated from its geometry and its energy
    sources, not from the monitor's checks (the point is to find the monitor's gaps).

    The only things that give energy are gravity (a cube falls from its drop point to the
    floor at most) and the belt (its friction drives a cube up to the belt's speed); the
    arm is a passive position servo at a fixed target (gravity compensated, damped), so it
    only stores what the cubes bring it. Hence, with v_phys = sqrt(v_belt^2 +
    2 g (drop point - floor)) per cube and 2x margins:
      - finite qpos and qvel;
      - no cube *wholly* inside the conveyor's solids or under the floor at any step (all
        8 corners inside the belt, frame or rails, or below the floor: it tunnelled), and
        no cube centre inside them at the end (it stayed sunk);
      - no cube above its drop point by more than 5 cm + 4x the height the belt's speed
        can throw it (v_belt^2 / 2g);
      - cube speed <= 2 v_phys + 0.5 m/s, cube kinetic energy (spin included) <= 4 x
        0.5 m v_phys^2 + 1 mJ;
      - tcp within TCP_TOL of HOME and the tool within TILT_TOL of pointing down;
        kinetic energy of the arm (joints and fingers) <= 4x what the cubes can bring to
        the gripper's height (fall from their drop point, belt speed) + 10 mJ.
    A cube riding off a fast belt's end to the floor (z -0.75), or dropped from 2 m and
    bouncing off the gripper at HOME, is physical: none of these fire.
    """

    # A 0.1 kg cube hitting the gripper barely moves the 2000 N m/rad servos: the full
    # grid's worst (dropped 2 m onto it) moved the tcp 1.3 cm and tilted it 2.3 deg.
    TCP_TOL = 0.03      # m
    TILT_TOL = 0.1      # rad

    def __init__(self, scene, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        self.scene = scene
        self.cubes = scene.cube_body                                   # (N,) body ids
        self.halves = np.asarray(scene.halves, dtype=np.float64)        # (N,) m
        self.mass = model.body_mass[self.cubes]                         # (N,) kg
        self.inertia = model.body_inertia[self.cubes, 0]                # (N,) kg m^2
        self.cube_dof = model.jnt_dofadr[model.body_jntadr[self.cubes]]  # (N,)
        mujoco.mj_kinematics(model, data)
        self.z0 = data.xpos[self.cubes, 2].copy()                       # drop points, m
        self.lo, self.hi = self._solids(model)
        self.floor = float(model.geom_pos[model.geom("floor").id, 2])
        v_belt = scene.belt_speed
        self.v_phys = np.sqrt(v_belt ** 2 + 2 * G * (self.z0 - self.floor))   # (N,) m/s
        # 5 cm: a cube tipping onto an edge (1.2 cm) or pushed out of the gripper it
        # was spawned into (drops of 0.35-0.55 m; 2.3 cm seen)
        self.rise_max = 0.05 + 4 * v_belt ** 2 / (2 * G)
        self.ke_cube_max = 4 * 0.5 * self.mass * self.v_phys ** 2 + 1e-3
        self.home = np.asarray(HOME_POSE[:3])
        # What a cube can bring to the gripper: its energy at the gripper's height (the
        # pads reach 16 mm below the tcp; 5 cm taken), from the fall and the belt.
        # Cubes on the belt cannot reach it unless the belt throws them 0.37 m up.
        brought = 0.5 * self.mass * v_belt ** 2 \
            + self.mass * G * (self.z0 - (self.home[2] - 0.05))
        self.ke_arm_max = 4 * float(np.maximum(brought, 0.0).sum()) + 0.01
        # every hinge and slide: the arm's 6 joints and the 2 fingers
        arm_j = np.flatnonzero(model.jnt_type != mujoco.mjtJoint.mjJNT_FREE)
        self.arm_dof = model.jnt_dofadr[arm_j]
        self.M = np.zeros((model.nv, model.nv))
        signs = np.array(list(itertools.product((-1.0, 1.0), repeat=3)))   # (8, 3)
        self.corner = signs[None] * self.halves[:, None, None]           # (N, 8, 3) local

    @staticmethod
    def _solids(model: mujoco.MjModel) -> tuple[np.ndarray, np.ndarray]:
        """World-aligned (lo, hi) corners (B, 3) of the conveyor's static boxes, from the
        model's geoms (belt, frame, rails are world children without rotation)."""
        ids = [model.geom(n).id for n in CONVEYOR_SOLIDS]
        for i in ids:
            aligned = np.allclose(model.geom_quat[i], [1, 0, 0, 0])
            if model.geom_bodyid[i] != 0 or not aligned:
                raise RuntimeError(f"arm plausibility: geom {model.geom(i).name!r} is no "
                                   f"longer a world-aligned static box")
        pos, half = model.geom_pos[ids], model.geom_size[ids]
        return pos - half, pos + half

    def _in_solid(self, p: np.ndarray) -> np.ndarray:
        """(..., 3) points -> (...) bool: inside a conveyor box or below the floor."""
        boxes = ((p[..., None, :] > self.lo) & (p[..., None, :] < self.hi)).all(-1).any(-1)
        return boxes | (p[..., 2] < self.floor)

    def __call__(self, model: mujoco.MjModel, data: mujoco.MjData,
                 end: bool = False) -> str | None:
        if not (np.isfinite(data.qpos).all() and np.isfinite(data.qvel).all()):
            return "non-finite state"
        pos = data.xpos[self.cubes]                                     # (N, 3)
        R = data.xmat[self.cubes].reshape(-1, 3, 3)
        corners = pos[:, None, :] + np.einsum("nij,nkj->nki", R, self.corner)   # (N, 8, 3)
        whole = self._in_solid(corners).all(axis=1)
        if whole.any():
            i = int(np.argmax(whole))
            return (f"cube{i} wholly inside the conveyor or under the floor at "
                    f"{np.round(pos[i], 3).tolist()}")
        if end and self._in_solid(pos).any():
            i = int(np.argmax(self._in_solid(pos)))
            return f"cube{i} ended with its centre sunk at {np.round(pos[i], 3).tolist()}"
        rise = pos[:, 2] - self.z0
        if (rise > self.rise_max).any():
            i = int(np.argmax(rise))
            return (f"cube{i} rose {rise[i]:.3g} m above its drop point "
                    f"(> {self.rise_max:.3g} the belt can throw it)")
        v = data.qvel[self.cube_dof[:, None] + np.arange(6)]            # (N, 6)
        speed = np.linalg.norm(v[:, :3], axis=1)
        if (speed > 2 * self.v_phys + 0.5).any():
            i = int(np.argmax(speed / self.v_phys))
            return (f"cube{i} speed {speed[i]:.3g} m/s > 2x the {self.v_phys[i]:.3g} "
                    f"belt and fall can give")
        ke = 0.5 * self.mass * speed ** 2 + 0.5 * self.inertia * (v[:, 3:] ** 2).sum(1)
        if (ke > self.ke_cube_max).any():
            i = int(np.argmax(ke / self.ke_cube_max))
            return (f"cube{i} kinetic energy {ke[i]:.3g} J (spin included) > "
                    f"{self.ke_cube_max[i]:.3g}, 4x what belt and fall can give")
        err = float(np.linalg.norm(data.site_xpos[self.scene.tcp] - self.home))
        tilt = math.acos(min(1.0, -float(data.site_xmat[self.scene.tcp][8])))
        if err > self.TCP_TOL or tilt > self.TILT_TOL:
            return (f"tcp {err * 100:.3g} cm from HOME, tool {math.degrees(tilt):.3g} deg "
                    f"off vertical (holding a fixed servo target)")
        mujoco.mj_fullM(model, data, self.M)     # qM of the step's forward pass
        qa = data.qvel[self.arm_dof]
        ke_arm = 0.5 * float(qa @ self.M[np.ix_(self.arm_dof, self.arm_dof)] @ qa)
        if ke_arm > self.ke_arm_max:
            return (f"arm kinetic energy {ke_arm:.3g} J > {self.ke_arm_max:.3g}, 4x what "
                    f"the cubes can bring it")
        return None


def arm_case(params: dict):
    """The real arm scene (sebvs.sim.arm), 3 cubes, the arm holding HOME: the idle command
    at every control tick and scene.scripted before every step, as the sim actor does."""
    scene = make_scene("arm", **arm_config(params))
    model = scene.compile()
    data = mujoco.MjData(model)
    scene.reset(model, data, np.random.default_rng(0))
    tick = max(1, round(ARM_TICK_S / model.opt.timestep))

    def hook(i: int) -> None:
        if i % tick == 0:
            scene.apply_command(model, data, scene.idle_command())
        scene.scripted(model, data)

    return model, data, scene.limits(), hook, ArmPlausibility(scene, model, data)
