#!/usr/bin/env python3
"""Issue 15, item 3: how long should the event window be? An event-only nav study.

The accumulator turns the last `window_s` seconds of events into the count frame a policy
sees at each control tick (0.1 s, one control period, is the paper's and the shipped
value). This study changes that one number and keeps everything else:

1. record  the same randomised nav episodes once per window (`sebvs record
           topologies/nav_record.toml --set accumulator.window_s=W`, one recording seed):
           the scenes, the expert's commands and the RGB are the same in every dataset,
           only the event frames differ;
2. train   event-only policies on each, one recipe (`sebvs train-sweep`, the grid below:
           conv stem, lr 5e-4, a reduced budget of 8,000 strided frames and 5 epochs,
           event counts clipped at 8, training seeds 0 and 1);
3. eval    each policy in closed loop on held-out test-split episodes (`sebvs eval
           --split test --seed S --set accumulator.window_s=W`), beside the expert and
           the no-action baseline on the same episodes.

Reported per window: the best validation MSE per training seed (the datasets share their
episodes and commands, and a seed draws the same split in each, so losses compare across
windows), and per condition and scenario the paper's rate, the strict rate and episode
success, mean over the training seeds, with a paired sign test (over episodes, seeds
pooled) of each window against 0.1 s. Nothing is chosen here: the windows, seeds, recipe
and test seed are fixed before the run.

Every step is skipped when its output is complete, so an interrupted study resumes.
Writes OUT/study.json, OUT/study.md and OUT/study.png.

    tools/study_event_window.py [--quick] [--out DIR] [--workers N] [...]
"""
from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from sebvs.metrics import paired_comparison  # noqa: E402

RECIPE = {"stem": "conv", "lr": 5e-4, "epochs": 5, "patience": 3, "max_frames": 8000,
          "size": 160, "event_clip": 8}
REFERENCE_WINDOW = 0.1
METRICS = (("success", "paper rate"), ("strict_success", "strict rate"),
           ("episode_success", "episode success"))


def sebvs(*args: str) -> None:
    cmd = [sys.executable, "-m", "sebvs.cli", *args]
    print("+ sebvs " + " ".join(args), flush=True)
    subprocess.run(cmd, cwd=ROOT, check=True)


def tag(window: float) -> str:
    return f"w{window:g}"


def episodes_in(dataset: Path) -> int:
    index = dataset / "index.json"
    return len(json.loads(index.read_text())["episodes"]) if index.is_file() else 0


def record(args, window: float) -> Path:
    out = args.out / "data" / tag(window)
    missing = args.episodes - episodes_in(out)
    if missing > 0:     # a recording into the dataset plays on with the seed's episodes
        sebvs("record", "topologies/nav_record.toml", "--episodes", str(missing),
              "--out", str(out), "--set", f"sim.episode_s={args.episode_s}",
              "--set", f"topology.seed={args.record_seed}",
              "--set", f"accumulator.window_s={window}", "--workers", str(args.workers),
              "--runs-dir", str(args.out / "runs"), "--quiet")
    return out


def train(args, window: float, data: Path) -> Path:
    out = args.out / "train" / tag(window)
    grid = args.out / "grids" / f"{tag(window)}.toml"
    grid.parent.mkdir(parents=True, exist_ok=True)
    recipe = {**RECIPE, **({"epochs": 1, "max_frames": 400} if args.quick else {})}
    lines = ["# written by tools/study_event_window.py", 'task = "nav"',
             f'data = "{data}"', "", "[train]"]
    lines += [f"{k} = {json.dumps(v)}" for k, v in recipe.items()]
    lines += ["", "[axes]", 'modality = ["event"]', f"seed = {json.dumps(args.train_seeds)}"]
    grid.write_text("\n".join(lines) + "\n")
    sebvs("train-sweep", str(grid), "--out", str(out), "--threads", str(args.threads),
          "--no-progress")      # resumes: finished points are skipped
    return out


def evaluate(args, name: str, extra: list[str]) -> dict:
    out = args.out / "eval" / name
    results = out / "results.json"
    if not results.is_file():
        sebvs("eval", "--task", "nav", "--split", "test", "--seed", str(args.eval_seed),
              "--episodes", str(args.eval_episodes), "--conditions", args.conditions,
              "--scenarios", args.scenarios, "--out", str(out), "--workers",
              str(args.workers), *extra)
    return json.loads(results.read_text())


