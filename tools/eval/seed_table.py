#!/usr/bin/env python3
"""Training seeds of two modalities on the same episodes: is A ahead of B in a cell because
of the modality, or because of one training run?

    tools/eval/seed_table.py seed0=out/arm_lead/eval_lead seed1=out/arm_lead/eval_seed1 \\
        seed2=out/arm_lead/eval_seed2 --a rgb+event --b rgb --min-diff 10 --json out/seeds.json \\
        --plot docs/figures/seeds.png

Each NAME=DIR is an `sebvs eval --out` directory holding modalities A and B trained with
one seed; a NAME given again joins another directory to that run (where its modalities
or its cells were evaluated apart; each cell of a modality in one of them). NAME@TAG=DIR
renames that directory's modalities to MODALITY@TAG, so that one modality under two
settings can be compared (a sensor, a recipe: --a event@fr --b event). All must have
played the same task and topology seed (the same episodes).

Per condition and scenario, one row: each run's A - B (points, over the episodes both
scored), the mean over runs of A, B and A - B, how many runs have A ahead, and a paired
test over the episodes of the outcomes averaged over the runs (the episode is the unit:
bootstrap 95 % interval and exact sign test, sebvs/metrics.py paired_comparison).

The reading column applies a rule given before the runs are read: "A helps" where the
mean difference is >= --min-diff points AND A is ahead in at least --min-ahead runs
(default: all of them), "A hurts" where the mirror holds, else "no clear difference".
Metric: the task's first (arm grasp success over graspable episodes, nav the paper rate),
or --metric.
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from sebvs.metrics import paired_comparison, points  # noqa: E402
from tools.eval.compare_evals import METRICS, TASK_METRICS, _by_key, read_results  # noqa: E402


def _scored(episodes: dict, key, metric: str) -> float | None:
    e = episodes.get(key)
    v = None if e is None else e["metrics"].get(metric)
    return None if v is None else float(v)


def scored_pairs(ea: dict, eb: dict, keys, metric: str) -> list[tuple[float, float]]:
    """(A's, B's) outcome of each of ``keys`` that both scored, in their order: the
    episodes a run's difference in a cell is taken over."""
    pairs = [(_scored(ea, k, metric), _scored(eb, k, metric)) for k in keys]
    return [(x, y) for x, y in pairs if x is not None and y is not None]


def tagged(results: dict, tag: str) -> dict:
    """``results`` with every episode's modality renamed MODALITY@TAG (tag "": unchanged)."""
    if not tag:
        return results
    return {**results, "episodes": [{**e, "modality": f"{e['modality']}@{tag}"}
                                    for e in results["episodes"]]}


class RunSpecError(ValueError):
    """A run argument that is not NAME=DIR or NAME@TAG=DIR."""


def load_runs(specs: list[str]) -> dict[str, dict]:
    """The NAME=DIR (or NAME@TAG=DIR) arguments as {name: results}, each name's
    directories merged (merge_runs). ValueError names the run that is wrong and why."""
    parts: dict[str, list[tuple[str, dict]]] = {}
    for spec in specs:
        label, sep, path = spec.partition("=")
        name, at, tag = label.partition("@")
        if not sep or not name or not path or (at and not tag):
            raise RunSpecError(f"a run is NAME=DIR or NAME@TAG=DIR, got {spec!r}")
        try:
            parts.setdefault(name, []).append((path, tagged(read_results(Path(path)), tag)))
        except ValueError as exc:
            raise ValueError(f"run {name!r}: {exc}") from None
    runs = {}
    for name, dirs in parts.items():
        try:
            runs[name] = merge_runs(dirs)
        except ValueError as exc:
            raise ValueError(f"run {name!r}: {exc}") from None
    return runs


