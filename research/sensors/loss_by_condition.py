#!/usr/bin/env python3
"""Where does a policy fail to imitate its expert, offline? Validation loss per scene setting.

    research/sensors/loss_by_condition.py DATASET CHECKPOINT.pt [CHECKPOINT.pt ...]
                                       [--by lighting,variant] [--held-out-from TRAIN_DATA]
                                       [--ablate rgb|second] [--json OUT] [--plot OUT.png]

A closed-loop figure mixes two failures: the policy cannot tell the expert's command from
its input (the sensor shows too little, or the policy learned too little of it), or it can
and its small errors compound on the road. This measures the first, on the frames the
checkpoint was validated on (the episodes its JSON record names, never trained on): the
loss training took (MSE on nav's [v, w], Smooth L1 in the arm head's loss space), per group
of episodes that share the scene settings named by --by (each episode's `conditions` in the
dataset's index), beside a constant predictor's on the same frames: the training targets'
mean (MSE) or median (Smooth L1) in the loss space, the best a policy that sees nothing can
do. Skill is 1 - loss / constant loss: 0 for a policy that learned nothing of its input
for that group, 1 for a perfect imitation. Each checkpoint is measured on its own
validation episodes (a training seed draws its own split), so a group's frames can differ
between checkpoints; the episodes and frames of each are printed beside it. A validation
split holds few episodes of a rare setting; --held-out-from TRAIN_DATA measures instead on
every episode of DATASET, a recording made for the purpose on seeds the training recording
never used (refused otherwise), the constant then from TRAIN_DATA's training episodes.

--ablate rgb | second replaces one part of a two-stream input (the frame; or the events,
or the frame difference) by its mean level over the frames measured: the skill lost is how
much the policy draws on that part there (a policy that ignores it loses nothing).

Printed: per group, the constant loss and each checkpoint's loss and skill; then per
modality the mean skill over its checkpoints. --plot draws the skill per group and
modality (one point per checkpoint, the bar their mean). A diagnostic, not a reading: the
study's plan (research/sensors/plan.md) reads only closed-loop results.
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from tools.eval.val_loss import (criterion_of, episodes_named, first_few,  # noqa: E402
                                    frames_of, mean_loss, validation_of)


def group_of(episode: dict, by: list[str]) -> str:
    """The episode's group: its `conditions` values for the keys in ``by``, "/"-joined
    ("-" for a key it does not set)."""
    conditions = episode.get("conditions") or {}
    return "/".join(str(conditions.get(key, "-")) for key in by)


def constant_of(model, cfg: dict, norm, data: Path):
    """The constant prediction in the loss space that sees nothing: the training targets'
    mean for MSE, their median for Smooth L1 (each minimises its loss, or nearly)."""
    import torch

    from sebvs.policy.dataset import EpisodeFrames
    training = cfg["training"]
    names = cfg.get("dataset", {}).get("train_episodes")
    if not names:
        raise ValueError("no training episodes in the checkpoint's record")
    frames = EpisodeFrames(data, episodes_named(data, cfg["task"], names, "training"),
                           cfg["task"], cfg["modality"], norm, training.get("max_frames", 0))
    try:
        targets = model.loss_space(torch.from_numpy(frames.targets()))
    finally:
        frames.close()
    if training.get("loss", "mse") == "mse":
        return targets.mean(dim=0)
    return targets.median(dim=0).values


def constant_loss(model, cfg: dict, frames, constant) -> float:
    """The constant prediction's loss per frame over ``frames`` (their targets only)."""
    import torch
    targets = model.loss_space(torch.from_numpy(frames.targets()))
    with torch.no_grad():
        return float(criterion_of(cfg["training"])(constant.expand_as(targets), targets))


RGB_CHANNELS = ("r", "g", "b")


def ablated_channels(cfg: dict, part: str) -> list[int]:
    """The input channels of one part of the checkpoint's input, by its record's
    channel_order: "rgb" the frame's r, g, b; "second" the rest (the events' planes, or the
    frame difference's up / down). ValueError where the model has no such part."""
    order = cfg.get("channel_order") or []
    picked = [i for i, name in enumerate(order) if (name in RGB_CHANNELS) == (part == "rgb")]
    if not picked or len(picked) == len(order):
        raise ValueError(f"modality {cfg.get('modality')!r} (channels {order}) has no "
                         f"{part!r} part to ablate beside another")
    return picked


