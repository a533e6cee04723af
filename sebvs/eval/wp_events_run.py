"""Event-emulation work-precision study: dvs sampling rate against a fast-sampled reference.

Motion: the nav scene (robot driven by the seeded commands of wp_physics.nav_commands, the
target on its scripted path), integrated at the reference step 1/ref_hz s with
implicitfast, rendered as luma at every step (the camera's front view, at luma size
= the emulator's input after the paper's downsample 0.5, as the camera's luma_scale does).
A rate r takes every (ref_hz / r)-th frame of that sequence, so every rate sees exactly
the same motion; the reference is the emulator fed every frame.

Per rate and emulator preset: wp_events.event_errors against the reference of the same
preset (rel L1 of ON/OFF counts per 50 ms control tick, timestamp errors of matched
events, count ratio). Seconds: wall seconds per simulated second of camera + emulator =
rate x (median render time of one luma frame) + (emulator wall time for the rate's frames,
median of cfg["repeats"] runs) / simulated seconds. Rendering is timed once per frame on the reference sequence rather
than re-rendered per rate (same frames, same cost per frame).

Needs sebvs.dvs (import fails with ImportError without it, and the study is skipped).
"""
from __future__ import annotations

import statistics
import time

import numpy as np

from sebvs.sim import make_scene
from sebvs.sim.render import FrameRenderer

import mujoco  # noqa: E402

from . import dvs_adapter  # ImportError while sebvs.dvs has no emulator
from . import wp_events
from .wp_physics import nav_commands

CONTROL_DT = 0.05    # s: the accumulator's window, one per control tick
# "noisy" is left out: its shot noise is drawn anew for every sampling, so its error is
# the noise itself (measured: relative L1 1.2 and p90 timestamp error ~150 ms at every
# rate from 50 to 1000 Hz), which says nothing about the sampling rate.
PRESETS = ("paper", "clean")


def n_runs(cfg: dict) -> int:
    """Bar length: one reference plus one run per rate, per preset, plus the render."""
    return 1 + len(PRESETS) * (1 + len(cfg["ev_rates"]))


def nav_luma(seed: int, seconds: float, ref_hz: int, size: int = 80,
             progress=None) -> tuple[np.ndarray, np.ndarray, float]:
    """-> (frames (N+1, size, size) uint8, t_ns (N+1,) int64, median render s per frame)."""
    dt = 1.0 / ref_hz
    scene = make_scene("nav", integrator="implicitfast", timestep=dt)
    model = scene.compile()
    data = mujoco.MjData(model)
    scene.reset(model, data, np.random.default_rng(seed))
    cmds = nav_commands(seed, seconds)
    n = int(round(seconds * ref_hz))
    per_tick = int(round(CONTROL_DT * ref_hz))
    frames = np.empty((n + 1, size, size), np.uint8)
    times = np.empty(n + 1)
    with FrameRenderer(model, size, size) as r:
        for i in range(n + 1):
            if i:
                if (i - 1) % per_tick == 0:
                    scene.apply_command(model, data, cmds[min(int((i - 1) * dt / 0.5),
                                                              len(cmds) - 1)])
                scene.scripted(model, data)
                mujoco.mj_step(model, data)
            t0 = time.perf_counter()
            scene.kinematics(model, data)
            r.update(data, "front")
            r.luma(frames[i])
            times[i] = time.perf_counter() - t0
    t_ns = np.round(np.arange(n + 1) * (1e9 / ref_hz)).astype(np.int64)
    if progress is not None:
        progress(1)
    return frames, t_ns, float(statistics.median(times))


def emulate(preset: str, frames: np.ndarray, t_ns: np.ndarray, seed: int) -> tuple:
    """Feed frames to a fresh emulator -> ((t, x, y, p) arrays, wall seconds)."""
    return dvs_adapter.run(preset, frames, t_ns, seed, downsample=1.0)


def study(cfg: dict, seed: int, progress=None) -> tuple[list[dict], list[dict], str]:
    """-> (points with error = rel L1, points with error = p90 timestamp error us, note)."""
    ref_hz, seconds = int(cfg["ev_ref_hz"]), float(cfg["ev_seconds"])
    frames, t_ns, render_s = nav_luma(seed, seconds, ref_hz, progress=progress)
    shape = frames.shape[1:]
    ticks = int(round(seconds / CONTROL_DT))
    l1_points, ts_points = [], []
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
            m = wp_events.event_errors(test, ref, shape, 0, int(CONTROL_DT * 1e9), ticks)
            secs = rate * render_s + wall / seconds
            common = {"method": preset, "setting": rate, "seconds": secs,
                      "render_s_per_frame": render_s, "emulator_s": wall / seconds,
                      "reference_hz": ref_hz, "sim_seconds": seconds, **m}
            l1_points.append({**common, "error": m["rel_l1"]})
            ts_points.append({**common, "error": m["ts_p90_us"]})
            if progress is not None:
                progress(1)
    note = (f"nav motion (seed {seed}), {seconds:g} s, luma {shape[1]}x{shape[0]} px "
            f"(emulator downsample 1: the camera's luma_scale 0.5 does it); reference: the "
            f"same preset fed every frame at {ref_hz} Hz; preset noisy left out (its "
            f"random shot noise is its error at every rate)"
            + (" (--quick: 5 kHz, not 10 kHz)" if ref_hz < 10000 else ""))
    return l1_points, ts_points, note