def merge_runs(parts: list[tuple[str, dict]]) -> dict:
    """One training seed's evaluations, made into separate directories ((label, results)
    each), as one results dict: a modality evaluated apart (a control added later), or
    cells evaluated apart (conditions run in two groups). Refused: parts of other
    episodes (task or topology seed), or a cell of one modality held by two parts (which
    would be the run's?)."""
    (first_label, first), held = parts[0], {}
    for label, res in parts:
        for key in ("task", "seed"):
            if res.get(key) != first.get(key):
                raise ValueError(f"{label} differs from {first_label} in {key} "
                                 f"({res.get(key)!r} vs {first.get(key)!r}): not the same "
                                 f"episodes")
        for cell in sorted({(e["modality"], e["condition"], e["scenario"])
                            for e in res["episodes"]}):
            if cell in held:
                m, cond, scen = cell
                raise ValueError(f"{held[cell]} and {label} both hold {m!r} episodes of "
                                 f"{cond}/{scen}: give each cell from one directory")
            held[cell] = label
    return {**first, "episodes": [e for _, res in parts for e in res["episodes"]]}


def seed_table(runs: dict[str, dict], a: str, b: str, metric: str | None = None,
               min_diff: float = 10.0, min_ahead: int | None = None) -> dict:
    """{"metric", "runs", "cells": {"condition/scenario": {...}}} for modalities a and b
    over the evaluations in ``runs`` (name -> results.json dict)."""
    if len(runs) < 2:
        raise ValueError(f"give at least two runs (training seeds), got {len(runs)}")
    first = next(iter(runs.values()))
    for name, res in runs.items():
        for key in ("task", "seed"):
            if res.get(key) != first.get(key):
                raise ValueError(f"run {name!r} differs in {key} ({res.get(key)!r} vs "
                                 f"{first.get(key)!r}): not the same episodes")
        held = {e["modality"] for e in res["episodes"]}
        for m in (a, b):
            if m not in held:
                raise ValueError(f"run {name!r} holds no {m!r} episodes "
                                 f"(it holds {', '.join(sorted(held)) or 'none'})")
    metric = metric or TASK_METRICS.get(first.get("task"), METRICS)[0][0]
    need = len(runs) if min_ahead is None else min_ahead
    if not 1 <= need <= len(runs):
        raise ValueError(f"--min-ahead must be between 1 and {len(runs)}, got {need}")
    by_run = {n: (_by_key(r, a), _by_key(r, b)) for n, r in runs.items()}
    cells = sorted({k[:2] for ea, _ in by_run.values() for k in ea})
    out: dict = {"metric": metric, "a": a, "b": b, "runs": list(runs),
                 "rule": {"min_diff_points": min_diff, "min_ahead": need}, "cells": {},
                 "left_out": []}
    for cond, scen in cells:
        keys = sorted({k for ea, eb in by_run.values() for k in ea if k[:2] == (cond, scen)})
        per_run, avg_a, avg_b = {}, [], []
        for name, (ea, eb) in by_run.items():
            if both := scored_pairs(ea, eb, keys, metric):
                ma = statistics.fmean(x for x, _ in both)
                mb = statistics.fmean(y for _, y in both)
                per_run[name] = {"a": ma, "b": mb, "diff": ma - mb, "n": len(both)}
        for k in keys:      # episodes every run scored on both sides
            xs = [(_scored(ea, k, metric), _scored(eb, k, metric)) for ea, eb in by_run.values()]
            if all(x is not None and y is not None for x, y in xs):
                avg_a.append(statistics.fmean(x for x, _ in xs))
                avg_b.append(statistics.fmean(y for _, y in xs))
        if len(per_run) < len(runs) or not avg_a:
            out["left_out"].append(f"{cond}/{scen}")   # some run scored none of it
            continue
        diffs = [r["diff"] for r in per_run.values()]
        mean_diff = statistics.fmean(diffs)
        ahead = sum(d > 0 for d in diffs)
        behind = sum(d < 0 for d in diffs)
        if 100 * mean_diff >= min_diff and ahead >= need:
            reading = f"{a} helps"
        elif -100 * mean_diff >= min_diff and behind >= need:
            reading = f"{a} hurts"
        else:
            reading = "no clear difference"
        out["cells"][f"{cond}/{scen}"] = {
            "per_run": per_run, "mean_a": statistics.fmean(r["a"] for r in per_run.values()),
            "mean_b": statistics.fmean(r["b"] for r in per_run.values()),
            "mean_diff": mean_diff, "ahead": ahead, "behind": behind,
            "episodes": paired_comparison(avg_a, avg_b), "reading": reading}
    return out