class MeanAblated:
    """Items of ``frames`` with some input channels replaced by their mean over the frames
    (one number per channel, from every k-th frame): what the model sees when that input
    carries nothing but its average level. Its ``pairs`` are the frames' (episode, tick)
    per item, so a recurrent checkpoint's windows of ticks (sequence.py's WindowBatches)
    are cut from it as from the frames themselves, burn-in ablated too."""

    def __init__(self, frames, channels: list[int], sample: int = 200):
        self.frames, self.channels = frames, channels
        self.pairs = frames.pairs
        step = max(1, len(frames) // sample)
        xs = [frames[i][0][channels] for i in range(0, len(frames), step)]
        self.level = sum(x.mean(axis=(1, 2)) for x in xs) / max(len(xs), 1)

    def __len__(self) -> int:
        return len(self.frames)

    def __getitem__(self, i: int):
        x, y = self.frames[i]          # x is built afresh per item (model_input)
        x[self.channels] = self.level[:, None, None]
        return x, y

    def close(self) -> None:
        self.frames.close()


def held_out(pt: Path, data: Path, train_data: Path):
    """(model, its config, norm, every episode of ``data``): a recording the checkpoint never
    saw. Refused (ValueError) where an episode of it has the seed of one in ``train_data``,
    the recording the checkpoint was trained on."""
    from sebvs.policy.checkpoint import load_checkpoint
    from sebvs.policy.dataset import load_index
    model, cfg, norm = load_checkpoint(pt)
    episodes = load_index(data, cfg["task"])
    seen = {e.get("seed") for e in load_index(train_data, cfg["task"])} - {None}
    shared = [e["file"] for e in episodes if e.get("seed") in seen]
    if shared:
        raise ValueError(f"{data}: {len(shared)} episodes have the seed of one in {train_data} "
                         f"({first_few(shared)}): not held out")
    return model, cfg, norm, episodes


def measure(data: Path, pt: Path, by: list[str], train_data: Path | None = None,
            ablate: str | None = None) -> dict:
    """{checkpoint, modality, task, on, ablated, groups: {group: {episodes, frames, loss,
    constant_loss, skill}}}: over the checkpoint's validation episodes in ``data`` or, given
    ``train_data`` (the recording it was trained on, whose training episodes then give the
    constant), over every episode of ``data``, a held-out recording (every frame).
    ``ablate`` ("rgb" or "second"): that part of the input mean-ablated (MeanAblated)."""
    from sebvs.policy.dataset import EpisodeFrames
    if train_data is None:
        model, cfg, norm, episodes = validation_of(pt, data)
        constant = constant_of(model, cfg, norm, data)
    else:
        model, cfg, norm, episodes = held_out(pt, data, train_data)
        constant = constant_of(model, cfg, norm, train_data)
    channels = ablated_channels(cfg, ablate) if ablate else None
    groups: dict[str, list[dict]] = {}
    for e in episodes:
        groups.setdefault(group_of(e, by), []).append(e)
    out = {}
    for group, members in sorted(groups.items()):
        frames = (frames_of(data, members, cfg, norm) if train_data is None else
                  EpisodeFrames(data, members, cfg["task"], cfg["modality"], norm))
        n = len(frames)
        base = constant_loss(model, cfg, frames, constant)
        if channels is not None:
            frames = MeanAblated(frames, channels)
        loss = mean_loss(model, frames, cfg["training"])          # closes the frames
        out[group] = {"episodes": len(members), "frames": n, "loss": loss,
                      "constant_loss": base,
                      "skill": 1.0 - loss / base if base > 0 else None}
    return {"checkpoint": str(pt), "modality": cfg["modality"], "task": cfg["task"],
            "on": "validation" if train_data is None else "held-out", "ablated": ablate,
            "groups": out}


def modality_skill(results: list[dict]) -> dict[str, dict[str, float]]:
    """{modality: {group: mean skill over its checkpoints}}."""
    skills: dict[str, dict[str, list[float]]] = {}
    for r in results:
        for group, g in r["groups"].items():
            if g["skill"] is not None:
                skills.setdefault(r["modality"], {}).setdefault(group, []).append(g["skill"])
    return {m: {g: statistics.fmean(v) for g, v in gs.items()} for m, gs in skills.items()}


def table(results: list[dict], by: list[str]) -> str:
    """Per group: each checkpoint's loss and skill (its episodes and frames), then the mean
    skill per modality, as markdown."""
    groups = sorted({g for r in results for g in r["groups"]})
    names = [Path(r["checkpoint"]).parent.name + "/" + Path(r["checkpoint"]).stem
             for r in results]
    lines = [f"| {'/'.join(by)} | " + " | ".join(names) + " |",
             "|---|" + "---|" * len(results)]
    for group in groups:
        cells = []
        for r in results:
            g = r["groups"].get(group)
            cells.append("-" if g is None else
                         f"{g['loss']:.4g} / const {g['constant_loss']:.4g}: skill "
                         f"{g['skill']:+.2f} ({g['episodes']} ep, {g['frames']} fr)"
                         if g["skill"] is not None else f"{g['loss']:.4g} (no baseline)")
        lines.append(f"| {group} | " + " | ".join(cells) + " |")
    means = modality_skill(results)
    lines += ["", "| " + "/".join(by) + " | " + " | ".join(means) + " |",
              "|---|" + "---|" * len(means)]
    for group in groups:
        lines.append(f"| {group} | " + " | ".join(
            f"{means[m][group]:+.2f}" if group in means[m] else "-" for m in means) + " |")
    return "\n".join(lines)


def plot(results: list[dict], path: Path, title: str) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    means = modality_skill(results)
    groups = sorted({g for r in results for g in r["groups"]})
    modalities = list(means)
    width = 0.8 / max(len(modalities), 1)
    fig, ax = plt.subplots(figsize=(max(6.0, 1.2 * len(groups) + 1.5), 4))
    for k, m in enumerate(modalities):
        xs = [i + (k - (len(modalities) - 1) / 2) * width for i in range(len(groups))]
        ax.bar(xs, [means[m].get(g, float("nan")) for g in groups], width, label=m,
               alpha=0.6)
        for r in results:
            if r["modality"] != m:
                continue
            pts = [(x, r["groups"][g]["skill"]) for x, g in zip(xs, groups)
                   if g in r["groups"] and r["groups"][g]["skill"] is not None]
            ax.plot([p[0] for p in pts], [p[1] for p in pts], "k.", ms=4)
    ax.axhline(0.0, color="0.3", lw=0.8)
    ax.set_xticks(range(len(groups)), groups, rotation=30, ha="right")
    ax.set_ylabel("skill = 1 - loss / constant's loss")
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog="\n\n".join(__doc__.split("\n\n")[1:]))
    ap.add_argument("dataset", type=Path,
                    help="the recording to measure on: the one the checkpoints were trained "
                         "on (their validation episodes), or a held-out one (--held-out-from)")
    ap.add_argument("checkpoints", type=Path, nargs="+",
                    help=".pt files, each with its .json record beside it")
    ap.add_argument("--by", default="lighting,variant",
                    help="the episodes' `conditions` keys to group by, comma-separated "
                         "(default lighting,variant; the arm: lighting,conveyor,objects)")
    ap.add_argument("--held-out-from", type=Path, default=None, metavar="TRAIN_DATA",
                    help="measure on every episode of DATASET instead, a recording the "
                         "checkpoints never saw (refused if an episode shares a seed with "
                         "TRAIN_DATA, the recording they were trained on, whose training "
                         "episodes then give the constant)")
    ap.add_argument("--ablate", choices=["rgb", "second"], default=None,
                    help="replace one part of each input by its mean level over the frames "
                         "measured: rgb the frame, second the other stream (the events, or "
                         "the frame difference); how much the policy draws on that part")
    ap.add_argument("--json", type=Path, help="also write the figures here")
    ap.add_argument("--plot", type=Path, help="draw the skill per group and modality here")
    args = ap.parse_args(argv)
    from sebvs.policy.checkpoint import CheckpointError
    by = [k for k in args.by.split(",") if k]
    results = []
    for k, pt in enumerate(args.checkpoints, 1):
        print(f"[{k}/{len(args.checkpoints)}] {pt}", file=sys.stderr, flush=True)
        try:
            results.append(measure(args.dataset, pt, by, args.held_out_from, args.ablate))
        except (CheckpointError, ValueError, OSError) as exc:
            print(f"loss_by_condition: {pt}: {exc}", file=sys.stderr)
            return 2
    if len({r["task"] for r in results}) > 1:
        print("loss_by_condition: the checkpoints are of different tasks", file=sys.stderr)
        return 2
    print(table(results, by))
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"dataset": str(args.dataset), "by": by,
                                         "held_out_from": None if args.held_out_from is None
                                         else str(args.held_out_from),
                                         "ablated": args.ablate,
                                         "results": results,
                                         "modality_skill": modality_skill(results)},
                                        indent=1) + "\n")
    if args.plot:
        args.plot.parent.mkdir(parents=True, exist_ok=True)
        plot(results, args.plot, f"{args.dataset.name}: offline skill by {'/'.join(by)} ("
                                 f"{'validation' if args.held_out_from is None else 'every'} "
                                 f"episode{'s' * (args.held_out_from is None)}"
                                 f"{f'; {args.ablate} mean-ablated' if args.ablate else ''})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
