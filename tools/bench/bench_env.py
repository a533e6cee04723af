#!/usr/bin/env python3
"""The Gymnasium environments' speed against the lockstep topology's, side by side.

topology  the task's policy topology (topologies/nav_policy.toml, arm_policy.toml) on the
          lockstep clock as `sebvs eval` runs its no-action row, with the event chain kept:
          sim, camera (RGB and luma at the topology's dvs rate), emulator, accumulator,
          the no-action baseline answering every tick (actors/baseline.py), the tracker,
          and a probe that receives the RGB and event frames of every tick. Ticks per
          second from the probe's first to its last RGB frame (start-up excluded).
env       sebvs.envs' environment of the same task, condition, scenario and sensors
          (every observation key: rgb, events, proprio), stepped with the same idle
          command in this process: ticks (env steps) per second over whole episodes,
          make() and the first reset() excluded.

Both play the same episodes (topology seed `--seed`): the same scene, the same renders,
events and event frames (tests/test_envs.py checks them equal, bit for bit). Each part
runs --repeats times, alternating; the headline figures are medians, each repeat's kept
beside them, with the machine's load average before and after.

--wrapper: sebvs.envs.EventCameraWrapper on stock Gymnasium MuJoCo envs (--envs), side by
side with the unwrapped env rendering each step (render_mode="rgb_array", render() after
every step) at the same resolution: env steps per second over --steps steps of the same
seeded actions, make(), the first reset and one warm-up step excluded, each side
--repeats times, alternating. The wrapper adds events and the frame camera's image
(obs "events", "rgb") at its default 100 Hz luma sampling; the target is wrapped >= 0.5x
unwrapped (issue 66).

    tools/bench/bench_env.py [--quick] [--task nav|arm|both] [--condition C]
                             [--episode-s S] [--repeats N] [--json OUT]
    tools/bench/bench_env.py --wrapper [--envs Pusher-v5,Reacher-v5] [--width 64]
                             [--height H] [--steps 100] [--preset physical] [--repeats N]
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))

from benchio import print_report  # noqa: E402

DEFAULT_EPISODE_S = {"nav": 10.0, "arm": 2.0}


def topology_overrides(task: str, condition: str = "nominal", scenario: str | None = None,
                       *, seed: int = 0, episodes: int = 1, episode_s: float | None = None,
                       probe: str | Path = "probe", max_arrays: int = 0,
                       extra: list | tuple = ()) -> tuple[Path, dict]:
    """The policy topology and the overrides of `sebvs eval`'s no-action run of this
    condition and scenario, with the event chain wired to a probe (which also keeps the
    RGB frames): (topology path, overrides)."""
    from sebvs.conditions import TASKS
    from sebvs.eval.plan import BASELINE, EvalPlan, Run
    from sebvs.runtime.overrides import merge
    scenario = scenario or TASKS[task].default_scenario
    plan = EvalPlan(task=task, modalities=[], conditions=[condition], episodes=episodes,
                    out=Path(tempfile.gettempdir()), scenarios=[scenario], seed=seed,
                    baseline=True, expert=False, extra=list(extra))
    plan.validate()
    path, sets = plan.overrides(Run(condition, scenario, BASELINE))
    probe_sets = {"probe": {"run": "actors.synthetic:Probe", "max_arrays": int(max_arrays),
                            "path": str(probe),
                            "inputs": {"events": {"from": "accumulator/frames", "queue": 256},
                                       "rgb": {"from": "camera/rgb", "queue": 256}}}}
    sets = merge(sets, {"tracker": {"path": ""}},
                 TASKS[task].condition(condition).event_sensor_overrides(), probe_sets,
                 {"sim": {"episode_s": float(episode_s)}} if episode_s is not None else {})
    return Path(path), sets


def run_topology(task: str, condition: str, scenario: str | None, seed: int, episode_s: float,
                 workdir: Path, max_arrays: int = 0, extra: list | tuple = ()) -> dict:
    """One lockstep run of one episode; its probe's entries (and arrays, if kept)."""
    import numpy as np
    from sebvs.runtime.supervisor import run_topology as run
    probe = workdir / "probe"
    path, sets = topology_overrides(task, condition, scenario, seed=seed, episode_s=episode_s,
                                    probe=probe, max_arrays=max_arrays, extra=extra)
    t0 = time.perf_counter()
    run(path, sets, duration_s=600, runs_dir=workdir / "runs")
    total = time.perf_counter() - t0
    entries = json.loads(probe.with_suffix(".json").read_text())
    arrays = {}
    if max_arrays:
        with np.load(probe.with_suffix(".npz")) as z:
            arrays = {k: z[k] for k in z.files}
    return {"entries": entries, "arrays": arrays, "wall_s_incl_startup": total}


