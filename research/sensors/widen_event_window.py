#!/usr/bin/env python3
"""A recording whose event frames cover K control periods instead of one: each tick's
counts become the sum of its own frame and the K - 1 before it in the same episode.

    research/sensors/widen_event_window.py datasets/study_nav30 datasets/diag_nav30_window100 \\
        --periods 3

Why: at 30 Hz the study's event-only policy never left the constant command, while the same
recipe learnt at 10 Hz (research/sensors/log.md, eleventh session). A 1/30 s frame holds
about a third of the events of a 1/10 s one, so one explanation is a signal too sparse to
learn from. Widening the window offline tests it without a new recording: the frames of
consecutive ticks cover adjacent windows (the accumulator's window at a tick ends at that
tick and lasts one control period), so their sum is the frame of the K-period window,
exactly as the accumulator with ``window_s`` = K / control rate makes it at run time (at
an episode's first K - 1 ticks both hold what the episode has seen so far). Two
differences, both rare: each stored frame was clipped at 255 counts per pixel before the
sum, and an event exactly at a tick's time lies in both frames that tick bounds (the
accumulator's window is closed at both ends), so the sum counts it twice (the emulator
places crossings between renders, so such events are few).

Only ``counts`` frames (one bin) are widened; a histogram's bins would need re-binning.
Everything else in an episode file (RGB, actions, truth, latencies) is copied unchanged;
the file's ``event_window_s`` becomes K times the source's and ``derived`` records the
source file, its sha256 and K. The destination gets its own index.json (with fresh
sha256s) and can be trained on and checked like a recording. An interrupted run resumes:
episodes already in the destination's index are kept.

A model trained on it keeps the widened window in its checkpoint, and ``sebvs eval
--control-hz`` makes the accumulator's window that one at run time (one control period only
for checkpoints that name none).
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
from pathlib import Path

import h5py
import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from sebvs.data.episode import PARTIAL  # noqa: E402
from sebvs.data.index import DatasetIndex, file_sha256, make_entry  # noqa: E402

FRAMES = "events/frame"


def widened(frames: np.ndarray, periods: int) -> np.ndarray:
    """[T, 2, H, W] uint8 counts -> the same with frame t = clip(sum of frames t-K+1..t, 255).

    A running sum over time in uint32; the clip is the stored frames' own (uint8)."""
    if frames.ndim != 4 or frames.shape[1] != 2:
        raise ValueError(f"expected counts frames [T, 2, H, W], got shape {frames.shape}")
    total = np.cumsum(frames, axis=0, dtype=np.uint32)
    out = total.copy()
    out[periods:] -= total[:-periods]
    return np.minimum(out, 255).astype(np.uint8)


def _episode_window(f: h5py.File, path: Path) -> float:
    window = f.attrs.get("event_window_s")
    if not isinstance(window, (int, float, np.floating, np.integer)) or not window > 0:
        raise ValueError(f"{path}: no event_window_s attribute: the window to widen is unknown")
    representation = f.attrs.get("event_representation", "counts")
    if isinstance(representation, bytes):
        representation = representation.decode()
    if representation != "counts" or FRAMES not in f or f[FRAMES].shape[1] != 2:
        raise ValueError(f"{path}: event frames are {representation!r} "
                         f"{f[FRAMES].shape if FRAMES in f else 'absent'}; only counts "
                         f"[T, 2, H, W] can be widened by summing ticks")
    return float(window)


def widen_episode(src: Path, dst: Path, periods: int) -> None:
    """Copy episode file ``src`` to ``dst`` with its event frames widened ``periods``-fold.

    Written as ``dst``.partial and renamed into place once whole, as the recorder does."""
    with h5py.File(src, "r") as f:      # refused before anything is written
        window = _episode_window(f, src)
    partial = dst.with_name(dst.name + PARTIAL)   # the name `sebvs data check` reports as lost
    try:
        shutil.copyfile(src, partial)
        with h5py.File(partial, "r+") as f:
            data = f[FRAMES]
            data[...] = widened(data[...], periods)
            keys = set(json.loads(f.attrs.get("json_keys", "[]")))
            f.attrs["event_window_s"] = window * periods
            f.attrs["derived"] = json.dumps({
                "from": str(src.resolve()), "sha256": file_sha256(src), "periods": periods,
                "tool": "research/sensors/widen_event_window.py",
                "source_event_window_s": window})
            f.attrs["json_keys"] = json.dumps(sorted(keys | {"derived"}))
        with open(partial, "rb+") as fh:
            os.fsync(fh.fileno())
    except BaseException:       # a full disk, an interrupt: no half-written file stays
        partial.unlink(missing_ok=True)
        raise
    os.replace(partial, dst)


def widen_dataset(src: Path, dst: Path, periods: int, progress: bool = True) -> dict:
    """Every episode of dataset ``src`` into ``dst``; returns counts of what was done."""
    if periods < 2 or periods > 256:
        raise ValueError(f"--periods must be 2..256, got {periods}")
    source = DatasetIndex(src)
    if not source.path.exists():
        raise ValueError(f"{src}: not a dataset (no index.json)")
    if src.resolve() == dst.resolve():
        raise ValueError("the destination must be another directory than the source")
    target = DatasetIndex(dst, task=source.task)
    done = {e["file"] for e in target.episodes()}
    todo = [e for e in source.episodes() if e["file"] not in done]
    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=len(todo), unit="episode", desc="widen")
    dst.mkdir(parents=True, exist_ok=True)
    for entry in todo:
        widen_episode(src / entry["file"], dst / entry["file"], periods)
        target.insert(make_entry(dst / entry["file"], reason=entry.get("reason")))
        if bar is not None:
            bar.update()
    if bar is not None:
        bar.close()
    return {"episodes": len(source.episodes()), "widened": len(todo), "kept": len(done),
            "periods": periods, "destination": str(dst)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("source", type=Path, help="dataset directory (index.json) to read")
    ap.add_argument("destination", type=Path, help="dataset directory to write (resumed "
                    "if it holds part of an earlier run)")
    ap.add_argument("--periods", type=int, required=True,
                    help="K: control periods each event frame covers (2..256)")
    ap.add_argument("--quiet", action="store_true", help="no progress bar")
    args = ap.parse_args(argv)
    try:
        result = widen_dataset(args.source, args.destination, args.periods,
                               progress=not args.quiet)
    except (ValueError, OSError) as exc:
        print(f"widen_event_window: {exc}", file=sys.stderr)
        return 2
    print(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
