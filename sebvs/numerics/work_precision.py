"""Work-precision diagrams: error against run time, one line per method, Pareto front marked.

A study is a list of points ``{"method", "setting", "error", "seconds"}`` (plus optional
fields such as ``diverged``). Diverged points have no meaningful error; they are kept in
the CSV and drawn as crosses at the top of the plot, never on the front.
"""
from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np


def pareto_front(points: list[dict]) -> list[int]:
    """Indices of the points no other point beats in both error and seconds."""
    ok = [i for i, p in enumerate(points) if not p.get("diverged")
          and _finite(p["error"]) and _finite(p["seconds"])]
    front = []
    for i in ok:
        pi = points[i]
        dominated = any(
            points[j]["error"] <= pi["error"] and points[j]["seconds"] <= pi["seconds"]
            and (points[j]["error"] < pi["error"] or points[j]["seconds"] < pi["seconds"])
            for j in ok if j != i)
        if not dominated:
            front.append(i)
    return sorted(front, key=lambda i: points[i]["seconds"])


def _finite(x) -> bool:
    return x is not None and isinstance(x, (int, float)) and math.isfinite(x)


def write_csv(points: list[dict], path: Path) -> None:
    keys = ["method", "setting", "error", "seconds"]
    keys += sorted({k for p in points for k in p} - set(keys))
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=keys)
        w.writeheader()
        for p in points:
            w.writerow({k: p.get(k, "") for k in keys})


def plot_study(name: str, points: list[dict], path: Path, error_label: str,
               seconds_label: str = "wall seconds per simulated second") -> None:
    """Log-log plot: one line per method in setting order, Pareto front in black."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.4))
    methods = list(dict.fromkeys(p["method"] for p in points))
    good = [p for p in points if not p.get("diverged") and _finite(p["error"])
            and p["error"] > 0 and _finite(p["seconds"]) and p["seconds"] > 0]
    top = max([p["error"] for p in good] or [1.0]) * 3
    for method in methods:
        mine = [p for p in points if p["method"] == method]
        ok = [p for p in mine if p in good]
        line, = ax.plot([p["seconds"] for p in ok], [p["error"] for p in ok], "o-",
                        label=method, ms=4)
        for p in ok:
            ax.annotate(str(p["setting"]), (p["seconds"], p["error"]), fontsize=6,
                        xytext=(3, 3), textcoords="offset points", color=line.get_color())
        bad = [p for p in mine if p.get("diverged") and _finite(p["seconds"])
               and p["seconds"] > 0]
        if bad:
            ax.plot([p["seconds"] for p in bad], [top] * len(bad), "x", color=line.get_color(),
                    ms=8, mew=2)
    front = [points[i] for i in pareto_front(points) if points[i] in good]
    if front:
        ax.plot([p["seconds"] for p in front], [p["error"] for p in front], "k--", lw=1,
                label="Pareto front", zorder=0)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel(seconds_label)
    ax.set_ylabel(error_label)
    ax.set_title(name + ("  (x: diverged)" if any(p.get("diverged") for p in points) else ""))
    ax.grid(True, which="both", alpha=0.25)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def write_summary(studies: list[dict], path: Path) -> None:
    """summary.json: {"studies": [{"name", "points": [...], "pareto": [...] }]}."""
    out = {"studies": [{**s, "pareto": pareto_front(s["points"])} for s in studies]}
    Path(path).write_text(json.dumps(out, indent=2, default=_plain))


def _plain(obj):
    if isinstance(obj, np.generic):
        return obj.item()
    raise TypeError(type(obj).__name__)