def bench_topology(task: str, condition: str, scenario: str | None, seed: int,
                   episode_s: float) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        out = run_topology(task, condition, scenario, seed, episode_s, Path(tmp))
    rgb = [e for e in out["entries"] if e["input"] == "rgb"]
    events = [e for e in out["entries"] if e["input"] == "events"]
    wall = (rgb[-1]["recv_ns"] - rgb[0]["recv_ns"]) / 1e9 if len(rgb) > 1 else float("nan")
    return {"ticks": len(rgb), "event_frames": len(events),
            "ticks_per_s": round((len(rgb) - 1) / wall, 2) if wall > 0 else None,
            "wall_s": round(wall, 3),
            "wall_s_incl_startup": round(out["wall_s_incl_startup"], 2)}


def bench_env(task: str, condition: str, scenario: str | None, seed: int,
              episode_s: float) -> dict:
    import gymnasium as gym
    import sebvs.envs
    t0 = time.perf_counter()
    env = gym.make(sebvs.envs.ENV_IDS[task], condition=condition, scenario=scenario,
                   episode_s=episode_s)
    base = env.unwrapped
    idle = base.sim.scene.idle_command().astype("float32")
    env.reset(seed=seed)
    startup = time.perf_counter() - t0
    t0 = time.perf_counter()
    steps = 0
    while True:
        _, _, terminated, truncated, _ = env.step(idle)
        steps += 1
        if terminated or truncated:
            break
    wall = time.perf_counter() - t0
    env.close()
    return {"ticks": steps + 1, "ticks_per_s": round(steps / wall, 2), "wall_s": round(wall, 3),
            "startup_s": round(startup, 2)}


def bench(task: str, condition: str, scenario: str | None, seed: int, episode_s: float,
          repeats: int) -> dict:
    topo, env = [], []
    for _ in range(repeats):
        topo.append(bench_topology(task, condition, scenario, seed, episode_s))
        env.append(bench_env(task, condition, scenario, seed, episode_s))
    t = statistics.median(r["ticks_per_s"] for r in topo)
    e = statistics.median(r["ticks_per_s"] for r in env)
    return {"task": task, "condition": condition, "scenario": scenario or "default",
            "seed": seed, "episode_s": episode_s, "repeats": repeats,
            "topology_ticks_per_s": t, "env_ticks_per_s": e,
            "env_over_topology": round(e / t, 2) if t else None,
            "topology_runs": topo, "env_runs": env}


def _timed_steps(env, actions, render: bool) -> float:
    """Steps per second of `env` over `actions` (a reset where an episode ends, counted)."""
    t0 = time.perf_counter()
    for action in actions:
        _, _, terminated, truncated, _ = env.step(action)
        if render:
            env.render()
        if terminated or truncated:
            env.reset()
    return len(actions) / (time.perf_counter() - t0)


def bench_wrapper_pair(env_id: str, width: int, height: int, steps: int, seed: int,
                       preset: str) -> dict:
    """One repeat: the unwrapped env rendering every step, then the wrapped one, on the
    same seeded actions (module docstring)."""
    import gymnasium as gym
    from sebvs.envs import EventCameraWrapper
    out = {}
    for side in ("unwrapped", "wrapped"):
        if side == "unwrapped":
            env = gym.make(env_id, render_mode="rgb_array", width=width, height=height)
        else:
            env = EventCameraWrapper(gym.make(env_id, width=width, height=height),
                                     width=width, height=height, preset=preset,
                                     obs=("events", "rgb"))
        env.reset(seed=seed)
        env.action_space.seed(seed)
        actions = [env.action_space.sample() for _ in range(steps + 1)]
        _timed_steps(env, actions[:1], side == "unwrapped")     # warm-up: GL, first frame
        out[side] = round(_timed_steps(env, actions[1:], side == "unwrapped"), 2)
        env.close()
    return out


