#!/usr/bin/env python3
"""Issue 15, item 3: what should the event input be? An event-only nav study.

At each control tick the accumulator turns the last `window_s` seconds of events into the
frame a policy sees: ON/OFF counts (the paper's, and the shipped input: 0.1 s, one control
period), or a histogram of K time bins per polarity, which keeps when in the window an
event fired. The study's default sensor is the paper's, half the RGB frame's size (80 px
for 160), whose events fill 2 x 2 blocks of the frame (the shipped nav policies have used
a 160 px sensor since this study's third piece). A variant is one such input, written
WINDOW[xK][@S]: counts or K bins over WINDOW seconds, from a sensor S times the frame's
size (default 0.5): 0.1, 0.4, 0.1x4, 0.1@1. This study changes the input and keeps
everything else:

1. record  the same randomised nav episodes once per variant (`sebvs record
           topologies/nav_record.toml --set accumulator.window_s=W [--set
           accumulator.representation="histogram" --set accumulator.bins=K] [--set
           camera.luma_scale=S]`, one recording seed): the scenes, the expert's commands
           and the RGB are the same in every dataset, only the event frames differ;
2. train   event-only policies on each, one recipe (`sebvs train-sweep`, the grid below:
           conv stem, lr 5e-4, a reduced budget of 8,000 strided frames and 5 epochs,
           event counts clipped at 8 per plane, training seeds 0 and 1); the model's input
           channels follow the recording (2 for counts, 2K for bins);
3. eval    each policy in closed loop on held-out test-split episodes (`sebvs eval
           --split test --seed S`, the accumulator set as recorded), beside the expert and
           the no-action baseline on the same episodes.

Reported per variant: the best validation MSE per training seed (the datasets share their
episodes and commands, and a seed draws the same split in each, so losses compare across
variants), and per condition and scenario the paper's rate, the strict rate and episode
success, mean over the training seeds, with a paired sign test (over episodes, seeds
pooled) of each variant against the reference (--reference, default 0.1: the shipped
input). Nothing is chosen here: the variants, seeds, recipe and test seed are fixed
before the run.

Every step is skipped when its output is complete, so an interrupted study resumes.
Writes OUT/study.json, OUT/study.md and OUT/study.png. The two studies of
research/ideal8/nav_event_input_study.md:

    research/ideal8/study_event_input.py --variants 0.05,0.1,0.2,0.4 --eval-seed 100004 \
        --out out/study_event_window
    research/ideal8/study_event_input.py --variants 0.1,0.1x4,0.4,0.4x4 --eval-seed 100005 \
        --out out/study_event_bins
    research/ideal8/study_event_input.py --quick    # plumbing check, a few minutes
"""
from __future__ import annotations

import json
import sys
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from research.ideal8.studyio import (METRICS, baseline_rows, baseline_table_head,  # noqa: E402
                                     best_losses, cell_summary, evaluate, evaluate_policy, keyed,
                                     loss_table, paired_text, sebvs, study_parser, write_study)

RECIPE = {"stem": "conv", "lr": 5e-4, "epochs": 5, "patience": 3, "max_frames": 8000,
          "size": 160, "event_clip": 8}


# The studies' default sensor: the paper's (v2e downsample 0.5), an 80 px sensor for 160 px
# RGB. The nav topologies had it until 2026-11-25 and now render 160 px luma, so every
# variant sets camera.luma_scale itself: a study reads the same whatever the topology says.
SENSOR_SCALE = 0.5