def best_losses(train_dir: Path) -> dict[int, float | None]:
    sweep = json.loads((train_dir / "sweep.json").read_text())
    return {p["settings"]["seed"]: p.get("best_val_loss") for p in sweep["points"]}


def cells(episodes: list[dict]) -> dict[tuple[str, str], list[dict]]:
    out: dict = {}
    for ep in episodes:
        out.setdefault((ep["condition"], ep["scenario"]), []).append(ep)
    return out


def summarise(args, losses: dict, policy_eps: dict, reference: dict) -> dict:
    """Per window and cell: metric means (over every episode of every training seed),
    and the paired comparison with the reference window on the same (seed, episode)."""
    ref_cells = cells(reference["episodes"])
    summary: dict = {"config": {k: (str(v) if isinstance(v, Path) else v)
                                for k, v in vars(args).items()},
                     "recipe": RECIPE, "windows": {}, "reference_rows": {}}
    for key, eps in ref_cells.items():
        for modality in ("expert", "no_action"):
            rows = [e for e in eps if e["modality"] == modality]
            if rows:
                summary["reference_rows"].setdefault(modality, {})[f"{key[0]}/{key[1]}"] = {
                    m: statistics.fmean(e["metrics"][m] for e in rows) for m, _ in METRICS}

    def keyed(window):
        return {(s, e["condition"], e["scenario"], e["seed"]): e
                for s, eps in policy_eps[window].items() for e in eps}

    base = keyed(REFERENCE_WINDOW) if REFERENCE_WINDOW in policy_eps else None
    for window in args.windows:
        row: dict = {"best_val_mse": {str(s): v for s, v in losses[window].items()},
                     "cells": {}}
        mine = keyed(window)
        for (cond, scen) in sorted({(k[1], k[2]) for k in mine}):
            keys = sorted(k for k in mine if k[1:3] == (cond, scen))
            cell = {m: statistics.fmean(mine[k]["metrics"][m] for k in keys)
                    for m, _ in METRICS}
            cell["episodes"] = len(keys)
            if base is not None and window != REFERENCE_WINDOW:
                paired = [k for k in keys if k in base]
                cell["vs_reference"] = {
                    m: paired_comparison([mine[k]["metrics"][m] for k in paired],
                                         [base[k]["metrics"][m] for k in paired])
                    for m, _ in METRICS}
            row["cells"][f"{cond}/{scen}"] = cell
        summary["windows"][str(window)] = row
    return summary


def report(summary: dict) -> str:
    windows = list(summary["windows"])
    cell_names = sorted({c for w in summary["windows"].values() for c in w["cells"]})
    seeds = sorted({s for w in summary["windows"].values() for s in w["best_val_mse"]})
    lines = ["# Event window study (tools/study_event_window.py)", "",
             "Best validation MSE per training seed (same episodes and commands in every "
             "dataset):", "", "| window (s) | " + " | ".join(f"seed {s}" for s in seeds) + " |",
             "|---|" + "---|" * len(seeds)]
    for w in windows:
        vals = summary["windows"][w]["best_val_mse"]
        lines.append(f"| {w} | " + " | ".join(
            "-" if vals.get(s) is None else f"{vals[s]:.5f}" for s in seeds) + " |")
    for metric, label in METRICS:
        lines += ["", f"Closed loop, {label} (%; mean over training seeds and episodes; "
                      f"in brackets: difference to {REFERENCE_WINDOW:g} s, sign-test p):", "",
                  "| row | " + " | ".join(cell_names) + " |",
                  "|---|" + "---|" * len(cell_names)]
        for name, rows in summary["reference_rows"].items():
            lines.append(f"| {name} | " + " | ".join(
                f"{100 * rows[c][metric]:.1f}" if c in rows else "-" for c in cell_names) + " |")
        for w in windows:
            out = []
            for c in cell_names:
                cell = summary["windows"][w]["cells"].get(c)
                if cell is None:
                    out.append("-")
                    continue
                text = f"{100 * cell[metric]:.1f}"
                vs = cell.get("vs_reference", {}).get(metric)
                if vs and vs["n"]:
                    text += f" ({100 * vs['mean_diff']:+.1f}, p {vs['p_sign']:.2f})"
                out.append(text)
            lines.append(f"| event, window {w} s | " + " | ".join(out) + " |")
    return "\n".join(lines) + "\n"


