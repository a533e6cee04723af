"""Event-emulation work-precision study: dvs sampling rate against a fast-sampled reference.

A *motion* is a seeded scene run seen by one camera, integrated at the reference step
1/ref_hz s with implicitfast and rendered as luma at every step (luma size = the
emulator's input after the paper's downsample 0.5, as the camera's luma_scale does):

  nav       the nav scene, robot driven by the seeded commands of wp_physics.nav_commands
            (a new one every 0.5 s, applied every 50 ms control tick), the target on its
            scripted path; front camera; count windows of 50 ms (20 Hz control).
  conveyor  the arm scene with its belt moving at `belt_speed` m/s and CONVEYOR_OBJECTS
            seeded cubes on it, the UR5 holding HOME (its idle command every tick); wrist
            camera; count windows of 100 ms (the arm topologies' 10 Hz control and
            accumulator window). The sequence starts conveyor_warmup_s() after reset: the
            belt has finished its start-up ramp and the cubes have landed and are carried at
            belt speed, so the study measures the steady motion alone. One motion per belt
            speed in cfg["ev_belt_speeds"]; their points' method is "<preset> <speed> m/s".

A rate r takes every (ref_hz / r)-th frame of that sequence, so every rate sees exactly
the same motion; the reference is the emulator fed every frame.

Per rate and emulator preset: wp_events.event_errors against the reference of the same
preset (rel L1 of ON/OFF counts per control tick, timestamp errors of matched events,
count ratio). Seconds: wall seconds per simulated second of camera + emulator =
rate x (median render time of one luma frame) + (emulator wall time for the rate's frames,
median of cfg["repeats"] runs) / simulated seconds. Rendering is timed once per frame on
the reference sequence rather than re-rendered per rate (same frames, same cost per frame).

Points: {"method", "setting" (rate, Hz), "error", "seconds", "render_s_per_frame",
"emulator_s", "reference_hz", "sim_seconds", "motion", "window_s", the fields of
wp_events.event_errors (rel_l1, ts_median_us, ts_p90_us, count_ratio, unmatched, events,
ref_events)}; conveyor points add "belt_speed" (m/s).
"""
from __future__ import annotations

import statistics
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from sebvs.sim import make_scene
from sebvs.sim.arm import BELT_ACCEL
from sebvs.sim.render import FrameRenderer

import mujoco  # noqa: E402

from . import dvs_adapter
from . import wp_events
from .wp_physics import nav_commands

CONTROL_DT = 0.05    # s: the nav accumulator's window, one per control tick
ARM_CONTROL_DT = 0.1  # s: the arm topologies' control tick (10 Hz) and accumulator window
MOTIONS = ("nav", "conveyor")
LUMA_SIZE = 80       # px: the cameras' 160 px at the camera actor's luma_scale 0.5
# "noisy" is left out: its shot noise is drawn anew for every sampling, so its error is
# the noise itself (measured: relative L1 1.2 and p90 timestamp error ~150 ms at every
# rate from 50 to 1000 Hz), which says nothing about the sampling rate.
PRESETS = ("paper", "clean")
# Several cubes: more moving edges (more events per tick) than the single-cube task, and
# the cluttered variant the arm topologies record (objects=3).
CONVEYOR_OBJECTS = 3
# After the belt's start-up ramp: the cubes fall their drop_height (~25 ms), slip, and are
# carried at belt speed to 1 % within 0.1 s of landing (measured at 0.08 and 0.25 m/s, 1e-4 s
# steps); 0.15 s covers both.
CUBE_SETTLE_S = 0.15


@dataclass
class Motion:
    """A built scene ready to step and the facts the loop needs.

    command(t) gives the command (the scene's command array) applied at the control tick
    starting t s after reset; warmup_s is simulated before the first frame; label is
    appended to the preset in the points' method; extra is copied into every point."""
    name: str
    scene: object
    model: mujoco.MjModel
    data: mujoco.MjData
    camera: str
    control_dt: float
    command: Callable[[float], np.ndarray]
    warmup_s: float = 0.0
    label: str = ""
    extra: dict | None = None


