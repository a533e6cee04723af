#!/usr/bin/env python3
"""The sensor study's report (issue 38): the tables docs/results.md opens with, built from
what tools/studies/sensor_study.py wrote, in the shape docs/study_sensors_plan.md fixes.

    tools/studies/sensor_report.py [--out out/study_sensors] [--markdown FILE] [--json FILE]

Per task, one table: per cell, the plan's reading of RGB+Event against RGB+Diff at each
control rate (the mean difference over the three training seeds, the episodes' paired 95 %
interval, how many seeds are ahead / behind, the rule's verdict), and beside it what the
plan's physics predicted and whether that held. Below it, per rate, the descriptive rows:
each modality's mean (over its training seeds), the expert and no action, per cell.

Nothing here reads a rule or a prediction of its own: the readings come from seed_table.py's
JSON (OUT/read/<task><rate>.json), the predictions are the plan's section "What the physics
predicts", copied into PREDICTIONS below. A cell the plan lists that has no reading yet is
shown as "not yet run"; one that seed_table.py left out (a row scored no episode of it)
as "no reading". The exit code is 0 when every planned cell has a reading, else 3.
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from tools.studies.compare_evals import TASK_METRICS, read_results  # noqa: E402
from tools.studies.sensor_study import (EVAL_GROUPS, PLAN_FILE, PLAN_SEEDS,  # noqa: E402
                                        READ_METRIC, eval_dir)

RATES = (10, 30)
# the plan's cells, in its order: (condition, scenarios)
PLAN_CELLS = {
    "nav": [(c, s) for c in ("nominal_physical", "hdr", "dusk", "dusk_fast")
            for s in ("indoor", "outdoor")]
           + [("flicker_100", "indoor"), ("flicker_120", "indoor")],
    "arm": [(c, s) for c in ("nominal_physical", "fast_physical", "hdr", "dusk_moving")
            for s in ("single", "multi")],
}
# The plan's "What the physics predicts", per task and condition: rate -> (the reading
# predicted, the other readings its words allow), or None where it made no firm one.
HELPS, HURTS, NONE = "helps", "hurts", "no clear difference"
PREDICTIONS = {
    ("nav", "hdr"): {10: (HELPS, ()), 30: (HELPS, ())},
    ("arm", "hdr"): {10: (HELPS, (NONE,)), 30: (HELPS, (NONE,))},
    ("nav", "dusk"): {10: (NONE, ()), 30: None},
    ("nav", "dusk_fast"): {10: (NONE, ()), 30: None},
    ("arm", "dusk_moving"): {10: (NONE, ()), 30: None},
    ("nav", "flicker_100"): {10: (HURTS, (NONE,)), 30: (HURTS, (NONE,))},
    ("nav", "flicker_120"): {10: (HURTS, (NONE,)), 30: (HURTS, (NONE,))},
    ("nav", "nominal_physical"): {10: (NONE, ()), 30: (NONE, ())},
    ("arm", "nominal_physical"): {10: (NONE, ()), 30: (NONE, ())},
    ("arm", "fast_physical"): {10: (NONE, ()), 30: (NONE, ())},
}
ROWS = ("expert", "no_action", "rgb", "event", "rgb+diff", "rgb+event")


def verdict(reading: str) -> str:
    """seed_table's reading ("rgb+event helps", ...) as helps / hurts / no clear difference."""
    for word in (HELPS, HURTS):
        if reading.endswith(" " + word):
            return word
    return NONE


def held(prediction, found: str | None) -> str:
    if found is None:
        return "-"
    if prediction is None:
        return "no firm prediction"
    expected, allowed = prediction
    if found == expected:
        return "held"
    return "allowed" if found in allowed else "did not hold"


def predicted(prediction) -> str:
    if prediction is None:
        return "no firm prediction"
    expected, allowed = prediction
    return expected + "".join(f" (or {a})" for a in allowed)


def reading_cell(table: dict | None, cell: str) -> tuple[str, str | None]:
    """(the text of one rate's column, the verdict or None) for condition/scenario."""
    if table is None:
        return "not yet run", None
    if cell in table.get("left_out", []):
        return "no reading (a row scored no episode)", None
    r = table["cells"].get(cell)
    if r is None:
        return "not yet run", None
    lo, hi = (100 * v for v in r["episodes"]["ci95"])
    found = verdict(r["reading"])
    return (f"{100 * r['mean_diff']:+.1f} [{lo:+.1f}, {hi:+.1f}], {r['ahead']}/{r['behind']}, "
            f"**{found}**"), found


