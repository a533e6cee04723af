"""Chrome trace-event export of a profile: one file to open in ui.perfetto.dev or
chrome://tracing.

The trace-event format (JSON object form): ``{"traceEvents": [...]}``, timestamps ``ts``
and durations ``dur`` in microseconds. Here:

- one process per actor (``pid``), one thread per input (``tid``; the handlers of one
  input never overlap, the runtime handles an input's messages in order), and a thread
  ``emit`` for what a source publishes outside any handler;
- a complete event ("X", category ``handler``) per handled message, its args the topic,
  seq, tick and, when the message's arrival was stamped, the queueing, wake-up and
  transport (receive path) that preceded it, in us (``chainsplit.py``);
- a flow ("s" at the producer's send, "f" at the consumer's handler start, category
  ``hop``) per message, so the UI draws an arrow along each hop; a send made outside a
  handler (a source's) gets a 1 us "X" ``emit`` slice for the arrow to start from.

Time 0 is the first event of the trace; the absolute monotonic ns of it is in
``otherData.origin_monotonic_ns``.
"""
from __future__ import annotations

import json
from pathlib import Path

EMIT_TRACK = "emit"
# an emit slice's length: wide enough for a viewer to bind the flow arrow to it, shorter
# than any two sends of one process can be apart (an emit alone costs more)
EMIT_US = 1.0


def select_records(kept: list[tuple], ticks: int) -> list[tuple]:
    """The records of the last ``ticks`` control ticks, and all records from their start.

    ``kept``: records as ``ProfileCollector.kept`` holds them (actor, input, tick, stamps,
    start, end, slept, woke, taken). Without ticks (a topology whose samples carry none),
    the last ``ticks * 10`` records.
    """
    ticked = sorted({r[2] for r in kept if r[2] is not None})
    if not ticked:
        return sorted(kept, key=lambda r: r[4])[-ticks * 10:]
    last = set(ticked[-ticks:])
    t0 = min(r[4] for r in kept if r[2] in last)
    return sorted((r for r in kept if r[4] >= t0), key=lambda r: r[4])


def build_trace(records: list[tuple], run: str = "") -> dict:
    """The trace-event JSON object for ``records`` (see ``select_records``)."""
    if not records:
        return {"traceEvents": [], "displayTimeUnit": "ms",
                "otherData": {"run": run, "origin_monotonic_ns": 0, "records": 0}}
    by_key = {(r[0], r[4]): r for r in records}
    origin = min(min(r[4] for r in records),
                 min((s[2] for r in records for s in r[3]), default=records[0][4]))
    pids: dict[str, int] = {}
    tids: dict[tuple, int] = {}
    events: list[dict] = []

    def us(t_ns: int) -> float:
        return round((t_ns - origin) / 1e3, 3)

    def track(actor: str, name: str) -> tuple[int, int]:
        if actor not in pids:
            pids[actor] = len(pids) + 1
            events.append({"ph": "M", "name": "process_name", "pid": pids[actor], "tid": 0,
                           "args": {"name": actor}})
        if (actor, name) not in tids:
            tids[(actor, name)] = len([k for k in tids if k[0] == actor]) + 1
            events.append({"ph": "M", "name": "thread_name", "pid": pids[actor],
                           "tid": tids[(actor, name)], "args": {"name": name}})
        return pids[actor], tids[(actor, name)]

    flow_id = 0
    emitted = set()     # (producer, send ns): one emit slice per send, however many consumers
    for actor, inp, tick, stamps, start, end, slept, woke, taken in records:
        pid, tid = track(actor, inp)
        args = {"tick": tick}
        if stamps and woke and stamps[-1][2] <= taken <= start:
            wakeup = max(0, woke - max(stamps[-1][2], slept))
            args.update(queueing_us=(taken - stamps[-1][2] - wakeup) / 1e3,
                        wakeup_us=wakeup / 1e3, transport_us=(start - taken) / 1e3)
        events.append({"ph": "X", "cat": "handler", "name": f"on_{inp}", "pid": pid,
                       "tid": tid, "ts": us(start), "dur": round((end - start) / 1e3, 3),
                       "args": args})
        if not stamps:
            continue
        producer, p_recv, p_send = stamps[-1]
        parent = by_key.get((producer, p_recv)) if p_recv else None
        if parent is not None and parent[4] <= p_send <= parent[5]:
            p_pid, p_tid = track(producer, parent[1])
        else:   # sent outside a handler (a source), or its handler is not in the trace
            p_pid, p_tid = track(producer, EMIT_TRACK)
            if (producer, p_send) not in emitted:
                emitted.add((producer, p_send))
                events.append({"ph": "X", "cat": "emit", "name": "emit", "pid": p_pid,
                               "tid": p_tid, "ts": us(p_send), "dur": EMIT_US})
        flow_id += 1
        events.append({"ph": "s", "cat": "hop", "name": "hop", "id": flow_id, "pid": p_pid,
                       "tid": p_tid, "ts": us(p_send)})
        events.append({"ph": "f", "bp": "e", "cat": "hop", "name": "hop", "id": flow_id,
                       "pid": pid, "tid": tid, "ts": us(start)})
    return {"traceEvents": events, "displayTimeUnit": "ms",
            "otherData": {"run": run, "origin_monotonic_ns": origin,
                          "records": len(records), "units": "microseconds"}}


def write_trace(trace: dict, path: str | Path) -> None:
    Path(path).write_text(json.dumps(trace))
