"""Two evaluations of the same episodes, paired: does checkpoint set (or setting) A play the
same test scenes better than B? (`sebvs eval compare`)

    from sebvs.eval.compare import compare, markdown
    from sebvs.eval.results import read_results
    table = compare(read_results(Path("out/eval_new")), read_results(Path("out/eval_old")))
    print(markdown(table, ("160 px sensor", "80 px sensor")))

A and B must have played the same task and topology seed, so the same episode seeds; an
episode of A pairs with B's of the same modality, condition, scenario and episode seed.
For each modality both hold (or those asked for) and each metric, one table, a row per
condition and scenario: A's mean, B's mean, A - B in points with its bootstrap 95 %
interval, A's wins / losses / ties over the pairs and the exact sign test's two-sided p
(sebvs/metrics.py paired_comparison). A cell either run lacks is left out and named.
Metrics: nav the paper rate, the strict rate and episode success; arm grasp success, over
the episodes where a cube was graspable (the scene decides which, so both sides agree).
"""
from __future__ import annotations

import statistics

from ..metrics import paired_comparison, points
from .results import METRICS, episodes_by_key, task_metrics


def compare(a: dict, b: dict, modalities: list[str] | None = None) -> dict:
    """Evaluation A against B, paired by episode.

    Parameters:
        a, b: two results.json dicts (results.read_results) of the same task and topology
            seed.
        modalities: the rows to pair (None: every modality both hold, expert and
            no_action included).

    Returns:
        {modality: {"condition/scenario": {metric: {"a", "b", **paired_comparison}}}},
        plus "unpaired" (the "modality condition/scenario" cells only one side holds) and
        "metrics" (the [metric, label] pairs read).

    Raises:
        ValueError: the two differ in task or topology seed (their episodes are not the
            same scenes), or a modality asked for is not in both.
    """
    for key in ("task", "seed"):
        if a.get(key) != b.get(key):
            raise ValueError(f"the evaluations differ in {key} ({a.get(key)!r} vs "
                             f"{b.get(key)!r}): their episodes are not the same scenes")
    both = sorted({e["modality"] for e in a["episodes"]}
                  & {e["modality"] for e in b["episodes"]})
    chosen = both if modalities is None else modalities
    missing = [m for m in chosen if m not in both]
    if missing:
        raise ValueError(f"modality {missing[0]!r} is not in both evaluations (both hold: "
                         f"{', '.join(both) or 'none'})")
    metrics = task_metrics(a)
    out: dict = {"unpaired": [], "metrics": [list(m) for m in metrics]}
    for m in chosen:
        mine, theirs = episodes_by_key(a, m), episodes_by_key(b, m)
        cells = sorted({k[:2] for k in mine} | {k[:2] for k in theirs})
        table = {}
        for cond, scen in cells:
            pairs = sorted(k for k in mine if k[:2] == (cond, scen) and k in theirs)
            if not pairs:
                out["unpaired"].append(f"{m} {cond}/{scen}")
                continue
            row = {}
            for metric, _ in metrics:
                scored = [k for k in pairs if mine[k]["metrics"].get(metric) is not None
                          and theirs[k]["metrics"].get(metric) is not None]
                if not scored:
                    continue
                xa = [float(mine[k]["metrics"][metric]) for k in scored]
                xb = [float(theirs[k]["metrics"][metric]) for k in scored]
                row[metric] = {"a": statistics.fmean(xa), "b": statistics.fmean(xb),
                               **paired_comparison(xa, xb)}
            table[f"{cond}/{scen}"] = row
        out[m] = table
    return out


def markdown(comparison: dict, names: tuple[str, str]) -> str:
    """The comparison as Markdown tables, one per modality and metric.

    Parameters:
        comparison: what compare() returned.
        names: the labels of A and B in the tables' headers.

    Returns:
        The tables, then a line naming the cells not in both evaluations (if any).
    """
    a, b = names
    lines = []
    for m, table in comparison.items():
        if m in ("unpaired", "metrics") or not table:
            continue
        for metric, label in comparison.get("metrics", METRICS):
            lines += [f"### {m}: {label}, {a} - {b}", "",
                      f"| cell | {a} | {b} | {a} - {b} (points) | 95 % interval | "
                      f"wins / losses / ties | p (sign) |", "|---|---|---|---|---|---|---|"]
            for cell, row in table.items():
                if metric not in row:
                    continue
                r = row[metric]
                lines.append(f"| {cell} | {100 * r['a']:.1f} | {100 * r['b']:.1f} | "
                             f"{points(r['mean_diff'])} | [{points(r['ci95'][0])}, "
                             f"{points(r['ci95'][1])}] | {r['wins']} / {r['losses']} / "
                             f"{r['ties']} | {r['p_sign']:.3g} |")
            lines.append("")
    if comparison["unpaired"]:
        lines.append("Not in both evaluations: " + ", ".join(comparison["unpaired"]))
    return "\n".join(lines).rstrip() + "\n"
