#!/usr/bin/env python3
"""A long realtime run, watched: does anything grow that should not?

Runs topologies/nav_policy.toml on the realtime clock (episodes back to back) with the
latency profiler attached the whole time, and every --every seconds samples, per actor
process: resident memory (RSS), open file descriptors; for the run: the shared-memory
rings in /dev/shm and the sim's control deadline misses. Printed as it goes; with --json
the series and a summary:

  rss_growth_mb      per process, the last sample minus the first after warm-up
                     (the first --warmup seconds: imports, models, first episode)
  fds_constant       per process, whether the descriptor count stayed the same
  rings_constant     whether the run's ring files stayed the same number
  deadline_misses    the sim's count (and its total ticks) at the end
  profiler_batches   telemetry batches the attached profiler took (it must not disturb)

    tools/checks/soak.py [--minutes M] [--every S] [--warmup S] [--json FILE] [--set K=V ...]
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from sebvs.runtime.profiler import ProfileCollector  # noqa: E402
from sebvs.runtime.shm import SHM_DIR  # noqa: E402
from sebvs.runtime.supervisor import Supervisor  # noqa: E402
from sebvs.runtime.topology import load_topology  # noqa: E402


def proc_sample(pid: int) -> dict | None:
    """RSS (bytes) and open descriptors of a live process; None when it is gone."""
    try:
        rss = 0
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                rss = int(line.split()[1]) * 1024
        return {"rss": rss, "fds": len(os.listdir(f"/proc/{pid}/fd"))}
    except OSError:
        return None


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--minutes", type=float, default=30.0)
    ap.add_argument("--every", type=float, default=30.0, help="seconds between samples")
    ap.add_argument("--warmup", type=float, default=60.0,
                    help="seconds before the baseline sample (default 60)")
    ap.add_argument("--topology", default=str(ROOT / "topologies" / "nav_policy.toml"))
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--json", metavar="FILE")
    args = ap.parse_args()
    seconds = args.minutes * 60
    overrides = ['topology.clock="realtime"', "sim.episodes=100000", *args.set]
    topo = load_topology(args.topology, overrides)
    sup = Supervisor(topo, runs_dir=ROOT / "runs", echo=lambda s: None)
    series: list[dict] = []
    prof = None
    t0 = time.monotonic()
    try:
        sup.start()
        prof = ProfileCollector(sup.info, sup.ctx)
        batches = 0
        next_sample = t0
        while time.monotonic() - t0 < seconds:
            batches += prof.poll(0.5)
            if sup._reap():
                print("soak: an actor ended; stopping", file=sys.stderr)
                break
            now = time.monotonic()
            if now < next_sample:
                continue
            next_sample = now + args.every
            procs = {name: proc_sample(p.popen.pid) for name, p in sup.procs.items()
                     if p.popen is not None}
            rings = len([f for f in os.listdir(SHM_DIR)
                         if f.startswith(f"sebvs-{sup.run_id}-")])
            sim = sup.request("sim", {"cmd": "stats"}) or {}
            deadlines = ((sim.get("result") or {}).get("actor_stats") or {}).get("deadlines")
            row = {"t_s": round(now - t0, 1), "procs": procs, "rings": rings,
                   "deadlines": deadlines, "profiler_batches": batches}
            series.append(row)
            rss = sum((v or {}).get("rss", 0) for v in procs.values()) / 2 ** 20
            print(f"soak {row['t_s']:7.1f} s: RSS {rss:7.1f} MB in {len(procs)} processes, "
                  f"fds {sum((v or {}).get('fds', 0) for v in procs.values())}, rings "
                  f"{rings}, deadlines {deadlines}", flush=True)
    finally:
        if prof is not None:
            prof.socket.close(linger=0)   # the supervisor's context ends only once it is closed
        sup.stop()
    base = next((r for r in series if r["t_s"] >= args.warmup), series[0] if series else None)
    last = series[-1] if series else None
    summary = {}
    if base and last:
        names = [n for n in base["procs"] if base["procs"][n] and last["procs"].get(n)]
        summary = {
            "minutes": round(last["t_s"] / 60, 2), "baseline_t_s": base["t_s"],
            "rss_growth_mb": {n: round((last["procs"][n]["rss"] - base["procs"][n]["rss"])
                                       / 2 ** 20, 2) for n in names},
            "fds_constant": {n: len({r["procs"][n]["fds"] for r in series
                                     if r["t_s"] >= base["t_s"] and r["procs"].get(n)}) == 1
                             for n in names},
            "rings_constant": len({r["rings"] for r in series if r["t_s"] >= base["t_s"]}) == 1,
            "deadline_misses": last["deadlines"], "profiler_batches": last["profiler_batches"]}
    print(json.dumps(summary, indent=1))
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps({"summary": summary, "series": series},
                                              indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
