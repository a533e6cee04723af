#!/usr/bin/env python3
"""N nav envs as one vector env: in one process (sebvs/envs/vector.py) against Gymnasium's
SyncVectorEnv and AsyncVectorEnv of the same env, side by side in one run.

shared  gym.make_vec(..., vectorization_mode="vector_entry_point"): N scenes in this
        process on one thread per core (env i on thread i % threads), each thread's
        event sensors emulated as one stack per sample time
shared1 the same on one thread (threads=1): all N sensors in one stack
sync    gymnasium.vector.SyncVectorEnv of N gym.make(...) envs, in this process
async   gymnasium.vector.AsyncVectorEnv, one spawned process per env ("module:id" ids)

Every side is built with the same options (the shipped v1 env: physical sensor pair,
160 px, dvs 100 Hz, every observation key), reset with seed --seed (env i plays seed + i)
and stepped with the idle command; episodes of --episode-s, so a run crosses autoresets as
training does. env-ticks/s = N * vector steps / wall time, make() and the first reset
excluded (startup_s beside it). Each (side, N) runs --repeats times, interleaved; the
figures are medians, every repeat kept. cpu_ms_per_env_tick is this process's CPU time
(llvmpipe's render threads included), for the in-process sides.

--breakdown also times the shared side's stages per env-tick (wall ms): the event
sensor's luma renders (SensorRig.luminance: radiance render, readback, decode), the frame
camera (CameraCore._frame: its chroma render, integration, noise), physics and stability
checks (SceneStepper.advance), the event chain (emulator and accumulator, batched), and
the rest.

    MUJOCO_GL=egl tools/bench/bench_vector_env.py [--quick] [--envs 1,8]
        [--sides shared,shared1,sync,async] [--ticks 96] [--repeats 3] [--episode-s 2]
        [--breakdown] [--json FILE [--force]]
"""
from __future__ import annotations

import argparse
import math
import os
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))

from benchio import counts_arg, print_report  # noqa: E402
from sebvs.output_guard import OutputRefused, check_output_file  # noqa: E402

SIDES = ("shared", "shared1", "sync", "async")
TARGET = {"num_envs": 8, "env_ticks_per_s": 300.0}


def make_vector(side: str, n: int, options: dict):
    """The vector env of `side` with n envs of SEBVS/ERPNav-v1 and `options`."""
    import gymnasium as gym
    import sebvs.envs
    env_id = sebvs.envs.ENV_IDS["nav"]
    if side in ("shared", "shared1"):
        return gym.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point",
                            **({"threads": 1} if side == "shared1" else {}), **options)
    if side == "sync":
        return gym.make_vec(env_id, num_envs=n, vectorization_mode="sync", **options)
    # spawned: a forked worker inherits this process's GL state and hangs (docs/envs.md)
    spawned = "sebvs.envs:" + env_id
    return gym.vector.AsyncVectorEnv([lambda: gym.make(spawned, **options)] * n,
                                     context="spawn")


def measure(side: str, n: int, ticks: int, options: dict, seed: int) -> dict:
    """One run: make, reset, ceil(ticks / n) vector steps of the idle command."""
    import numpy as np
    t0 = time.perf_counter()
    envs = make_vector(side, n, options)
    try:
        envs.reset(seed=seed)
        startup = time.perf_counter() - t0
        idle = np.zeros((n, 2), np.float32)
        steps = max(1, math.ceil(ticks / n))
        ends = 0
        c0, t0 = time.process_time(), time.perf_counter()
        for _ in range(steps):
            _, _, terminated, truncated, _ = envs.step(idle)
            ends += int((terminated | truncated).sum())
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    finally:
        envs.close()
    out = {"env_ticks_per_s": round(n * steps / wall, 2), "steps": steps, "episode_ends": ends,
           "wall_s": round(wall, 3), "startup_s": round(startup, 2)}
    threads = getattr(envs.unwrapped, "threads", None)
    if threads is not None:
        out["threads"] = threads
    if side != "async":
        out["cpu_ms_per_env_tick"] = round(1e3 * cpu / (n * steps), 2)
    return out


class StageTimer:
    """Wall time inside a few functions, patched in for one run (outermost calls only)."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}
        self._patched: list = []
        self._depth = 0

    def wrap(self, owner, attr: str, stage: str) -> None:
        real = getattr(owner, attr)
        timer = self

        def timed(*args, **kwargs):
            if timer._depth:
                return real(*args, **kwargs)
            timer._depth += 1
            t0 = time.perf_counter()
            try:
                return real(*args, **kwargs)
            finally:
                timer._depth -= 1
                timer.seconds[stage] = timer.seconds.get(stage, 0.0) + \
                    time.perf_counter() - t0
        setattr(owner, attr, timed)
        self._patched.append((owner, attr, real))

    def undo(self) -> None:
        for owner, attr, real in reversed(self._patched):
            setattr(owner, attr, real)
        self._patched.clear()


def breakdown(n: int, ticks: int, options: dict, seed: int) -> dict:
    """The shared side's wall time per env-tick by stage (module docstring)."""
    import numpy as np
    import sebvs.envs.vector as vector
    from sebvs.sensors.camera import CameraCore
    from sebvs.sensors.rig import SensorRig
    from sebvs.sim.stepper import SceneStepper
    envs = make_vector("shared", n, options)
    timer = StageTimer()
    try:
        envs.reset(seed=seed)
        timer.wrap(SensorRig, "luminance", "luma_renders")
        timer.wrap(CameraCore, "_frame", "frame_camera")
        timer.wrap(SceneStepper, "advance", "physics")
        timer.wrap(vector, "run_chains", "event_chain")
        idle = np.zeros((n, 2), np.float32)
        steps = max(1, math.ceil(ticks / n))
        t0 = time.perf_counter()
        for _ in range(steps):
            envs.step(idle)
        wall = time.perf_counter() - t0
    finally:
        timer.undo()
        envs.close()
    per = 1e3 / (n * steps)
    stages = {k: round(v * per, 2) for k, v in sorted(timer.seconds.items())}
    stages["other"] = round(wall * per - sum(stages.values()), 2)
    return {"num_envs": n, "steps": steps, "wall_ms_per_env_tick": round(wall * per, 2),
            "ms_per_env_tick": stages,
            "share": {k: round(v / (wall * per), 3) for k, v in stages.items()}}


