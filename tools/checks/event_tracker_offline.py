#!/usr/bin/env python3
"""The event-cluster tracker's measurement (sebvs/experts/event_tracker.py) on recorded
event frames, against the sim's truth: what one frame holds for a non-learned detector,
beside what the probe (sebvs/probe) learns from the same frames.

Per dataset, on the episodes the probe tests on (the recipe's split: sebvs/probe/fit.py)
or on all (--all-episodes):
  single   a fresh tracker per frame (no memory, the acquisition threshold `acquire_z`):
           the share of visible frames where it finds a cluster within 12.5 px of the
           true centroid (the strict radius at 160 px), its error there (median), and the
           share of frames without the target where it reports one anyway;
  tracked  one tracker over each episode (memory: the gate, the constant velocity, the
           coast), on the recording's own driving (not its own: closed loop is
           tools/checks/event_tracker_eval.py and tools/checks/event_tracker_env.py):
           the same shares.
Errors in px of the recorded image (160 px in the probe's recordings).

    tools/checks/event_tracker_offline.py datasets/probe/still/* [--json FILE]
        [--all-episodes] [--set KEY=VALUE ...]   # EventTrackerConfig fields
"""
from __future__ import annotations

import argparse
import json
import sys
from dataclasses import asdict
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from sebvs.experts.event_tracker import EventTracker, EventTrackerConfig  # noqa: E402
from sebvs.probe.data import ProbeDataError, load_frames  # noqa: E402
from sebvs.probe.fit import Recipe, split  # noqa: E402

STRICT_PX = 12.5


def _shares(found: list, errors: list, visible: np.ndarray) -> dict:
    found, errors = np.array(found, bool), np.array(errors, np.float64)
    near = found & (errors < STRICT_PX)
    return {"found_within_12_5px": float(near[visible].mean()) if visible.any() else None,
            "error_median_px": float(np.median(errors[found & visible]))
            if (found & visible).any() else None,
            "reported_when_hidden": float(found[~visible].mean()) if (~visible).any()
            else None}


def check(root: Path, cfg: EventTrackerConfig, all_episodes: bool) -> dict:
    frames = load_frames(root, ("event",))
    index = np.arange(len(frames.episode)) if all_episodes else split(frames, Recipe())[1]
    results = {}
    for mode in ("single", "tracked"):
        tracker = EventTracker(cfg)
        found, errors, last = [], [], None
        for k in index:
            if mode == "single" or frames.episode[k] != last:
                tracker.reset()
            last = frames.episode[k]
            det = tracker.step(frames.events[k], 0.1)
            found.append(det is not None)
            errors.append(np.inf if det is None or not frames.visible[k] else
                          float(np.hypot(*(np.array(det.centroid) - frames.centroid[k]))))
        results[mode] = _shares(found, errors, frames.visible[index])
    return {"dataset": str(root), "frames": int(len(index)),
            "visible_frames": int(frames.visible[index].sum()), **results}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("datasets", nargs="+", type=Path)
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--all-episodes", action="store_true",
                    help="every episode, not only the probe's test episodes")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    fields = asdict(EventTrackerConfig())
    given = {}
    for item in args.set:
        key, _, value = item.partition("=")
        if key not in fields:
            ap.error(f"unknown tracker setting {key!r} (one of {', '.join(fields)})")
        try:
            given[key] = type(fields[key])(value)
        except ValueError:
            ap.error(f"--set {item}: {value!r} is not a {type(fields[key]).__name__}")
    try:
        cfg = EventTrackerConfig(**given)
        rows = [check(d, cfg, args.all_episodes) for d in args.datasets]
    except (ProbeDataError, ValueError) as exc:
        print(f"event_tracker_offline: {exc}", file=sys.stderr)
        return 2
    out = {"config": asdict(cfg), "episodes": "all" if args.all_episodes else "probe test",
           "datasets": rows}
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(out, indent=1) + "\n")
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
