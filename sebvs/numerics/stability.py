"""Stability sweep: stiff and extreme settings, each classified stable / detected / undetected.

Every case runs with the detector the project ships (sebvs.sim.stability.StabilityMonitor
with the scene's Limits, checked after every step, as the sim actor does) and, beside it,
an independent *plausibility* test that knows what the scenario can physically do (the
robot cannot leave its walled room or hold more kinetic energy than its drive can give; a
box cannot tunnel into the belt, end sunk in it, or rise above where it was dropped). The
class:

  stable      the monitor stayed silent and every state was plausible
  detected    the monitor ended the run with a reason (or, for emulator cases, the
              emulator raised a ValueError with a message)
  undetected  the monitor stayed silent but a state was not plausible (NaN/inf, a body
              where it cannot be, an absurd speed or energy): a silent blow-up, a detector
              gap; for emulator cases, any other exception, a numpy RuntimeWarning or
              insane events (sebvs/numerics/dvs_cases.py)

The grids (QUICK for the test suite, FULL for tools/checks/stability_sweep.py):
  nav_servo    servo_gain x integrator x timestep, commands alternating every 0.5 s
  nav_contact  wall contact solref time constant = ratio x timestep (refsafe off), the
               robot driven into a wall of a 3 m room, x integrator x timestep
  belt         a box dropped from `drop` m onto a belt moving at `speed` m/s (a static geom
               with surfacevel, as the arm scene's conveyor), contact time constant ratio,
               x integrator x timestep. Our own minimal MJCF, whose plausibility is easy
               to state.
  arm          the real arm scene (sebvs/sim/arm.py; arm_cases.py): UR5 holding HOME (its idle command
               every 0.1 s control tick, scene.scripted before every step, as the sim
               actor), 3 cubes, one stiff knob at a time (servo_gain; contact ratio =
               contact_timeconst / timestep, refsafe off; belt_speed with the conveyor
               moving; drop_height) and, in FULL, a small product of them, x integrator x
               timestep. Plausibility: ArmPlausibility (energy sources and geometry, not
               the monitor's checks).
  dvs          emulator extremes (black, saturated, alternating frames, dt 0 and 100 s,
               cutoff extremes, a time step backwards), sebvs/numerics/dvs_cases.py.

Counts (stable / detected / undetected), 2 shared cores, load average 2.6-2.8 (`uptime`):
  tools/checks/stability_sweep.py --quick --out DIR   180 cases, 6.5 s: 143 / 37 / 0
      nav_servo 24/0/0, nav_contact 18/6/0, belt 46/18/0, arm 46/10/0, dvs 9/3/0
  tools/checks/stability_sweep.py --out DIR           2336 cases, 168 s: 1465 / 869 / 2
      nav_servo 96/0/0, nav_contact 56/24/0, belt 836/662/2, arm 450/174/0, dvs 27/9/0
  The 2 undetected are belt cases (a box dropped 5 m onto a 20 m/s belt at 10 ms,
  `discrete`, ends sunk 3.7 cm: the minimal belt MJCF's Limits declare no solid boxes).
  docs/numerics.md ("Stability sweep") reads the results.
"""
from __future__ import annotations

import itertools
import math
from typing import Callable

import numpy as np

from sebvs.sim import make_scene
from sebvs.sim.scene import INTEGRATORS as _ALL
from sebvs.sim.stability import Limits, StabilityMonitor

import mujoco  # noqa: E402

from . import dvs_cases
from .arm_cases import arm_case
from .sweep import SweepCase, summarise

INTEGRATORS = tuple(i for i in ("euler", "implicitfast", "rk4", "discrete") if i in _ALL)


