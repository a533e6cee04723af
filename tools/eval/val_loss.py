#!/usr/bin/env python3
"""Does a dataset hold the validation frames a checkpoint was trained on?

    tools/eval/val_loss.py CHECKPOINT.pt DATASET [DATASET ...] [--rtol 1e-6] [--json OUT]

A checkpoint trained on several datasets (a DAgger round's: the expert's recording and
each round's) takes them all, in the order it was trained on them.

A recording made again from the same commands is the same recording only where the
frames and labels are; its files never are byte for byte (each episode stores the wall-
clock latencies of its hops), so the dataset hash in a checkpoint's record cannot say.
This asks the checkpoint instead: it computes the loss on DATASET's validation episodes
(those the checkpoint's JSON record names), as training computed it (same loss, batch,
order, one torch thread), and sets it beside the best validation loss the record holds,
which is that same model's loss on the original frames.

What it can see, measured on the sensor study's nav 10 Hz recording, made again on
another CPU of the same machine kind (research/sensors/log.md, 2026-11-28): the float
kernels alone move a loss by a relative 2e-9 to 3e-8 (torch forced to AVX2 kernels on an
AVX-512 CPU: 3e-8); the RGB and RGB+Diff checkpoints' losses agreed to 2e-9 and 4e-9, the
event-input ones differed by 6e-5 and 2e-4. It cannot see a small change of the frames:
+1 DN on 100 pixels of one of the 4,824 validation frames moved the RGB model's loss by
6e-10. So an agreement says "the same frames as far as this model can tell", and a
difference says the frames or labels are not the ones it was trained on. --rtol
(default 1e-6) sits between the two.

Exit 0 when the two agree within --rtol, 1 when they do not, 2 when an input is not
usable (a checkpoint without a record, validation episodes the dataset lacks).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))


def first_few(names: list[str], n: int = 3) -> str:
    """The first ``n`` names, comma-separated, and ", ..." when there are more."""
    return ", ".join(names[:n]) + (", ..." if len(names) > n else "")


def as_roots(data) -> list[Path]:
    """One dataset (a path) or several (a list of paths, in the order trained on): a list."""
    return [Path(data)] if isinstance(data, (str, Path)) else [Path(d) for d in data]


def episodes_named(data, task: str, names: list[str], what: str) -> list[dict]:
    """The datasets' index entries of these episodes (named as the record names them), in
    the datasets' and their indexes' order (the order training used: its split keeps it);
    ValueError naming what is missing."""
    from sebvs.policy.dataset import load_datasets
    from sebvs.policy.train import record_name
    data, wanted = as_roots(data), set(names)
    episodes = [e for e in load_datasets(data, task) if record_name(data[0], e) in wanted]
    missing = sorted(wanted - {record_name(data[0], e) for e in episodes})
    if missing:
        given = ", ".join(map(str, data))
        verb = "lacks" if len(data) == 1 else "lack"
        raise ValueError(f"{given}: {verb} {len(missing)} of the checkpoint's {what} "
                         f"episodes ({first_few(missing)})")
    return episodes


def validation_of(pt: Path, data):
    """(model, its config, its input normalisation, the dataset's entries of the
    checkpoint's validation episodes), from the checkpoint's JSON record; ValueError when
    the record or the dataset lacks them."""
    from sebvs.policy.checkpoint import load_checkpoint
    model, cfg, norm = load_checkpoint(pt)
    record, training = cfg.get("dataset", {}), cfg.get("training", {})
    names = record.get("val_episodes")
    if not names or "best_val_loss" not in training:
        raise ValueError(f"{pt.with_suffix('.json')}: no validation episodes or best "
                         f"validation loss in its record")
    return model, cfg, norm, episodes_named(data, cfg["task"], names, "validation")


def criterion_of(training: dict):
    """The training's loss (its record's "loss": mse, else Smooth L1), mean over a batch."""
    import torch
    return torch.nn.MSELoss() if training.get("loss", "mse") == "mse" else torch.nn.SmoothL1Loss()


def frames_of(data, episodes: list[dict], cfg: dict, norm):
    """The frames training would have validated on from these episodes (its max_frames
    rule: a quarter of the training's cap, spread over them)."""
    from sebvs.policy.dataset import EpisodeFrames
    training = cfg.get("training", {})
    return EpisodeFrames(as_roots(data)[0], episodes, cfg["task"], cfg["modality"], norm,
                         max(1, training["max_frames"] // 4) if training.get("max_frames") else 0)


def mean_loss(model, frames, training: dict) -> float:
    """The model's loss per frame over ``frames``, as training's validation pass takes it
    (same loss, batch and order, one torch thread; a recipe's windows of ticks where its
    record names one, sebvs/policy/sequence.py); the frames are closed after."""
    import torch
    from torch.utils.data import DataLoader

    from sebvs.policy.sequence import WindowBatches, sequence_epoch
    from sebvs.policy.train import _collate, _epoch
    recipe = training.get("recipe")
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        if recipe:      # trained on windows of ticks: validated on them, as trained
            lanes = WindowBatches(frames, recipe["lanes"], recipe["seq_len"],
                                burn_in=recipe.get("burn_in", 0))
            return sequence_epoch(model, lanes, None, None, "val", False, "cpu",
                                  loss=training.get("loss", "mse"))
        loader = DataLoader(frames, batch_size=training.get("batch", 32), shuffle=False,
                            collate_fn=_collate)
        return _epoch(model, loader, criterion_of(training), None, "val", False, "cpu")
    finally:
        torch.set_num_threads(threads)
        frames.close()


def recompute(pt: Path, data: Path | list[Path]) -> dict:
    """The checkpoint's validation loss on ``data`` (one dataset, or the list it was
    trained on) now, beside the one its record holds."""
    data = as_roots(data)
    model, cfg, norm, episodes = validation_of(pt, data)
    training = cfg["training"]
    val = frames_of(data, episodes, cfg, norm)
    frames = len(val)
    now = mean_loss(model, val, training)
    then = float(training["best_val_loss"])
    return {"checkpoint": str(pt), "dataset": ", ".join(map(str, data)),
            "modality": cfg["modality"],
            "val_frames": frames, "val_loss_now": now, "val_loss_recorded": then,
            "relative_difference": abs(now - then) / max(abs(then), 1e-30)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog="\n\n".join(__doc__.split("\n\n")[1:]))
    ap.add_argument("checkpoint", type=Path, help="a .pt with its .json record beside it")
    ap.add_argument("dataset", type=Path, nargs="+",
                    help="the dataset directories (index.json) it was trained on, in order")
    ap.add_argument("--rtol", type=float, default=1e-6,
                    help="the relative difference still called the same (default 1e-6)")
    ap.add_argument("--json", type=Path, help="also write the result here")
    args = ap.parse_args(argv)
    from sebvs.policy.checkpoint import CheckpointError
    try:
        result = recompute(args.checkpoint, args.dataset)
    except (CheckpointError, ValueError, OSError) as exc:
        print(f"val_loss: {exc}", file=sys.stderr)
        return 2
    result["same"] = result["relative_difference"] <= args.rtol
    verdict = ("agrees: the same frames as far as the model can tell" if result["same"]
               else "DIFFERS: not the frames or labels it was trained on")
    print(f"{args.checkpoint}: validation loss {result['val_loss_now']:.10g} on "
          f"{result['dataset']} ({result['val_frames']} frames), {result['val_loss_recorded']:.10g} "
          f"in its record: relative difference {result['relative_difference']:.2g} "
          f"({verdict}, at rtol {args.rtol:g})")
    if args.json:
        args.json.write_text(json.dumps(result, indent=1) + "\n")
    return 0 if result["same"] else 1


if __name__ == "__main__":
    sys.exit(main())
