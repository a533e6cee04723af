#!/usr/bin/env python3
"""How often would `sebvs eval table`'s rule give a verdict if the two modalities were one policy?

    research/sensors/rule_null.py --study nav10,nav30,arm10 [--draws 20000] [--json OUT]
    research/sensors/rule_null.py seed0=DIR seed1=DIR seed2=DIR --a rgb+event --b rgb+diff \\
        --min-diff 10 --min-ahead 3 [--metric strict_success]

A reading applies its rule (mean difference >= --min-diff points and >= --min-ahead runs
the same way) to every cell, so across many cells some verdict can come from chance
alone. This asks how likely that is, by randomisation on the reading's own episodes: in
each run (training seed), every episode both modalities scored keeps its two outcomes,
but which of them is A's and which B's is drawn by a fair coin, independently per run and
episode. That is the null "A and B are the same policy on these episodes". The rule is
applied to each draw, as `sebvs eval table` applies it.

Printed per cell: the observed effect and verdict, the chance of "A helps" and of "A
hurts" under the null, and for a cell with a verdict the share of draws with that verdict
and an effect at least as large (its randomisation p). Then, over the cells: the number
of verdicts to expect by chance and the chance of at least one. With --study, the same
over several of the sensor study's readings together (their cells play other episodes,
so their draws are independent).

What it does not resample: the trainings. A second training draw changes which episodes
a policy fails on (research/sensors/log.md has the arm at 10 Hz read on two draws), so
this null is conditional on the policies that were evaluated; it tells how much of a
verdict the episodes alone could make. A diagnostic, not the plan's rule: it changes no
reading.
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from sebvs.eval.results import episodes_by_key as _by_key  # noqa: E402
from sebvs.eval.table import load_runs, scored_pairs, seed_table  # noqa: E402
from sebvs.metrics import points  # noqa: E402


def paired_outcomes(runs: dict[str, dict], a: str, b: str, metric: str,
                    cells: list[str]) -> dict[str, list[np.ndarray]]:
    """Per cell, per run, the (n, 2) array of A's and B's outcome on each episode both
    scored: the pairs `sebvs eval table` averages."""
    out: dict[str, list[np.ndarray]] = {cell: [] for cell in cells}
    for res in runs.values():
        ea, eb = _by_key(res, a), _by_key(res, b)
        for cell in cells:
            keys = sorted(k for k in ea if f"{k[0]}/{k[1]}" == cell)
            out[cell].append(np.array(scored_pairs(ea, eb, keys, metric), float)
                             .reshape(-1, 2))
    return out


def null_verdicts(pairs: list[np.ndarray], min_diff: float, min_ahead: int, draws: int,
                  rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(mean difference in points, verdict) of ``draws`` label-swapped copies of one cell;
    verdict +1 helps, -1 hurts, 0 no clear difference. pairs: per run, (n, 2) outcomes."""
    diffs = []
    for p in pairs:
        d = p[:, 0] - p[:, 1]                                   # (n,)
        signs = rng.integers(0, 2, size=(draws, len(d))) * 2 - 1
        diffs.append((signs * d).mean(axis=1) if len(d) else np.zeros(draws))
    per_run = np.stack(diffs, axis=1)                           # (draws, runs)
    mean = 100 * per_run.mean(axis=1)
    ahead, behind = (per_run > 0).sum(axis=1), (per_run < 0).sum(axis=1)
    verdict = np.where((mean >= min_diff) & (ahead >= min_ahead), 1,
                       np.where((-mean >= min_diff) & (behind >= min_ahead), -1, 0))
    return mean, verdict


def rule_null(runs: dict[str, dict], a: str, b: str, metric: str | None, min_diff: float,
              min_ahead: int | None, draws: int, seed: int) -> dict:
    """The reading (seed_table) and, per cell it read, the rule's verdicts under the null."""
    table = seed_table(runs, a, b, metric, min_diff, min_ahead)
    need = table["rule"]["min_ahead"]
    rng = np.random.default_rng(seed)
    pairs = paired_outcomes(runs, a, b, table["metric"], list(table["cells"]))
    cells, any_verdict = {}, np.zeros(draws, int)
    for cell, observed in table["cells"].items():
        mean, verdict = null_verdicts(pairs[cell], min_diff, need, draws, rng)
        seen = {f"{a} helps": 1, f"{a} hurts": -1}.get(observed["reading"], 0)
        effect = 100 * observed["mean_diff"]
        as_large = (verdict == seen) & (np.abs(mean) >= abs(effect) - 1e-9)
        cells[cell] = {"effect_points": effect, "reading": observed["reading"],
                       "episodes_per_run": [len(p) for p in pairs[cell]],
                       "p_helps": float((verdict == 1).mean()),
                       "p_hurts": float((verdict == -1).mean()),
                       "p_as_large": float(as_large.mean()) if seen else None}
        any_verdict += verdict != 0
    seen = sum(c["reading"] != "no clear difference" for c in cells.values())
    return {"metric": table["metric"], "a": a, "b": b, "rule": table["rule"],
            "runs": table["runs"], "draws": draws, "seed": seed, "cells": cells,
            "verdicts_seen": seen, "verdicts_expected": float(any_verdict.mean()),
            "p_at_least_one": float((any_verdict > 0).mean()),
            "p_at_least_as_many": float((any_verdict >= seen).mean()),
            "any_verdict_per_draw": any_verdict}