def gl_renderer() -> str:
    """The GL renderer MuJoCo's EGL context gets here (llvmpipe on a CPU machine)."""
    try:
        import mujoco
        from OpenGL import GL
        ctx = mujoco.GLContext(16, 16)
        ctx.make_current()
        try:
            return GL.glGetString(GL.GL_RENDERER).decode()
        finally:
            ctx.free()
    except Exception as exc:        # the report says so; the timings still stand
        return f"unknown ({type(exc).__name__})"


def run(sides, counts, ticks: int, repeats: int, options: dict, seed: int,
        with_breakdown: bool) -> dict:
    load0 = os.getloadavg()
    runs: dict = {s: {str(n): [] for n in counts} for s in sides}
    t_start = time.perf_counter()
    for _ in range(repeats):
        for n in counts:
            for side in sides:
                runs[side][str(n)].append(measure(side, n, ticks, options, seed))
    results = {s: {n: {"env_ticks_per_s": statistics.median(r["env_ticks_per_s"]
                                                            for r in rows),
                       **({"cpu_ms_per_env_tick": statistics.median(
                           r["cpu_ms_per_env_tick"] for r in rows)}
                          if "cpu_ms_per_env_tick" in rows[0] else {}),
                       "runs": rows}
                   for n, rows in by_n.items()} for s, by_n in runs.items()}
    report = {
        "bench": "bench_vector_env", "env": "SEBVS/ERPNav-v1", "options": options,
        "seed": seed, "ticks_per_run": ticks, "repeats": repeats,
        "machine": {"cpus": os.cpu_count(), "gl_renderer": gl_renderer(),
                    "load_avg_before": [round(x, 2) for x in load0]},
        "env_ticks_per_s": {s: {n: v["env_ticks_per_s"] for n, v in by_n.items()}
                            for s, by_n in results.items()},
        "results": results,
    }
    if with_breakdown:
        report["breakdown"] = breakdown(max(counts), ticks, options, seed)
    report["machine"]["load_avg_after"] = [round(x, 2) for x in os.getloadavg()]
    report["wall_s"] = round(time.perf_counter() - t_start, 1)
    best = report["env_ticks_per_s"].get("shared", {}).get(str(TARGET["num_envs"]))
    report["target"] = {**TARGET, "shared_measured": best,
                        "met": None if best is None else best >= TARGET["env_ticks_per_s"]}
    return report


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="32 env-ticks a run, 1 repeat")
    ap.add_argument("--envs", type=counts_arg("--envs"), default=(1, 8), help="env counts (1,8)")
    ap.add_argument("--sides", default=",".join(SIDES), help="shared,shared1,sync,async")
    ap.add_argument("--ticks", type=int, default=96, help="env-ticks per run (96)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--episode-s", type=float, default=2.0, help="episode length, s (2)")
    ap.add_argument("--width", type=int, default=160, help="image px, square (160)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--breakdown", action="store_true",
                    help="also time the shared side's stages per env-tick")
    ap.add_argument("--json", metavar="FILE")
    ap.add_argument("--force", action="store_true", help="replace --json FILE if it exists")
    args = ap.parse_args()
    sides = tuple(args.sides.split(","))
    ticks, repeats = (32, 1) if args.quick else (args.ticks, args.repeats)
    bad = [s for s in sides if s not in SIDES]
    problem = (f"--sides: unknown {bad}; known: {', '.join(SIDES)}" if bad else
               f"--ticks {ticks}: give >= 1" if ticks < 1 else
               f"--repeats {repeats}: give >= 1" if repeats < 1 else
               f"--episode-s {args.episode_s}: give > 0" if not args.episode_s > 0 else
               f"--width {args.width}: give 8 to 640 px" if not 8 <= args.width <= 640
               else None)
    if problem:
        print(f"bench_vector_env: {problem}", file=sys.stderr)
        return 2
    if args.json:
        try:
            check_output_file(args.json, force=args.force)
        except OutputRefused as e:
            print(f"bench_vector_env: {e}", file=sys.stderr)
            return 2
    os.environ.setdefault("MUJOCO_GL", "egl")
    options = {"width": args.width, "height": args.width, "episode_s": args.episode_s}
    report = run(sides, args.envs, ticks, repeats, options, args.seed, args.breakdown)
    print_report(report, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
