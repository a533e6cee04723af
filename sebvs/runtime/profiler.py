"""The latency profiler: attaches to a live run's telemetry and summarises every hop.

Each actor publishes, per handled message, a record (``RECORD_FIELDS``): the stamp chain
it arrived with ([actor, recv_ns, send_ns] per hop), its handler start and end, and three
arrival stamps: when its event loop last entered and left select() before taking the
message (``inputs.LoopClock``) and when it took the message off its socket. All are
``time.monotonic_ns()``, one clock for every process of a host. From these:

- edge latency     = handler start at the consumer - send stamp of the producer
- handler time     = handler end - handler start, per actor input
- end-to-end chain = handler end - send stamp of the first actor, at a sink (an actor
                     whose outputs nobody consumes) and where a loop closes (the chain's
                     first actor receives it: sim > camera > ... > policy > sim)
- chain split      = each chain's hops cut into queueing, wake-up, transport and handler
                     (exact definitions in ``chainsplit.py``; they add up to the chain)

A multi-host run's hosts have clocks of their own. The primary's run.json carries each
host's offset against the primary's clock and its uncertainty (``clocksync.py``, re-read
every CLOCK_REREAD_S while attached); every stamp is moved onto the primary's clock as it
is ingested, and an edge or chain whose two ends are on different hosts is reported with
``clock_uncertainty_us``, the sum of the two hosts' uncertainties.

Telemetry that does not parse (a batch, a record, a stamp of the wrong shape) is counted
in ``skipped`` and left out; it never stops the profiler.
"""
from __future__ import annotations

import collections
import json
import time
from pathlib import Path

import numpy as np
import zmq

from . import curve
from .chainsplit import COMPONENTS, split_hops
from .inputs import TELEMETRY_MAX_RECORDS
from .stats import summarize
from .wire import WireError, unpack_bounded

# one telemetry batch (a node's records of one period, at most TELEMETRY_MAX_RECORDS)
MAX_TELEMETRY_BYTES = 16 << 20

# a telemetry record, as inputs.Inputs._handled writes it; the three arrival stamps came
# later, so a record without them (8 fields) still counts everywhere but in the split
RECORD_FIELDS = ("input", "topic", "seq", "tick", "t_sim", "stamps", "start_ns", "end_ns",
                 "slept_ns", "woke_ns", "taken_ns")
KEEP_RECORDS = 200_000     # records kept for the split and the trace (oldest dropped first)
KEEP_CHAINS = 100_000      # chain instances kept per chain for the split
# the sensor-to-action loop on the realtime clock (issues 18 and 37): docs/runtime.md
LOOP_TARGETS_MS = {"p50": 5.0, "p99": 15.0}
LOOP_WARMUP_S = 1.0
CLOCK_REREAD_S = 1.0       # run.json re-read for refreshed clock offsets (multi-host runs)


