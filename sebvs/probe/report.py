"""The probe's results as one summary per (dataset, sensor) and as a Markdown table.

    rows = summarise(results["fits"])          # seeds pooled: mean of each seed's figure
    print(markdown(rows))
"""
from __future__ import annotations

from collections import defaultdict

import numpy as np

SENSOR_ORDER = ("rgb", "event", "both")


def _mean(values):
    values = [v for v in values if v is not None]
    return float(np.mean(values)) if values else None


def _spread(values):
    values = [v for v in values if v is not None]
    return [float(min(values)), float(max(values))] if values else None


def summarise(fits: list[dict]) -> list[dict]:
    """One row per (dataset, sensor): each figure's mean over the seeds (and its range),
    the baseline and the split's sizes (the same for every seed)."""
    groups = defaultdict(list)
    for f in fits:
        groups[(f["dataset"], f["sensor"])].append(f)
    rows = []
    for (dataset, sensor), fs in groups.items():
        first = fs[0]
        rows.append({
            "dataset": dataset, "driver": first.get("driver"), "cell": first.get("cell"),
            "sensor": sensor, "seeds": [f["seed"] for f in fs],
            "train_episodes": len(first["train_episodes"]),
            "test_episodes": len(first["test_episodes"]),
            "train_frames": first["train_frames"], "test_frames": first["test_frames"],
            "test_visible": first["test_visible"],
            "error_median_px": _mean(f["error_px"]["median"] for f in fs),
            "error_median_px_range": _spread(f["error_px"]["median"] for f in fs),
            "error_p90_px": _mean(f["error_px"]["p90"] for f in fs),
            "baseline_median_px": first["baseline_px"]["median"],
            "baseline_p90_px": first["baseline_px"]["p90"],
            "auc": _mean(f["auc"] for f in fs),
            "auc_range": _spread(f["auc"] for f in fs),
            "wall_s": float(sum(f["wall_s"] for f in fs))})
    order = {s: i for i, s in enumerate(SENSOR_ORDER)}
    rows.sort(key=lambda r: (r["dataset"], order.get(r["sensor"], 99)))
    return rows


def _px(value, width: int = 160) -> str:
    if value is None:
        return "-"
    return f"{value:.1f} ({100 * value / width:.0f} %)"


def _auc(value) -> str:
    return "n/a" if value is None else f"{value:.2f}"


def markdown(rows: list[dict]) -> str:
    """A table: per dataset, the split, then per sensor the median / p90 error (px at
    160 px and % of the width) and the AUC; the baseline's beside."""
    by_dataset = defaultdict(dict)
    meta = {}
    for r in rows:
        by_dataset[r["dataset"]][r["sensor"]] = r
        meta[r["dataset"]] = r
    sensors = [s for s in SENSOR_ORDER if any(s in d for d in by_dataset.values())]
    head = (["cell", "train / test episodes (frames; test visible)",
             "mean-centroid baseline, median / p90 px"]
            + [f"{s}: median / p90 px, AUC" for s in sensors])
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for dataset, per in by_dataset.items():
        m = meta[dataset]
        label = f"{m['driver']}/{m['cell']}" if m.get("driver") else dataset
        cells = [label,
                 f"{m['train_episodes']} / {m['test_episodes']} ({m['train_frames']} / "
                 f"{m['test_frames']}; {m['test_visible']})",
                 f"{_px(m['baseline_median_px'])} / {_px(m['baseline_p90_px'])}"]
        for s in sensors:
            r = per.get(s)
            if r is None:
                cells.append("-")
                continue
            seeds = f" [{len(r['seeds'])} seeds]" if len(r["seeds"]) > 1 else ""
            cells.append(f"{_px(r['error_median_px'])} / {_px(r['error_p90_px'])}, "
                         f"{_auc(r['auc'])}{seeds}")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)