def markdown(name: str, result: dict) -> str:
    lines = [f"{name}: {result['a']} - {result['b']}, {result['metric']}; rule: >= "
             f"{result['rule']['min_diff_points']:g} points and >= "
             f"{result['rule']['min_ahead']} of {len(result['runs'])} runs the same way; "
             f"{result['draws']} label-swapped draws", "",
             "| cell | effect (points) | reading | episodes per run | P(helps) under the null "
             "| P(hurts) under the null | p, as large |", "|---|---|---|---|---|---|---|"]
    for cell, c in result["cells"].items():
        p = "-" if c["p_as_large"] is None else f"{c['p_as_large']:.4f}"
        lines.append(f"| {cell} | {points(c['effect_points'] / 100)} | {c['reading']} "
                     f"| {', '.join(map(str, c['episodes_per_run']))} | {c['p_helps']:.4f} "
                     f"| {c['p_hurts']:.4f} | {p} |")
    lines += ["", f"verdicts: {result['verdicts_seen']} seen in {len(result['cells'])} cells; "
                  f"{result['verdicts_expected']:.2f} expected by chance; at least one with "
                  f"chance {result['p_at_least_one']:.3f}, as many or more with chance "
                  f"{result['p_at_least_as_many']:.3f}", ""]
    return "\n".join(lines)


def study_runs(name: str) -> list[str]:
    """A sensor study reading's seed_table arguments, by its TASKRATE name (nav10...)."""
    from research.sensors.sensor_study import READINGS, STUDY_DIR, read_arguments
    if name not in READINGS:
        raise ValueError(f"--study {name!r}: expected one of {', '.join(READINGS)}")
    return read_arguments(STUDY_DIR, *READINGS[name])


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("runs", nargs="*", metavar="NAME=DIR",
                    help="as `sebvs eval table`: an `sebvs eval --out` directory per training seed")
    ap.add_argument("--study", metavar="TASKRATE[,TASKRATE]",
                    help="the sensor study's readings instead of NAME=DIR (nav10, nav30, "
                         "arm10, arm30), each with its plan's rule and metric")
    ap.add_argument("--a", help="modality A (e.g. rgb+event)")
    ap.add_argument("--b", help="modality B (e.g. rgb+diff)")
    ap.add_argument("--metric", help="episode metric (default: the task's first)")
    ap.add_argument("--min-diff", type=float, default=10.0,
                    help="points of mean difference for a verdict (default 10)")
    ap.add_argument("--min-ahead", type=int, help="runs that must agree (default: all)")
    ap.add_argument("--draws", type=int, default=20_000,
                    help="label-swapped draws per cell (default 20000)")
    ap.add_argument("--seed", type=int, default=0, help="the draws' random seed (default 0)")
    ap.add_argument("--json", type=Path, help="also write the figures here")
    return ap


def main(argv: list[str] | None = None) -> int:
    ap = parser()
    args = ap.parse_args(argv)
    if bool(args.study) == bool(args.runs):
        ap.error("give NAME=DIR runs or --study, one of the two")
    if args.study and (args.a or args.b or args.metric or args.min_ahead is not None
                       or args.min_diff != ap.get_default("min_diff")):
        ap.error("--study reads each reading by its plan's rule and metric: give no --a, "
                 "--b, --metric, --min-diff or --min-ahead with it")
    if args.draws < 1:
        ap.error(f"--draws must be at least 1, got {args.draws}")
    try:
        readings = ([(name, ap.parse_args(study_runs(name))) for name in args.study.split(",")]
                    if args.study else [("reading", args)])
    except ValueError as exc:
        print(f"rule_null: {exc}", file=sys.stderr)
        return 2
    results, total = {}, np.zeros(args.draws, int)
    for k, (name, spec) in enumerate(readings):
        if not spec.a or not spec.b:
            ap.error("--a and --b are needed with NAME=DIR runs")
        try:
            runs = load_runs(spec.runs)
            result = rule_null(runs, spec.a, spec.b, spec.metric, spec.min_diff,
                               spec.min_ahead, args.draws, args.seed + k)
        except ValueError as exc:
            print(f"rule_null: {name}: {exc}", file=sys.stderr)
            return 2
        total += result.pop("any_verdict_per_draw")
        results[name] = result
        print(markdown(name, result))
    summary = {"cells": sum(len(r["cells"]) for r in results.values()),
               "verdicts_seen": sum(r["verdicts_seen"] for r in results.values()),
               "verdicts_expected": float(total.mean()),
               "p_at_least_as_many": float((total >= sum(r["verdicts_seen"]
                                                          for r in results.values())).mean()),
               "verdicts_by_chance_p50": float(statistics.median(total.tolist()))}
    if len(results) > 1:
        print(f"all {len(results)} readings: {summary['verdicts_seen']} verdicts seen in "
              f"{summary['cells']} cells; {summary['verdicts_expected']:.2f} expected by "
              f"chance; as many or more with chance {summary['p_at_least_as_many']:.3f}")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"readings": results, "together": summary},
                                        indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
