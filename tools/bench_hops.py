#!/usr/bin/env python3
"""Per-hop latency of the runtime against raw pyzmq, measured side by side in one run.

Per hop = from the sender's send call to the start of the receiver's handler. The
runtime case runs two actor processes under the supervisor (payload written in place
into the shared-memory slot, as a renderer does); the baseline is two plain processes
with pyzmq over ipc://, zero-copy send, no asyncio. Both are paced identically.

    tools/bench_hops.py [--quick] --json out/bench_hops.json
"""
from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import zmq

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from sebvs.runtime.profiler import ProfileCollector  # noqa: E402
from sebvs.runtime.supervisor import Supervisor  # noqa: E402
from sebvs.runtime.topology import load_topology  # noqa: E402

SIZES = (64, 307_200, 1_228_800, 4_194_304)
# Pacing per size, the same for runtime and baseline. Raw pyzmq copies a 4 MB payload
# through the socket in about 1 ms here, so at a 1 ms pace it queues and its "latency"
# grows without bound (we saw p50s of 0.6 s): that would measure a backlog, not a hop.
PACING_MS = {64: 1.0, 307_200: 1.0, 1_228_800: 1.0, 4_194_304: 4.0}

TOPOLOGY = """
[topology]
name = "bench-hops"
clock = "realtime"

[actors.source]
run = "actors.bench:PayloadSource"
nbytes = {nbytes}
count = {count}
interval_ms = {interval_ms}

[actors.sink]
run = "actors.bench:LatencySink"
inputs = {{ payload = {{ from = "source/payload", queue = 64 }} }}
path = "{path}"
"""


def run_runtime(nbytes: int, count: int, interval_ms: float, tmp: Path,
                profile: bool = False) -> np.ndarray:
    path = tmp / f"lat-{nbytes}-{int(profile)}.npy"
    topo_path = tmp / f"hops-{nbytes}.toml"
    topo_path.write_text(TOPOLOGY.format(nbytes=nbytes, count=count, interval_ms=interval_ms,
                                         path=path))
    sup = Supervisor(load_topology(topo_path), runs_dir=tmp / "runs", echo=lambda s: None)
    collector = None
    try:
        sup.start()
        if profile:
            collector = ProfileCollector(sup.info)
        code = sup.wait(count * interval_ms / 1e3 + 30, collector.poll if collector else None)
    finally:
        sup.stop()
        if collector:
            collector.close()
    if code != 0:
        raise RuntimeError(f"runtime run failed: {sup.failure}")
    lat = np.load(path)
    if lat[-1] != -1:
        raise RuntimeError(f"{-lat[-1] - 1} payloads arrived with the wrong bytes")
    return lat[:-1]


def _baseline_receiver(endpoint: str, n: int, queue) -> None:
    ctx = zmq.Context()
    sock = ctx.socket(zmq.PULL)
    sock.bind(endpoint)
    queue.put("bound")
    out = np.empty(n, np.int64)
    for i in range(n):
        frames = sock.recv_multipart(copy=False)
        out[i] = time.monotonic_ns() - int(frames[0].bytes)
    queue.put(out)
    sock.close()
    ctx.term()


def run_baseline(nbytes: int, count: int, interval_ms: float, tmp: Path, warmup: int = 50):
    endpoint = f"ipc://{tmp}/baseline.sock"
    queue = mp.Queue()
    proc = mp.Process(target=_baseline_receiver, args=(endpoint, warmup + count, queue))
    proc.start()
    queue.get(timeout=10)
    ctx = zmq.Context()
    sock = ctx.socket(zmq.PUSH)
    sock.connect(endpoint)
    payload = np.arange(nbytes, dtype=np.uint8)
    period = int(interval_ms * 1e6)
    t_next = time.monotonic_ns()
    for _ in range(warmup + count):
        sock.send_multipart([str(time.monotonic_ns()).encode(), payload], copy=False)
        t_next += period
        while (delay := t_next - time.monotonic_ns()) > 0:
            time.sleep(delay / 1e9)
    out = queue.get(timeout=60)
    proc.join(10)
    sock.close()
    ctx.term()
    return out[warmup:]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="300 messages per size (< 40 s)")
    ap.add_argument("--count", type=int, default=None, help="messages per size (default 2000)")
    ap.add_argument("--interval-ms", type=float, default=None,
                    help="pacing between messages, same for both (default: 1 ms, 4 ms for "
                         "4 MB, so raw pyzmq does not queue)")
    ap.add_argument("--json", metavar="FILE", help="write the results here")
    args = ap.parse_args()
    count = args.count or (300 if args.quick else 2000)
    results = []
    with tempfile.TemporaryDirectory(prefix="bench-hops-") as tmp:
        tmp = Path(tmp)
        def pace(nbytes: int) -> float:
            return args.interval_ms or PACING_MS[nbytes]

        for nbytes in SIZES:
            interval = pace(nbytes)
            rt = run_runtime(nbytes, count, interval, tmp) / 1e3
            base = run_baseline(nbytes, count, interval, tmp) / 1e3
            row = {"bytes": nbytes, "count": int(rt.size), "interval_ms": interval,
                   "runtime_p50_us": round(float(np.median(rt)), 1),
                   "runtime_p99_us": round(float(np.percentile(rt, 99)), 1),
                   "baseline_p50_us": round(float(np.median(base)), 1),
                   "baseline_p99_us": round(float(np.percentile(base, 99)), 1)}
            row["ratio_p50"] = round(row["runtime_p50_us"] / row["baseline_p50_us"], 3)
            if interval != pace(64):
                # the runtime alone at the small payloads' pace, for the flatness target:
                # a longer idle between messages costs a deeper wake-up, not payload work
                same = run_runtime(nbytes, count, pace(64), tmp) / 1e3
                row["runtime_p50_us_at_base_pace"] = round(float(np.median(same)), 1)
            results.append(row)
            print(json.dumps(row), file=sys.stderr)
        prof = run_runtime(1_228_800, count, pace(1_228_800), tmp, profile=True) / 1e3
    by = {r["bytes"]: r for r in results}
    report = {
        "sizes": results,
        "profiler_attached": {"bytes": 1_228_800,
                              "runtime_p50_us": round(float(np.median(prof)), 1),
                              "runtime_p99_us": round(float(np.percentile(prof, 99)), 1),
                              "without_p50_us": by[1_228_800]["runtime_p50_us"]},
        "targets": {
            "p50_1228800_le_100us": by[1_228_800]["runtime_p50_us"] <= 100,
            "ratio_1228800_le_0.6": by[1_228_800]["ratio_p50"] <= 0.6,
            "p50_4MB_le_1.5x_64B": by[4_194_304].get("runtime_p50_us_at_base_pace",
                                                     by[4_194_304]["runtime_p50_us"])
            <= 1.5 * by[64]["runtime_p50_us"]},
        "per_hop": "sender's send call -> receiver's handler start",
    }
    text = json.dumps(report, indent=2)
    print(text)
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
