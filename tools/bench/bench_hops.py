#!/usr/bin/env python3
"""Per-hop latency of the runtime against raw pyzmq, measured side by side in one run.

Per hop = from the sender's send call to the start of the receiver's handler. The
runtime case runs two actor processes under the supervisor (payload written in place
into the shared-memory slot, as a renderer does); the baseline is two plain processes
with pyzmq over ipc://, zero-copy send, no asyncio. Both are paced identically and
placed identically on the CPUs.

Two placements, each repeated (runtime and baseline alternate, so each ratio is taken
side by side): "unpinned", where the OS places the four threads of a hop (each side's
main and ZeroMQ I/O thread) as it likes, and "pinned", each side on its own CPU (the
topology's `cpus` key; the baseline's processes pinned the same way). Figures are the
medians over the repeats of each repeat's p50 / p99 / ratio.

    tools/bench/bench_hops.py [--quick] [--repeats N] [--cpus SRC,DST|none] --json out/bench_hops.json
"""
from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import zmq

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from sebvs.runtime.profiler import ProfileCollector  # noqa: E402
from sebvs.runtime.supervisor import Supervisor  # noqa: E402
from sebvs.runtime.topology import load_topology  # noqa: E402
from sebvs.runtime.worker import pin_process  # noqa: E402
from tools.benchio import print_report  # noqa: E402

SIZES = (64, 307_200, 1_228_800, 4_194_304)
# Pacing per size, the same for runtime and baseline. Raw pyzmq copies a 4 MB payload
# through the socket in about 1 ms here, so at a 1 ms pace it queues and its "latency"
# grows without bound (we saw p50s of 0.6 s): that would measure a backlog, not a hop.
PACING_MS = {64: 1.0, 307_200: 1.0, 1_228_800: 1.0, 4_194_304: 4.0}
PROFILED_BYTES = 1_228_800   # also measured with `sebvs profile`'s collector attached

TOPOLOGY = """
[topology]
name = "bench-hops"
clock = "realtime"

[actors.source]
run = "actors.bench:PayloadSource"
nbytes = {nbytes}
count = {count}
interval_ms = {interval_ms}
{source_cpus}
[actors.sink]
run = "actors.bench:LatencySink"
inputs = {{ payload = {{ from = "source/payload", queue = 64 }} }}
path = "{path}"
{sink_cpus}"""


def _cpus_line(cpu: int | None) -> str:
    return "" if cpu is None else f"cpus = [{cpu}]\n"


def run_runtime(nbytes: int, count: int, interval_ms: float, tmp: Path,
                cpus: tuple[int, int] | None = None, profile: bool = False) -> np.ndarray:
    """Hop latencies in ns through two actor processes; ``cpus`` = (source, sink) or None."""
    src, dst = cpus or (None, None)
    path = tmp / f"lat-{nbytes}-{int(profile)}.npy"
    topo_path = tmp / f"hops-{nbytes}.toml"
    topo_path.write_text(TOPOLOGY.format(nbytes=nbytes, count=count, interval_ms=interval_ms,
                                         path=path, source_cpus=_cpus_line(src),
                                         sink_cpus=_cpus_line(dst)))
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


def _baseline_receiver(endpoint: str, n: int, cpu: int | None, queue) -> None:
    if cpu is not None:
        pin_process([cpu])          # before the context: its I/O thread inherits it
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


def _baseline_sender(endpoint: str, nbytes: int, n: int, interval_ms: float,
                     cpu: int | None) -> None:
    if cpu is not None:
        pin_process([cpu])
    ctx = zmq.Context()
    sock = ctx.socket(zmq.PUSH)
    sock.connect(endpoint)
    payload = np.arange(nbytes, dtype=np.uint8)
    period = int(interval_ms * 1e6)
    t_next = time.monotonic_ns()
    for _ in range(n):
        sock.send_multipart([str(time.monotonic_ns()).encode(), payload], copy=False)
        t_next += period
        while (delay := t_next - time.monotonic_ns()) > 0:
            time.sleep(delay / 1e9)
    sock.close(linger=5000)
    ctx.term()


