#!/usr/bin/env python3
"""The event-only tracker in closed loop, per nav cell, beside the expert and no action.

Per cell (a physical condition x a scene variant), each row one topology run of N seeded
episodes on the same topology seed, so the same episodes in every row:
  expert         topologies/nav_expert.toml as `sebvs eval` runs it (its overrides from
                 sebvs.eval.plan.EvalPlan: the policy topology's physics and rates)
  no_action      topologies/nav_policy.toml with the baseline answering each tick, as
                 `sebvs eval` runs it
  event_tracker  topologies/nav_event_tracker.toml (actors/event_tracker.py: an event
                 cluster tracker driving the nav expert's PIDs from the event frames alone)
with the condition's overrides and its event sensor (sebvs/conditions.py), the scene
variant, the lockstep clock, and the tracker sink's episode lines (actors/tracker.py).
`sebvs eval --modalities` cannot name the tracker row and sebvs/eval is not changed for
it: this driver runs the rows itself and pools each row's lines as `sebvs eval` does
(frame-weighted rates with Wilson intervals; the episode rate) with sebvs.metrics, and
pairs the tracker with no action and with the expert episode by episode.

    tools/checks/event_tracker_eval.py [--cells all] [--rows expert,no_action,event_tracker]
        [--episodes 10] [--episode-s S] [--split dev|test] [--seed N]
        [--out out/event_tracker] [--json docs/figures/event_tracker_closed_loop.json]
        [--set ACTOR.KEY=VALUE ...]

A run whose episode file already holds N episodes of the seed is not run again (resume),
and the JSON is rewritten after every cell. The seeds are `sebvs eval`'s: --split dev
(1,000-99,999, the default) or test (100,000-199,999; the sensor study's test rows ran
seed 100,000 with 30 s episodes, the topologies' length, which --episode-s left out
keeps); the seed must lie in the split. --set lines apply to the tracker row only (e.g.
--set driver.coast_s=0.5).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
os.environ.setdefault("MUJOCO_GL", "egl")

from tqdm import tqdm  # noqa: E402

from sebvs.conditions import task  # noqa: E402
from sebvs.data.splits import SPLITS  # noqa: E402
from sebvs.metrics import paired_comparison, wilson_interval  # noqa: E402
from sebvs.runtime.overrides import as_mapping, merge, replace  # noqa: E402

CONDITIONS = ("nominal_physical", "hdr", "dusk_fast", "flicker_120")
SCENARIOS = ("indoor", "outdoor")
CELLS = tuple(f"{c}/{s}" for c in CONDITIONS for s in SCENARIOS)
ROWS = ("expert", "no_action", "event_tracker")
TRACKER_TOPOLOGY = ROOT / "topologies" / "nav_event_tracker.toml"


def episode_file(out: Path, cell: str, row: str) -> Path:
    condition, scenario = cell.split("/")
    return out / "episodes" / f"{condition}__{scenario}__{row}.jsonl"


def read_lines(path: Path, seed: int) -> list[dict]:
    if not path.exists():
        return []
    out = []
    for line in path.read_text().splitlines():
        try:
            rec = json.loads(line)
        except json.JSONDecodeError:
            break
        if rec.get("topology_seed") != seed:
            break
        out.append(rec)
    return out


def run_spec(cell: str, row: str, args) -> tuple[Path, dict]:
    """The topology file and overrides of one row of one cell."""
    from sebvs.eval.plan import BASELINE, EvalPlan, Run
    condition, scenario = cell.split("/")
    sim = {} if args.episode_s is None else {"sim": {"episode_s": float(args.episode_s)}}
    path = episode_file(args.out, cell, row)
    if row in ("expert", "no_action"):
        plan = EvalPlan(task="nav", modalities=[], conditions=[condition],
                        scenarios=[scenario], episodes=args.episodes, out=args.out,
                        split=args.split, seed=args.seed, extra=sim)
        topology, overrides = plan.overrides(Run(condition, scenario,
                                                 "expert" if row == "expert" else BASELINE))
        # the same file naming for every row
        overrides = merge(overrides, {"tracker": {"path": str(path)}})
        return topology, overrides
    spec = task("nav")
    cond = spec.condition(condition)
    run_sets = {"topology": {"seed": args.seed, "clock": "lockstep"},
                "sim": {"episodes": args.episodes},
                "tracker": {"path": str(path),
                            "label": replace({"condition": condition, "modality": row,
                                              "topology_seed": args.seed})}}
    return TRACKER_TOPOLOGY, merge(run_sets, cond.overrides(),
                                   spec.scenario(scenario).overrides(),
                                   cond.event_sensor_overrides(), sim,
                                   as_mapping(args.set))


def play(cell: str, row: str, args, bar) -> list[dict]:
    from sebvs.eval.run import play_to_end
    from sebvs.runtime.supervisor import RunFailed
    path = episode_file(args.out, cell, row)
    done = read_lines(path, args.seed)
    if len(done) >= args.episodes:
        bar.update(args.episodes)
        return done[:args.episodes]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.unlink(missing_ok=True)
    topology, overrides = run_spec(cell, row, args)
    start = bar.n
    sup = play_to_end(topology, overrides, args.out / "runs", bar, f"{cell} {row}")
    lines = read_lines(path, args.seed)
    bar.update(start + len(lines) - bar.n)
    if len(lines) < args.episodes:
        raise RunFailed(f"{cell} {row}: {len(lines)} of {args.episodes} episodes finished "
                        f"(see {sup.rundir}/logs)")
    return lines


def pool(lines: list[dict]) -> dict:
    """A row's episodes pooled as `sebvs eval` pools them (frame-weighted rates)."""
    ms = [e["metrics"] for e in lines]
    frames = np.array([m["frames"] for m in ms], np.float64)
    out = {"episodes": len(ms), "frames": int(frames.sum())}
    for key in ("success", "strict_success"):
        hits = float((np.array([m[key] for m in ms]) * frames).sum())
        out[key] = hits / frames.sum()
        out[f"{key}_ci95"] = list(wilson_interval(hits, int(frames.sum())))
    ok = np.array([m["episode_success"] for m in ms])
    out["episode_success"] = float(ok.mean())
    out["visible"] = float((np.array([m["visible"] for m in ms]) * frames).sum() / frames.sum())
    vis = np.array([m["visible"] for m in ms]) * frames
    err = np.array([m["centroid_error_px"] for m in ms])
    keep = vis > 0
    out["centroid_error_px"] = float((vis[keep] * err[keep]).sum() / vis[keep].sum()) \
        if keep.any() else math.nan
    health = [e.get("health") or {} for e in lines]
    out["nonfinite_actions"] = int(sum(h.get("nonfinite_actions", 0) for h in health))
    out["rejected"] = int(sum(h.get("rejected", 0) for h in health))
    return out


