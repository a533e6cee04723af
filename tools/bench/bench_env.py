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

    tools/bench/bench_env.py [--quick] [--task nav|arm|both] [--condition C]
                             [--episode-s S] [--repeats N] [--json OUT]
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


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="one short repeat per task")
    ap.add_argument("--task", choices=("nav", "arm", "both"), default="both")
    ap.add_argument("--condition", default="nominal")
    ap.add_argument("--scenario", default=None)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--episode-s", type=float, default=None,
                    help="episode length (default: nav 10 s, arm 2 s; --quick: 2 s)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--json", metavar="FILE", help="write the results here")
    args = ap.parse_args(argv)
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
