#!/usr/bin/env python3
"""Where did the arm aim? Each graspable episode's last pose (the one grasped) against
every cube, so a miss can be told apart from another.

    research/ideal8/arm_aims.py out/arm_aim/dev5001 --conditions moving --scenarios multi \\
        --radius-mm 20 --json out/arm_aim/dev5001_aims.json

Reads an `sebvs eval` output directory (or its results.json) of the arm task, made with a
tracker that records cube positions (the target index and `cubes_mm` per scored tick).
For the last tick of each episode where the task asks for a grasp, every cube is led as
the scored reference is (the reference's x, y minus the target cube's: all cubes ride the
same belt), and the pose is classed by the nearest led cube and its distance:

    on target    nearest is the target, within the radius
    off target   nearest is the target, beyond the radius: the right cube, badly aimed
    other cube   nearest is another cube, within the radius: the wrong cube
    between      nearest is another cube, beyond the radius

Per modality, condition and scenario: episodes in each class, how many of them grasped,
and the median offset (pose minus led target, mm, x and y) over the missed grasps. y is
the belt's direction on the arm scene.
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from sebvs.eval.results import read_results  # noqa: E402

CLASSES = ("on target", "off target", "other cube", "between")


def classify(metrics: dict, radius_mm: float) -> dict | None:
    """One arm episode's metrics -> {"class", "grasped", "offset_mm": [dx, dy],
    "distance_mm"}; None where the last tick asked for no grasp or has no cube record."""
    cubes, targets = metrics.get("cubes_mm"), metrics.get("target")
    if not cubes or not targets or metrics.get("grasp_success") is None:
        return None
    if metrics["modes"][-1] != "grasp" or targets[-1] < 0:
        return None
    target = targets[-1]
    xy = np.asarray([c[:2] for c in cubes[-1]], np.float64)
    lead = np.asarray(metrics["expert"][-1][:2], np.float64) * 1e3 - xy[target]
    led = xy + lead
    pose = np.asarray(metrics["pred"][-1][:2], np.float64) * 1e3
    dist = np.linalg.norm(led - pose, axis=1)
    nearest = int(np.argmin(dist))
    within = dist[nearest] <= radius_mm
    name = ("on target" if within else "off target") if nearest == target else \
        ("other cube" if within else "between")
    return {"class": name, "grasped": bool(metrics["grasp_success"]),
            "offset_mm": [round(float(v), 1) for v in pose - led[target]],
            "distance_mm": round(float(dist[target]), 1)}


def summarise(results: dict, radius_mm: float, conditions=None, scenarios=None) -> dict:
    """{"modality/condition/scenario": {class: {"episodes", "grasped"}, "misses": n,
    "miss_offset_mm": [median dx, median dy] or None}}"""
    if results.get("task") != "arm":
        raise ValueError(f"not an arm evaluation (task {results.get('task')!r})")
    cells: dict[str, list] = defaultdict(list)
    unrecorded = 0
    for ep in results["episodes"]:
        if conditions and ep["condition"] not in conditions:
            continue
        if scenarios and ep["scenario"] not in scenarios:
            continue
        if "cubes_mm" not in ep["metrics"]:
            unrecorded += 1
            continue
        aim = classify(ep["metrics"], radius_mm)
        if aim is not None:
            cells[f"{ep['modality']}/{ep['condition']}/{ep['scenario']}"].append(aim)
    if unrecorded and not cells:
        raise ValueError(f"{unrecorded} episodes hold no cube positions: the evaluation "
                         f"predates the tracker's cube record (actors/tracker.py)")
    table = {}
    for key, aims in sorted(cells.items()):
        row = {c: {"episodes": sum(a["class"] == c for a in aims),
                   "grasped": sum(a["class"] == c and a["grasped"] for a in aims)}
               for c in CLASSES}
        misses = [a["offset_mm"] for a in aims if not a["grasped"]]
        row["misses"] = len(misses)
        row["miss_offset_mm"] = ([round(statistics.median(m[i] for m in misses), 1)
                                  for i in (0, 1)] if misses else None)
        table[key] = row
    return table


def markdown(table: dict, radius_mm: float) -> str:
    head = " | ".join(f"{c} (grasped)" for c in CLASSES)
    lines = [f"Last pose against the led cubes, radius {radius_mm:g} mm",
             "", f"| modality / condition / scenario | {head} | misses: median dx, dy mm |",
             "|---|" + "---|" * (len(CLASSES) + 1)]
    for key, row in table.items():
        cells = " | ".join(f"{row[c]['episodes']} ({row[c]['grasped']})" for c in CLASSES)
        off = row["miss_offset_mm"]
        lines.append(f"| {key} | {cells} | "
                     f"{'-' if off is None else f'{off[0]:+.1f}, {off[1]:+.1f}'} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog="Example:\n" + __doc__.split("\n\n")[1])
    ap.add_argument("evaluation", type=Path, help="an `sebvs eval --task arm` output "
                    "directory or its results.json")
    ap.add_argument("--radius-mm", type=float, default=20.0,
                    help="a pose this close to a led cube aims at it (default 20)")
    ap.add_argument("--conditions", default="", help="comma-separated (default: all)")
    ap.add_argument("--scenarios", default="", help="single, multi (default: both)")
    ap.add_argument("--json", type=Path, help="also write the table here")
    args = ap.parse_args(argv)
    if not args.radius_mm > 0:
        ap.error(f"--radius-mm must be > 0, got {args.radius_mm}")
    split = lambda s: {v for v in s.split(",") if v} or None   # noqa: E731
    try:
        table = summarise(read_results(args.evaluation), args.radius_mm,
                          split(args.conditions), split(args.scenarios))
    except ValueError as exc:
        print(f"arm_aims: {exc}", file=sys.stderr)
        return 2
    if not table:
        print("arm_aims: no graspable episode in the selection", file=sys.stderr)
        return 2
    print(markdown(table, args.radius_mm))
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"radius_mm": args.radius_mm, "cells": table},
                                        indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
