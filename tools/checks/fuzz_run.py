#!/usr/bin/env python3
"""Hostile input, by class: messages through a live run (the default) or files (--class files).

--class messages: is every hostile message counted, and does the input live on?

Runs topologies/fuzz.toml (actors/fuzz.py): a producer sends rounds of every hostile class
of sebvs/runtime/hostile.py (garbage, not a map, wrong version, bad fields, stamps, dtypes,
shapes, buffers, topics, ring locations, seqs going back or leaping) with a valid probe
after each round, and every `--oversize-every` rounds a message over the sink's
`max_bytes` (ZeroMQ drops the peer; the input must reconnect). The sink reports its
input's counters, the probes it handled and its memory. Printed (and with --json written):

  sent              per class
  counters          per counter where sebvs/runtime/hostile.EXPECTED says a class must
                    land (classes sharing one are summed): sent, counted, and uncounted =
                    sent - counted (0 everywhere is the target: none lost, none counted twice)
  probes_handled    of probes_sent: each probe after a hostile round is the "next valid
                    message" that must get through (the probes sent during an oversize
                    reconnection are the only ones allowed to be lost: `probes_lost_to_reconnect`)
  actors_alive      both actors ended as asked (the run did not fail)
  memory_growth_mb  the sink's RSS at the end minus at its first probe

    tools/checks/fuzz_run.py [--messages N] [--oversize-every R] [--json FILE]

--class files: every writing command at every hostile output path and every reader at
every damaged episode, each as its own `sebvs` process (tools/checks/fuzz_files.py has
the cases); printed: overwritten, accepted, unnamed and tracebacks, 0 the target of each.

    tools/checks/fuzz_run.py --class files [--json FILE]
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))     # fuzz_files beside it

from sebvs.runtime.hostile import EXPECTED, ROUND  # noqa: E402
from sebvs.runtime.supervisor import RunFailed, run_topology  # noqa: E402


def counted(kind: str, stats: dict) -> int:
    where, sub = EXPECTED[kind]
    if where == "malformed":
        return stats["malformed_kinds"].get(sub, 0)
    return stats[where]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--messages", type=int, default=10_000, help="hostile messages (10,000)")
    ap.add_argument("--oversize-every", type=int, default=200,
                    help="rounds between oversized messages (0: none)")
    ap.add_argument("--json", metavar="FILE", help="write the results here")
    ap.add_argument("--class", dest="kind", choices=("messages", "files"), default="messages",
                    help="hostile messages through a live run (default), or hostile output "
                         "paths and damaged episodes through every command")
    args = ap.parse_args()
    if args.kind == "files":
        return files_main(args)
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="sebvs-fuzz-") as tmp:
        sent_path, sink_path = Path(tmp) / "sent.json", Path(tmp) / "sink.json"
        alive = True
        try:
            run_topology(ROOT / "topologies" / "fuzz.toml",
                         [f"hostile.messages={args.messages}",
                          f"hostile.oversize_every={args.oversize_every}",
                          f"hostile.report={json.dumps(str(sent_path))}",
                          f"sink.report={json.dumps(str(sink_path))}"],
                         duration_s=3600, runs_dir=Path(tmp) / "runs")
        except RunFailed as exc:
            alive = False
            print(f"fuzz_run: the run failed: {str(exc).splitlines()[0]}", file=sys.stderr)
        sent = json.loads(sent_path.read_text()) if sent_path.exists() else None
        sink = json.loads(sink_path.read_text()) if sink_path.exists() else None
    if sent is None or sink is None:
        print("fuzz_run: an actor did not report (see the message above)", file=sys.stderr)
        return 1
    stats = sink["input"]
    # classes that share a counter (buffer and no_header both land in "frames") are
    # accounted together, under the counter
    per: dict = {}
    for kind in (*ROUND, "oversize"):
        where, sub = EXPECTED[kind]
        key = f"{where}[{sub}]" if sub else where
        row = per.setdefault(key, {"classes": [], "sent": 0, "counted": counted(kind, stats)})
        row["classes"].append(kind)
        row["sent"] += sent["sent"][kind]
    for v in per.values():
        v["uncounted"] = v["sent"] - v["counted"]
    probes_sent = sent["sent"]["probe"]
    out = {"messages_sent": sent["total"], "rounds": sent["rounds"], "counters": per,
           "uncounted_total": sum(abs(v["uncounted"]) for v in per.values()),
           "probes_sent": probes_sent, "probes_handled": sink["probes"],
           "inputs_cut_off": int(sink["last_probe"] != probes_sent - 1),
           "actors_alive": alive, "actors_dead": 0 if alive else 1,
           "memory_growth_mb": round((sink["rss_end"] - sink["rss_first"]) / 2 ** 20, 2),
           "input_counters": {k: v for k, v in stats.items() if k != "handler_us"},
           "wall_s": round(time.monotonic() - t0, 1)}
    print(json.dumps({k: v for k, v in out.items() if k != "input_counters"}, indent=1))
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(out, indent=1))
    return 0 if alive and out["uncounted_total"] == 0 and not out["inputs_cut_off"] else 1


def files_main(args) -> int:
    from fuzz_files import run_files
    with tempfile.TemporaryDirectory(prefix="sebvs-fuzz-files-") as tmp:
        out = run_files(Path(tmp), progress=lambda line: print(line, flush=True))
    print(json.dumps({k: v for k, v in out.items() if k != "cases"}, indent=1))
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(out, indent=1))
    return 0 if not (out["overwritten"] or out["accepted"] or out["unnamed"]
                     or out["tracebacks"]) else 1


if __name__ == "__main__":
    sys.exit(main())