def nav_motion(seed: int, seconds: float, ref_hz: int) -> Motion:
    """The nav scene at dt = 1/ref_hz, reset with `seed`, driven by nav_commands(seed)."""
    scene = make_scene("nav", integrator="implicitfast", timestep=1.0 / ref_hz)
    model = scene.compile()
    data = mujoco.MjData(model)
    scene.reset(model, data, np.random.default_rng(seed))
    cmds = nav_commands(seed, seconds)
    return Motion("nav", scene, model, data, "front", CONTROL_DT,
                  lambda t: cmds[min(int(t / 0.5), len(cmds) - 1)])


def conveyor_warmup_s(belt_speed: float) -> float:
    """Simulated s from reset to steady motion: the belt's ramp to speed, then the cubes'."""
    return belt_speed / BELT_ACCEL + CUBE_SETTLE_S


def conveyor_motion(seed: int, ref_hz: int, belt_speed: float,
                    objects: int = CONVEYOR_OBJECTS) -> Motion:
    """The arm scene at dt = 1/ref_hz, belt moving at belt_speed m/s, `objects` cubes
    placed by `seed`, the arm given its idle command (HOME) every control tick."""
    scene = make_scene("arm", conveyor="moving", belt_speed=float(belt_speed),
                       objects=int(objects), integrator="implicitfast", timestep=1.0 / ref_hz)
    model = scene.compile()
    data = mujoco.MjData(model)
    scene.reset(model, data, np.random.default_rng(seed))
    idle = scene.idle_command()
    return Motion("conveyor", scene, model, data, "wrist", ARM_CONTROL_DT, lambda t: idle,
                  warmup_s=conveyor_warmup_s(belt_speed), label=f" {belt_speed:g} m/s",
                  extra={"belt_speed": float(belt_speed)})


def make_motions(motion: str, cfg: dict, seed: int, seconds: float, ref_hz: int):
    """The study's motions, built one at a time (a 10 kHz sequence is ~100 MB of frames).

    nav: one; conveyor: one per belt speed of cfg["ev_belt_speeds"] (m/s)."""
    if motion == "nav":
        yield nav_motion(seed, seconds, ref_hz)
    elif motion == "conveyor":
        for speed in cfg["ev_belt_speeds"]:
            yield conveyor_motion(seed, ref_hz, speed)
    else:
        raise ValueError(f"unknown motion {motion!r} (one of {', '.join(MOTIONS)})")


def n_runs(cfg: dict, motion: str = "nav") -> int:
    """Bar length: per motion, the render plus one reference and one run per rate, per
    preset."""
    variants = len(cfg["ev_belt_speeds"]) if motion == "conveyor" else 1
    return variants * (1 + len(PRESETS) * (1 + len(cfg["ev_rates"])))


def luma_sequence(m: Motion, seconds: float, ref_hz: int, size: int = LUMA_SIZE,
                  progress=None) -> tuple[np.ndarray, np.ndarray, float]:
    """Step m's scene every 1/ref_hz s and render m.camera's luma after every step.

    -> (frames (N+1, size, size) uint8, t_ns (N+1,) int64 from 0 at the first frame,
    median render s per frame), N = seconds * ref_hz. Each step: the command at a control
    tick, scene.scripted, mj_step (the sim actor's order); the first warmup_s are stepped
    but not rendered."""
    dt = 1.0 / ref_hz
    n = int(round(seconds * ref_hz))
    warm = int(round(m.warmup_s * ref_hz))
    per_tick = int(round(m.control_dt * ref_hz))
    frames = np.empty((n + 1, size, size), np.uint8)
    times = np.empty(n + 1)
    with FrameRenderer(m.model, size, size) as r:
        for k in range(warm + n + 1):
            if k:
                s = k - 1                  # the step that leads to state k
                if s % per_tick == 0:
                    m.scene.apply_command(m.model, m.data, m.command(s * dt))
                m.scene.scripted(m.model, m.data)
                mujoco.mj_step(m.model, m.data)
            if k < warm:
                continue
            t0 = time.perf_counter()
            m.scene.kinematics(m.model, m.data)
            r.update(m.data, m.camera)
            r.luma(frames[k - warm])
            times[k - warm] = time.perf_counter() - t0
    t_ns = np.round(np.arange(n + 1) * (1e9 / ref_hz)).astype(np.int64)
    if progress is not None:
        progress(1)
    return frames, t_ns, float(statistics.median(times))


