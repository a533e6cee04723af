"""A sweep's summary: ``sweep.json`` (every point: settings, status, numbers) and
``sweep.md`` (the points and their seed groups sorted by the best validation loss).

    write_summary(out, summary)         # out/sweep.json and out/sweep.md, atomically
    print(format_markdown(summary))

A point's status: "trained" (by this run), "skipped" (trained by an earlier run; its numbers
read back from its config), "failed" (with its error), "interrupted" or "pending" (not
run, or not finished, when the sweep stopped). Only trained and skipped points count in
the tables' statistics.
"""
from __future__ import annotations

import json
import math
import os
import statistics
from collections import Counter
from pathlib import Path

from .sweep_grid import format_value

SUMMARY_JSON = "sweep.json"
SUMMARY_MD = "sweep.md"
STATUSES = ("trained", "skipped", "failed", "interrupted", "pending")
LOSS_NAMES = {"mse": "MSE", "smooth_l1": "Smooth L1 (in the arm's loss units: cm, 0.05 rad)"}


def write_summary(out: Path, summary: dict) -> None:
    """Rewrite both files whole (a tmp file renamed over each): a reader, or a sweep killed
    mid-write, never sees half of one."""
    _write_atomic(out / SUMMARY_JSON, json.dumps(summary, indent=2) + "\n")
    _write_atomic(out / SUMMARY_MD, format_markdown(summary))


def _write_atomic(path: Path, text: str) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text, encoding="utf-8")
    os.replace(tmp, path)


def has_loss(point: dict) -> bool:
    return point["status"] in ("trained", "skipped") and point["best_val_loss"] is not None


def format_markdown(summary: dict) -> str:
    points = summary["points"]
    counts = Counter(p["status"] for p in points)
    lines = [f"# Training sweep: {summary['task']} on {summary['data']}", "",
             f"Grid `{summary['grid']}`: {len(points)} point(s): " +
             ", ".join(f"{counts[s]} {s}" for s in STATUSES if counts[s]) + ".",
             f"Loss: the best epoch's validation "
             f"{LOSS_NAMES.get(summary['loss'], summary['loss'])}."]
    if summary["train"]:
        lines.append("Every point: " + ", ".join(f"{k}={format_value(v)}"
                                                   for k, v in summary["train"].items()) + ".")
    lines += ["", *group_table(points, [k for k in summary["axes"] if k != "seed"]),
              "", *point_table(points)]
    failed = [p for p in points if p["status"] == "failed"]
    if failed:
        lines += ["", "## Failed", "", "| point | error |", "|---|---|"]
        lines += [f"| {p['name']} | {_cell(p['error'] or '')} |" for p in failed]
    return "\n".join(lines) + "\n"


def group_table(points: list[dict], keys: list[str]) -> list[str]:
    """One row per setting (the axes but the seed), over its seeds: mean, standard
    deviation (n - 1), min and max of the best validation losses; best mean first."""
    keys = keys or ["modality"]
    groups: dict[tuple, list[dict]] = {}
    for p in points:
        groups.setdefault(tuple(p["settings"][k] for k in keys), []).append(p)

    def stats(members: list[dict]) -> tuple:
        losses = [p["best_val_loss"] for p in members if has_loss(p)]
        if not losses:
            return (math.inf, None, None, None, 0)
        spread = statistics.stdev(losses) if len(losses) > 1 else None
        return (statistics.fmean(losses), spread, min(losses), max(losses), len(losses))

    rows = sorted(((key, members, stats(members)) for key, members in groups.items()),
                  key=lambda row: row[2][0])
    out = ["## Per setting, over seeds (best mean first)", "",
           "| " + " | ".join(keys) + " | seeds | mean | std | min | max |",
           "|" + "---|" * (len(keys) + 5)]
    for key, members, (mean, spread, low, high, n) in rows:
        seeds = f"{n}" if n == len(members) else f"{n} of {len(members)}"
        out.append("| " + " | ".join(format_value(v) for v in key) + f" | {seeds} | "
                   f"{_loss(mean if n else None)} | {_loss(spread)} | {_loss(low)} | "
                   f"{_loss(high)} |")
    return out


def point_table(points: list[dict]) -> list[str]:
    """Every point, best validation loss first; points without one after, by status."""
    def order(p: dict) -> tuple:
        return (0, p["best_val_loss"], p["name"]) if has_loss(p) else \
            (1 + STATUSES.index(p["status"]), 0.0, p["name"])
    out = ["## Every point (best validation loss first)", "",
           "| point | best val loss | epochs run | train s | parameters | status |",
           "|---|---|---|---|---|---|"]
    for p in sorted(points, key=order):
        out.append(f"| {p['name']} | {_loss(p['best_val_loss'])} | "
                   f"{_plain(p['epochs_run'])} | {_plain(p['seconds'])} | "
                   f"{_plain(p['parameters'], ',')} | {p['status']} |")
    return out


def _loss(value: float | None) -> str:
    return "-" if value is None else f"{value:.5g}"


def _plain(value, spec: str = "") -> str:
    return "-" if value is None else format(value, spec)


def _cell(text: str) -> str:
    return text.replace("|", "\\|")
