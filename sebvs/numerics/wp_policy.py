"""Policy work-precision study: action error on held-out episodes against latency per call.

One point per (modality, input size): error = mean absolute action error (mean over
frames and action components, in the action's own units: [-1, 1] commands for nav) on
episodes the model never trained on; seconds = median wall time of one PolicySet.act call
(input preparation + batch-1 inference, as the policy actor does per tick), in seconds,
timed for all variants in interleaved rounds once all are loaded (interleaved_latency).

Two sources:
  real       --data DIR (recorded dataset) and --checkpoints DIR (``<task>-<modality>.pt``
             files): each checkpoint is evaluated on the validation episodes its config
             lists (the split it was trained with), else on every episode in DIR
  synthetic  no data given: a small dataset is generated on the fly (``make_synthetic``:
             a lit square drifting over a noisy background, rendered with its ON/OFF
             event frames; the action is a function of where the square is and how big it
             looks), tiny models are trained for a few epochs per modality and size, and
             held-out episodes from another seed are scored. Every point carries
             ``source="synthetic"``: these numbers test the study's plumbing and the
             latency axis, not the paper's policies.
Each point also carries ``baseline_error``: the error of always answering the training
set's mean action, so a model that learned nothing is recognisable.
"""
from __future__ import annotations

import statistics
import time
from pathlib import Path

import numpy as np

from sebvs.data.episode import EpisodeWriter, open_episode
from sebvs.data.index import DatasetIndex, make_entry
from sebvs.policy.dataset import load_index