def emulate(preset: str, frames: np.ndarray, t_ns: np.ndarray, seed: int) -> tuple:
    """Feed frames to a fresh emulator -> ((t, x, y, p) arrays, wall seconds)."""
    return dvs_adapter.run(preset, frames, t_ns, seed, downsample=1.0)


def motion_points(m: Motion, cfg: dict, seed: int, progress=None) -> list[dict]:
    """Render m's reference sequence and score every (preset, rate) on it -> points with
    every field but "error" (see the module docstring)."""
    ref_hz, seconds = int(cfg["ev_ref_hz"]), float(cfg["ev_seconds"])
    frames, t_ns, render_s = luma_sequence(m, seconds, ref_hz, progress=progress)
    shape = frames.shape[1:]
    window_ns = int(round(m.control_dt * 1e9))
    ticks = int(round(seconds / m.control_dt))
    points = []
    for preset in PRESETS:
        ref, _ = emulate(preset, frames, t_ns, seed)
        if progress is not None:
            progress(1)
        for rate in cfg["ev_rates"]:
            stride = ref_hz // rate
            idx = np.arange(0, len(frames), stride)
            test, wall = emulate(preset, frames[idx], t_ns[idx], seed)
            # the emulator is deterministic: repeats change only the wall time (median)
            walls = [wall] + [emulate(preset, frames[idx], t_ns[idx], seed)[1]
                              for _ in range(int(cfg.get("repeats", 1)) - 1)]
            wall = statistics.median(walls)
            metrics = wp_events.event_errors(test, ref, shape, 0, window_ns, ticks)
            points.append({"method": preset + m.label, "setting": rate,
                           "seconds": rate * render_s + wall / seconds,
                           "render_s_per_frame": render_s, "emulator_s": wall / seconds,
                           "reference_hz": ref_hz, "sim_seconds": seconds,
                           "motion": m.name, "window_s": m.control_dt,
                           **(m.extra or {}), **metrics})
            if progress is not None:
                progress(1)
    return points


def motion_note(motion: str, cfg: dict, seed: int) -> str:
    """What the study ran, for summary.json and the tool's printout."""
    ref_hz, seconds = int(cfg["ev_ref_hz"]), float(cfg["ev_seconds"])
    if motion == "nav":
        what = f"nav motion (seed {seed}), {seconds:g} s"
    else:
        speeds = ", ".join(f"{s:g}" for s in cfg["ev_belt_speeds"])
        warm = ", ".join(f"{conveyor_warmup_s(s):.3g}" for s in cfg["ev_belt_speeds"])
        what = (f"conveyor motion (arm scene, belt {speeds} m/s, {CONVEYOR_OBJECTS} cubes, "
                f"seed {seed}, arm holding HOME, wrist camera), {seconds:g} s starting "
                f"{warm} s after reset (belt at speed, cubes carried), counts per "
                f"{ARM_CONTROL_DT * 1e3:g} ms tick")
    return (f"{what}, luma {LUMA_SIZE}x{LUMA_SIZE} px (emulator downsample 1: the camera's "
            f"luma_scale 0.5 does it); reference: the same preset fed every frame at {ref_hz} "
            f"Hz; preset noisy left out (its random shot noise is its error at every rate)"
            + (" (--quick: 5 kHz, not 10 kHz)" if ref_hz < 10000 else ""))


def study(cfg: dict, seed: int, progress=None,
          motion: str = "nav") -> tuple[list[dict], list[dict], str]:
    """-> (points with error = rel L1, points with error = p90 timestamp error us, note)."""
    ref_hz, seconds = int(cfg["ev_ref_hz"]), float(cfg["ev_seconds"])
    points = [p for m in make_motions(motion, cfg, seed, seconds, ref_hz)
              for p in motion_points(m, cfg, seed, progress)]
    l1_points = [{**p, "error": p["rel_l1"]} for p in points]
    ts_points = [{**p, "error": p["ts_p90_us"]} for p in points]
    return l1_points, ts_points, motion_note(motion, cfg, seed)