# ---------------------------------------------------------------------- the grids
GRIDS = {
    "quick": {
        "nav_servo": {"servo_gain": [1.0, 100.0, 1e4], "timestep": [0.002, 0.01],
                      "seconds": 1.0},
        "nav_contact": {"ratio": [0.5, 1.0, 4.0], "timestep": [0.002, 0.01], "seconds": 2.5},
        "belt": {"drop": [0.05, 2.0], "speed": [0.5, 5.0], "ratio": [0.0, 0.5],
                 "timestep": [0.002, 0.01], "seconds": 1.0},
        # one stiff knob at a time (the arm's own tests/test_sim_arm.py STIFF set), and
        # cubes dropped 2 m onto a 3 m/s belt that carries them off its end to the floor
        "arm": {"knobs": [{}, {"servo_gain": 1e4}, {"ratio": 0.5}, {"ratio": 1.0},
                          {"belt_speed": 3.0}, {"drop_height": 2.0},
                          {"belt_speed": 3.0, "drop_height": 2.0}],
                "timestep": [0.002, 0.01], "seconds": 2.0},
    },
    "full": {
        "nav_servo": {"servo_gain": [1.0, 10.0, 100.0, 1e3, 1e4, 1e5],
                      "timestep": [0.0005, 0.002, 0.005, 0.01], "seconds": 3.0},
        "nav_contact": {"ratio": [0.25, 0.5, 1.0, 2.0, 4.0],
                        "timestep": [0.0005, 0.002, 0.005, 0.01], "seconds": 3.0},
        "belt": {"drop": [0.0, 0.05, 0.5, 2.0, 5.0], "speed": [0.0, 0.5, 2.0, 5.0, 20.0],
                 "ratio": [0.0, 0.25, 0.5, 1.0, 2.0], "timestep": [0.0005, 0.002, 0.01],
                 "seconds": 2.0},
        # each knob alone over its range, then a small product of them. The belt starts
        # from rest at g/2 (arm.BELT_ACCEL): a cube lying on it rides off its end within
        # 0.71 s, before the belt passes 3.5 m/s, so settings above 6 m/s would repeat
        # 6 m/s. Drops of 0.35-0.55 m start some cube overlapping the gripper at HOME
        # (seed 0 at 0.5 m: cube0 6.5 mm into the housing); its push-out is part of them.
        "arm": {"knobs": [{}]
                + [{"servo_gain": g} for g in (0.1, 10.0, 100.0, 1e3, 1e4, 1e5, 1e6)]
                + [{"ratio": r} for r in (0.25, 0.5, 1.0, 2.0, 4.0)]
                + [{"belt_speed": v} for v in (0.08, 0.5, 1.0, 3.0, 6.0)]
                + [{"drop_height": h} for h in (0.05, 0.5, 2.0, 5.0, 10.0)]
                + [{"ratio": r, "belt_speed": v, "drop_height": h, "servo_gain": g}
                   for r, v, h, g in itertools.product((0.0, 0.5), (1.0, 3.0), (0.5, 2.0),
                                                       (1.0, 1e4))],
                "timestep": [0.0005, 0.002, 0.005, 0.01], "seconds": 2.0},
    },
}


def physics_cases(grid: str = "quick") -> list[SweepCase]:
    """Every physics case of a grid ("quick" | "full"), integrators innermost."""
    g = GRIDS[grid]
    cases = []
    s = g["nav_servo"]
    for gain, dt, integ in itertools.product(s["servo_gain"], s["timestep"], INTEGRATORS):
        cases.append(SweepCase("nav_servo", {"servo_gain": gain, "timestep": dt,
                                             "integrator": integ, "seconds": s["seconds"]}))
    c = g["nav_contact"]
    for ratio, dt, integ in itertools.product(c["ratio"], c["timestep"], INTEGRATORS):
        cases.append(SweepCase("nav_contact", {"ratio": ratio, "timestep": dt,
                                               "integrator": integ, "seconds": c["seconds"]}))
    b = g["belt"]
    for drop, speed, ratio, dt, integ in itertools.product(b["drop"], b["speed"], b["ratio"],
                                                           b["timestep"], INTEGRATORS):
        cases.append(SweepCase("belt", {"drop": drop, "speed": speed, "ratio": ratio,
                                        "timestep": dt, "integrator": integ,
                                        "seconds": b["seconds"]}))
    a = g["arm"]
    for knobs, dt, integ in itertools.product(a["knobs"], a["timestep"], INTEGRATORS):
        cases.append(SweepCase("arm", {**knobs, "timestep": dt, "integrator": integ,
                                       "seconds": a["seconds"]}))
    return cases


