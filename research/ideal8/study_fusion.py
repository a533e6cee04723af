"""Issue 15, item 3: how should a policy fuse RGB and events? A nav study of four arms.

    rgb             RGB only, one conv stem                       (the baseline to beat)
    early           RGB+Event, one conv stem over all five planes (the paper's early fusion)
    dual            RGB+Event, a conv stem per modality, the tokens summed (model.DualStem,
                    --stem dual): the control that tells the gate from the second stem
    gated           RGB+Event, a conv stem per modality and a learned gate that adds the
                    event tokens to the RGB ones (model.GatedFusionStem, --stem gated)

Every arm trains on the same recording with the same reduced recipe (the event input
study's: lr 5e-4, 8,000 strided frames, 5 epochs, counts clipped at 8) and the same
training seeds; only the input and the stem differ:

1. train   `sebvs train-sweep research/ideal8/grids/nav_fusion_conv.toml` (rgb and early),
           `nav_fusion_dual.toml` (dual) and `nav_fusion_gated.toml` (gated), into
           OUT/train/<stem>; the grids name the data (datasets/nav_rand60; the command
           that records it is in the grid files) and the seeds;
2. eval    each arm's policy per training seed in closed loop on held-out test-split
           episodes (`sebvs eval --split test --seed S`), beside the expert and the
           no-action baseline on the same episodes.

Reported per arm: the best validation MSE per training seed (one split per seed, the same
in every arm) and, per condition and scenario, the paper's rate, the strict rate and
episode success, mean over the training seeds, with paired sign tests (over episodes,
seeds pooled): each fusion against rgb (do the events help?), dual against early (does
a stem per modality help?), gated against early and against dual (does the gate?).
Nothing is chosen here: arms, seeds, recipe and test seed are fixed before the run. Every
step is skipped when its output is complete, so an interrupted study resumes. Writes
OUT/study.json, OUT/study.md and OUT/study.png.

    research/ideal8/study_fusion.py --eval-seed 100006 --out out/study_fusion   # nav_event_input_study.md
    research/ideal8/study_fusion.py --eval-seed 100007 --train-seeds 2,3 \
        --out out/study_fusion_confirm     # its replication: new training seeds, new episodes
"""
from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from research.ideal8.studyio import (METRICS, baseline_rows, baseline_table_head,  # noqa: E402
                                     best_losses, cell_summary, evaluate, evaluate_policy, keyed,
                                     loss_table, paired_text, sebvs, study_parser, write_study)

# arm -> (modality, stem, grid); the grid's stem is the arm's, its other settings shared
ARMS = {"rgb": ("rgb", "conv", "nav_fusion_conv"),
        "early": ("rgb+event", "conv", "nav_fusion_conv"),
        "dual": ("rgb+event", "dual", "nav_fusion_dual"),
        "gated": ("rgb+event", "gated", "nav_fusion_gated")}
DESCRIPTION = {"rgb": "RGB only", "early": "RGB+Event, early fusion",
               "dual": "RGB+Event, two stems, no gate", "gated": "RGB+Event, gated fusion"}
# (arm, the arm it is paired against)
COMPARISONS = (("early", "rgb"), ("dual", "rgb"), ("gated", "rgb"), ("dual", "early"),
               ("gated", "early"), ("gated", "dual"))


def grid_with_seeds(grid: Path, seeds: list[int] | None, out: Path) -> Path:
    """The grid as it is, or, given ``seeds``, a copy under ``out`` whose seed axis lists
    them instead (everything else as in the file)."""
    if seeds is None:
        return grid
    lines = grid.read_text().splitlines()
    axis = [i for i, line in enumerate(lines) if line.replace(" ", "").startswith("seed=[")]
    if len(axis) != 1:
        raise SystemExit(f"{grid}: expected one 'seed = [...]' axis line, found {len(axis)}")
    lines[axis[0]] = f"seed = {seeds}"
    copy = out / "grids" / grid.name
    copy.parent.mkdir(parents=True, exist_ok=True)
    copy.write_text(f"# {grid.name} with seed = {seeds}, written by "
                    f"research/ideal8/study_fusion.py\n" + "\n".join(lines) + "\n")
    return copy


def train(args) -> dict:
    """The three sweeps (finished points are skipped); {(arm, seed): best validation MSE}."""
    losses = {}
    for stem in ("conv", "dual", "gated"):
        out = args.out / "train" / stem
        grid = grid_with_seeds(ROOT / "research" / "ideal8" / "grids" / f"nav_fusion_{stem}.toml",
                               args.train_seeds, args.out)
        sebvs("train-sweep", str(grid), "--out", str(out), "--threads", str(args.threads),
              "--no-progress")
        for (modality, seed), loss in best_losses(out).items():
            arm = next(a for a, (m, s, _) in ARMS.items() if (m, s) == (modality, stem))
            losses[(arm, seed)] = loss
    return losses


def checkpoint_dir(args, arm: str, seed: int) -> Path:
    modality, stem, _ = ARMS[arm]
    return args.out / "train" / stem / f"modality={modality}__seed={seed}"


