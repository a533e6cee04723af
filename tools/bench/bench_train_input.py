#!/usr/bin/env python3
"""Training's input pipeline (issue 37): how fast the frames reach the model.

For one dataset and modality, side by side in every repeat (the order alternating):

files     items read from the episode files one by one (HDF5 chunk decode per item), as
          `sebvs train --cache none` does
memory    the streams read whole into memory first (`--cache memory`, and `auto` when they
          fit), then served from there; its one-off load time is reported apart

each with 0 and --workers DataLoader workers. Per variant: items per second of a full pass
of the training loader over the training set (the shuffle, batching and the model's input
preparation included, no model: the rate a GPU could at most be fed at), median over
repeats. Then one epoch of the real training step (the paper's nav ERP at --size on the
CPU) with files/0 workers and memory/0 workers, so the share of an epoch that input takes
on this machine is visible.

The dataset is --data DIR (a recording), or by default synthetic frames written in the
recorded layout (tests/policy_data.py: EpisodeWriter, lzf, one chunk per frame) at
--size px.

    tools/bench/bench_train_input.py [--quick] [--data DIR] [--json FILE]
"""
from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))

from benchio import print_report  # noqa: E402


def loader_rate(data: Path, modality: str, size: int, cache: str, workers: int,
                batch: int) -> dict:
    """Items per second of one pass of a shuffled training loader; the preload's time."""
    import torch
    from torch.utils.data import DataLoader

    from sebvs.policy.dataset import EpisodeFrames, event_frames_of, load_index
    from sebvs.policy.inputs import Normalisation
    from sebvs.policy.train import _collate
    episodes = load_index(data)
    norm = Normalisation(size=size)
    if modality in ("event", "rgb+event"):
        norm = Normalisation(size=size, event_bins=event_frames_of(data, episodes)["bins"])
    ds = EpisodeFrames(data, episodes, "nav", modality, norm)
    t0 = time.perf_counter()
    held = ds.preload() if cache == "memory" else 0
    load_s = time.perf_counter() - t0
    loader = DataLoader(ds, batch_size=batch, shuffle=True, num_workers=workers,
                        collate_fn=_collate, generator=torch.Generator().manual_seed(0))
    t0 = time.perf_counter()
    items = sum(len(x) for x, _ in loader)
    seconds = time.perf_counter() - t0
    ds.close()
    return {"items": items, "items_per_s": items / seconds, "preload_s": load_s,
            "held_mib": held / 2**20}


def epoch_seconds(data: Path, out: Path, modality: str, size: int, cache: str) -> float:
    """Wall time of one training epoch (train and validation passes) on the CPU."""
    from sebvs.policy.inputs import Normalisation
    from sebvs.policy.train import train
    t0 = time.perf_counter()
    train(data, out, "nav", [modality], epochs=1, batch=32, cache=cache, num_workers=0,
          norm=Normalisation(size=size), progress=False, log=lambda s: None)
    return time.perf_counter() - t0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog="\n\n".join(__doc__.split("\n\n")[1:]))
    ap.add_argument("--quick", action="store_true",
                    help="12 episodes of 40 frames, 1 repeat, no training epoch")
    ap.add_argument("--data", type=Path, default=None, help="a recorded dataset")
    ap.add_argument("--modality", default="rgb+event")
    ap.add_argument("--size", type=int, default=160)
    ap.add_argument("--workers", type=int, default=2, help="the loader workers beside 0")
    ap.add_argument("--repeats", type=int, default=None, help="default 1 quick, else 3")
    ap.add_argument("--json", metavar="FILE")
    args = ap.parse_args()
    repeats = args.repeats or (1 if args.quick else 3)
    variants = [(c, w) for c in ("files", "memory") for w in (0, args.workers)]
    with tempfile.TemporaryDirectory(prefix="bench-train-input-") as tmp:
        data = args.data
        if data is None:
            from tests.policy_data import make_dataset
            data = make_dataset(Path(tmp) / "data", episodes=12 if args.quick else 40,
                                frames=40 if args.quick else 100, height=args.size,
                                width=args.size, target="position")
        rates = {v: [] for v in variants}
        for r in range(repeats):
            for cache, workers in (variants if r % 2 == 0 else variants[::-1]):
                rates[(cache, workers)].append(loader_rate(
                    data, args.modality, args.size, "memory" if cache == "memory" else "none",
                    workers, 32))
                print(f"repeat {r + 1}/{repeats} {cache} workers={workers}: "
                      f"{rates[(cache, workers)][-1]['items_per_s']:.0f} items/s",
                      file=sys.stderr)
        report = {
            "config": {"data": str(args.data) if args.data else "synthetic (tests/policy_data)",
                       "modality": args.modality, "size": args.size, "repeats": repeats,
                       "statistic": "median over repeats", "cpus": os.cpu_count(),
                       "machine": platform.machine(),
                       "load": round(os.getloadavg()[0], 2)},
            "loader": [{"cache": c, "workers": w, "items": rs[0]["items"],
                        "items_per_s": round(statistics.median(x["items_per_s"] for x in rs), 1),
                        "preload_s": round(statistics.median(x["preload_s"] for x in rs), 3),
                        "held_mib": round(rs[0]["held_mib"], 1)}
                       for (c, w), rs in rates.items()]}
        base = next(x for x in report["loader"] if x["cache"] == "files" and x["workers"] == 0)
        for row in report["loader"]:
            row["x_files_0"] = round(row["items_per_s"] / base["items_per_s"], 2)
        if not args.quick:
            report["epoch_s"] = {
                c: round(statistics.median(
                    epoch_seconds(data, Path(tmp) / f"ckpt-{c}-{i}", args.modality, args.size,
                                  "memory" if c == "memory" else "none")
                    for i in range(repeats)), 2)
                for c in ("files", "memory")}
    print_report(report, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
