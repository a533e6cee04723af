#!/usr/bin/env python3
"""Two evaluations of the same episodes, paired: does checkpoint set (or setting) A play
the same test scenes better than B?

    tools/eval/compare_evals.py out/eval_new out/eval_old --modalities event \\
        --names "160 px sensor,80 px sensor" --json out/compare.json

Each of A and B is an `sebvs eval` output directory (or its results.json). They must have
played the same task and topology seed, so the same episode seeds; an episode of A pairs
with B's of the same modality, condition, scenario and episode seed. For each modality
both hold (or those of --modalities) and each metric, one markdown table, a row per
condition and scenario: A's mean, B's mean, A - B in points with its bootstrap 95 %
interval, A's wins / losses / ties over the pairs and the exact sign test's two-sided p
(sebvs/metrics.py paired_comparison). A cell either run lacks is left out and named.
Metrics: nav the paper rate, the strict rate and episode success; arm grasp success, over
the episodes where a cube was graspable (the scene decides which, so both sides agree).
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

# the nav metrics every table reads, with their names in a table's header
METRICS = (("success", "paper rate"), ("strict_success", "strict rate"),
           ("episode_success", "episode success"))


def read_results(path: Path) -> dict:
    """An evaluation's results.json, from the file or the directory holding it."""
    path = path / "results.json" if path.is_dir() else path
    try:
        results = json.loads(path.read_text())
    except FileNotFoundError:
        raise ValueError(f"{path}: no such file (an `sebvs eval --out` directory or its "
                         f"results.json)") from None
    except (OSError, json.JSONDecodeError) as exc:
        raise ValueError(f"{path}: not a readable results.json ({exc})") from None
    if not isinstance(results, dict) or not isinstance(results.get("episodes"), list):
        raise ValueError(f"{path}: no 'episodes' list: not an `sebvs eval` results.json")
    return results


# the arm's grasp_success is None where the task says HOME: those episodes have no grasp
TASK_METRICS = {"nav": METRICS, "arm": (("grasp_success", "grasp success"),)}


def _by_key(results: dict, modality: str) -> dict:
    return {(e["condition"], e["scenario"], e["seed"]): e
            for e in results["episodes"] if e["modality"] == modality}


def compare(a: dict, b: dict, modalities: list[str] | None = None) -> dict:
    """{modality: {"condition/scenario": {metric: {"a", "b", **paired_comparison}}}},
    plus "unpaired": the cells only one side holds. Refuses runs of different episodes."""
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
    metrics = TASK_METRICS.get(a.get("task"), METRICS)
    out: dict = {"unpaired": [], "metrics": [list(m) for m in metrics]}
    for m in chosen:
        mine, theirs = _by_key(a, m), _by_key(b, m)
        cells = sorted({k[:2] for k in mine} | {k[:2] for k in theirs})
        table = {}
        for cond, scen in cells:
            pairs = sorted(k for k in mine if k[:2] == (cond, scen) and k in theirs)
            if not pairs:
                out["unpaired"].append(f"{m} {cond}/{scen}")
                continue
            row = {}
            for metric, _ in metrics:
                both = [k for k in pairs if mine[k]["metrics"].get(metric) is not None
                        and theirs[k]["metrics"].get(metric) is not None]
                if not both:
                    continue
                xa = [float(mine[k]["metrics"][metric]) for k in both]
                xb = [float(theirs[k]["metrics"][metric]) for k in both]
                row[metric] = {"a": statistics.fmean(xa), "b": statistics.fmean(xb),
                               **paired_comparison(xa, xb)}
            table[f"{cond}/{scen}"] = row
        out[m] = table
    return out


def markdown(comparison: dict, names: tuple[str, str]) -> str:
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


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("a", type=Path, help="evaluation A: an `sebvs eval --out` directory")
    ap.add_argument("b", type=Path, help="evaluation B, of the same task and topology seed")
    ap.add_argument("--modalities", help="comma-separated (default: every modality both hold, "
                                         "expert and no_action included)")
    ap.add_argument("--names", default="A,B", help="two labels for the tables (default A,B)")
    ap.add_argument("--json", type=Path, help="also write the comparison here")
    args = ap.parse_args(argv)
    names = tuple(n.strip() for n in args.names.split(","))
    if len(names) != 2 or not all(names):
        ap.error(f"--names takes two comma-separated labels, got {args.names!r}")
    try:
        comparison = compare(read_results(args.a), read_results(args.b),
                             args.modalities.split(",") if args.modalities else None)
    except ValueError as exc:
        print(f"compare_evals: {exc}", file=sys.stderr)
        return 2
    print(markdown(comparison, names), end="")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"a": str(args.a), "b": str(args.b), "names": names,
                                         **comparison}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