class ProfileCollector:
    """Subscribes to every actor's telemetry endpoint listed in a run's run.json."""

    def __init__(self, info: dict, ctx: zmq.Context | None = None):
        self.info = info
        self.ctx = ctx or zmq.Context.instance()
        self.socket = self.ctx.socket(zmq.SUB)
        self.socket.setsockopt(zmq.LINGER, 0)
        self.socket.setsockopt(zmq.SUBSCRIBE, b"")
        for actor in info["actors"].values():
            # one socket for every actor: its CURVE client keys (tcp) serve them all
            curve.client(self.socket, actor["telemetry"], curve.token_of(info))
            self.socket.connect(actor["telemetry"])
        self.sinks = {n for n, a in info["actors"].items() if not a.get("consumed")}
        self.edges = collections.defaultdict(list)
        self.handlers = collections.defaultdict(list)
        self.chains = collections.defaultdict(list)
        # (actor, handler start ns) -> (actor, input, tick, stamps, start, end, slept, woke,
        # taken): the join of a chain's hops to their consumers' records, and the trace
        self.kept: collections.OrderedDict = collections.OrderedDict()
        # chain name -> [(stamps, end_ns, the closing record's key)], split at report()
        self.chain_instances = collections.defaultdict(list)
        self.events = collections.Counter()
        self.last_events: list = []
        self.drops_first: dict = {}
        self.drops_last: dict = {}
        self.skipped = collections.Counter()   # ours: batches/records that did not parse
        self.node_skipped: dict = {}            # per actor: records beyond its batch limit
        self.t_start = time.monotonic()
        self.t_first = None
        # multi-host: actor -> its host, and per host (offset_ns, uncertainty_ns) on the
        # primary's clock; hosts whose offset run.json does not give yet are listed apart
        self.host_of = {n: a.get("host") for n, a in info["actors"].items()
                        if isinstance(a, dict)}
        self.host_clock: dict = {}
        self.offset: dict = {}          # actor -> ns to subtract (only nonzero ones)
        self.clock_unknown: set = set()
        self._next_clock_read = time.monotonic() + CLOCK_REREAD_S
        self.read_clocks(info)

    def read_clocks(self, info: dict) -> None:
        """Take the hosts' clock offsets of a run.json (ignored where malformed)."""
        hosts = info.get("hosts")
        if not isinstance(hosts, dict):
            return
        clocks, unknown = {}, set()
        for host, entry in hosts.items():
            c = entry.get("clock") if isinstance(entry, dict) else None
            if isinstance(c, dict) and _is_int(c.get("offset_ns")) \
                    and _is_int(c.get("uncertainty_ns")):
                clocks[host] = (c["offset_ns"], c["uncertainty_ns"])
            else:
                unknown.add(host)
        self.host_clock, self.clock_unknown = clocks, unknown
        self.offset = {a: clocks[h][0] for a, h in self.host_of.items()
                       if h in clocks and clocks[h][0]}

    def _reread_clocks(self) -> None:
        if not self.host_clock and not self.clock_unknown:
            return      # a one-host run: nothing to refresh
        self._next_clock_read = time.monotonic() + CLOCK_REREAD_S
        try:
            info = json.loads((Path(self.info["rundir"]) / "run.json").read_text())
        except (OSError, ValueError, KeyError, TypeError):
            return      # between rewrites, or gone with its run: keep what we have
        if isinstance(info, dict):
            self.read_clocks(info)

    def clock_uncertainty_ns(self, a: str, b: str) -> int:
        """How far a latency from actor a's stamp to actor b's may be off (0 on one host)."""
        ha, hb = self.host_of.get(a), self.host_of.get(b)
        if ha == hb:
            return 0
        return self.host_clock.get(ha, (0, 0))[1] + self.host_clock.get(hb, (0, 0))[1]

    def poll(self, timeout_s: float) -> int:
        """Receive what arrives within ``timeout_s``; returns the number of batches."""
        n = 0
        deadline = time.monotonic() + timeout_s
        while True:
            left = deadline - time.monotonic()
            if not self.socket.poll(max(0, int(left * 1000))):
                return n
            if time.monotonic() >= self._next_clock_read:
                self._reread_clocks()
            frames = self.socket.recv_multipart()
            try:
                # the data plane's bounded decoder: a telemetry batch is counted, not trusted
                batch = unpack_bounded(frames[-1], "telemetry", MAX_TELEMETRY_BYTES,
                                       TELEMETRY_MAX_RECORDS + 16)
            except WireError:
                self.skipped["batches"] += 1
                continue
            self.ingest(batch)
            n += 1
            if left <= 0:
                return n

    def ingest(self, batch) -> None:
        """One telemetry batch (as node.Node._flush_telemetry publishes it)."""
        if not isinstance(batch, dict) or not isinstance(batch.get("actor"), str):
            self.skipped["batches"] += 1
            return
        actor = batch["actor"]
        if self.t_first is None:
            self.t_first = time.monotonic()
        records = batch.get("records")
        for rec in records if isinstance(records, list) else ():
            if not self._ingest_record(actor, rec):
                self.skipped["records"] += 1
        events = batch.get("events")
        for ev in events if isinstance(events, list) else ():
            if not (isinstance(ev, list) and len(ev) == 3 and isinstance(ev[0], str)):
                self.skipped["events"] += 1
                continue
            kind, t_ns, fields = ev
            if _is_int(t_ns):
                t_ns -= self.offset.get(actor, 0)
            self.events[f"{actor}:{kind}"] += 1
            self.last_events = (self.last_events + [[actor, kind, t_ns, fields]])[-50:]
        drops = batch.get("drops")
        for inp, counters in (drops.items() if isinstance(drops, dict) else ()):
            if not isinstance(counters, dict):
                self.skipped["drops"] += 1
                continue
            key = (actor, inp)
            self.drops_first.setdefault(key, counters)
            self.drops_last[key] = counters
        if _is_int(batch.get("skipped")):
            self.node_skipped[actor] = batch["skipped"]

    def _ingest_record(self, actor: str, rec) -> bool:
        """Account one record; False (and nothing counted) if it does not parse."""
        if not (isinstance(rec, list) and len(rec) in (8, len(RECORD_FIELDS))):
            return False
        inp, topic, _seq, tick, _t_sim, stamps, start, end = rec[:8]
        arrival = rec[8:] or [0, 0, 0]
        if not (isinstance(inp, str) and isinstance(topic, str) and isinstance(stamps, list)
                and all(map(_is_int, (start, end, *arrival))) and start <= end
                and all(_is_stamp(s) for s in stamps)):
            return False
        if tick is not None and not _is_int(tick):
            tick = None
        if self.offset:     # onto the primary's clock (a one-host run skips this)
            stamps, start, end, arrival = self._on_primary_clock(actor, stamps, start, end,
                                                                 arrival)
        if stamps:
            self.edges[(topic, f"{actor}.{inp}")].append(start - stamps[-1][2])
            if actor in self.sinks or actor == stamps[0][0]:
                chain = " > ".join([s[0] for s in stamps] + [actor])
                self.chains[chain].append(end - stamps[0][2])
                instances = self.chain_instances[chain]
                if len(instances) < KEEP_CHAINS:
                    instances.append((stamps, end, (actor, start)))
        self.handlers[(actor, inp)].append(end - start)
        if len(self.kept) >= KEEP_RECORDS:
            self.kept.popitem(last=False)
        self.kept[(actor, start)] = (actor, inp, tick, stamps, start, end, *arrival)
        return True

    def _on_primary_clock(self, actor, stamps, start, end, arrival):
        off = self.offset.get
        own = off(actor, 0)
        # a source's receive stamp is 0 (it received nothing) and stays 0
        stamps = [[a, r - off(a, 0) if r else 0, t - off(a, 0)] for a, r, t in stamps]
        return stamps, start - own, end - own, [t - own if t else 0 for t in arrival]

    # ------------------------------------------------------------------ chain split
    def split(self, since_ns: int | None = None) -> list[dict]:
        """Per chain, its hops' components (``chainsplit.split_hops``), one row per hop.

        ``since_ns``: only the instances whose first send is at or after it (a start-up
        transient left out).

        Instances whose hops cannot all be joined to their consumers' records (a record
        from before the profiler attached, one an actor skipped, a batch lost) are counted
        as ``unresolved`` and left out of the split, not out of the chain figures.
        """
        out = []
        for chain, instances in sorted(self.chain_instances.items()):
            per_hop, totals, unresolved = None, [], 0
            if since_ns is not None:
                instances = [i for i in instances if i[0][0][2] >= since_ns]
            for stamps, end, key in instances:
                keys = [(s[0], s[1]) for s in stamps[1:]] + [key]
                arrivals = []
                for k in keys:
                    r = self.kept.get(k)
                    arrivals.append(None if r is None else (r[6], r[7], r[8], r[4]))
                hops = split_hops(stamps, end, arrivals)
                if hops is None:
                    unresolved += 1
                    continue
                if per_hop is None:
                    per_hop = [{c: [] for c in COMPONENTS} for _ in hops]
                for row, hop in zip(per_hop, hops):
                    for c in COMPONENTS:
                        row[c].append(hop[c])
                totals.append(end - stamps[0][2])
            names = chain.split(" > ")
            entry = {"chain": chain, "instances": len(instances), "resolved": len(totals),
                     "unresolved": unresolved, "chain_us": summarize(totals, 1e-3),
                     "hops": [], "components": {}}
            if per_hop:
                total_ns = float(np.sum(totals))
                sums = {c: np.zeros(len(totals)) for c in COMPONENTS}
                for j, row in enumerate(per_hop):
                    hop = {"hop": f"{names[j]} > {names[j + 1]}", "actor": names[j + 1]}
                    for c in COMPONENTS:
                        v = np.asarray(row[c], dtype=np.float64)
                        sums[c] += v
                        hop[c] = dict(summarize(v, 1e-3),
                                      share=float(v.sum() / total_ns) if total_ns else None)
                    entry["hops"].append(hop)
                for c in COMPONENTS:
                    entry["components"][c] = dict(
                        summarize(sums[c], 1e-3),
                        share=float(sums[c].sum() / total_ns) if total_ns else None)
                # the chain's own compute (its handlers' share) beside the chain itself
                compute = sums["handler"]
                entry["compute_us"] = summarize(compute, 1e-3)
                with np.errstate(divide="ignore", invalid="ignore"):
                    entry["chain_over_compute_p50"] = (
                        float(np.median(totals) / np.median(compute))
                        if np.median(compute) > 0 else None)
            out.append(entry)
        return out

    def loop_latency(self, warmup_s: float = LOOP_WARMUP_S) -> dict | None:
        """The closed loop's latency: from the sim's state to its tick's action applied,
        over every path that closes the loop at one actor (the most observed such actor),
        leaving out the chains that started in the first ``warmup_s`` (models compile and
        renderers start on the first samples), beside LOOP_TARGETS_MS. A tick's action
        carries the stamps of the input that completed it, so where two inputs race (the
        frame and the events of rgb+event) each tick counts once, on the path of the later
        one; "paths" says how many went each way, "chain" is the most frequent, "since_ns"
        the start stamp from which chains count. None when no chain closes a loop."""
        by_actor: dict[str, list[str]] = collections.defaultdict(list)
        for c, inst in self.chain_instances.items():
            if _closes_loop(c) and inst:
                by_actor[c.split(" > ")[0]].append(c)
        if not by_actor:
            return None
        paths = max(by_actor.values(),
                    key=lambda cs: sum(len(self.chain_instances[c]) for c in cs))
        since = min(i[0][0][2] for c in paths for i in self.chain_instances[c]) + \
            int(warmup_s * 1e9)
        totals, counts = [], {}
        for c in paths:
            kept = [end - stamps[0][2] for stamps, end, _ in self.chain_instances[c]
                    if stamps[0][2] >= since]
            if kept:
                totals += kept
                counts[c] = len(kept)
        if not totals:
            return None
        p50, p99 = (float(np.percentile(totals, q)) / 1e6 for q in (50, 99))
        return {"chain": max(counts, key=counts.get),
                "paths": dict(sorted(counts.items(), key=lambda kv: -kv[1])),
                "instances": len(totals), "warmup_s": warmup_s, "since_ns": since,
                "p50_ms": round(p50, 2), "p99_ms": round(p99, 2),
                "target_p50_ms": LOOP_TARGETS_MS["p50"], "target_p99_ms": LOOP_TARGETS_MS["p99"],
                "met": p50 <= LOOP_TARGETS_MS["p50"] and p99 <= LOOP_TARGETS_MS["p99"]}

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
            "edges": [{"edge": f"{topic} -> {dst}", **summarize(v, 1e-3),
                       **self._uncertainty(topic.split("/")[0], dst.split(".")[0])}
                      for (topic, dst), v in sorted(self.edges.items())],
            "handlers": [{"actor": a, "input": i, **summarize(v, 1e-3), "drops": drops((a, i))}
                         for (a, i), v in sorted(self.handlers.items())],
            "chains": [{"chain": c, **summarize(v, 1e-3),
                        **self._uncertainty(c.split(" > ")[0], c.split(" > ")[-1])}
                       for c, v in sorted(self.chains.items())],
            "split": self.split(),
            "events": dict(self.events),
            "skipped": {"profiler": dict(self.skipped), "actors": dict(self.node_skipped)},
            "units": "microseconds",
        }

    def _uncertainty(self, a: str, b: str) -> dict:
        """{"clock_uncertainty_us": ...} for a latency between two hosts, else {}."""
        if self.host_of.get(a) == self.host_of.get(b):
            return {}
        if {self.host_of.get(a), self.host_of.get(b)} & self.clock_unknown:
            return {"clock_uncertainty_us": None}     # an offset not estimated yet
        return {"clock_uncertainty_us": self.clock_uncertainty_ns(a, b) / 1e3}

    def close(self) -> None:
        self.socket.close()