def task_table(task: str, tables: dict[int, dict | None]) -> tuple[list[str], int]:
    """The markdown rows of one task's headline table; the number of cells read at
    every rate."""
    metric = tables_metric(task, tables)
    lines = [f"**{task}** ({metric}; RGB+Event - RGB+Diff in points, mean over training "
             f"seeds [episodes' paired 95 % interval], seeds ahead/behind, the plan's reading)",
             "", "| cell | " + " | ".join(f"{r} Hz" for r in RATES)
             + " | predicted (10 / 30 Hz) | held (10 / 30 Hz) |",
             "|---|" + "---|" * (len(RATES) + 2)]
    complete = 0
    for condition, scenario in PLAN_CELLS[task]:
        cell = f"{condition}/{scenario}"
        texts, found = zip(*(reading_cell(tables.get(rate), cell) for rate in RATES))
        complete += all(f is not None for f in found)
        pred = PREDICTIONS[(task, condition)]
        lines.append(f"| {cell} | " + " | ".join(texts) + " | "
                     + " / ".join(predicted(pred[r]) for r in RATES) + " | "
                     + " / ".join(held(pred[r], f) for r, f in zip(RATES, found)) + " |")
    return lines, complete


def tables_metric(task: str, tables: dict[int, dict | None]) -> str:
    for t in tables.values():
        if t:
            return t["metric"]
    return READ_METRIC[task] or TASK_METRICS[task][0][0]


def row_means(out: Path, task: str, rate: int, metric: str) -> dict[str, dict[str, float]]:
    """{row: {condition/scenario: mean metric}} over every evaluation found for the task
    and rate; a modality trained with several seeds is averaged over them (each seed's
    cell mean first)."""
    per_seed: dict[str, dict[str, list[float]]] = {}
    for seed in sorted({s for ss in PLAN_SEEDS[rate].values() for s in ss}):
        for group, _, _ in EVAL_GROUPS[task]:
            path = eval_dir(out, task, rate, seed, group) / "results.json"
            if not path.exists():
                continue
            cells: dict[tuple[str, str], list[float]] = {}
            for e in read_results(path)["episodes"]:
                v = e["metrics"].get(metric)
                if v is not None:
                    cells.setdefault((e["modality"], f"{e['condition']}/{e['scenario']}"),
                                     []).append(float(v))
            for (row, cell), xs in cells.items():
                per_seed.setdefault(row, {}).setdefault(cell, []).append(statistics.fmean(xs))
    return {row: {cell: statistics.fmean(ms) for cell, ms in cells.items()}
            for row, cells in per_seed.items()}


def rows_table(task: str, rate: int, means: dict[str, dict[str, float]]) -> list[str]:
    seeds = {m: len(s) for m, s in PLAN_SEEDS[rate].items()}
    head = [f"{r} ({seeds[r]} seed{'s' * (seeds[r] > 1)})" if r in seeds else r for r in ROWS]
    lines = ["| cell | " + " | ".join(head) + " |", "|---|" + "---|" * len(ROWS)]
    for condition, scenario in PLAN_CELLS[task]:
        cell = f"{condition}/{scenario}"
        vals = [means.get(r, {}).get(cell) for r in ROWS]
        lines.append(f"| {cell} | " + " | ".join("-" if v is None else f"{100 * v:.1f}"
                                                  for v in vals) + " |")
    return lines


def report(out: Path) -> tuple[str, dict, bool]:
    """(markdown, the data behind it, whether every planned cell has a reading)."""
    lines = [f"The sensor study's readings, by the rule of {PLAN_FILE} (fixed before any "
             f"recording): RGB+Event against the RGB+Diff control, three training seeds "
             f"each, test seeds never used before.", ""]
    data: dict = {"plan": PLAN_FILE, "tasks": {}}
    done = True
    for task in ("nav", "arm"):
        tables = {}
        for rate in RATES:
            path = out / "read" / f"{task}{rate}.json"
            tables[rate] = json.loads(path.read_text()) if path.exists() else None
        rows, complete = task_table(task, tables)
        done &= complete == len(PLAN_CELLS[task])
        lines += rows + [""]
        metric = tables_metric(task, tables)
        data["tasks"][task] = {"readings": tables, "rows": {}}
        for rate in RATES:
            means = row_means(out, task, rate, metric)
            data["tasks"][task]["rows"][rate] = means
            lines += [f"{task} at {rate} Hz, every row ({metric}, %, mean over the seeds "
                      f"each modality was trained with; test seed episodes):", "",
                      *rows_table(task, rate, means), ""]
    return "\n".join(lines), data, done


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=ROOT / "out" / "study_sensors",
                    help="the study driver's --out (default out/study_sensors)")
    ap.add_argument("--markdown", type=Path, help="write the tables here (default: print)")
    ap.add_argument("--json", type=Path, help="also write the data behind them here")
    args = ap.parse_args(argv)
    text, data, done = report(args.out)
    if args.markdown:
        args.markdown.parent.mkdir(parents=True, exist_ok=True)
        args.markdown.write_text(text)
    else:
        print(text)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(data, indent=1) + "\n")
    if not done:
        print("sensor_report: some planned cells have no reading yet (see the tables)",
              file=sys.stderr)
    return 0 if done else 3


if __name__ == "__main__":
    sys.exit(main())
