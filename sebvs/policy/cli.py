"""`sebvs train`: registered by sebvs/cli.py. torch is imported only when the command runs."""
from __future__ import annotations

import argparse
import sys

SIZE_PRESETS = {"cpu": 160, "paper": 640}


def _size(text: str) -> int:
    if text in SIZE_PRESETS:
        return SIZE_PRESETS[text]
    try:
        size = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{text!r} is neither a size in pixels nor a preset ({', '.join(SIZE_PRESETS)})")
    if size <= 0 or size % 16:
        raise argparse.ArgumentTypeError(f"size {size} must be a positive multiple of 16")
    return size


def _cmd_train(args) -> int:
    from .inputs import MODALITIES, Normalisation
    from .train import train
    modalities = list(MODALITIES) if args.modality == "all" else [args.modality]
    if args.size >= 640 and args.device == "cpu":
        print(f"sebvs train: note: {args.size} px is the paper's GPU preset; on a 2-core CPU "
              f"one batch of 32 takes ~8 s (tools/bench_policy.py). Use --device cuda, or "
              f"--size 160.", file=sys.stderr)
    try:
        train(args.data, args.out, args.task, modalities, progress=not args.no_progress,
              epochs=args.epochs, batch=args.batch, seed=args.seed, max_frames=args.max_frames,
              num_workers=args.workers, threads=args.threads, val_fraction=args.val_fraction,
              patience=args.patience, lr=args.lr, device=args.device, stem=args.stem,
              norm=Normalisation(size=args.size, event_clip=args.event_clip))
    except (FileNotFoundError, ValueError) as exc:   # bad data or settings: say so, no trace
        print(f"sebvs train: {exc}", file=sys.stderr)
        return 2
    return 0


def register(subparsers) -> None:
    t = subparsers.add_parser(
        "train", help="behaviour-clone ERP policies from a recorded dataset",
        description="Train the ERP transformer on recorded episodes with the paper's settings "
                    "(nav: Adam 2e-4, wd 1e-4, MSE, early stopping 2; arm: Adam 1e-4, "
                    "ReduceLROnPlateau, Smooth L1). Writes <out>/<task>-<modality>.pt and "
                    ".json, loss CSVs and <out>/<task>-losses.png.")
    t.add_argument("--task", required=True, choices=["nav", "arm"])
    t.add_argument("--modality", required=True, choices=["rgb", "event", "rgb+event", "all"],
                   help="'all' trains the three variants one after another")
    t.add_argument("--data", required=True, help="dataset directory (index.json + episodes)")
    t.add_argument("--out", required=True, help="where checkpoints and curves go")
    t.add_argument("--size", type=_size, default=160,
                   help="input side in px, or a preset: cpu=160 (100 tokens), "
                        "paper=640 (1600 tokens, for GPUs) (default 160)")
    t.add_argument("--stem", choices=["patch", "conv"], default="patch",
                   help="token embedding: patch, the paper's linear 16x16 patchify, or conv, "
                        "four 3x3 stride-2 convolutions giving the same tokens (docs/policy.md; "
                        "default patch)")
    t.add_argument("--epochs", type=int, default=None, help="default 10")
    t.add_argument("--batch", type=int, default=None, help="default 32")
    t.add_argument("--seed", type=int, default=0)
    t.add_argument("--max-frames", type=int, default=0,
                   help="cap on training frames, strided over all episodes (0: all)")
    t.add_argument("--lr", type=float, default=None, help="default: the paper's per task")
    t.add_argument("--patience", type=int, default=None,
                   help="early stopping patience in epochs (default nav 2, arm 4)")
    t.add_argument("--val-fraction", type=float, default=None,
                   help="share of episodes held out (default 0.2)")
    t.add_argument("--event-clip", type=int, default=8,
                   help="event counts saturate here before scaling to [0, 1] (default 8)")
    t.add_argument("--workers", type=int, default=0, help="DataLoader workers (default 0)")
    t.add_argument("--threads", type=int, default=0, help="torch threads (default: torch's)")
    t.add_argument("--device", default="cpu",
                   help="torch device, e.g. cuda for the paper preset (default cpu; "
                        "bit-reproducible on cpu only)")
    t.add_argument("--no-progress", action="store_true", help="no tqdm bars")
    t.set_defaults(func=_cmd_train)
