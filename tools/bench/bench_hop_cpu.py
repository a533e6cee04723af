#!/usr/bin/env python3
"""CPU cost of the runtime's own work per message: `emit` on one end, reader callback to
handler start on the other.

tools/bench/bench_hops.py times whole hops, which on an idle 2-CPU machine are mostly wake-ups
(raw pyzmq pays those too) and drift with the machine's phases. This benchmark times only
the code the runtime runs, in one process: a sending and a receiving Node joined by a real
ipc:// socket and a real shared-memory ring, the payload written in place as a renderer
does. Three conditions:

  warm        rounds of back-to-back emits, each round then drained from the queue:
              caches warm, ZeroMQ's I/O thread awake (emit: total / count; receive: the
              gap between consecutive handler starts)
  paced       one message at a time, each waited for: emit pays the wake-up signal to
              ZeroMQ's I/O thread, as in a paced pipeline
  after_fill  as paced, with the payload written into its slot before each emit (as
              bench_hops' source and a renderer do): the write evicts the caches. In this
              one process the receiving side meets them evicted too, which across two
              processes on two CPUs only the sender does.

    tools/bench/bench_hop_cpu.py [--quick] [--bytes N] [--count N] [--repeats N] --json out/bench_hop_cpu.json
"""
from __future__ import annotations

import argparse
import asyncio
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import zmq

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from sebvs.runtime.node import Node  # noqa: E402
from tools.benchio import print_report  # noqa: E402

BURST = 32   # messages per warm round: at most inputs.DRAIN_BATCH, so one callback


class _Endpoint:
    """The least an actor must be for a Node: a stop flag and one handler."""

    def __init__(self, node):
        self.stopping = asyncio.Event()
        self.started_ns: list[int] = []

    async def on_payload(self, msg) -> None:
        self.started_ns.append(msg.recv_ns)


def _spec(name: str, tmp: str, outputs: dict | None = None, inputs: dict | None = None) -> dict:
    # the keys Node reads of the spec the supervisor writes (supervisor._plan)
    return {"name": name, "run_id": f"benchcpu{os.getpid()}",
            "outputs": outputs or {}, "inputs": inputs or {},
            "control": f"ipc://{tmp}/{name}.ctl", "telemetry": f"ipc://{tmp}/{name}.tel"}


async def measure(nbytes: int, count: int) -> dict:
    """Per-message emit and receive times in us under each condition (medians and p90)."""
    with tempfile.TemporaryDirectory(prefix="bench-hop-cpu-") as tmp:
        endpoint = f"ipc://{tmp}/payload"
        sender = Node(_spec("src", tmp, outputs={"payload": {
            "endpoint": endpoint, "hwm": 2 * BURST, "slots": BURST + 4, "subscribers": 1,
            "ring": f"sebvs-benchcpu{os.getpid()}-src-payload"}}), _Endpoint)
        receiver = Node(_spec("dst", tmp, inputs={"payload": {
            "endpoint": endpoint, "topic": "src/payload", "queue": 2 * BURST,
            "hwm": 2 * BURST}}), _Endpoint)
        sender._bind_sockets()
        receiver._bind_sockets()
        inp = receiver.inputs.ports["payload"]
        out = sender.outputs.ports["payload"]
        deadline = time.monotonic() + 10
        while out.subscribers < 1:          # no slow-joiner loss of the first messages
            sender.outputs.drain_subscriptions(out)
            if time.monotonic() > deadline:
                raise RuntimeError("the receiving socket never subscribed")
            await asyncio.sleep(0.01)
        pattern = np.arange(nbytes, dtype=np.uint8)
        try:
            return {"warm": _warm(sender, receiver, inp, pattern, count),
                    "paced": _paced(sender, receiver, inp, pattern, count, fill=False),
                    "after_fill": _paced(sender, receiver, inp, pattern, count, fill=True)}
        finally:
            sender.close()
            receiver.close()


def _reserve(sender: Node, pattern: np.ndarray, fill: bool) -> dict:
    arrays = sender.reserve("payload", {"data": (pattern.shape, pattern.dtype)})
    if fill:
        arrays["data"][...] = pattern
    return arrays