def markdown(table: dict) -> str:
    a, b, runs = table["a"], table["b"], table["runs"]
    lines = [f"{a} - {b}, {table['metric']}, points; rule: mean >= "
             f"{table['rule']['min_diff_points']:g} and ahead in >= "
             f"{table['rule']['min_ahead']} of {len(runs)} runs", "",
             "| cell | " + " | ".join(runs) + f" | mean {a} | mean {b} | mean diff | ahead / "
             f"behind | episodes: 95 % interval, p (sign) | reading |",
             "|---|" + "---|" * (len(runs) + 6)]
    for cell, r in table["cells"].items():
        e = r["episodes"]
        lines.append(f"| {cell} | " + " | ".join(points(r['per_run'][n]['diff'])
                                                 for n in runs) +
                     f" | {100 * r['mean_a']:.1f} | {100 * r['mean_b']:.1f} | "
                     f"{points(r['mean_diff'])} | {r['ahead']} / {r['behind']} | "
                     f"[{points(e['ci95'][0])}, {points(e['ci95'][1])}], "
                     f"{e['p_sign']:.3g} | {r['reading']} |")
    if table["left_out"]:
        lines += ["", "Not scored by every run: " + ", ".join(table["left_out"])]
    return "\n".join(lines) + "\n"


def plot(table: dict, path: Path) -> None:
    """Per cell, A - B in points: a bar for the mean over runs, a dot per run, the
    episodes' 95 % interval as a line; cells coloured by their reading."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cells = list(table["cells"])
    colour = {f"{table['a']} helps": "tab:green", f"{table['a']} hurts": "tab:red"}
    fig, ax = plt.subplots(figsize=(3.0 + 0.55 * len(cells), 3.6))
    for j, cell in enumerate(cells):
        r = table["cells"][cell]
        ax.bar(j, 100 * r["mean_diff"], 0.6, color=colour.get(r["reading"], "0.7"),
               alpha=0.8)
        runs = [100 * v["diff"] for v in r["per_run"].values()]
        ax.scatter([j] * len(runs), runs, s=12, color="black", zorder=3)
        lo, hi = (100 * v for v in r["episodes"]["ci95"])
        ax.vlines(j + 0.22, lo, hi, color="0.3", lw=1.2)
    ax.axhline(0, color="black", lw=0.8)
    ax.set_xticks(range(len(cells)), cells, fontsize=8, rotation=30, ha="right")
    ax.set_ylabel(f"{table['a']} - {table['b']} (points)")
    ax.set_title(f"{table['metric']}: bars the mean over {len(table['runs'])} training runs, "
                 f"dots each run, lines the episodes' 95 % interval; green / red: the rule "
                 f"says helps / hurts", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("runs", nargs="+", metavar="NAME=DIR",
                    help="an `sebvs eval --out` directory per training seed (a NAME given "
                         "again adds a directory to that seed's run; NAME@TAG=DIR names its "
                         "modalities MODALITY@TAG)")
    ap.add_argument("--a", required=True, help="modality A (e.g. rgb+event)")
    ap.add_argument("--b", required=True, help="modality B (e.g. rgb)")
    ap.add_argument("--metric", help="episode metric (default: the task's first)")
    ap.add_argument("--min-diff", type=float, default=10.0,
                    help="points of mean difference for a reading (default 10)")
    ap.add_argument("--min-ahead", type=int,
                    help="runs that must agree for a reading (default: all)")
    ap.add_argument("--json", type=Path, help="also write the table here")
    ap.add_argument("--plot", type=Path, help="also draw the differences here (PNG)")
    args = ap.parse_args(argv)
    try:
        runs = load_runs(args.runs)
    except RunSpecError as exc:
        ap.error(str(exc))
    except ValueError as exc:
        print(f"seed_table: {exc}", file=sys.stderr)
        return 2
    try:
        table = seed_table(runs, args.a, args.b, args.metric, args.min_diff, args.min_ahead)
    except ValueError as exc:
        print(f"seed_table: {exc}", file=sys.stderr)
        return 2
    print(markdown(table), end="")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(table, indent=1) + "\n")
    if args.plot:
        args.plot.parent.mkdir(parents=True, exist_ok=True)
        plot(table, args.plot)
    return 0


if __name__ == "__main__":
    sys.exit(main())
