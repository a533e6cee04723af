#!/usr/bin/env python3
"""Fan-out of episodes (issue 17): episodes per second against the number of workers.

eval     `sebvs eval --task nav`, one condition (nominal) and scenario (indoor): the
         expert, the no-action baseline and the three shipped policies, E short episodes
         each (lockstep), timed whole (process start to results.json)
record   `sebvs record topologies/nav_record.toml`, E short episodes (lockstep)

Each runs at workers 1, 2, 4, ... up to os.cpu_count() (the local pool, `--workers N`);
each figure is the median wall time of `--repeats` runs, alternating the worker counts
within a repeat so a slow phase of a shared machine hits all of them. Reported per job:
episodes per second, speed-up against workers 1, and the cores the run kept busy (CPU
seconds of the command and everything it started, per wall second). Ray: each job again
with `--ray --workers 2` (a local Ray started by the command); its overhead per episode is
(Ray wall - pool wall at 2 workers) / episodes, as a fraction of an episode's wall time at
one worker, with and without Ray's start-up (timed alone: ray.init + shutdown). The load
average before and after each job is recorded: on a shared machine the speed-up is
depressed by whatever else runs.

Sizes: the default (5 runs x 4 eval episodes, 8 recorded, 4 s each) and --quick are
small, so a topology's fixed start-up (processes, imports, MuJoCo compile, GL contexts:
about 1.5 s, paid once per worker) weighs on them; `--size paper` records issue 18's
yardstick instead, the paper's nav set of 70 episodes of 30 s (about 6 min at one worker
here), where it is amortised as in a real recording (record only: `--jobs record`);
`--size cores` records 4 episodes of 10 s per core (64 on 16 cores), the size at which a
many-core machine's top worker count still plays whole waves after its start-up.

startup  where a worker's time goes before and between its episodes (issue 37), from one
         `sebvs record --workers W` per worker count (3 episodes per worker): the driver
         (command start to the first worker's actors spawned: the CLI's imports, the pool,
         the topology's load), then per worker from its run.json: actors (spawned to all
         ready: each actor's imports, MuJoCo compile, GL context, in parallel processes),
         clock (ready to the clock's start), first episode (clock start to its file),
         episodes after (the gaps between a worker's later episode files); medians over
         workers and repeats. `per_worker_startup_s` = actors + clock. Beside it, the
         pieces timed one after the other in one fresh process (`components`): the imports
         in four groups (the runtime; mujoco and the scenes; OpenCV, h5py and the
         emulator; torch, which only a policy imports), the nav scene's MuJoCo compile, a
         GL context with its first 160 px render.

Targets (issue 17): speed-up at 2 workers >= 1.7x on a 2-core machine, >= 0.8 x workers on
16 cores; Ray's overhead per episode < 5 % of an episode's wall time. Issue 37: per-worker
start-up <= 1 s at 2 workers here.

    tools/bench/bench_scale.py [--quick | --size paper|cores] [--jobs eval,record,startup] [--repeats N]
                         [--json FILE] [--no-ray]
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from tools.benchio import print_report  # noqa: E402


# episodes and episode seconds per job: eval (per run) and record
SIZES = {"quick": {"eval": (2, 2.0), "record": (4, 2.0)},
         "default": {"eval": (4, 4.0), "record": (8, 4.0)},
         "paper": {"eval": (4, 4.0), "record": (70, 30.0)},
         # four recorded episodes per core: at every worker count each worker plays whole
         # waves, and the top count still plays four episodes after its start-up
         "cores": {"eval": (4, 4.0), "record": (4 * (os.cpu_count() or 1), 10.0)}}


def worker_counts() -> list[int]:
    """1, 2, 4, ... and the core count itself."""
    cores = os.cpu_count() or 1
    counts, n = [1], 2
    while n < cores:
        counts.append(n)
        n *= 2
    if cores > 1:
        counts.append(cores)
    return sorted(set(counts))


def children_cpu_s() -> float:
    """CPU seconds (user + system) of every process this one started and waited for, and
    of theirs (each of our commands waits for its workers and actors)."""
    use = resource.getrusage(resource.RUSAGE_CHILDREN)
    return use.ru_utime + use.ru_stime


def timed(cmd: list[str], cwd: Path) -> tuple[float, float]:
    """(wall seconds, CPU seconds) of one command; its output kept only when it fails."""
    cpu0, t0 = children_cpu_s(), time.monotonic()
    proc = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True)
    wall, cpu = time.monotonic() - t0, children_cpu_s() - cpu0
    if proc.returncode != 0:
        tail = "\n".join((proc.stdout + proc.stderr).splitlines()[-15:])
        raise RuntimeError(f"{' '.join(cmd)} failed ({proc.returncode}):\n{tail}")
    return wall, cpu


def eval_cmd(out: Path, episodes: int, episode_s: float, fanout: list[str]) -> list[str]:
    return [sys.executable, "-m", "sebvs.cli", "eval", "--task", "nav", "--conditions",
            "nominal", "--scenarios", "indoor", "--episodes", str(episodes),
            "--set", f"sim.episode_s={episode_s}", "--out", str(out), *fanout]


def record_cmd(out: Path, episodes: int, episode_s: float, fanout: list[str]) -> list[str]:
    return [sys.executable, "-m", "sebvs.cli", "record", "topologies/nav_record.toml",
            "--episodes", str(episodes), "--out", str(out), "--runs-dir",
            str(out.parent / "runs"), "--quiet", "--set", f"sim.episode_s={episode_s}",
            *fanout]


COMPONENTS_PROBE = r"""
import json, os, sys, time
t = {}
t0 = time.perf_counter()
import sebvs.runtime.worker, sebvs.runtime.node  # noqa  (numpy, zmq, msgpack)
t["import_runtime_s"] = time.perf_counter() - t0
t0 = time.perf_counter()
import mujoco, sebvs.sim  # noqa
t["import_mujoco_sim_s"] = time.perf_counter() - t0
t0 = time.perf_counter()
import cv2, sebvs.dvs.emulator, sebvs.data.episode  # noqa  (OpenCV, h5py)
t["import_dvs_data_s"] = time.perf_counter() - t0
t0 = time.perf_counter()
import torch  # noqa  (the policy's only: a recording imports none)
t["import_torch_s"] = time.perf_counter() - t0
from sebvs.sim import make_scene
from sebvs.sim.render import FrameRenderer
t0 = time.perf_counter()
model = make_scene("nav", width=160, height=160).compile()
data = mujoco.MjData(model)
mujoco.mj_forward(model, data)
t["mujoco_compile_s"] = time.perf_counter() - t0
t0 = time.perf_counter()
renderer = FrameRenderer(model, 160, 160)
renderer.update(data, "front")
renderer.rgb()
t["gl_context_first_render_s"] = time.perf_counter() - t0
print(json.dumps(t))
"""


def components() -> dict:
    """imports, MuJoCo compile, GL context + first render, in one fresh process."""
    out = subprocess.run([sys.executable, "-c", COMPONENTS_PROBE], cwd=ROOT, text=True,
                         capture_output=True, timeout=300,
                         env=dict(os.environ, MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl")))
    if out.returncode:
        raise RuntimeError(f"components probe failed:\n{out.stderr[-2000:]}")
    return {k: round(v, 3) for k, v in json.loads(out.stdout.splitlines()[-1]).items()}


def startup_run(workers: int, per_worker: int, episode_s: float, tmp: Path) -> dict:
    """One `sebvs record --workers W`: the driver, and per worker actors / clock / first
    episode / episodes after, in seconds (see the module's docstring)."""
    from sebvs.scale import split_episodes
    where = Path(tempfile.mkdtemp(prefix=f"startup-{workers}-", dir=tmp))
    n = per_worker * workers
    t0 = time.time()
    subprocess.run(record_cmd(where / "data", n, episode_s, ["--workers", str(workers)]),
                   cwd=ROOT, check=True, stdout=subprocess.DEVNULL)
    infos = [json.loads(p.read_text()) for p in (where / "runs").glob("*/run.json")]
    if len(infos) != workers:
        raise RuntimeError(f"{len(infos)} run.json files for {workers} workers")
    done = {int(p.stem.split("_")[1]): p.stat().st_mtime
            for p in (where / "data").glob("episode_*.h5")}
    clocks = sorted(i["clock_started_at"] for i in infos)
    shards = [sorted(done[k] for k in range(a, b)) for a, b in split_episodes(0, n, workers)]
    # the worker whose clock started k-th finished its first episode k-th: pair them so
    firsts = sorted(s[0] for s in shards)
    return {
        "driver_s": min(i["spawned_at"] for i in infos) - t0,
        "actors_s": [max(i["ready_at"].values()) - i["spawned_at"] for i in infos],
        "clock_s": [i["clock_started_at"] - max(i["ready_at"].values()) for i in infos],
        "first_episode_s": [f - c for f, c in zip(firsts, clocks)],
        "episode_after_s": [b - a for s in shards for a, b in zip(s, s[1:])],
    }


def bench_startup(counts: list[int], per_worker: int, episode_s: float, repeats: int,
                  tmp: Path) -> dict:
    runs = {w: [] for w in counts}
    for r in range(repeats):
        for w in (counts if r % 2 == 0 else counts[::-1]):
            runs[w].append(startup_run(w, per_worker, episode_s, tmp))
            print(f"startup repeat {r + 1}/{repeats}, {w} workers: per worker "
                  f"{statistics.median(runs[w][-1]['actors_s']):.2f} s to ready",
                  file=sys.stderr, flush=True)
    rows = []
    for w, rs in runs.items():
        med = {k: round(statistics.median(
            v for r in rs for v in (r[k] if isinstance(r[k], list) else [r[k]])), 3)
            for k in rs[0]}
        rows.append({"workers": w, "episode_s": episode_s, **med,
                     "per_worker_startup_s": round(med["actors_s"] + med["clock_s"], 3)})
    return {"job": "startup", "rows": rows, "components": components()}


def ray_start_s() -> float | None:
    """Seconds to start and stop a local Ray (what `--ray` pays once per command)."""
    code = ("import time, ray; t = time.monotonic(); "
            "ray.init(include_dashboard=False, log_to_driver=False); ray.shutdown(); "
            "print(time.monotonic() - t)")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    return float(proc.stdout.split()[-1]) if proc.returncode == 0 else None


def load() -> list[float]:
    return [round(x, 2) for x in os.getloadavg()]


def bench_job(name: str, make_cmd, episodes_total: int, episodes: int, episode_s: float,
              counts: list[int], repeats: int, tmp: Path, ray: bool) -> dict:
    variants = [(f"workers {n}", [] if n == 1 else ["--workers", str(n)]) for n in counts]
    if ray:
        variants.append(("ray workers 2", ["--ray", "--workers", "2"]))
    walls: dict[str, list[float]] = {label: [] for label, _ in variants}
    cpus: dict[str, list[float]] = {label: [] for label, _ in variants}
    row: dict = {"job": name, "episodes": episodes_total, "episode_s": episode_s,
                 "load_before": load()}
    for r in range(repeats):
        for label, fanout in variants:      # alternating within a repeat
            out = tmp / f"{name}-{label.replace(' ', '')}-{r}"
            wall, cpu = timed(make_cmd(out, episodes, episode_s, fanout), ROOT)
            walls[label].append(round(wall, 2))
            cpus[label].append(round(cpu, 2))
            busy = "" if label.startswith("ray") else f", {cpu / wall:.2f} cores busy"
            print(f"{name} [{label}] {wall:.1f} s, {episodes_total / wall:.3f} "
                  f"episodes/s{busy} (load {load()[0]})", flush=True)
    row["load_after"] = load()
    w1 = statistics.median(walls["workers 1"])
    row["runs"] = {}
    for label, _ in variants:
        med = statistics.median(walls[label])
        row["runs"][label] = {"wall_s": walls[label], "median_wall_s": round(med, 2),
                              # CPU seconds per wall second: how many cores the run kept
                              # busy. Not for Ray: its tasks run in Ray's worker processes,
                              # which are not this command's children
                              "cpu_s": None if label.startswith("ray") else cpus[label],
                              "cores_busy": None if label.startswith("ray") else round(
                                  statistics.median(c / w for c, w in
                                                    zip(cpus[label], walls[label])), 2),
                              "episodes_per_s": round(episodes_total / med, 4),
                              "speedup": round(w1 / med, 3)}
    if ray:
        pool = statistics.median(walls["workers 2"])
        ray_wall = statistics.median(walls["ray workers 2"])
        episode_wall = w1 / episodes_total       # one episode's wall time, one worker
        start = ray_start_s()
        per_ep = (ray_wall - pool) / episodes_total
        row["ray_overhead"] = {
            "per_episode_s": round(per_ep, 3),
            "fraction_of_episode": round(per_ep / episode_wall, 4),
            "ray_start_s": None if start is None else round(start, 2),
            "per_episode_s_without_start": None if start is None
            else round((ray_wall - pool - start) / episodes_total, 3),
            "fraction_without_start": None if start is None
            else round((ray_wall - pool - start) / episodes_total / episode_wall, 4)}
    return row


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--quick", action="store_true",
                    help="2 eval episodes per run and 4 recorded, 2 s each, one repeat")
    ap.add_argument("--size", choices=sorted(SIZES), default="default",
                    help="episodes per job: default 4 per eval run and 8 recorded, 4 s each; "
                         "paper: 70 recorded of 30 s (issue 18's nav set); cores: 4 "
                         "recorded of 10 s per core (64 on 16 cores), for a many-core "
                         "machine's speed-up (both keep the eval job's default size)")
    ap.add_argument("--jobs", default="eval,record,startup",
                    help="which jobs, comma-separated (eval, record, startup; default all)")
    ap.add_argument("--repeats", type=int, default=0,
                    help="runs per worker count, median reported (default 1 quick, else 3)")
    ap.add_argument("--json", metavar="FILE", help="write the results here")
    ap.add_argument("--no-ray", action="store_true", help="skip the Ray comparison")
    args = ap.parse_args()
    repeats = args.repeats or (1 if args.quick else 3)
    jobs = [j for j in args.jobs.split(",") if j]
    unknown = [j for j in jobs if j not in ("eval", "record", "startup")]
    if unknown or not jobs:
        ap.error(f"--jobs: {', '.join(unknown) or 'none'}: give eval, record, startup")
    if args.quick and args.size != "default":
        ap.error("--quick and --size: give one")
    size = SIZES["quick" if args.quick else args.size]
    ray = not args.no_ray
    if ray:
        try:
            import ray as _  # noqa: F401
        except ImportError:
            print("note: Ray not installed (pip install -e .[ray]); no Ray figures",
                  flush=True)
            ray = False
    counts = worker_counts()
    report: dict = {"config": {"quick": args.quick, "size": "quick" if args.quick
                               else args.size, "repeats": repeats,
                               "statistic": "median", "cpu_count": os.cpu_count(),
                               "worker_counts": counts, "clock": "lockstep"},
                    "jobs": []}
    # five runs per condition: expert, no-action baseline, rgb, event, rgb+event
    eval_runs = 5
    with tempfile.TemporaryDirectory(prefix="bench_scale-") as tmp:
        tmp = Path(tmp)
        if "eval" in jobs:
            eps, episode_s = size["eval"]
            report["jobs"].append(bench_job("eval", eval_cmd, eval_runs * eps, eps,
                                            episode_s, counts, repeats, tmp, ray))
        if "record" in jobs:
            eps, episode_s = size["record"]
            report["jobs"].append(bench_job("record", record_cmd, eps, eps, episode_s,
                                            counts, repeats, tmp, ray))
        if "startup" in jobs:
            report["jobs"].append(bench_startup(counts, 3, size["record"][1], repeats, tmp))
            rows = {r["workers"]: r for r in report["jobs"][-1]["rows"]}
            if 2 in rows:
                got = rows[2]["per_worker_startup_s"]
                report.setdefault("targets", {})["per_worker_startup_s at 2 workers"] = {
                    "target": 1.0, "got": got, "met": got <= 1.0}
    print_report(report, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
