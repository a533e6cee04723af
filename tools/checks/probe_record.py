#!/usr/bin/env python3
"""Record the stream probe's datasets (docs/probe.md): one dataset per nav cell
(condition x scene variant), each `sebvs record topologies/nav_record.toml --condition C
--scenario S` (the condition's overrides, the topology's per-episode randomisation off) on
a train-split topology seed, and the wall time each took.

Three drivers, the same scenes and seeds:
  expert  the recording topology as written: the expert drives (reading the ideal render),
          as in the policies' own training data; the target stays near the image centre
  still   the same with the expert's gains and search set to 0: the robot holds still (the
          no-action row's view), so the target crosses the image and leaves it, which
          gives the visibility head both classes
  wander  the expert with execution noise on every command: the robot moves and turns,
          and the target wanders over the image

    tools/checks/probe_record.py [--drivers expert,still,wander] [--cells all] [--episodes 10]
        [--episode-s 10] [--seed 500] [--workers 2] [--out datasets/probe]
        [--json docs/figures/probe_record.json] [--dry-run]

Each dataset lands in OUT/DRIVER/CONDITION__SCENARIO; a dataset that already holds the
episodes asked for is skipped (`--fill`: a stopped run records only what is missing). The
JSON lists each cell's command, episodes, frames and wall seconds.
"""
from __future__ import annotations

import argparse
import json
import os
import shlex
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

CONDITIONS = ("nominal_physical", "hdr", "dusk_fast", "flicker_120")
SCENARIOS = ("indoor", "outdoor")
CELLS = tuple(f"{c}/{s}" for c in CONDITIONS for s in SCENARIOS)
# the expert with every gain and its search at 0: it answers each tick with [0, 0]
STILL = ("expert.yaw_kp=0.0", "expert.yaw_ki=0.0", "expert.yaw_kd=0.0",
         "expert.speed_kp=0.0", "expert.speed_ki=0.0", "expert.speed_kd=0.0",
         "expert.search_w=0.0")
# the expert with execution noise on every applied command (std 0.3 in v, 1.5 in w, then
# the scene's clip): the robot moves and turns as the expert does, and the target wanders
# over the image (|u - centre| median 18 px at 160 px, measured in the env on seed 500)
WANDER = ("sim.command_noise=[0.3, 1.5]",)
DRIVERS = {"expert": (), "still": STILL, "wander": WANDER}


def dataset_dir(out: Path, driver: str, cell: str) -> Path:
    condition, scenario = cell.split("/")
    return out / driver / f"{condition}__{scenario}"


def command(cell: str, driver: str, args) -> list[str]:
    condition, scenario = cell.split("/")
    sets = [f"sim.episode_s={float(args.episode_s)}", f"topology.seed={args.seed}",
            *DRIVERS[driver]]
    cmd = [str(ROOT / ".venv" / "bin" / "sebvs"), "record", "topologies/nav_record.toml",
           "--condition", condition, "--scenario", scenario, "--episodes",
           str(args.episodes), "--out", str(dataset_dir(args.out, driver, cell)), "--fill",
           "--workers", str(args.workers)]
    for s in sets:
        cmd += ["--set", s]
    return cmd


def held(path: Path) -> int:
    index = path / "index.json"
    if not index.exists():
        return 0
    return len(json.loads(index.read_text()).get("episodes", []))


def frames(path: Path) -> int:
    index = path / "index.json"
    if not index.exists():
        return 0
    return sum(int(e.get("frames", 0)) for e in json.loads(index.read_text())["episodes"])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--drivers", default="expert,still,wander",
                    help="comma-separated: expert, still, wander (default all)")
    ap.add_argument("--cells", default="all", help=f"comma-separated of {', '.join(CELLS)}")
    ap.add_argument("--episodes", type=int, default=10)
    ap.add_argument("--episode-s", type=float, default=10.0)
    ap.add_argument("--seed", type=int, default=500, help="topology seed (train split)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", type=Path, default=Path("datasets/probe"))
    ap.add_argument("--json", type=Path, default=None, help="write the costs here")
    ap.add_argument("--dry-run", action="store_true", help="print the commands only")
    args = ap.parse_args(argv)
    cells = CELLS if args.cells == "all" else tuple(args.cells.split(","))
    drivers = tuple(args.drivers.split(","))
    for name in drivers:
        if name not in DRIVERS:
            ap.error(f"unknown driver {name!r} (one of {', '.join(DRIVERS)})")
    for cell in cells:
        if cell not in CELLS:
            ap.error(f"unknown cell {cell!r} (one of {', '.join(CELLS)})")
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    rows = []
    previous = json.loads(args.json.read_text()) if args.json and args.json.exists() else {}
    done = {(r["driver"], r["cell"]): r for r in previous.get("cells", [])}
    for driver in drivers:
        for cell in cells:
            cmd = command(cell, driver, args)
            shown = shlex.join(["sebvs", *cmd[1:]])
            path = dataset_dir(args.out, driver, cell)
            if args.dry_run:
                print(shown)
                continue
            if held(path) >= args.episodes:
                print(f"{driver} {cell}: {path} holds {held(path)} episodes, skipped",
                      file=sys.stderr)
                if (driver, cell) in done:
                    rows.append(done[(driver, cell)])
                continue
            t0 = time.perf_counter()
            print(f"{driver} {cell}: {shown}", file=sys.stderr, flush=True)
            code = subprocess.run(cmd, cwd=ROOT, env=env).returncode
            wall = time.perf_counter() - t0
            if code != 0:
                print(f"{driver} {cell}: sebvs record exited {code}", file=sys.stderr)
                return code
            rows.append({"driver": driver, "cell": cell, "command": shown,
                         "episodes": held(path), "frames": frames(path),
                         "sim_s": args.episodes * args.episode_s, "wall_s": round(wall, 1)})
            print(json.dumps(rows[-1]), flush=True)
            if args.json:
                merged = {**done, **{(r["driver"], r["cell"]): r for r in rows}}
                args.json.parent.mkdir(parents=True, exist_ok=True)
                args.json.write_text(json.dumps({"cells": list(merged.values())}, indent=1)
                                     + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
