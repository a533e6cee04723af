#!/usr/bin/env python3
"""docs/probe.md's tables from the JSON the runs wrote: per nav cell, what the probe finds
in each stream for each driver of the recordings, what the event-cluster tracker finds in
the same test frames without learning, and the event-only driver in closed loop beside
the expert and no action.

    tools/checks/probe_summary.py --probe docs/figures/probe_still.json \
        --probe docs/figures/probe_wander.json \
        [--offline docs/figures/event_tracker_offline.json] \
        [--closed-loop docs/figures/event_tracker_closed_loop.json]

Reads what `sebvs probe`, tools/checks/event_tracker_offline.py and
tools/checks/event_tracker_eval.py wrote; prints Markdown.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

SENSORS = (("rgb", "frame camera"), ("event", "events"), ("both", "both"))
CELL_ORDER = ("nominal_physical/indoor", "nominal_physical/outdoor", "hdr/indoor",
              "hdr/outdoor", "dusk_fast/indoor", "dusk_fast/outdoor")


def _cell_key(cell: str) -> tuple:
    return (CELL_ORDER.index(cell) if cell in CELL_ORDER else len(CELL_ORDER), cell)


def _probe_cell(row: dict | None) -> str:
    if row is None or row["error_median_px"] is None:
        return "-"
    text = f"{row['error_median_px']:.1f} / {row['error_p90_px']:.0f}"
    return text + (f", {row['auc']:.2f}" if row["auc"] is not None else ", n/a")


def _pct(value) -> str:
    return "-" if value is None else f"{100 * value:.0f} %"


def probe_table(results: list[dict], offline: dict | None) -> str:
    """One row per (driver, cell): the split, the baseline, each sensor's median / p90
    error (px at 160 px) and AUC; the tracker's single-frame share where given."""
    single = {r["dataset"]: r["single"] for r in (offline or {}).get("datasets", [])}
    head = (["driver", "cell", "test frames (visible)", "mean-centroid baseline"]
            + [f"probe on {name}" for _, name in SENSORS]
            + (["tracker, one frame: found within 12.5 px (false when hidden)"]
               if offline else []))
    out = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for data in results:
        rows = {(r["dataset"], r["sensor"]): r for r in data["summary"]}
        cells = {r["dataset"]: r["cell"] for r in data["summary"]}
        for dataset in sorted(cells, key=lambda d: _cell_key(cells[d])):
            first = next(r for (d, _), r in rows.items() if d == dataset)
            line = [first["driver"], first["cell"],
                    f"{first['test_frames']} ({first['test_visible']})",
                    f"{first['baseline_median_px']:.1f} / {first['baseline_p90_px']:.0f}"]
            line += [_probe_cell(rows.get((dataset, s))) for s, _ in SENSORS]
            if offline:
                s = single.get(dataset)
                line.append("-" if s is None else
                            f"{_pct(s['found_within_12_5px'])} "
                            f"({_pct(s['reported_when_hidden'])})")
            out.append("| " + " | ".join(line) + " |")
    return "\n".join(out)


def closed_loop_table(loop: dict) -> str:
    """Per cell: success / strict rate of each row and the tracker's paired difference to
    no action (success, episode by episode)."""
    head = ["cell", "episodes", "expert", "no action", "event tracker",
            "tracker - no action, success points [95 %], wins / losses"]
    out = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for c in loop["cells"]:
        rows = c["rows"]
        line = [c["cell"], str(max(r["episodes"] for r in rows.values()))]
        for row in ("expert", "no_action", "event_tracker"):
            r = rows.get(row)
            line.append("-" if r is None else
                        f"{100 * r['success']:.1f} / {100 * r['strict_success']:.1f} %")
        p = c.get("tracker_vs_no_action_success")
        line.append("-" if not p else f"{100 * p['mean_diff']:+.1f} [{100 * p['ci95'][0]:+.1f}, "
                                      f"{100 * p['ci95'][1]:+.1f}], {p['wins']} / {p['losses']}")
        out.append("| " + " | ".join(line) + " |")
    return "\n".join(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--probe", type=Path, action="append", default=[], required=True)
    ap.add_argument("--offline", type=Path, default=None)
    ap.add_argument("--closed-loop", type=Path, default=None)
    args = ap.parse_args(argv)
    try:
        probes = [json.loads(p.read_text()) for p in args.probe]
        offline = json.loads(args.offline.read_text()) if args.offline else None
        loop = json.loads(args.closed_loop.read_text()) if args.closed_loop else None
    except (OSError, ValueError) as exc:
        print(f"probe_summary: {exc}", file=sys.stderr)
        return 2
    print(probe_table(probes, offline))
    if loop is not None:
        print()
        print(closed_loop_table(loop))
    return 0


if __name__ == "__main__":
    sys.exit(main())