def _is_int(v) -> bool:
    return type(v) is int


def _is_stamp(s) -> bool:
    return (isinstance(s, list) and len(s) == 3 and isinstance(s[0], str)
            and _is_int(s[1]) and _is_int(s[2]))


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
            if "clock_uncertainty_us" in r:   # across hosts: how far the clocks may be off
                u = r["clock_uncertainty_us"]
                extra += "  clocks +-" + ("unknown" if u is None else f"{_fmt(u)}")
            lines.append(f"{r[key]:<{width}}  {cells}{extra}")

    lines.append("")
    table("transport (edge)", rep["edges"], "edge")
    lines.append("")
    table("handler (actor.input)",
          [dict(r, name=f"{r['actor']}.{r['input']}") for r in rep["handlers"]], "name")
    lines.append("")
    table("end to end (chain)", rep["chains"], "chain")
    # the text shows the chains that close a loop (sensor to action) when there are any,
    # else every chain; the JSON has them all
    splits = rep.get("split", [])
    loops = [e for e in splits if _closes_loop(e["chain"])]
    for entry in loops or splits:
        lines.append("")
        lines.extend(format_split(entry))
    if loops and len(loops) < len(splits):
        lines.append(f"({len(splits) - len(loops)} more chain split(s) in --json)")
    if rep["events"]:
        lines.append("")
        lines.append("events: " + ", ".join(f"{k}={v}" for k, v in sorted(rep["events"].items())))
    return "\n".join(lines)