def bench_wrapper(env_id: str, width: int, height: int, steps: int, seed: int,
                  preset: str, repeats: int) -> dict:
    runs = [bench_wrapper_pair(env_id, width, height, steps, seed, preset)
            for _ in range(repeats)]
    u = statistics.median(r["unwrapped"] for r in runs)
    w = statistics.median(r["wrapped"] for r in runs)
    return {"env": env_id, "width": width, "height": height, "steps": steps,
            "preset": preset, "seed": seed, "repeats": repeats,
            "unwrapped_render_steps_per_s": u, "wrapped_steps_per_s": w,
            "wrapped_over_unwrapped": round(w / u, 2) if u else None, "target": 0.5,
            "runs": runs}


def main_wrapper(args) -> int:
    os.environ.setdefault("MUJOCO_GL", "egl")
    import gymnasium as gym
    from sebvs.dvs.params import PRESETS
    envs = [e for e in args.envs.split(",") if e]
    bad = [e for e in envs if e not in gym.registry]
    problem = (f"--envs: {bad[0]!r} is not a registered Gymnasium env id" if bad else
               "--envs: name at least one env id" if not envs else
               f"--preset: {args.preset!r} is not one of {', '.join(PRESETS)}"
               if args.preset not in PRESETS else
               "--width, --height and --steps must be positive"
               if min(args.width, args.height or args.width, args.steps) < 1 else None)
    if problem:
        print(f"bench_env: {problem}", file=sys.stderr)
        return 2
    steps = 30 if args.quick else args.steps
    repeats = 1 if args.quick else args.repeats
    report = {"bench": "env_wrapper", "quick": args.quick, "cpus": os.cpu_count(),
              "load_before": os.getloadavg(), "results": []}
    for env_id in envs:
        report["results"].append(bench_wrapper(env_id, args.width, args.height or args.width,
                                               steps, args.seed, args.preset, repeats))
    report["load_after"] = os.getloadavg()
    print_report(report, args.json)
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="one short repeat per task")
    ap.add_argument("--wrapper", action="store_true",
                    help="EventCameraWrapper against the unwrapped env rendering each step")
    ap.add_argument("--envs", default="Pusher-v5,Reacher-v5",
                    help="--wrapper: stock Gymnasium MuJoCo env ids, comma-separated")
    ap.add_argument("--width", type=int, default=64, help="--wrapper: image width, px")
    ap.add_argument("--height", type=int, default=None, help="--wrapper: (default: width)")
    ap.add_argument("--steps", type=int, default=100, help="--wrapper: timed steps")
    ap.add_argument("--preset", default="physical", help="--wrapper: the emulator preset")
    ap.add_argument("--task", choices=("nav", "arm", "both"), default="both")
    ap.add_argument("--condition", default="nominal")
    ap.add_argument("--scenario", default=None)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--episode-s", type=float, default=None,
                    help="episode length (default: nav 10 s, arm 2 s; --quick: 2 s)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--json", metavar="FILE", help="write the results here")
    args = ap.parse_args(argv)
    if args.wrapper:
        return main_wrapper(args)
    tasks = ("nav", "arm") if args.task == "both" else (args.task,)
    repeats = 1 if args.quick else args.repeats
    report = {"bench": "env", "quick": args.quick, "cpus": os.cpu_count(),
              "load_before": os.getloadavg(), "results": []}
    for task in tasks:
        episode_s = args.episode_s or (2.0 if args.quick else DEFAULT_EPISODE_S[task])
        report["results"].append(bench(task, args.condition, args.scenario, args.seed,
                                       episode_s, repeats))
    report["load_after"] = os.getloadavg()
    print_report(report, args.json)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