@dataclass(frozen=True)
class Variant:
    """One event input: the accumulator's window, its time bins (1: plain counts) and the
    emulator's sensor size as a fraction of the RGB frame (camera.luma_scale)."""
    window: float
    bins: int = 1
    sensor: float = SENSOR_SCALE

    @classmethod
    def parse(cls, text: str) -> "Variant":
        """WINDOW[xBINS][@SENSOR]: "0.1" (counts over 0.1 s), "0.1x4" (4 time bins per
        polarity), "0.1@1" (counts from a sensor of the RGB frame's size)."""
        head, at, sensor = text.strip().partition("@")
        window, sep, bins = head.partition("x")
        try:
            v = cls(float(window), int(bins) if sep else 1,
                    float(sensor) if at else SENSOR_SCALE)
        except ValueError:
            raise ValueError(f"variant {text!r} is not WINDOW[xBINS][@SENSOR] "
                             f"(e.g. 0.1, 0.1x4, 0.1@1)") from None
        if not v.window > 0 or not 1 <= v.bins <= 64 or not 0 < v.sensor <= 1:
            raise ValueError(f"variant {text!r}: the window must be > 0 s, the bins in "
                             f"1..64 and the sensor scale in (0, 1]")
        return v

    @property
    def label(self) -> str:
        text = f"{self.window:g}" + ("" if self.bins == 1 else f"x{self.bins}")
        return text + ("" if self.sensor == SENSOR_SCALE else f"@{self.sensor:g}")

    @property
    def tag(self) -> str:
        """Directory name; counts keep the window study's names (w0.1), so its outputs
        are found again."""
        return (f"w{self.window:g}" + ("" if self.bins == 1 else f"_h{self.bins}")
                + ("" if self.sensor == SENSOR_SCALE else f"_s{self.sensor:g}"))

    @property
    def description(self) -> str:
        text = (f"counts, {self.window:g} s" if self.bins == 1 else
                f"{self.bins} bins, {self.window:g} s")
        return text + ("" if self.sensor == SENSOR_SCALE else f", sensor x{self.sensor:g}")

    def accumulator_sets(self) -> list[str]:
        """The --set options that make this input (recording and evaluation alike)."""
        sets = ["--set", f"accumulator.window_s={self.window}"]
        if self.bins > 1:
            sets += ["--set", 'accumulator.representation="histogram"',
                     "--set", f"accumulator.bins={self.bins}"]
        return sets + ["--set", f"camera.luma_scale={self.sensor}"]


def episodes_in(dataset: Path) -> int:
    index = dataset / "index.json"
    return len(json.loads(index.read_text())["episodes"]) if index.is_file() else 0


def record(args, variant: Variant) -> Path:
    out = args.out / "data" / variant.tag
    missing = args.episodes - episodes_in(out)
    if missing > 0:     # a recording into the dataset plays on with the seed's episodes
        sebvs("record", "topologies/nav_record.toml", "--episodes", str(missing),
              "--out", str(out), "--set", f"sim.episode_s={args.episode_s}",
              "--set", f"topology.seed={args.record_seed}", *variant.accumulator_sets(),
              "--workers", str(args.workers), "--runs-dir", str(args.out / "runs"),
              "--quiet")
    return out


def train(args, variant: Variant, data: Path) -> Path:
    out = args.out / "train" / variant.tag
    grid = args.out / "grids" / f"{variant.tag}.toml"
    grid.parent.mkdir(parents=True, exist_ok=True)
    recipe = {**RECIPE, **({"epochs": 1, "max_frames": 400} if args.quick else {})}
    lines = ["# written by research/ideal8/study_event_input.py", 'task = "nav"',
             f'data = "{data}"', "", "[train]"]
    lines += [f"{k} = {json.dumps(v)}" for k, v in recipe.items()]
    lines += ["", "[axes]", 'modality = ["event"]', f"seed = {json.dumps(args.train_seeds)}"]
    grid.write_text("\n".join(lines) + "\n")
    sebvs("train-sweep", str(grid), "--out", str(out), "--threads", str(args.threads),
          "--no-progress")      # resumes: finished points are skipped
    return out


def summarise(args, losses: dict, policy_eps: dict, reference: dict) -> dict:
    """Per variant and cell: metric means (over every episode of every training seed),
    and the paired comparison with the reference variant on the same (seed, episode)."""
    summary: dict = {"config": {k: (str(v) if isinstance(v, Path) else
                                    [x.label for x in v] if k == "variants" else
                                    v.label if isinstance(v, Variant) else v)
                                for k, v in vars(args).items()},
                     "recipe": RECIPE, "reference": args.reference.label,
                     "variants": {}, "reference_rows": baseline_rows(reference)}
    base = keyed(policy_eps[args.reference]) if args.reference in policy_eps else None
    for variant in args.variants:
        against = {"reference": base} if base is not None and variant != args.reference else {}
        summary["variants"][variant.label] = {
            "description": variant.description,
            "best_val_mse": {str(s): v for s, v in losses[variant].items()},
            "cells": cell_summary(keyed(policy_eps[variant]), against)}
    return summary


def report(summary: dict) -> str:
    variants = summary["variants"]
    cell_names = sorted({c for v in variants.values() for c in v["cells"]})
    lines = ["# Event input study (research/ideal8/study_event_input.py)", "",
             "Best validation MSE per training seed (same episodes and commands in every "
             "dataset):", "", *loss_table(variants, "event input")]
    ref = variants.get(summary["reference"], {}).get("description", summary["reference"])
    for metric, label in METRICS:
        lines += ["", f"Closed loop, {label} (%; mean over training seeds and episodes; "
                      f"in brackets: difference to {ref}, sign-test p):", "",
                  *baseline_table_head(cell_names, summary["reference_rows"], metric)]
        for v in variants.values():
            out = []
            for c in cell_names:
                cell = v["cells"].get(c)
                if cell is None:
                    out.append("-")
                    continue
                text = f"{100 * cell[metric]:.1f}"
                vs = cell.get("vs_reference", {}).get(metric)
                if vs and vs["n"]:
                    text += f" ({paired_text(vs)})"
                out.append(text)
            lines.append(f"| event, {v['description']} | " + " | ".join(out) + " |")
    return "\n".join(lines) + "\n"