# ---------------------------------------------------------------------- scenarios
# Each builder -> (model, data, limits, step_hook(i) or None,
#                  plausible(model, data, end=False) -> None or why not; end: the last state)

def _nav(params: dict, contact: bool):
    dt = params["timestep"]
    config = {"integrator": params["integrator"], "timestep": dt}
    if contact:
        config.update(arena=3.0, contact_timeconst=params["ratio"] * dt)
    else:
        config["servo_gain"] = params["servo_gain"]
    scene = make_scene("nav", **config)
    model = scene.compile()
    data = mujoco.MjData(model)
    scene.reset(model, data, np.random.default_rng(0))
    tick = max(1, round(0.05 / dt))
    half = max(1, round(0.5 / dt))

    def hook(i: int) -> None:
        if i % tick == 0:
            sign = (-1.0) ** (i // half)
            # into the wall ahead (+x) with a weave, or full-scale alternating commands
            cmd = [1.0, 0.3 * sign] if contact else [sign, -sign]
            scene.apply_command(model, data, np.array(cmd))
        scene.scripted(model, data)

    a, vmax, wmax = float(scene.config["arena"]), float(scene.config["v_max"]), \
        float(scene.config["w_max"])
    qx, qy, qyaw = scene.qadr
    robot = model.body("robot").id
    # The most kinetic energy the drive can give the robot (top speed and top turn rate at
    # once, from the mass matrix): no contact or servo can add more. 1.5x + 1 J of margin.
    M = np.zeros((model.nv, model.nv))
    mujoco.mj_fullM(model, data, M)   # MuJoCo 4 signature: (m, d, dst)
    ke_max = 1.5 * 0.5 * (M[qx, qx] * vmax ** 2 + M[qyaw, qyaw] * wmax ** 2) + 1.0

    def plausible(model, data, end: bool = False) -> str | None:
        # walls stand at +-arena: the chassis centre cannot get past them
        x, y = data.qpos[qx], data.qpos[qy]
        if not (abs(x) <= a + 0.3 and abs(y) <= a + 0.3):
            return f"robot at ({x:.3g}, {y:.3g}) m outside its {a:g} m room"
        ke = 0.5 * float(data.qvel @ (M @ data.qvel))
        if not ke <= ke_max:
            return f"robot kinetic energy {ke:.3g} J > {ke_max:.3g} J the drive can give"
        if not abs(data.xpos[robot, 2] - 0.1) < 1e-6:
            return f"robot left its plane: z {data.xpos[robot, 2]:.3g} m"
        return None

    return model, data, scene.limits(), hook, plausible


BOX = 0.05          # box half side, m
BELT_TOP = 0.1      # m


def belt_mjcf(drop: float, speed: float, timeconst: float, length: float) -> str:
    """A box `drop` m above a static belt geom moving its surface at `speed` m/s along x.
    timeconst > 0 sets the contact solref time constant and disables refsafe."""
    flag = '<flag refsafe="disable" energy="enable"/>' if timeconst > 0 \
        else '<flag energy="enable"/>'
    solref = f'solref="{timeconst} 1"' if timeconst > 0 else ""
    return f"""<mujoco model="sweep_belt">
  <option timestep="0.002">{flag}</option>
  <default><geom {solref} friction="1 0.005 0.0001"/></default>
  <worldbody>
    <geom name="floor" type="plane" size="60 60 1"/>
    <geom name="belt" type="box" size="{length} 0.3 {BELT_TOP / 2}" pos="0 0 {BELT_TOP / 2}"
          surfacevel="{speed} 0 0"/>
    <body name="box" pos="0 0 {BELT_TOP + BOX + drop}">
      <freejoint/>
      <geom type="box" size="{BOX} {BOX} {BOX}" mass="0.2"/>
    </body>
  </worldbody>
</mujoco>"""


def _belt(params: dict):
    dt, speed, drop = params["timestep"], params["speed"], params["drop"]
    length = 1.0 + abs(speed) * params["seconds"] * 1.5
    model = mujoco.MjModel.from_xml_string(
        belt_mjcf(drop, speed, params["ratio"] * dt, length))
    model.opt.integrator = _ALL[params["integrator"]]
    model.opt.timestep = dt
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    box = model.body("box").id
    z0 = BELT_TOP + BOX + drop
    # The limits a conveyor-cell author would declare (and what we recommend for the arm
    # scene): speeds from the belt and the fall, no body above its drop point, energy
    # jumps on the scale of the box's own kinetic energy, not the nav robot's 50 J.
    vphys = max(abs(speed), math.sqrt(2 * 9.81 * drop))
    mass = float(model.body_mass[box])
    limits = Limits(bounds=(-length - 1, length + 1, -2, 2, -0.5, z0 + 0.25),
                    max_speed=1.5 * vphys + 1.0, max_angular=100.0,
                    max_energy_jump=0.5 * mass * (vphys + 1.0) ** 2)
    vmax = 2.0 * vphys + 2.0

    def plausible(model, data, end: bool = False) -> str | None:
        x, y, z = data.xpos[box]
        if not np.isfinite(data.qpos).all():
            return "non-finite state"
        on_belt = abs(x) <= length - BOX and abs(y) <= 0.3 - BOX
        # An impact may sink the box by about one step's travel (6 cm at 6 m/s and 10 ms)
        # and the contact pushes it back out; wholly inside the belt means it tunnelled,
        # and at the end it must rest on top (soft contact: a few mm).
        if on_belt and z < BELT_TOP - BOX:
            return f"box tunnelled into the belt: z {z:.3g} m"
        if end and on_belt and z < BELT_TOP + BOX - 0.01:
            return f"box ended sunk into the belt: z {z:.3g} m"
        if z < 0:
            return f"box fell through the floor: z {z:.3g} m"
        if z > z0 + 0.5:
            return f"box rose to z {z:.3g} m, 0.5 m above its drop point"
        v = float(np.linalg.norm(data.qvel[:3]))
        if v > vmax:
            return f"box speed {v:.3g} m/s > {vmax:.3g} (2x what belt or fall can give)"
        return None

    return model, data, limits, None, plausible


BUILDERS: dict[str, Callable] = {
    "nav_servo": lambda p: _nav(p, contact=False),
    "nav_contact": lambda p: _nav(p, contact=True),
    "belt": _belt,
    "arm": arm_case,
}


def run_physics_case(case: SweepCase) -> dict:
    """Run one physics case; -> {"name", "kind", "params", "class", "reason", "t"}.

    The monitor is checked after every step; the plausibility test too (its first failure
    is kept, and the run goes on: the monitor may still catch the blow-up later, which
    counts as detected)."""
    model, data, limits, hook, plausible = BUILDERS[case.kind](case.params)
    mon = StabilityMonitor(model, limits)
    mon.reset(data)
    n = int(round(case.params["seconds"] / model.opt.timestep))
    reason, silent, t = None, None, None
    for i in range(n):
        if hook is not None:
            hook(i)
        mujoco.mj_step(model, data)
        reason = mon.check(model, data)
        if reason:
            t = float(data.time)
            break
        if silent is None:
            mujoco.mj_kinematics(model, data)     # xpos of this qpos for the test
            bad = plausible(model, data)
            if bad:
                silent, t = bad, float(data.time)
    if reason is None and silent is None:
        mujoco.mj_kinematics(model, data)
        silent = plausible(model, data, end=True)
        t = float(data.time) if silent else None
    cls = "detected" if reason else ("undetected" if silent else "stable")
    return {"name": case.name, "kind": case.kind, "params": case.params, "class": cls,
            "reason": reason or silent or "", "t": t}


def all_cases(grid: str = "quick") -> list[SweepCase]:
    """Physics cases plus the emulator's."""
    return physics_cases(grid) + dvs_cases.cases(grid)


def run_case(case: SweepCase) -> dict:
    if case.kind == "dvs":
        return dvs_cases.run(case)
    return run_physics_case(case)


def sweep(grid: str = "quick", progress: Callable | None = None) -> dict:
    """Run every case of a grid; the summarised JSON-able result."""
    results = []
    for case in all_cases(grid):
        results.append(run_case(case))
        if progress is not None:
            progress(1)
    return summarise(results)