def run_baseline(nbytes: int, count: int, interval_ms: float, tmp: Path,
                 cpus: tuple[int, int] | None = None, warmup: int = 50) -> np.ndarray:
    """Hop latencies in ns of raw pyzmq between two processes, placed like the runtime's."""
    src, dst = cpus or (None, None)
    endpoint = f"ipc://{tmp}/baseline.sock"
    queue = mp.Queue()
    receiver = mp.Process(target=_baseline_receiver, args=(endpoint, warmup + count, dst, queue))
    receiver.start()
    queue.get(timeout=10)
    sender = mp.Process(target=_baseline_sender,
                        args=(endpoint, nbytes, warmup + count, interval_ms, src))
    sender.start()
    try:
        out = queue.get(timeout=count * interval_ms / 1e3 + 60)
    finally:
        sender.join(10)
        receiver.join(10)
        for proc in (sender, receiver):
            if proc.is_alive():
                proc.kill()
    return out[warmup:]


def one_repeat(nbytes: int, count: int, interval_ms: float, tmp: Path,
               cpus: tuple[int, int] | None, base_pace_ms: float) -> dict:
    """Runtime then baseline for one size and placement: p50/p99 in us, their ratio."""
    rt = run_runtime(nbytes, count, interval_ms, tmp, cpus) / 1e3
    base = run_baseline(nbytes, count, interval_ms, tmp, cpus) / 1e3
    rep = {"runtime_p50_us": np.median(rt), "runtime_p99_us": np.percentile(rt, 99),
           "baseline_p50_us": np.median(base), "baseline_p99_us": np.percentile(base, 99),
           "ratio_p50": np.median(rt) / np.median(base)}
    if interval_ms != base_pace_ms:
        # the runtime alone at the small payloads' pace, for the flatness target:
        # a longer idle between messages costs a deeper wake-up, not payload work
        rep["runtime_p50_us_at_base_pace"] = np.median(
            run_runtime(nbytes, count, base_pace_ms, tmp, cpus)) / 1e3
    return {k: float(v) for k, v in rep.items()}


def summarise(nbytes: int, count: int, interval_ms: float, reps: list[dict]) -> dict:
    """Medians over the repeats, and each repeat's p50 and ratio to show the spread."""
    row = {"bytes": nbytes, "count": count, "repeats": len(reps), "interval_ms": interval_ms}
    for key in reps[0]:
        row[key] = round(float(np.median([r[key] for r in reps])), 3 if "ratio" in key else 1)
    row["runtime_p50_us_each"] = [round(r["runtime_p50_us"], 1) for r in reps]
    row["baseline_p50_us_each"] = [round(r["baseline_p50_us"], 1) for r in reps]
    row["ratio_p50_each"] = [round(r["ratio_p50"], 3) for r in reps]
    return row


def targets(rows: list[dict]) -> dict:
    by = {r["bytes"]: r for r in rows}
    return {"p50_1228800_le_100us": by[1_228_800]["runtime_p50_us"] <= 100,
            "ratio_1228800_le_0.6": by[1_228_800]["ratio_p50"] <= 0.6,
            "p50_4MB_le_1.5x_64B": by[4_194_304].get("runtime_p50_us_at_base_pace",
                                                     by[4_194_304]["runtime_p50_us"])
            <= 1.5 * by[64]["runtime_p50_us"]}


def targets_each_repeat(reps: dict, label: str, repeats: int) -> list[dict]:
    """The targets judged on each repeat alone: how often one stretch of the run meets them."""
    return [targets([{"bytes": n, **reps[(label, n)][r]} for n in SIZES]) for r in range(repeats)]


