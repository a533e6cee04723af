"""The latency profiler: attaches to a live run's telemetry and summarises every hop.

Each actor publishes, per handled message, the stamp chain it arrived with plus its own
handler start and end. From these:

- edge transport latency = handler start at the consumer - send stamp of the producer
- handler time           = handler end - handler start, per actor input
- end-to-end chain       = handler end at a sink - send stamp of the first actor
"""
from __future__ import annotations

import collections
import json
import time
from pathlib import Path

import msgpack
import zmq

from .stats import summarize


class ProfileCollector:
    """Subscribes to every actor's telemetry endpoint listed in a run's run.json."""

    def __init__(self, info: dict, ctx: zmq.Context | None = None):
        self.info = info
        self.ctx = ctx or zmq.Context.instance()
        self.socket = self.ctx.socket(zmq.SUB)
        self.socket.setsockopt(zmq.LINGER, 0)
        self.socket.setsockopt(zmq.SUBSCRIBE, b"")
        for actor in info["actors"].values():
            self.socket.connect(actor["telemetry"])
        self.sinks = {n for n, a in info["actors"].items() if not a.get("consumed")}
        self.edges = collections.defaultdict(list)
        self.handlers = collections.defaultdict(list)
        self.chains = collections.defaultdict(list)
        self.events = collections.Counter()
        self.last_events: list = []
        self.drops_first: dict = {}
        self.drops_last: dict = {}
        self.skipped = collections.Counter()
        self.t_start = time.monotonic()
        self.t_first = None

    def poll(self, timeout_s: float) -> int:
        """Receive what arrives within ``timeout_s``; returns the number of batches."""
        n = 0
        deadline = time.monotonic() + timeout_s
        while True:
            left = deadline - time.monotonic()
            if not self.socket.poll(max(0, int(left * 1000))):
                return n
            _, body = self.socket.recv_multipart()
            self._ingest(msgpack.unpackb(body, raw=False))
            n += 1
            if left <= 0:
                return n

    def _ingest(self, batch: dict) -> None:
        actor = batch["actor"]
        if self.t_first is None:
            self.t_first = time.monotonic()
        for inp, topic, seq, tick, t_sim, stamps, start, end in batch["records"]:
            if stamps:
                self.edges[(topic, f"{actor}.{inp}")].append(start - stamps[-1][2])
                if actor in self.sinks:
                    chain = " > ".join([s[0] for s in stamps] + [actor])
                    self.chains[chain].append(end - stamps[0][2])
            self.handlers[(actor, inp)].append(end - start)
        for kind, t_ns, fields in batch["events"]:
            self.events[f"{actor}:{kind}"] += 1
            self.last_events = (self.last_events + [[actor, kind, t_ns, fields]])[-50:]
        for inp, counters in batch["drops"].items():
            key = (actor, inp)
            self.drops_first.setdefault(key, counters)
            self.drops_last[key] = counters
        self.skipped[actor] = batch.get("skipped", 0)

    def report(self) -> dict:
        def drops(key):
            first, last = self.drops_first.get(key), self.drops_last.get(key)
            if not last:
                return {}
            return {k: last[k] - first.get(k, 0) for k in last
                    if k.startswith("dropped") or k in ("malformed", "torn", "errors", "seq_resets",
                                                           "seq_jumps")}

        return {
            "run": self.info.get("name"), "run_id": self.info.get("run_id"),
            "seconds": round(time.monotonic() - self.t_start, 3),
            "edges": [{"edge": f"{topic} -> {dst}", **summarize(v, 1e-3)}
                      for (topic, dst), v in sorted(self.edges.items())],
            "handlers": [{"actor": a, "input": i, **summarize(v, 1e-3), "drops": drops((a, i))}
                         for (a, i), v in sorted(self.handlers.items())],
            "chains": [{"chain": c, **summarize(v, 1e-3)} for c, v in sorted(self.chains.items())],
            "events": dict(self.events),
            "units": "microseconds",
        }

    def close(self) -> None:
        self.socket.close()


def _fmt(v) -> str:
    if v is None:
        return "-"
    return f"{v:.0f}" if v >= 100 else f"{v:.1f}"


def format_report(rep: dict) -> str:
    lines = [f"run {rep['run']} ({rep['run_id']}), {rep['seconds']:.1f} s observed, "
             f"latencies in microseconds"]
    cols = ("count", "p50", "p90", "p99", "max")

    def table(title, rows, key):
        if not rows:
            lines.append(f"{title}: (nothing observed)")
            return
        width = max([len(title)] + [len(r[key]) for r in rows])
        lines.append(f"{title:<{width}}  " + "  ".join(f"{c:>8}" for c in cols)
                     + ("  drops" if key == "name" else ""))
        for r in rows:
            cells = "  ".join(f"{_fmt(r[c]) if c != 'count' else r[c]:>8}" for c in cols)
            extra = ""
            if r.get("drops"):
                extra = "  " + ", ".join(f"{k.replace('dropped_', '')}={v}"
                                         for k, v in r["drops"].items() if v) or "  0"
            lines.append(f"{r[key]:<{width}}  {cells}{extra}")

    lines.append("")
    table("transport (edge)", rep["edges"], "edge")
    lines.append("")
    table("handler (actor.input)",
          [dict(r, name=f"{r['actor']}.{r['input']}") for r in rep["handlers"]], "name")
    lines.append("")
    table("end to end (chain)", rep["chains"], "chain")
    if rep["events"]:
        lines.append("")
        lines.append("events: " + ", ".join(f"{k}={v}" for k, v in sorted(rep["events"].items())))
    return "\n".join(lines)


def plot_report(rep: dict, collector: ProfileCollector, path: str | Path) -> None:
    """Latency histograms per edge and per chain (log-scaled microseconds)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    series = [(f"{t} -> {d}", v) for (t, d), v in sorted(collector.edges.items())]
    series += [(c, v) for c, v in sorted(collector.chains.items())]
    series = [(name, np.asarray(v) / 1e3) for name, v in series if len(v)]
    fig, axes = plt.subplots(len(series) or 1, 1, figsize=(8, 2.2 * max(1, len(series))),
                             squeeze=False)
    for ax, (name, us) in zip(axes[:, 0], series):
        us = np.clip(us, 1e-1, None)
        bins = np.logspace(np.log10(us.min()), np.log10(us.max() * 1.01 + 1e-9), 50)
        ax.hist(us, bins=bins, color="tab:blue")
        ax.set_xscale("log")
        ax.axvline(np.median(us), color="k", lw=1)
        ax.set_title(f"{name}  (p50 {np.median(us):.0f} us, n={us.size})", fontsize=9)
    axes[-1, 0].set_xlabel("latency [us]")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_json(rep: dict, path: str | Path) -> None:
    Path(path).write_text(json.dumps(rep, indent=2))