def plot(summary: dict, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    windows = [float(w) for w in summary["windows"]]
    cell_names = sorted({c for w in summary["windows"].values() for c in w["cells"]})
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for c in cell_names:
        line, = axes[0].plot(windows, [100 * summary["windows"][str(w)]["cells"].get(
            c, {}).get("success", float("nan")) for w in windows], "o-", label=c)
        base = summary["reference_rows"].get("no_action", {}).get(c)
        if base:
            axes[0].axhline(100 * base["success"], ls=":", lw=1.0, color=line.get_color())
    axes[0].set(xscale="log", xlabel="event window (s)", ylabel="paper rate (%)",
                title="event-only, closed loop (dotted: no action)")
    axes[0].legend(fontsize=7)
    seeds = sorted({s for w in summary["windows"].values() for s in w["best_val_mse"]})
    for s in seeds:
        axes[1].plot(windows, [summary["windows"][str(w)]["best_val_mse"].get(s) or
                               float("nan") for w in windows], "o-", label=f"seed {s}")
    axes[1].set(xscale="log", xlabel="event window (s)", ylabel="best validation MSE",
                title="offline")
    axes[1].legend(fontsize=7)
    for ax in axes:
        ax.set_xticks(windows, [f"{w:g}" for w in windows])
        ax.minorticks_off()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--out", type=Path, default=ROOT / "out" / "study_event_window")
    ap.add_argument("--windows", default="0.05,0.1,0.2,0.4",
                    help="accumulator windows in seconds (default 0.05,0.1,0.2,0.4)")
    ap.add_argument("--episodes", type=int, default=60, help="recorded episodes per window")
    ap.add_argument("--episode-s", type=float, default=20.0)
    ap.add_argument("--record-seed", type=int, default=3,
                    help="topology seed of the recordings (a recording seed, < 1000)")
    ap.add_argument("--train-seeds", default="0,1")
    ap.add_argument("--eval-seed", type=int, default=100004,
                    help="test-split topology seed (100000+; unused by earlier studies)")
    ap.add_argument("--eval-episodes", type=int, default=10, help="episodes per cell")
    ap.add_argument("--conditions", default="nominal,fast")
    ap.add_argument("--scenarios", default="indoor,outdoor")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--threads", type=int, default=2, help="torch threads for training")
    ap.add_argument("--quick", action="store_true",
                    help="plumbing check: 2 windows, 4 x 2 s episodes, 1 epoch, 1 seed, "
                         "2 eval episodes, nominal indoor")
    args = ap.parse_args()
    args.windows = [float(w) for w in args.windows.split(",")]
    args.train_seeds = [int(s) for s in args.train_seeds.split(",")]
    if args.quick:
        args.windows, args.episodes, args.episode_s = [0.1, 0.2], 4, 2.0
        args.train_seeds, args.eval_episodes = [0], 2
        args.conditions, args.scenarios = "nominal", "indoor"
    if args.record_seed >= 1000 or args.eval_seed < 100000:
        ap.error("recording seeds are below 1000 and test seeds 100000 and above "
                 "(sebvs/data/splits.py): keep them apart")
    args.out = args.out.resolve()
    losses, policy_eps = {}, {}
    for window in args.windows:
        data = record(args, window)
        losses[window] = best_losses(train(args, window, data))
    reference = evaluate(args, "reference", ["--modalities="])    # expert and no action
    for window in args.windows:
        policy_eps[window] = {}
        for seed in args.train_seeds:
            ck = args.out / "train" / tag(window) / f"modality=event__seed={seed}"
            res = evaluate(args, f"{tag(window)}_seed{seed}",
                           ["--modalities", "event", "--no-expert", "--no-baseline",
                            "--checkpoints", str(ck),
                            "--set", f"accumulator.window_s={window}"])
            policy_eps[window][seed] = res["episodes"]
    summary = summarise(args, losses, policy_eps, reference)
    (args.out / "study.json").write_text(json.dumps(summary, indent=1))
    (args.out / "study.md").write_text(report(summary))
    plot(summary, args.out / "study.png")
    print(report(summary))
    print(f"wrote {args.out}/study.json, study.md, study.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
