"""The one place the studies touch the event emulator's API (sebvs/dvs).

    presets()                          -> preset names, e.g. ("paper", "clean", "noisy")
    run(preset, frames, t_ns, seed, **overrides)
                                       -> ((t int64 ns, x, y, p +1/-1) arrays, wall s)

`run` feeds every frame to a fresh EventEmulator (preset with `overrides`, e.g.
downsample=1.0 when the frames are already at the emulated size, as the camera's
luma_scale renders them) and times only the emulator's own work.
"""
from __future__ import annotations

import time

import numpy as np

from sebvs.dvs.emulator import EVENT_DTYPE, EventEmulator
from sebvs.dvs.params import PRESETS, preset


def presets() -> tuple[str, ...]:
    return tuple(PRESETS)


def run(name: str, frames: np.ndarray, t_ns: np.ndarray, seed: int = 0,
        **overrides) -> tuple[tuple, float]:
    """frames (N, H, W) uint8, t_ns (N,) int64 -> (events as four arrays, wall seconds).

    ValueError from the emulator (bad input or parameters) propagates: the stability
    sweep counts it as a detected case."""
    emu = EventEmulator(preset(name, seed=seed, **overrides))
    chunks = []
    t0 = time.perf_counter()
    for f, t in zip(frames, t_ns):
        ev = emu.step(f, int(t))
        if ev.size:
            chunks.append(ev)
    wall = time.perf_counter() - t0
    ev = np.concatenate(chunks) if chunks else np.zeros(0, EVENT_DTYPE)
    return (ev["t"].astype(np.int64), ev["x"].astype(np.int64), ev["y"].astype(np.int64),
            ev["p"].astype(np.int64)), wall