def make_synthetic(root: str | Path, episodes: int, frames: int, size: int,
                   seed: int) -> Path:
    """Write `episodes` nav episodes of `frames` frames (size x size px) + index.json.

    Written with sebvs.data (EpisodeWriter, DatasetIndex), as the recorder writes.
    Per frame: rgb [H, W, 3] uint8, events/frame [2, H, W] uint8 (ON where the square
    arrived, OFF where it left), action [v, w] float32 with
        w = 1 - 2 * x_centre / W   (turn towards the square; left of centre -> w > 0)
        v = 1 - 2 * side / side_max (approach while it looks small)
    """
    root = Path(root)
    rng = np.random.default_rng(seed)
    smin, smax = max(2, size // 10), max(4, size // 3)
    for e in range(episodes):
        rgb = np.empty((frames, size, size, 3), np.uint8)
        ev = np.zeros((frames, 2, size, size), np.uint8)
        act = np.empty((frames, 2), np.float32)
        x, y = rng.uniform(0, size - smax, 2)
        vx, vy = rng.uniform(-1, 1, 2) * size / 24
        side, ds = rng.uniform(smin, smax), rng.uniform(-0.5, 0.5) * size / 64
        prev = np.zeros((size, size), bool)
        for t in range(frames):
            x, y, side = x + vx, y + vy, float(np.clip(side + ds, smin, smax))
            if not 0 <= x <= size - side:
                vx, x = -vx, float(np.clip(x, 0, size - side))
            if not 0 <= y <= size - side:
                vy, y = -vy, float(np.clip(y, 0, size - side))
            if side in (smin, smax):
                ds = -ds
            mask = np.zeros((size, size), bool)
            mask[int(y):int(y + side), int(x):int(x + side)] = True
            rgb[t] = rng.integers(40, 90, (size, size, 3), dtype=np.uint8)
            rgb[t][mask] = (230, 60, 40)
            if t:
                ev[t, 0][mask & ~prev] = 3
                ev[t, 1][prev & ~mask] = 3
            prev = mask
            act[t] = (1 - 2 * side / smax, 1 - 2 * (x + side / 2) / size)
        index = DatasetIndex(root, "nav")
        path = index.path_for(index.next_episode_number())
        with EpisodeWriter(path, "nav", {"seed": seed * 1000 + e, "synthetic": True,
                                         "scene": "synthetic"}) as w:
            for t in range(frames):
                w.append(rgb=rgb[t], event_frame=ev[t], action=np.clip(act[t], -1, 1),
                         t_sim=t * 0.05, tick=t)
            w.finish("synthetic")
        index.add(make_entry(path))
    return root


def evaluate(pt: str | Path, data: str | Path, episodes: list[str] | None = None,
             max_frames: int = 200, timing_calls: int = 30) -> dict:
    """Score one checkpoint -> {"modality", "size", "error", "seconds", "frames",
    "p90_seconds"}. Frames are read in episode order, at most `max_frames` (evenly
    strided); timing uses the first `timing_calls` of them after one warm-up call."""
    from sebvs.policy.infer import PolicySet
    from sebvs.policy.checkpoint import read_config
    cfg = read_config(pt)
    policies = PolicySet({cfg["modality"]: Path(pt)})
    task, modality = cfg["task"], cfg["modality"]
    data = Path(data)
    files = episodes or [e["file"] for e in load_index(data, task)]
    frames = []
    for name in files:
        with open_episode(data / name) as ep:
            frames += [(name, t) for t in range(len(ep))]
    if len(frames) > max_frames:
        pick = np.linspace(0, len(frames) - 1, max_frames).round().astype(int)
        frames = [frames[i] for i in pick]
    errs, times = [], []
    opened: dict = {}
    try:
        for k, (name, t) in enumerate(frames):
            ep = opened.get(name) or opened.setdefault(name, open_episode(data / name))
            obs = {"rgb": ep.rgb[t]}
            if ep.event_frame is not None:
                obs["events"] = ep.event_frame[t]
            if k == 0:
                policies.act(modality, **obs)          # warm-up: first calls allocate
            t0 = time.perf_counter()
            y, _, _ = policies.act(modality, **obs)
            dt = time.perf_counter() - t0
            if k < timing_calls:
                times.append(dt)
            errs.append(np.abs(y - np.asarray(ep.target[t], np.float32)).mean())
    finally:
        for ep in opened.values():
            ep.close()
    return {"modality": modality, "size": int(cfg["size"]), "error": float(np.mean(errs)),
            "seconds": statistics.median(times), "p90_seconds": float(np.percentile(times, 90)),
            "frames": len(errs), "policy": policies, "obs": obs}


def interleaved_latency(runs: list[dict], rounds: int = 7, calls: int = 10) -> None:
    """Re-time every evaluated policy in turn, `rounds` times `calls` calls each, and set
    its "seconds" (median) and "p90_seconds": on shared cores a load spike then hits all
    variants alike instead of whichever happened to be timed during it."""
    times: list[list[float]] = [[] for _ in runs]
    for _ in range(rounds):
        for i, r in enumerate(runs):
            m = r["modality"]
            for _ in range(calls):
                t0 = time.perf_counter()
                r["policy"].act(m, **r["obs"])
                times[i].append(time.perf_counter() - t0)
    for r, ts in zip(runs, times):
        r["seconds"] = statistics.median(ts)
        r["p90_seconds"] = float(np.percentile(ts, 90))


def _targets(data: Path, task: str, files: list[str] | None = None) -> np.ndarray:
    files = files or [e["file"] for e in load_index(data, task)]
    out = []
    for name in files:
        with open_episode(Path(data) / name) as ep:
            out.append(np.asarray(ep.target[:], np.float32))
    return np.concatenate(out)


def mean_baseline(train: str | Path, held: str | Path, task: str = "nav",
                  train_files: list[str] | None = None,
                  held_files: list[str] | None = None) -> float:
    """Error of always answering the training set's mean action: the level a model that
    learned nothing from its input reaches (same metric as `evaluate`)."""
    mean = _targets(Path(train), task, train_files).mean(axis=0)
    return float(np.abs(_targets(Path(held), task, held_files) - mean).mean())


def real_points(data: str | Path, checkpoints: str | Path) -> list[dict]:
    """Every checkpoint in `checkpoints` (its ``*.pt`` but resume states) scored on its own
    validation episodes in `data`."""
    import torch

    from sebvs.policy.checkpoint import checkpoints_in, read_config
    prev = torch.get_num_threads()
    torch.set_num_threads(1)     # as in synthetic_points: one thread, shared cores
    try:
        return _real_points(data, checkpoints_in(checkpoints), read_config)
    finally:
        torch.set_num_threads(prev)


def _real_points(data, checkpoints: list[Path], read_config) -> list[dict]:
    points, runs = [], []
    for pt in checkpoints:
        cfg = read_config(pt)
        val = (cfg.get("dataset") or {}).get("val_episodes") or None
        if val and not all((Path(data) / v).exists() for v in val):
            val = None
        r = evaluate(pt, data, val)
        runs.append(r)
        tr = (cfg.get("dataset") or {}).get("train_episodes") or None
        base = mean_baseline(data, data, cfg["task"], tr if val else None, val) \
            if (val and tr) else None
        points.append({"method": r["modality"], "setting": r["size"], "error": r["error"],
                       "seconds": r["seconds"], "p90_seconds": r["p90_seconds"],
                       "frames": r["frames"], "source": "real", "checkpoint": str(pt),
                       "baseline_error": base,
                       "held_out": "validation split" if val else "all episodes of --data"})
    _retime(points, runs)
    return points


def _retime(points: list[dict], runs: list[dict]) -> None:
    interleaved_latency(runs)
    for p, r in zip(points, runs):
        p["seconds"], p["p90_seconds"] = r["seconds"], r["p90_seconds"]


def synthetic_points(work: str | Path, sizes=(32, 64), modalities=("rgb", "event", "rgb+event"),
                     episodes: int = 8, frames: int = 40, epochs: int = 3, seed: int = 0,
                     progress=None, log=lambda *a: None) -> list[dict]:
    """Generate, train and score tiny models; points marked source="synthetic"."""
    import torch

    from sebvs.policy.inputs import Normalisation
    from sebvs.policy.train import train
    work = Path(work)
    prev = torch.get_num_threads()
    torch.set_num_threads(1)     # shared cores; the latency axis is per single thread
    points, runs = [], []
    try:
        for size in sizes:
            data = make_synthetic(work / f"data{size}", episodes, frames, size, seed)
            held = make_synthetic(work / f"held_out{size}", max(2, episodes // 4), frames,
                                  size, seed + 1)
            ck = work / f"checkpoints{size}"
            base = mean_baseline(data, held)
            for m in modalities:
                train(data, ck, "nav", [m], progress=False, log=log, epochs=epochs,
                      lr=1e-3, norm=Normalisation(size=size), threads=1, patience=epochs)
                r = evaluate(ck / f"nav-{m}.pt", held)
                runs.append(r)
                points.append({"method": m, "setting": size, "error": r["error"],
                               "seconds": r["seconds"], "p90_seconds": r["p90_seconds"],
                               "frames": r["frames"], "source": "synthetic",
                               "baseline_error": base,
                               "held_out": f"{held.name}: other seed, never trained on",
                               "epochs": epochs})
                if progress is not None:
                    progress(1)
        _retime(points, runs)
    finally:
        torch.set_num_threads(prev)
    return points