def per_episode(lines: list[dict], key: str) -> list[float]:
    return [e["metrics"][key] for e in sorted(lines, key=lambda e: e["episode"])]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cells", default="all", help=f"comma-separated of {', '.join(CELLS)}")
    ap.add_argument("--rows", default=",".join(ROWS), help="comma-separated of "
                    + ", ".join(ROWS))
    ap.add_argument("--episodes", type=int, default=10)
    ap.add_argument("--episode-s", type=float, default=None,
                    help="episode length, s (default: the topologies', 30 s)")
    ap.add_argument("--split", choices=("dev", "test"), default="dev",
                    help="the seeds' split (default dev)")
    ap.add_argument("--seed", type=int, default=None,
                    help="topology seed (default: the split's first, dev 1000, test 100000)")
    ap.add_argument("--out", type=Path, default=Path("out/event_tracker"))
    ap.add_argument("--json", type=Path, default=None, help="write the summary here")
    ap.add_argument("--set", action="append", default=[], metavar="ACTOR.KEY=VALUE",
                    help="an override of the tracker row's topology (repeatable)")
    ap.add_argument("--table", action="store_true", help="print the Markdown table too")
    args = ap.parse_args(argv)
    split = SPLITS[args.split]
    if args.seed is None:
        args.seed = split.first
    if args.seed not in split:
        ap.error(f"--seed {args.seed} is outside the {args.split} split ({split})")
    if args.episodes < 1 or (args.episode_s is not None and not args.episode_s > 0):
        ap.error("--episodes and --episode-s must be positive")
    cells = CELLS if args.cells == "all" else tuple(args.cells.split(","))
    rows = tuple(args.rows.split(","))
    for c in cells:
        if c not in CELLS:
            ap.error(f"unknown cell {c!r} (one of {', '.join(CELLS)})")
    for r in rows:
        if r not in ROWS:
            ap.error(f"unknown row {r!r} (one of {', '.join(ROWS)})")
    bar = tqdm(total=len(cells) * len(rows) * args.episodes, unit="ep", desc="closed loop")
    summary, walls = [], {}

    def result() -> dict:
        return {"seed": args.seed, "split": args.split, "episodes": args.episodes,
                "episode_s": args.episode_s, "tracker_overrides": list(args.set),
                "cells": summary}
    for cell in cells:
        entry = {"cell": cell, "rows": {}}
        lines = {}
        for row in rows:
            bar.set_postfix_str(f"{cell} {row}")
            t0 = time.perf_counter()
            lines[row] = play(cell, row, args, bar)
            walls[f"{cell} {row}"] = round(time.perf_counter() - t0, 1)
            entry["rows"][row] = {**pool(lines[row]), "wall_s": walls[f"{cell} {row}"]}
        for other in ("no_action", "expert"):
            if "event_tracker" in lines and other in lines:
                entry[f"tracker_vs_{other}"] = paired_comparison(
                    per_episode(lines["event_tracker"], "strict_success"),
                    per_episode(lines[other], "strict_success"))
                entry[f"tracker_vs_{other}_success"] = paired_comparison(
                    per_episode(lines["event_tracker"], "success"),
                    per_episode(lines[other], "success"))
        summary.append(entry)
        if args.json:
            args.json.parent.mkdir(parents=True, exist_ok=True)
            args.json.write_text(json.dumps(result(), indent=1) + "\n")
    bar.close()
    if args.table:
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        from probe_summary import closed_loop_table
        print(closed_loop_table(result()), file=sys.stderr)
    print(json.dumps(result()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