COMPONENT_TITLES = {"queueing": "queueing", "wakeup": "wake-up", "transport": "transport",
                    "handler": "handler"}


def format_loop_latency(loop: dict | None, clock: str) -> str:
    """One line: the loop's p50 and p99 beside the targets, for the clock it ran on."""
    if loop is None:
        return "loop latency: no closed-loop chain observed after the warm-up"
    verdict = "met" if loop["met"] else "not met"
    more = len(loop.get("paths", ())) - 1
    path = loop["chain"] + (f" and {more} more path{'s' if more > 1 else ''}" if more > 0
                            else "")
    line = (f"loop latency ({path}): p50 {loop['p50_ms']:.2f} ms, p99 "
            f"{loop['p99_ms']:.2f} ms over {loop['instances']} chains after the first "
            f"{loop['warmup_s']:g} s; target p50 <= {loop['target_p50_ms']:g} ms, p99 <= "
            f"{loop['target_p99_ms']:g} ms on a quiet machine: {verdict}")
    if clock != "realtime":
        line += " (the target is for the realtime clock; this run was lockstep)"
    return line


def _closes_loop(chain: str) -> bool:
    names = chain.split(" > ")
    return len(names) > 1 and names[0] == names[-1]


def format_split(entry: dict) -> list[str]:
    """One chain's split: per hop and component p50/p90/p99 (us) and share of the chain."""
    c = entry["chain_us"]
    head = (f"chain split: {entry['chain']}  ({entry['resolved']} of {entry['instances']} "
            f"instances joined")
    if not entry["hops"]:
        return [head + "; nothing to split)"]
    lines = [head + f"; chain p50 {_fmt(c['p50'])} p99 {_fmt(c['p99'])} us, "
                    f"compute p50 {_fmt(entry['compute_us']['p50'])} us)"]
    width = max(len(h["hop"]) for h in entry["hops"] + [{"hop": "all hops"}])
    lines.append(f"{'hop':<{width}}  {'component':<9}  {'p50':>8}  {'p90':>8}  {'p99':>8}"
                 f"  {'share':>6}")
    for h in entry["hops"] + [dict(entry["components"], hop="all hops")]:
        for comp in COMPONENTS:
            r = h[comp]
            share = "-" if r["share"] is None else f"{100 * r['share']:.1f}%"
            lines.append(f"{h['hop'] if comp == 'queueing' else '':<{width}}  "
                         f"{COMPONENT_TITLES[comp]:<9}  {_fmt(r['p50']):>8}  "
                         f"{_fmt(r['p90']):>8}  {_fmt(r['p99']):>8}  {share:>6}")
    return lines


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
