"""Physics work-precision study: integrator x timestep against a fine reference.

A *case* is a scene plus a seeded, deterministic drive: the same command sequence (and
the same scripted motion) at every timestep, so the only difference between two runs is
the numerical method. A run integrates `seconds` of simulated time and reports the final
position of one tracked body; its error is the distance (m) to the same body in the
reference run (rk4 at REFERENCE_DT). Run time is wall seconds per simulated second of the
sim actor's per-step work: scripted() + mj_step + StabilityMonitor.check (the median of
`repeats` runs, taken in rounds over all settings; runs are deterministic, so the first
also gives the error).

A run is *diverged* when the monitor names a reason or the state is not finite; its error
is None (work_precision.plot_study draws it as a cross).

Cases:
  nav       the nav robot (planar base, velocity servos) driven by a seeded command
            sequence: a new uniform [-1, 1]^2 command every `hold` s (steps in the command
            exercise the servos' force limits); tracked body: "robot".
  belt      a 10 cm cube dropped 2 cm onto a belt whose surface moves at 0.5 m/s (a static
            geom with surfacevel, the mechanism of the arm scene's conveyor), carried for
            N s: contacts and friction, which the nav robot never touches. Our own MJCF
            (sebvs.numerics.stability.belt_mjcf): its plausibility is easy to state.
  conveyor  a cube carried by the arm scene's moving belt (sebvs/sim/arm.py), the UR5
            holding HOME under its joint servos: `conveyor_case()`.

Reference check: `reference_spread` runs the reference method at half its step; the
distance between the two bounds the reference's own error (errors far below it are
noise of the reference, not accuracy of the method).
"""
from __future__ import annotations

import math
import statistics
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from sebvs.sim import make_scene  # sets MUJOCO_GL before mujoco
from sebvs.sim.scene import INTEGRATORS as ALL
from sebvs.sim.stability import Limits, StabilityMonitor

import mujoco  # noqa: E402

from .stability import BELT_TOP, BOX, belt_mjcf

INTEGRATORS = ("euler", "implicitfast", "rk4", "discrete")
TIMESTEPS = (0.0005, 0.001, 0.002, 0.005, 0.01)      # s; all divide the 50 ms control tick
REFERENCE = ("rk4", 1e-4)                             # the fine reference: method, dt (s)
CONTROL_DT = 0.05                                     # s, 20 Hz as the topologies use


@dataclass
class Case:
    """One physics scenario. `build(integrator, dt)` -> (scene, model, data), where scene
    has limits() and scripted(model, data) (a Scene, or any object with both);
    `drive(scene, model, data, t)` is called at every control tick t (s) to apply
    commands; `body` is the tracked body's name."""
    name: str
    build: Callable
    body: str
    drive: Callable | None = None
    note: str = ""
    extra: dict = field(default_factory=dict)


def nav_commands(seed: int, seconds: float, hold: float = 0.5) -> np.ndarray:
    """The seeded command sequence: (ceil(seconds/hold), 2) in [-1, 1], one per `hold` s."""
    rng = np.random.default_rng(seed)
    return rng.uniform(-1.0, 1.0, (int(math.ceil(seconds / hold)) + 1, 2))


def nav_case(seed: int = 0, seconds: float = 4.0, hold: float = 0.5) -> Case:
    cmds = nav_commands(seed, seconds, hold)

    def build(integrator: str, dt: float):
        scene = make_scene("nav", integrator=integrator, timestep=dt)
        model = scene.compile()
        data = mujoco.MjData(model)
        scene.reset(model, data, np.random.default_rng(seed))
        return scene, model, data

    def drive(scene, model, data, t: float) -> None:
        scene.apply_command(model, data, cmds[min(int(t / hold + 1e-9), len(cmds) - 1)])

    return Case("nav", build, "robot", drive,
                note=f"nav robot, seeded commands (seed {seed}, new command every {hold} s)")


class _Plain:
    """The two Scene methods run_case needs, for a bare MJCF model."""

    def __init__(self, limits) -> None:
        self._limits = limits

    def limits(self):
        return self._limits

    def scripted(self, model, data) -> None:
        pass


def belt_case(speed: float = 0.5, drop: float = 0.02) -> Case:

    def build(integrator: str, dt: float):
        model = mujoco.MjModel.from_xml_string(belt_mjcf(drop, speed, 0.0, 10.0))
        model.opt.integrator = ALL[integrator]
        model.opt.timestep = dt
        data = mujoco.MjData(model)
        mujoco.mj_forward(model, data)
        z0 = BELT_TOP + BOX + drop
        lim = Limits(bounds=(-11, 11, -2, 2, -0.5, z0 + 0.25), max_speed=1.5 * speed + 1.0,
                     max_angular=100.0, max_energy_jump=0.5 * 0.2 * (speed + 1.0) ** 2)
        return _Plain(lim), model, data

    return Case("belt", build, "box", None,
                note=f"10 cm box dropped {drop * 100:g} cm onto a belt moving at {speed:g} "
                     "m/s (static geom, surfacevel), default contact solref")