def run_all(args, tmp: Path, placements: dict) -> tuple[dict[str, list[dict]], dict]:
    """Every size in every placement, repeat after repeat.

    The repeats are the outer loop: this machine's wake-up cost drifts in phases of tens of
    seconds (raw pyzmq's own 64 B p50 has read 43 us and 125 us on the same day), so each
    size's median is taken over repeats spread across the whole run instead of over one
    stretch of it.
    """
    intervals = {n: args.interval_ms or PACING_MS[n] for n in SIZES}
    reps = {(label, n): [] for label in placements for n in SIZES}
    for r in range(args.repeats):
        for nbytes in SIZES:
            interval = intervals[nbytes]
            for label, cpus in placements.items():
                rep = one_repeat(nbytes, args.count, interval, tmp, cpus, intervals[64])
                if nbytes == PROFILED_BYTES and cpus is None:
                    # right after the unattached run, so the two meet the same conditions
                    rep["runtime_p50_us_profiler_attached"] = float(np.median(run_runtime(
                        nbytes, args.count, interval, tmp, cpus, profile=True))) / 1e3
                reps[(label, nbytes)].append(rep)
                print(json.dumps({"repeat": r, "placement": label, "bytes": nbytes,
                                  **{k: round(v, 2) for k, v in rep.items()}}),
                      file=sys.stderr, flush=True)
    rows = {label: [summarise(n, args.count, intervals[n], reps[(label, n)]) for n in SIZES]
            for label in placements}
    return rows, {label: targets_each_repeat(reps, label, args.repeats) for label in placements}


def resolve_cpus(text: str, allowed: list[int]) -> tuple[int, int] | None:
    """--cpus: "auto" (the last and the first CPU, None on a 1-CPU machine), "none", or SRC,DST."""
    if text == "none" or (text == "auto" and len(allowed) < 2):
        return None
    if text == "auto":
        return allowed[-1], allowed[0]
    try:
        src, dst = (int(c) for c in text.split(","))
    except ValueError:
        raise ValueError(f"--cpus {text!r}: expected SRC,DST (e.g. 1,0), auto or none") from None
    if src not in allowed or dst not in allowed:
        raise ValueError(f"--cpus {text!r}: this process may use CPUs {allowed}")
    return src, dst


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--quick", action="store_true",
                    help="300 messages per size, one repeat (< 40 s)")
    ap.add_argument("--count", type=int, default=None, help="messages per size (default 2000)")
    ap.add_argument("--repeats", type=int, default=None,
                    help="runs per size and placement (default 5, 1 with --quick)")
    ap.add_argument("--interval-ms", type=float, default=None,
                    help="pacing between messages, same for both (default: 1 ms, 4 ms for "
                         "4 MB, so raw pyzmq does not queue)")
    ap.add_argument("--cpus", default="auto", metavar="SRC,DST",
                    help="CPUs of the sender and the receiver for the pinned placement "
                         "(default auto: the last and the first this process may use; "
                         "none: measure the unpinned placement only)")
    ap.add_argument("--json", metavar="FILE", help="write the results here")
    args = ap.parse_args()
    args.count = args.count or (300 if args.quick else 2000)
    args.repeats = args.repeats or (1 if args.quick else 5)
    allowed = sorted(os.sched_getaffinity(0))
    try:
        pinned = resolve_cpus(args.cpus, allowed)
    except ValueError as exc:
        ap.error(str(exc))
    with tempfile.TemporaryDirectory(prefix="bench-hops-") as tmp:
        tmp = Path(tmp)
        placements = {"unpinned": None, **({"pinned": pinned} if pinned else {})}
        rows, each = run_all(args, tmp, placements)
        unpinned_rows, pinned_rows = rows["unpinned"], rows.get("pinned")
    by = {r["bytes"]: r for r in unpinned_rows}
    report = {
        "sizes": unpinned_rows,
        "pinned": None if pinned is None else {"source_cpu": pinned[0], "sink_cpu": pinned[1],
                                               "sizes": pinned_rows},
        "profiler_attached": {"bytes": PROFILED_BYTES, "placement": "unpinned",
                              "runtime_p50_us": by[PROFILED_BYTES][
                                  "runtime_p50_us_profiler_attached"],
                              "without_p50_us": by[PROFILED_BYTES]["runtime_p50_us"]},
        "targets": {"unpinned": targets(unpinned_rows),
                    **({"pinned": targets(pinned_rows)} if pinned else {})},
        # in how many repeats each placement met all three targets on that repeat's figures
        "repeats_meeting_all": {label: sum(all(t.values()) for t in ts)
                                for label, ts in each.items()},
        "targets_each_repeat": each,
        "per_hop": "sender's send call -> receiver's handler start",
        "cpus_available": allowed,
    }
    print_report(report, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
