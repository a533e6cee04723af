"""Training seeds of two modalities on the same episodes: is A ahead of B in a cell because
of the modality, or because of one training run? (`sebvs eval table`)

    from sebvs.eval.table import load_runs, markdown, seed_table
    runs = load_runs(["seed0=out/eval_s0", "seed1=out/eval_s1", "seed2=out/eval_s2"])
    print(markdown(seed_table(runs, "rgb+event", "rgb", min_diff=10)))

Each NAME=DIR is an `sebvs eval --out` directory holding modalities A and B trained with
one seed; a NAME given again joins another directory to that run; NAME@TAG=DIR renames
that directory's modalities MODALITY@TAG (one modality under two settings). Per cell one
row: each run's A - B, the means over runs, how many runs have A ahead, and a paired test
over the episodes of the outcomes averaged over the runs (sebvs/metrics.py
paired_comparison). The reading applies a rule given before the runs are read: "A helps"
where the mean difference is >= min_diff points AND A is ahead in >= min_ahead runs.
"""
from __future__ import annotations

import statistics
from pathlib import Path

from ..metrics import paired_comparison, points
from .results import episodes_by_key, read_results, task_metrics


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
    """The runs named on the command line, each name's directories merged (merge_runs).

    Parameters:
        specs: NAME=DIR or NAME@TAG=DIR strings, DIR an `sebvs eval --out` directory.

    Returns:
        {name: results.json dict}, in the order the names first appear.

    Raises:
        RunSpecError: a spec that is not NAME=DIR or NAME@TAG=DIR.
        ValueError: naming the run, where a directory is not an evaluation or its
            directories do not join (merge_runs).
    """
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
    """Modality A against B per cell, over the training runs.

    Parameters:
        runs: {run name: results.json dict}, at least two, of one task and topology seed.
        a, b: the modalities compared (each in every run).
        metric: the episode metric (None: the task's first).
        min_diff: points of mean difference the rule needs for a reading.
        min_ahead: runs that must agree for a reading (None: all of them).

    Returns:
        {"metric", "a", "b", "runs", "rule", "cells": {"condition/scenario": {"per_run",
        "mean_a", "mean_b", "mean_diff", "ahead", "behind", "episodes", "reading"}},
        "left_out": cells some run scored none of}.

    Raises:
        ValueError: fewer than two runs, runs of other episodes, a modality a run lacks,
            or min_ahead outside 1..len(runs).
    """
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
    metric = metric or task_metrics(first)[0][0]
    need = len(runs) if min_ahead is None else min_ahead
    if not 1 <= need <= len(runs):
        raise ValueError(f"min_ahead must be between 1 and {len(runs)}, got {need}")
    by_run = {n: (episodes_by_key(r, a), episodes_by_key(r, b)) for n, r in runs.items()}
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
    """seed_table()'s result as one Markdown table, the rule in its first line.

    Parameters:
        table: what seed_table() returned.

    Returns:
        The table, then a line naming the cells left out (if any).
    """
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
    episodes' 95 % interval as a line; cells coloured by their reading.

    Parameters:
        table: what seed_table() returned.
        path: the PNG to write.
    """
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