def conveyor_case(seed: int = 0) -> Case:
    """The arm scene's cube on its moving belt (conveyor "moving"), the arm holding HOME
    (its idle command each tick): the tracked body is the first body whose name contains
    "cube". Uses only the Scene interface; the tool reports any failure as a note."""
    def build(integrator: str, dt: float):
        scene = make_scene("arm", conveyor="moving", integrator=integrator, timestep=dt)
        model = scene.compile()
        data = mujoco.MjData(model)
        scene.reset(model, data, np.random.default_rng(seed))
        return scene, model, data

    scene, model, _ = build("implicitfast", 0.002)
    names = [model.body(i).name for i in range(model.nbody)]
    cube = next((n for n in names if "cube" in n.lower()), None)
    if cube is None:
        raise ValueError(f"arm scene: no body named like 'cube' among {names}")
    idle = scene.idle_command()

    def drive(scene, model, data, t: float) -> None:
        scene.apply_command(model, data, idle)

    return Case("conveyor", build, cube, drive,
                note=f"arm scene, body {cube!r} carried by the conveyor, arm idle, seed {seed}")


def run_case(case: Case, integrator: str, dt: float, seconds: float) -> dict:
    """Integrate `seconds`; -> {"pos": (3,) or None, "wall": s, "reason": str | None}."""
    scene, model, data = case.build(integrator, dt)
    mon = StabilityMonitor(model, scene.limits())
    mon.reset(data)
    body = model.body(case.body).id
    n = int(round(seconds / dt))
    per_tick = max(1, int(round(CONTROL_DT / dt)))
    reason = None
    step, scripted, check = mujoco.mj_step, scene.scripted, mon.check
    t0 = time.perf_counter()
    for i in range(n):
        if case.drive is not None and i % per_tick == 0:
            case.drive(scene, model, data, i * dt)
        scripted(model, data)
        step(model, data)
        reason = check(model, data)
        if reason:
            break
    wall = time.perf_counter() - t0
    mujoco.mj_kinematics(model, data)          # xpos of the final qpos, not one step behind
    pos = data.xpos[body].copy()
    if reason is None and not np.isfinite(pos).all():
        reason = "diverged: non-finite body position"
    return {"pos": None if reason else pos, "wall": wall, "reason": reason,
            "sim_s": (i + 1) * dt if n else 0.0}


def reference_spread(case: Case, seconds: float, reference=REFERENCE) -> float:
    """Distance (m) between the reference and the same method at half its step."""
    a = run_case(case, reference[0], reference[1], seconds)
    b = run_case(case, reference[0], reference[1] / 2, seconds)
    if a["pos"] is None or b["pos"] is None:
        return float("nan")
    return float(np.linalg.norm(a["pos"] - b["pos"]))


def physics_study(case: Case, seconds: float, integrators=INTEGRATORS, timesteps=TIMESTEPS,
                  repeats: int = 1, reference=REFERENCE, progress=None) -> list[dict]:
    """Points {"method", "setting" (dt s), "error" (m), "seconds" (wall per sim s),
    "diverged", "reason", "case", "reference", "timing_runs"} for every integrator x
    timestep; the reference itself is not a point (it defines zero error)."""
    ref = run_case(case, reference[0], reference[1], seconds)
    if ref["pos"] is None:
        raise RuntimeError(f"{case.name}: the reference {reference} diverged: {ref['reason']}")
    points, walls = [], []
    for integ in integrators:
        for dt in timesteps:
            r = run_case(case, integ, dt, seconds)
            walls.append([r["wall"] / max(r["sim_s"], 1e-12)])
            diverged = r["pos"] is None
            err = None if diverged else float(np.linalg.norm(r["pos"] - ref["pos"]))
            points.append({"method": integ, "setting": dt, "error": err,
                           "diverged": diverged, "reason": r["reason"] or "",
                           "case": case.name,
                           "reference": f"{reference[0]} dt={reference[1]:g}s",
                           "sim_seconds": seconds})
            if progress is not None:
                progress(1)
    # Timing repeats in rounds over every setting (not back to back): on shared cores a
    # load spike then slows all settings alike. Runs are deterministic, so only the wall
    # time changes; a diverged run is not timed again.
    for _ in range(max(1, repeats) - 1):
        for p, w in zip(points, walls):
            if not p["diverged"]:
                r = run_case(case, p["method"], p["setting"], seconds)
                w.append(r["wall"] / max(r["sim_s"], 1e-12))
    for p, w in zip(points, walls):
        p["seconds"] = statistics.median(w)
        p["timing_runs"] = len(w)
    return points
