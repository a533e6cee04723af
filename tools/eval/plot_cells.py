#!/usr/bin/env python3
"""One modality across several evaluations, side by side: a bar per evaluation and cell.

    tools/eval/plot_cells.py out/contrast/eval_checker_default out/contrast/eval_plain_default \\
        --labels "checker floor,plain floor" --modality event --out cells.png [--json cells.json]

Each input is an `sebvs eval --out` directory (or its results.json) that played the
modality (--modality: one for all, or one per evaluation, comma-separated). For every
(condition, scenario) cell it holds, a bar shows the modality's mean rate over the cell's
episodes (--metric: nav the paper rate by default; arm grasp success, over the episodes
where a cube was graspable), a dot each episode,
and a black tick what the evaluation's no-action row scores on the same seeds (when it
has one): the rate the metric gives for free. Printed (and written with --json): per
evaluation and cell, the mean, the episode count and the no-action mean.
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from sebvs.eval.run import BASELINE  # noqa: E402
from sebvs.eval.results import TASK_METRICS, read_results  # noqa: E402

METRIC_LABELS = {m: label for metrics in TASK_METRICS.values() for m, label in metrics}


def cell_rates(results: dict, modality: str, metric: str) -> dict[str, dict]:
    """{"condition/scenario": {"episodes": [per-episode values], "no_action": mean | None}}
    for the cells where `modality` played."""
    cells: dict[str, dict] = {}
    for ep in results["episodes"]:
        key = f"{ep['condition']}/{ep['scenario']}"
        value = ep["metrics"].get(metric)
        if ep["modality"] == modality and value is not None:    # None: no grasp to make
            cells.setdefault(key, {"episodes": [], "baseline": []})["episodes"].append(
                float(value))
    for ep in results["episodes"]:
        key = f"{ep['condition']}/{ep['scenario']}"
        value = ep["metrics"].get(metric)
        if ep["modality"] == BASELINE and key in cells and value is not None:
            cells[key]["baseline"].append(float(value))
    return {k: {"episodes": v["episodes"],
                "no_action": statistics.fmean(v["baseline"]) if v["baseline"] else None}
            for k, v in sorted(cells.items())}


def plot(rows: list[tuple[str, dict]], title: str, metric_label: str, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    cells = sorted({c for _, table in rows for c in table})
    width = 0.8 / len(rows)
    fig, ax = plt.subplots(figsize=(3.0 + max(2.5, 0.32 * len(cells) * len(rows)), 3.6))
    rng = np.random.default_rng(0)      # dot jitter only
    for i, (label, table) in enumerate(rows):
        xs, means = [], []
        for j, cell in enumerate(cells):
            if cell not in table:
                continue
            x = j + (i - (len(rows) - 1) / 2) * width
            values = 100 * np.asarray(table[cell]["episodes"], float)
            xs.append(x)
            means.append(values.mean())
            ax.scatter(x + rng.uniform(-0.3, 0.3, len(values)) * width, values, s=6,
                       color="0.2", alpha=0.5, zorder=3)
            if table[cell]["no_action"] is not None:
                ax.hlines(100 * table[cell]["no_action"], x - width / 2, x + width / 2,
                          color="black", lw=2, zorder=4)
        ax.bar(xs, means, width * 0.9, label=label, alpha=0.8)
    ax.set_xticks(range(len(cells)), cells, fontsize=8)
    ax.set_ylim(0, 102)
    ax.set_ylabel(f"{metric_label} (%)")
    ax.set_title(f"{title}: bars the mean, dots the episodes, black ticks no action",
                 fontsize=9)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("evals", nargs="+", type=Path, help="`sebvs eval --out` directories")
    ap.add_argument("--labels", help="comma-separated, one per evaluation (default: the "
                                     "directory names)")
    ap.add_argument("--modality", required=True,
                    help="the row to compare, e.g. event; or one per evaluation, "
                         "comma-separated (rgb+event,expert)")
    ap.add_argument("--metric", choices=sorted(METRIC_LABELS),
                    help="nav: success (the paper rate, default), strict_success, "
                         "episode_success; arm: grasp_success (default)")
    ap.add_argument("--out", type=Path, required=True, help="the figure (PNG)")
    ap.add_argument("--json", type=Path, help="also write the numbers here")
    args = ap.parse_args(argv)
    labels = args.labels.split(",") if args.labels else [p.name for p in args.evals]
    if len(labels) != len(args.evals):
        ap.error(f"--labels names {len(labels)} evaluations, {len(args.evals)} given")
    modalities = args.modality.split(",")
    if len(modalities) == 1:
        modalities *= len(args.evals)
    if len(modalities) != len(args.evals):
        ap.error(f"--modality names {len(modalities)} modalities for {len(args.evals)} "
                 f"evaluations (give one, or one per evaluation)")
    rows, metric = [], args.metric
    for label, path, modality in zip(labels, args.evals, modalities):
        try:
            results = read_results(path)
        except ValueError as exc:
            ap.error(str(exc))
        task_metrics = TASK_METRICS.get(results.get("task"), TASK_METRICS["nav"])
        metric = metric or task_metrics[0][0]
        table = cell_rates(results, modality, metric)
        if not table:
            ap.error(f"{path}: no {modality!r} episodes with {metric}")
        rows.append((label, table))
    summary = {label: {cell: {"mean": statistics.fmean(v["episodes"]),
                              "episodes": len(v["episodes"]), "no_action": v["no_action"]}
                       for cell, v in table.items()} for label, table in rows}
    for label, table in summary.items():
        for cell, v in table.items():
            base = "-" if v["no_action"] is None else f"{100 * v['no_action']:.1f}"
            print(f"{label:<28} {cell:<24} {100 * v['mean']:6.1f} % over {v['episodes']:3d} "
                  f"episodes (no action {base})")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    title = modalities[0] if len(set(modalities)) == 1 else "per evaluation"
    plot(rows, title, METRIC_LABELS[metric], args.out)
    print(f"figure: {args.out}")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"modality": args.modality, "metric": metric,
                                         "evaluations": dict(zip(labels, map(str, args.evals))),
                                         "cells": summary}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