def _warm(sender, receiver, inp, pattern, count) -> dict:
    """Rounds of BURST back-to-back emits, each round then drained in one reader callback.

    Emit: total time / count. Receive: the median gap between consecutive handler starts
    within a round, i.e. the steady per-message cost once the callback runs (the first
    message of a round also pays the wake from sleep, which `paced` measures).
    """
    emit_ns, gaps = 0, []
    for first in range(0, count, BURST):
        n = min(BURST, count - first)
        for i in range(first, first + n):
            arrays = _reserve(sender, pattern, fill=False)
            t0 = time.perf_counter_ns()
            sender.emit("payload", arrays, tick=i)
            emit_ns += time.perf_counter_ns() - t0
        # ZeroMQ's I/O thread moves a round in microseconds on an idle machine; on a busy
        # one it may take longer, and a drain then takes what has arrived: gaps are taken
        # within each drain only, so a wait between two never counts as a receive
        got, deadline = 0, time.monotonic() + 10
        while got < n:
            time.sleep(0.05)
            started = len(receiver.actor.started_ns)
            receiver.inputs.drain(inp)
            handled = receiver.actor.started_ns[started:]
            got += len(handled)
            gaps.extend(np.diff(handled))
            if got < n and time.monotonic() > deadline:
                raise RuntimeError(f"{got} of {n} messages handled in 10 s "
                                   f"(stats: {inp.stats})")
    if not gaps:
        raise RuntimeError("every drain took a single message: no gap between two to time")
    return {"emit_us": round(emit_ns / count / 1e3, 2),
            "receive_us": round(float(np.median(gaps)) / 1e3, 2)}


def _paced(sender, receiver, inp, pattern, count, fill: bool) -> dict:
    emit, receive = [], []
    for i in range(count):
        arrays = _reserve(sender, pattern, fill)
        t0 = time.monotonic_ns()
        sender.emit("payload", arrays, tick=i)
        emit.append(time.monotonic_ns() - t0)
        if not zmq.select([inp.socket], [], [], 5.0)[0]:
            raise RuntimeError(f"message {i} did not arrive within 5 s")
        handled = len(receiver.actor.started_ns)
        t0 = time.monotonic_ns()
        receiver.inputs.drain(inp)
        if len(receiver.actor.started_ns) != handled + 1:
            raise RuntimeError(f"message {i} was not handled (stats: {inp.stats})")
        receive.append(receiver.actor.started_ns[-1] - t0)
    return {"emit_us": round(float(np.median(emit)) / 1e3, 2),
            "emit_p90_us": round(float(np.percentile(emit, 90)) / 1e3, 2),
            "receive_us": round(float(np.median(receive)) / 1e3, 2),
            "receive_p90_us": round(float(np.percentile(receive, 90)) / 1e3, 2)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="100 messages, 3 repeats (< 10 s)")
    ap.add_argument("--bytes", type=int, default=1_228_800,
                    help="payload size (default 1,228,800: a 640x640x3 frame)")
    ap.add_argument("--count", type=int, default=None, help="messages per condition (default 200)")
    ap.add_argument("--repeats", type=int, default=None, help="default 7, 3 with --quick")
    ap.add_argument("--json", metavar="FILE", help="write the results here")
    args = ap.parse_args()
    count = args.count or (100 if args.quick else 200)
    repeats = args.repeats or (3 if args.quick else 7)
    if args.bytes < 65536:
        ap.error("--bytes below 65536 go inline, not through the ring this measures")
    runs = []
    for r in range(repeats):
        runs.append(asyncio.run(measure(args.bytes, count)))
        print(json.dumps({"repeat": r, **runs[-1]}), file=sys.stderr, flush=True)
    summary = {cond: {key: round(float(np.median([run[cond][key] for run in runs])), 2)
                      for key in runs[0][cond]} for cond in runs[0]}
    report = {"bytes": args.bytes, "count": count, "repeats": repeats,
              "what": "CPU time of emit, and of the reader callback up to the handler's "
                      "start, per message (medians over repeats)",
              **summary}
    print_report(report, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