def plot(summary: dict, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    variants = summary["variants"]
    labels = list(variants)
    x = range(len(labels))
    cell_names = sorted({c for v in variants.values() for c in v["cells"]})
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for c in cell_names:
        line, = axes[0].plot(x, [100 * variants[v]["cells"].get(c, {}).get(
            "success", float("nan")) for v in labels], "o-", label=c)
        base = summary["reference_rows"].get("no_action", {}).get(c)
        if base:
            axes[0].axhline(100 * base["success"], ls=":", lw=1.0, color=line.get_color())
    axes[0].set(ylabel="paper rate (%)", title="event-only, closed loop (dotted: no action)")
    axes[0].legend(fontsize=7)
    seeds = sorted({s for v in variants.values() for s in v["best_val_mse"]})
    for s in seeds:
        axes[1].plot(x, [variants[v]["best_val_mse"].get(s) or float("nan") for v in labels],
                     "o-", label=f"seed {s}")
    axes[1].set(ylabel="best validation MSE", title="offline")
    axes[1].legend(fontsize=7)
    for ax in axes:
        ax.set_xticks(list(x), [variants[v]["description"] for v in labels], fontsize=8,
                      rotation=20)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> int:
    ap = study_parser(__doc__, "study_event_input", 100004, "nominal,fast")
    ap.add_argument("--variants", default="0.05,0.1,0.2,0.4",
                    help="event inputs, WINDOW (counts) or WINDOWxBINS (time bins per "
                         "polarity), seconds; default 0.05,0.1,0.2,0.4 (the window study)")
    ap.add_argument("--reference", default="0.1",
                    help="the variant the others are paired against (default 0.1: shipped)")
    ap.add_argument("--episodes", type=int, default=60, help="recorded episodes per variant")
    ap.add_argument("--episode-s", type=float, default=20.0)
    ap.add_argument("--record-seed", type=int, default=3,
                    help="topology seed of the recordings (a recording seed, < 1000)")
    ap.add_argument("--train-seeds", default="0,1")
    ap.add_argument("--threads", type=int, default=2, help="torch threads for training")
    ap.add_argument("--quick", action="store_true",
                    help="plumbing check: variants 0.1 and 0.1x2, 4 x 2 s episodes, 1 "
                         "epoch, 1 seed, 2 eval episodes, nominal indoor")
    args = ap.parse_args()
    try:
        args.variants = [Variant.parse(v) for v in args.variants.split(",")]
        args.reference = Variant.parse(args.reference)
    except ValueError as exc:
        ap.error(str(exc))
    args.train_seeds = [int(s) for s in args.train_seeds.split(",")]
    if args.quick:
        args.variants, args.episodes, args.episode_s = [Variant(0.1), Variant(0.1, 2)], 4, 2.0
        args.reference = Variant(0.1)
        args.train_seeds, args.eval_episodes = [0], 2
        args.conditions, args.scenarios = "nominal", "indoor"
    if len(set(args.variants)) != len(args.variants):
        ap.error("a variant is listed twice")
    if args.record_seed >= 1000:     # (--eval-seed refuses a seed outside the test split)
        ap.error("recording seeds are below 1000 and test seeds 100000 and above "
                 "(sebvs/data/splits.py): keep them apart")
    args.out = args.out.resolve()
    losses, policy_eps = {}, {}
    for variant in args.variants:
        data = record(args, variant)
        losses[variant] = {seed: loss for (_, seed), loss
                           in best_losses(train(args, variant, data)).items()}
    reference = evaluate(args, "reference", ["--modalities="])    # expert and no action
    for variant in args.variants:
        policy_eps[variant] = {}
        for seed in args.train_seeds:
            ck = args.out / "train" / variant.tag / f"modality=event__seed={seed}"
            policy_eps[variant][seed] = evaluate_policy(
                args, f"{variant.tag}_seed{seed}", "event", ck, variant.accumulator_sets())
    summary = summarise(args, losses, policy_eps, reference)
    write_study(args.out, summary, report(summary), plot)
    return 0


if __name__ == "__main__":
    sys.exit(main())
