#!/usr/bin/env python3
"""The closed loop at the speed of its compute (issue 18): sensor-to-action latency beside
the chain's own compute, and the nav pipeline and recording throughput, in one run.

loop      topologies/nav_policy.toml (sim, camera, emulator, accumulator, the shipped
          rgb+event policy, tracker) on the **realtime** clock, the profiler attached,
          on the sensor pair the shipped topology runs (default: its camera.sensor,
          "physical", the topology as it ships), or the one `--sensor` names with the
          checkpoints trained on it: `--sensor ideal8` for the 8-bit path the runtime's
          anchors were set on (docs/runtime.md). Every row of the output names its
          "sensor".
          The sensor-to-action chain runs from the sim's send of a state to the end of
          its on_action handler (the action applied), through whichever input completed
          the tick: sim > camera > emulator > accumulator > policy > sim when the events
          come last, sim > camera > policy > sim when the frame does (the physical pair
          emits its frame last); every tick counts once (ProfileCollector.loop_latency),
          `paths` says how many went each way. Beside it, the chain's own compute on the
          most frequent path's instances: the handler time along the chain (each actor's
          handler start to the emit that carried the chain on; the sim's whole
          on_action), and their ratio (the issue's figure: <= 1.7x). Per hop, p50 and share of the chain of queueing,
          wake-up, transport and handler (definitions: sebvs/runtime/chainsplit.py,
          docs/runtime.md). The headline figures leave out the first second (the
          camera compiles its model and renderer on the first state, and the samples
          behind it queue); `all` keeps it. Deadline: one control period
          (1 / sim.control_hz); an action later than that, or a control tick that got
          none, is a miss (counted over the whole run, warm-up apart as well); the sim's
          own count (sebvs/runtime/deadlines.py, its "deadlines" event) is kept beside it.
          Three variants, side by side in every repeat: `plain` (every actor at the
          default priority, the policy eager: topology.loop_priority="none",
          policy.graph="eager"), `realtime` (the loop's actors at SCHED_FIFO, the policy
          eager) and `shipped` (what a realtime run gets by default since issue 37: the
          loop's actors at SCHED_FIFO and the policy on its frozen inference graph,
          sebvs/policy/graph.py). The targets are read on `shipped`. `--load N` runs N
          CPU-bound processes at the default priority during the loop parts, so the tail
          is measured on a machine that is loaded on purpose, not by chance.
pipeline  nav expert + emulator + accumulator, lockstep, dvs 200 Hz, on the same sensor
          pair: real-time factor (tools/bench/bench_sim.py's bench_pipeline).
record    `sebvs record topologies/nav_record.toml` at dvs 200 Hz on the same sensor pair:
          real-time factor of the whole command, start-up included
          (tools/bench/bench_sim.py's bench_record).

`--variant NAME` (repeatable) runs only those loop variants (e.g. `--variant shipped`).

Each part runs --repeats times, one after the other; the headline figures are medians
over the repeats, each repeat's figure is kept beside them. The machine's load average
is recorded before and after: on a shared machine read the ratios, not the absolutes.

    tools/bench/bench_loop.py [--quick] [--repeats N] [--load N] [--loop-only]
                              [--sensor ideal8|physical] [--variant NAME ...]
                              [--set A.K=V] [--json OUT]
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from sebvs.runtime.profiler import LOOP_TARGETS_MS, ProfileCollector  # noqa: E402
from sebvs.runtime.supervisor import Supervisor  # noqa: E402
from sebvs.runtime.topology import load_topology  # noqa: E402
from sebvs.sensor_pairs import SENSORS, topology_overrides  # noqa: E402
from tools.bench.bench_sim import bench_pipeline, bench_record, sensor_of  # noqa: E402
from tools.benchio import print_report  # noqa: E402

NAV_POLICY = ROOT / "topologies" / "nav_policy.toml"
# docs/runtime.md, "The loop's priority": on the realtime clock the loop's actors run at
# SCHED_FIFO and the policy on its frozen graph unless told otherwise
VARIANTS = {"plain": ['topology.loop_priority="none"', 'policy.graph="eager"'],
            "realtime": ['policy.graph="eager"'],
            "shipped": []}
TARGET_VARIANT = "shipped"
BURN = "while True: pass"
TARGETS = {"chain_p50_ms": LOOP_TARGETS_MS["p50"], "chain_p99_ms": LOOP_TARGETS_MS["p99"],
           "chain_over_compute": 1.7,
           "pipeline_x_real_time": 15.0, "record_x_real_time": 10.0}


def bench_closed_loop(seconds: float, warmup_s: float, extra: list = ()) -> dict:
    """nav_policy on the realtime clock for one episode of ``seconds``, profiled.

    The headline figures leave out the chains whose state was sent in the first
    ``warmup_s`` (the camera compiles its model and the policy's first inference warms up
    on the first samples); ``all`` keeps them.
    """
    overrides = ['topology.clock="realtime"', f"sim.episode_s={seconds}", "sim.episodes=1",
                 "sim.linger_s=0.5", *extra]
    topo = load_topology(NAV_POLICY, overrides)
    control_hz = float(topo.actors["sim"].params.get("control_hz", 10.0))
    with tempfile.TemporaryDirectory(prefix="bench-loop-") as tmp:
        sup = Supervisor(topo, runs_dir=tmp, echo=lambda s: None)
        collector = None
        try:
            sup.start()
            collector = ProfileCollector(sup.info)
            sup.wait(seconds + 60, collector.poll)
        finally:
            sup.stop()
            if collector is not None:
                collector.close()
        if sup.failure:
            raise RuntimeError(f"nav_policy failed: {sup.failure.splitlines()[0]}")
    rep = collector.report()
    loop = collector.loop_latency(warmup_s)
    if loop is None:
        raise RuntimeError(f"no closed loop observed after the warm-up "
                           f"(chains: {[c['chain'] for c in rep['chains']]})")
    instances = [i for c in loop["paths"] for i in collector.chain_instances[c]]
    since = loop["since_ns"]
    split = next(s for s in collector.split(since_ns=since) if s["chain"] == loop["chain"])
    if not split["hops"]:
        raise RuntimeError(f"no joined instance of {loop['chain']!r} after the warm-up")
    every = np.array([end - stamps[0][2] for stamps, end, _ in instances], float)
    after = np.array([end - stamps[0][2] for stamps, end, _ in instances
                      if stamps[0][2] >= since], float)
    # deadline: the action for tick k must be applied before tick k+1 (one control period)
    deadline_ns = 1e9 / control_hz
    ticks_sent = {r[2] for r in collector.kept.values()
                  if r[0] == "camera" and r[2] is not None}
    ticks_acted = {r[2] for r in collector.kept.values()
                   if r[0] == "sim" and r[1] == "action" and r[2] is not None}
    late = [i[1] - i[0][0][2] > deadline_ns for i in instances]
    lost = len(ticks_sent - ticks_acted)
    return {
        "chain": loop["chain"], "paths": loop["paths"], "warmup_s": warmup_s,
        "instances": loop["instances"], "split_resolved": split["resolved"],
        "chain_p50_ms": loop["p50_ms"], "chain_p90_ms": _pct_ms(after, 90),
        "chain_p99_ms": loop["p99_ms"], "chain_max_ms": _pct_ms(after, 100),
        "all": {"instances": len(every), "chain_p50_ms": _pct_ms(every, 50),
                "chain_p99_ms": _pct_ms(every, 99), "chain_max_ms": _pct_ms(every, 100),
                "late_in_warmup": sum(x for x, i in zip(late, instances)
                                      if i[0][0][2] < since)},
        "compute_p50_ms": _ms(split["compute_us"]["p50"]),
        "compute_p99_ms": _ms(split["compute_us"]["p99"]),
        "chain_over_compute": _round(split["chain_over_compute_p50"], 2),
        "per_hop": [{"hop": h["hop"],
                     **{c: {"p50_us": _round(h[c]["p50"], 1), "p99_us": _round(h[c]["p99"], 1),
                            "share": _round(h[c]["share"], 3)}
                        for c in ("queueing", "wakeup", "transport", "handler")}}
                    for h in split["hops"]],
        "components": {c: {"p50_us": _round(v["p50"], 1), "p99_us": _round(v["p99"], 1),
                           "share": _round(v["share"], 3)}
                       for c, v in split["components"].items()},
        "deadline": {"period_ms": round(deadline_ns / 1e6, 3), "ticks": len(ticks_sent),
                     "late": sum(late), "without_action": lost, "misses": sum(late) + lost},
        "sim_deadlines": next((e[3] for e in reversed(collector.last_events)
                               if e[0] == "sim" and e[1] == "deadlines"), None),
        "other_chains": {c["chain"]: {"count": c["count"], "p50_ms": _ms(c["p50"]),
                                      "p99_ms": _ms(c["p99"])}
                         for c in rep["chains"] if c["chain"] not in loop["paths"]},
        "skipped": rep["skipped"],
    }


def _ms(us):
    return None if us is None else round(us / 1e3, 3)


def _pct_ms(ns: np.ndarray, q: float):
    return round(float(np.percentile(ns, q)) / 1e6, 3) if ns.size else None


def _round(v, digits):
    return None if v is None else round(v, digits)


def _median(rows: list[dict], key: str):
    vals = [r[key] for r in rows if r.get(key) is not None]
    return round(statistics.median(vals), 3) if vals else None


def summarize_loops(loops: list[dict]) -> dict:
    """One variant's repeats: medians of the headline figures, each repeat kept."""
    best = sorted(loops, key=lambda x: x["chain_p50_ms"])[len(loops) // 2]
    sim = [x["sim_deadlines"] for x in loops if x.get("sim_deadlines")]
    return {
        "sensor": best.get("sensor"),
        "chain": best["chain"], "paths": [x["paths"] for x in loops], "clock": "realtime",
        **{k: _median(loops, k) for k in ("chain_p50_ms", "chain_p99_ms",
                                          "compute_p50_ms", "chain_over_compute")},
        "p99_over_p50": _round(_median(loops, "chain_p99_ms") / _median(loops, "chain_p50_ms"),
                               2) if _median(loops, "chain_p50_ms") else None,
        "warmup_s": 1.0,
        "deadline_misses": [x["deadline"]["misses"] for x in loops],
        "deadline_misses_in_warmup": [x["all"]["late_in_warmup"] for x in loops],
        "sim_deadline_misses": [d.get("misses") for d in sim],
        "sim_action_latency_p99_ms": [_round(d.get("latency_p99_ms"), 2) for d in sim],
        "per_hop_of_median_repeat": best["per_hop"],
        "components_of_median_repeat": best["components"],
        "repeats": loops}


class Burners:
    """N CPU-bound processes at the default priority: a machine loaded on purpose."""

    def __init__(self, n: int) -> None:
        self.n, self.procs = n, []

    def __enter__(self):
        self.procs = [subprocess.Popen([sys.executable, "-c", BURN]) for _ in range(self.n)]
        return self

    def __exit__(self, *exc) -> None:
        for proc in self.procs:
            proc.kill()
            proc.wait()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--quick", action="store_true",
                    help="10 s loop, 5 s pipeline, one 5 s recorded episode, 1 repeat")
    ap.add_argument("--repeats", type=int, default=None, help="default 3, 1 with --quick")
    ap.add_argument("--load", type=int, default=0, metavar="N",
                    help="N busy processes beside the loop parts (default 0)")
    ap.add_argument("--loop-only", action="store_true",
                    help="only the closed loop (every variant), no pipeline or record")
    ap.add_argument("--set", action="append", default=[], metavar="ACTOR.KEY=VALUE",
                    help="a topology override for the loop and record parts (repeatable), "
                         "e.g. camera.luma_scale=0.5 for the paper's 80 px sensor; the "
                         "pipeline part keeps its own settings")
    ap.add_argument("--sensor", choices=SENSORS, default=None,
                    help="the sensor pair of every part, with the checkpoints trained on it: "
                         "physical or ideal8 (the 8-bit path the anchors were set on); "
                         "default: the shipped topologies' own (nav_policy's camera.sensor), "
                         "which they run as shipped; --set lines come after it")
    ap.add_argument("--variant", action="append", choices=list(VARIANTS), default=None,
                    help="only this loop variant (repeatable; default: all three)")
    ap.add_argument("--json", metavar="OUT", help="write the results here")
    args = ap.parse_args()
    repeats = args.repeats or (1 if args.quick else 3)
    variants = {v: VARIANTS[v] for v in VARIANTS if v in (args.variant or VARIANTS)}
    sensor = sensor_of(args.set, args.sensor, NAV_POLICY)
    loop_s, pipe_s, rec_eps, rec_s = (10.0, 5.0, 1, 5.0) if args.quick else (30.0, 20.0, 2, 20.0)
    out: dict = {"config": {"quick": args.quick, "repeats": repeats, "loop_s": loop_s,
                            "pipeline_s": pipe_s, "record_episodes": rec_eps,
                            "record_episode_s": rec_s, "dvs_hz": 200.0, "load": args.load,
                            "variants": {k: v for k, v in variants.items()},
                            "sensor": sensor, "sensor_from": "--sensor" if args.sensor
                            else "topologies/nav_policy.toml as shipped", "sets": args.set,
                            "cpus": os.cpu_count(), "statistic": "median over repeats"},
                 "load_avg_before": list(os.getloadavg())}
    loops = {v: [] for v in variants}
    pipes, recs, notes = [], [], []
    loop_sets = [*([topology_overrides(args.sensor)] if args.sensor else []), *args.set]
    parts = [(f"loop {v}", lambda v=v: bench_closed_loop(loop_s, 1.0, variants[v] + loop_sets),
              loops[v]) for v in variants]
    if not args.loop_only:
        parts += [("pipeline", lambda: bench_pipeline(pipe_s, 200.0, sensor=sensor), pipes),
                  ("record", lambda: bench_record(rec_eps, rec_s, 200.0, sets=args.set,
                                                  sensor=args.sensor), recs)]
    for r in range(repeats):
        # the variants alternate their order, so a slow phase of the machine hits both
        order = parts[:len(variants)][::-1 if r % 2 else 1] + parts[len(variants):]
        for name, fn, rows in order:
            try:
                if name.startswith("loop"):
                    with Burners(args.load):
                        rows.append({"sensor": sensor, **fn()})
                else:
                    rows.append(fn())
            except Exception as exc:    # one part failing still leaves the others' figures
                notes.append(f"repeat {r} {name}: {type(exc).__name__}: {exc}")
            print(f"repeat {r} {name}: " + json.dumps(rows[-1] if rows else None)[:300],
                  file=sys.stderr, flush=True)
    out["load_avg_after"] = list(os.getloadavg())
    for variant, rows in loops.items():
        if rows:
            out[f"loop_{variant}"] = summarize_loops(rows)
    if pipes:
        out["pipeline"] = {"sensor": sensor, "x_real_time": _median(pipes, "real_time_factor"),
                           "repeats": pipes}
    if recs:
        out["record"] = {"sensor": recs[0]["sensor"],
                         "x_real_time": _median(recs, "real_time_factor"), "repeats": recs}
    tuned = out.get(f"loop_{TARGET_VARIANT}", {})
    got = {"chain_p50_ms": tuned.get("chain_p50_ms"),
           "chain_p99_ms": tuned.get("chain_p99_ms"),
           "chain_over_compute": tuned.get("chain_over_compute"),
           "pipeline_x_real_time": out.get("pipeline", {}).get("x_real_time"),
           "record_x_real_time": out.get("record", {}).get("x_real_time")}
    out["targets"] = {k: {"target": t, "got": got[k], "sensor": sensor,
                          "met": None if got[k] is None else
                          (got[k] >= t if k.endswith("real_time") else got[k] <= t)}
                      for k, t in TARGETS.items()}
    out["targets_measured_on"] = (f"loop_{TARGET_VARIANT} (chain figures), load {args.load}, "
                                  f"sensor {sensor}")
    if notes:
        out["notes"] = notes
    print_report(out, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
