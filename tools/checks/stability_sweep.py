#!/usr/bin/env python3
"""Stability sweep (issue 8): every stiff or extreme setting is stable, detected, or not.

    tools/checks/stability_sweep.py [--quick] --out DIR

Runs the grid of sebvs/numerics/stability.py (QUICK: the one tests/test_stability_sweep.py
runs; FULL otherwise) and writes DIR/stability.json:
    {"grid", "counts": {"stable", "detected", "undetected"}, "by_kind": {kind: counts},
     "cases": [{"name", "kind", "params", "class", "reason", "t"}], "wall_seconds"}
and prints the counts and every undetected case. MuJoCo's own warnings go to
DIR/MUJOCO_LOG.TXT (the sweep runs with DIR as its working directory). Exit status 1 when
an undetected case appears.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from tqdm import tqdm  # noqa: E402

from sebvs.numerics import stability, sweep  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="the test suite's grid")
    ap.add_argument("--out", required=True, type=Path)
    a = ap.parse_args(argv)
    out = a.out.resolve()
    out.mkdir(parents=True, exist_ok=True)
    os.chdir(out)
    grid = "quick" if a.quick else "full"
    t0 = time.perf_counter()
    cases = stability.all_cases(grid)
    results = []
    for case in tqdm(cases, unit="case", desc=f"stability sweep ({grid})", dynamic_ncols=True):
        results.append(stability.run_case(case))
    summary = {"grid": grid, **sweep.summarise(results),
               "wall_seconds": round(time.perf_counter() - t0, 2)}
    (out / "stability.json").write_text(json.dumps(summary, indent=1, default=str))
    print(f"{len(results)} cases: {summary['counts']}")
    for kind, counts in summary["by_kind"].items():
        print(f"  {kind:12s} {counts}")
    bad = [r for r in results if r["class"] == "undetected"]
    for r in bad:
        print(f"UNDETECTED {r['name']}: {r['reason']}")
    print(f"wrote {out / 'stability.json'} in {summary['wall_seconds']} s")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