def summarise(args, losses: dict, arm_eps: dict, reference: dict) -> dict:
    """Per arm and cell: metric means over every episode of every training seed, and the
    paired comparisons of COMPARISONS on the same (training seed, episode)."""
    by_arm = {arm: keyed(eps) for arm, eps in arm_eps.items()}
    summary: dict = {"config": {k: str(v) if isinstance(v, Path) else v
                                for k, v in vars(args).items()},
                     "arms": {}, "reference_rows": baseline_rows(reference)}
    for arm, mine in by_arm.items():
        against = {base: by_arm[base] for a, base in COMPARISONS if a == arm and base in by_arm}
        modality, stem, _ = ARMS[arm]
        summary["arms"][arm] = {
            "description": DESCRIPTION[arm], "modality": modality, "stem": stem,
            "best_val_mse": {str(s): v for (a, s), v in sorted(losses.items()) if a == arm},
            "cells": cell_summary(mine, against)}
    return summary


def report(summary: dict) -> str:
    arms = summary["arms"]
    cell_names = sorted({c for a in arms.values() for c in a["cells"]})
    lines = ["# Fusion study (research/ideal8/study_fusion.py)", "",
             "Best validation MSE per training seed (same data and split per seed):", "",
             *loss_table(arms, "arm")]
    for metric, label in METRICS:
        lines += ["", f"Closed loop, {label} (%; mean over training seeds and episodes):", "",
                  *baseline_table_head(cell_names, summary["reference_rows"], metric)]
        for a in arms.values():
            lines.append(f"| {a['description']} | " + " | ".join(
                f"{100 * a['cells'][c][metric]:.1f}" if c in a["cells"] else "-"
                for c in cell_names) + " |")
        lines += ["", f"Paired differences, {label} (points; episodes of both seeds pooled; "
                      f"exact sign test p):", "",
                  "| comparison | " + " | ".join(cell_names) + " |",
                  "|---|" + "---|" * len(cell_names)]
        for arm, base in COMPARISONS:
            if arm not in arms:
                continue
            lines.append(f"| {arm} - {base} | " + " | ".join(
                paired_text(arms[arm]["cells"].get(c, {}).get(f"vs_{base}", {}).get(metric))
                for c in cell_names) + " |")
    return "\n".join(lines) + "\n"


def plot(summary: dict, path: Path) -> None:
    """Paper rate and strict rate per cell, one bar per arm; the no-action baseline dotted
    and the expert dashed across each cell's bars."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np
    arms = summary["arms"]
    cell_names = sorted({c for a in arms.values() for c in a["cells"]})
    x = np.arange(len(cell_names))
    width = 0.8 / max(1, len(arms))
    fig, axes = plt.subplots(2, 1, figsize=(max(8.0, 2 + 1.5 * len(cell_names)), 6.4),
                             sharex=True)
    for ax, (metric, label) in zip(axes, METRICS[:2]):
        for j, a in enumerate(arms.values()):
            ax.bar(x + (j - (len(arms) - 1) / 2) * width,
                   [100 * a["cells"].get(c, {}).get(metric, float("nan")) for c in cell_names],
                   width, label=a["description"])
        for row, style in (("no_action", ":"), ("expert", "--")):
            rows = summary["reference_rows"].get(row, {})
            for i, c in enumerate(cell_names):
                if c in rows:
                    ax.hlines(100 * rows[c][metric], i - 0.45, i + 0.45, colors="k",
                              linestyles=style, label=row.replace("_", " ") if i == 0 else None)
        ax.set(ylabel=f"{label} (%)", ylim=(0, 105))
    axes[0].set_title("nav, test split: RGB alone and three fusions (mean over seeds)")
    axes[1].set_xticks(x, [c.replace("/", "\n") for c in cell_names], fontsize=8)
    axes[1].legend(fontsize=7, ncol=5, loc="upper center")   # the strict panel has room
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> int:
    ap = study_parser(__doc__, "study_fusion", 100006, "nominal,fast,low_light")
    ap.add_argument("--threads", type=int, default=1, help="torch threads for training")
    ap.add_argument("--train-seeds", default=None,
                    help="training seeds, e.g. 2,3,4 (default: the grids' own, 0 and 1)")
    args = ap.parse_args()
    if args.train_seeds is not None:
        args.train_seeds = [int(x) for x in args.train_seeds.split(",")]
    args.out = args.out.resolve()
    losses = train(args)
    seeds = sorted({s for _, s in losses})
    reference = evaluate(args, "reference", ["--modalities="])    # expert and no action
    arm_eps = {}
    for arm, (modality, _, _) in ARMS.items():
        arm_eps[arm] = {}
        for seed in seeds:
            arm_eps[arm][seed] = evaluate_policy(args, f"{arm}_seed{seed}", modality,
                                                 checkpoint_dir(args, arm, seed))
    summary = summarise(args, losses, arm_eps, reference)
    write_study(args.out, summary, report(summary), plot)
    return 0


if __name__ == "__main__":
    sys.exit(main())
