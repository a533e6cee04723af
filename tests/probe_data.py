"""Tiny synthetic nav recordings with the sim's truth, for the stream probe's tests.

A copy of tests/policy_data.py's bright drifting square with the truth a recording holds
(`truth/centroid` px, `truth/visible`, `truth/bbox`, `truth/image`): the square's centre is
known, so a probe that localises it is measurable against the mean-centroid baseline. With
`hidden` > 0 a share of the frames show no square (visible False, centroid -1): the
visibility head has both classes to tell apart. `events` "square" fires events where the
square moved (as policy_data does), "noise" fires them at random wherever the square is (a
stream that holds no target).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from sebvs.data.episode import EpisodeWriter
from sebvs.data.index import DatasetIndex, make_entry


def make_truth_dataset(root: str | Path, *, episodes: int = 10, frames: int = 24,
                       size: int = 32, seed: int = 0, hidden: float = 0.0,
                       events: str = "square", truth: bool = True) -> Path:
    """Write `episodes` nav episodes and index.json under `root`; returns root."""
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    index = DatasetIndex(root, "nav")
    side = max(4, size // 5)
    for e in range(episodes):
        x, y = rng.uniform(0, size - side, 2)
        vx, vy = rng.uniform(-2, 2, 2) * max(1, size // 32)
        prev = np.zeros((size, size), bool)
        path = index.path_for(index.next_episode_number())
        attrs = {"seed": seed * 1000 + e, "scene": "synthetic", "event_window_s": 0.1,
                 "event_representation": "counts", "event_sensor": [size, size]}
        with EpisodeWriter(path, "nav", attrs, compression="none") as w:
            for t in range(frames):
                x, y = x + vx, y + vy
                if not 0 <= x <= size - side:
                    vx, x = -vx, float(np.clip(x, 0, size - side))
                if not 0 <= y <= size - side:
                    vy, y = -vy, float(np.clip(y, 0, size - side))
                shown = rng.uniform() >= hidden
                mask = np.zeros((size, size), bool)
                if shown:
                    mask[int(y):int(y) + side, int(x):int(x) + side] = True
                rgb = rng.integers(0, 40, (size, size, 3), dtype=np.uint8)
                rgb[mask] = (250, 240, 80)
                ev = np.zeros((2, size, size), np.uint8)
                if events == "square":
                    ev[0][mask & ~prev] = 6
                    ev[1][prev & ~mask] = 6
                    ev[0][mask] = np.maximum(ev[0][mask], 4)
                else:                       # noise: nothing of the square in the events
                    ev[rng.integers(0, 2), rng.integers(0, size, 40),
                       rng.integers(0, size, 40)] = 5
                prev = mask
                cx, cy = int(x) + side / 2, int(y) + side / 2
                row = {"centroid": [cx, cy] if shown else [-1.0, -1.0],
                       "visible": bool(shown),
                       "bbox": [int(x), int(y), int(x) + side, int(y) + side] if shown
                       else [0.0, 0.0, 0.0, 0.0],
                       "image": [size, size]}
                w.append(rgb=rgb, event_frame=ev, t_sim=t / 10.0, tick=t,
                         action=np.zeros(2, np.float32), truth=row if truth else None)
            w.finish("synthetic")
        index.add(make_entry(path))
    return root
