#!/usr/bin/env python3
"""The event-only driver (sebvs/experts/event_agent.py) in closed loop in the Gymnasium
environment, on train-split seeds: the loop its settings were chosen in, kept out of the
dev and test seeds that tools/checks/event_tracker_eval.py reports on.

Per cell (condition/scene): N episodes of `SEBVS/ERPNav-v1` (the lockstep topology's loop
in one process, sebvs/envs) from one topology seed, the driver reading only `obs["events"]`;
prints each cell's frame-pooled success (the paper's 50 px at 160 px) and strict (12.5 px)
rate and the share of frames with the target in view, then their means over the cells.

    tools/checks/event_tracker_env.py [--cells nominal_physical/indoor,...] [--episodes 3]
        [--episode-s 10] [--seed 500] [--set tracker.KEY=VALUE] [--set driver.KEY=VALUE]
        [--json FILE] [--verbose]
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from dataclasses import asdict, fields
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
os.environ.setdefault("MUJOCO_GL", "egl")

from sebvs.data.splits import SPLITS  # noqa: E402
from sebvs.experts.event_agent import EventAgentConfig, EventTrackerAgent  # noqa: E402
from sebvs.experts.event_tracker import EventTrackerConfig  # noqa: E402

CELLS = ("nominal_physical/indoor", "nominal_physical/outdoor", "hdr/indoor", "hdr/outdoor",
         "dusk_fast/indoor", "dusk_fast/outdoor")
CONFIGS = {"tracker": EventTrackerConfig, "driver": EventAgentConfig}


def settings(lines: list[str]) -> dict[str, dict]:
    """--set tracker.KEY=VALUE / driver.KEY=VALUE lines -> {"tracker": {...}, "driver":
    {...}}; ValueError (one line) for an unknown key or a value of the wrong type."""
    out: dict[str, dict] = {"tracker": {}, "driver": {}}
    for line in lines:
        key, eq, value = line.partition("=")
        which, _, name = key.partition(".")
        if not eq or which not in CONFIGS:
            raise ValueError(f"--set {line!r}: expected tracker.KEY=VALUE or driver.KEY=VALUE")
        known = {f.name: f.type for f in fields(CONFIGS[which])}
        if name not in known:
            raise ValueError(f"--set {line!r}: unknown {which} setting (one of "
                             f"{', '.join(known)})")
        default = getattr(CONFIGS[which](), name)
        try:
            out[which][name] = type(default)(value)
        except ValueError:
            raise ValueError(f"--set {line!r}: not a {type(default).__name__}") from None
    return out


def run_cell(cell: str, args, given: dict) -> dict:
    import gymnasium as gym
    import sebvs.envs  # noqa: F401  (registers the ids)
    condition, scenario = cell.split("/")
    env = gym.make("SEBVS/ERPNav-v1", condition=condition, scenario=scenario,
                   obs=("events",), episode_s=args.episode_s)
    records = []
    obs, info = env.reset(seed=args.seed)
    for e in range(args.episodes):
        if e:
            obs, info = env.reset()
        agent = EventTrackerAgent(EventTrackerConfig(**given["tracker"]),
                                  EventAgentConfig(**given["driver"]))
        done = False
        while not done:
            cmd, det, mode = agent.act(obs["events"], 0.1, episode=e)
            if args.verbose:
                t = info["truth"]
                print(cell, e, info["tick"], t["visible"], np.round(t["centroid"]),
                      None if det is None else np.round(det.centroid), mode, np.round(cmd, 2))
            obs, _, terminated, truncated, info = env.step(cmd)
            done = terminated or truncated
        records.append(info["episode_metrics"])
    env.close()
    w = np.array([m["frames"] for m in records], np.float64)
    return {"cell": cell, "episodes": len(records),
            **{k: float((np.array([m[k] for m in records]) * w).sum() / w.sum())
               for k in ("success", "strict_success", "visible")}}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cells", default=",".join(CELLS))
    ap.add_argument("--episodes", type=int, default=3)
    ap.add_argument("--episode-s", type=float, default=10.0)
    ap.add_argument("--seed", type=int, default=500, help="topology seed, train split")
    ap.add_argument("--set", action="append", default=[], metavar="WHICH.KEY=VALUE")
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--verbose", action="store_true", help="one line per tick")
    args = ap.parse_args(argv)
    if args.seed not in SPLITS["train"]:
        ap.error(f"--seed {args.seed}: settings are chosen on the train split "
                 f"({SPLITS['train']}) only")
    try:
        given = settings(args.set)
        CONFIGS["tracker"](**given["tracker"]), CONFIGS["driver"](**given["driver"])
    except (ValueError, TypeError) as exc:
        ap.error(str(exc))
    t0 = time.perf_counter()
    rows = []
    for cell in args.cells.split(","):
        if cell not in CELLS:
            ap.error(f"unknown cell {cell!r} (one of {', '.join(CELLS)})")
        rows.append(run_cell(cell, args, given))
        r = rows[-1]
        print(f"{cell}: success {100 * r['success']:.1f} %, strict "
              f"{100 * r['strict_success']:.1f} %, visible {100 * r['visible']:.1f} %",
              flush=True)
    mean = {k: float(np.mean([r[k] for r in rows])) for k in ("success", "strict_success")}
    print(f"mean over cells: success {100 * mean['success']:.1f} %, strict "
          f"{100 * mean['strict_success']:.1f} % ({time.perf_counter() - t0:.0f} s)")
    if args.json:
        out = {"seed": args.seed, "episodes": args.episodes, "episode_s": args.episode_s,
               "tracker": asdict(EventTrackerConfig(**given["tracker"])),
               "driver": asdict(EventAgentConfig(**given["driver"])), "cells": rows,
               "mean": mean}
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(out, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
