"""Actors used only by the policy tests (importable by the worker as tests.policy_actors)."""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from sebvs.runtime import Actor


class TickSource(Actor):
    """Emits `rgb` (arrays["rgb"] uint8 [H, W, 3]) and `events` (arrays["frame"] uint8
    [2, H, W]) for ticks 0, 1, 2, ... at `rate_hz`, like a camera and an accumulator.

    The two streams of a tick are sent in alternating order (events first on odd ticks), so
    the policy's pairing by tick is exercised both ways.
    """
    outputs = ("rgb", "events")

    @dataclass
    class Params:
        width: int = 32
        height: int = 32
        rate_hz: float = 50.0

    async def run(self) -> None:
        p = self.params
        period = int(1e9 / p.rate_hz)
        t0 = time.monotonic_ns()
        rng = np.random.default_rng(self.seed)
        tick = 0
        while not self.stopping.is_set():
            rgb = rng.integers(0, 255, (p.height, p.width, 3), dtype=np.uint8)
            ev = rng.integers(0, 4, (2, p.height, p.width), dtype=np.uint8)
            sends = [("rgb", {"rgb": rgb}), ("events", {"frame": ev})]
            if tick % 2:
                sends.reverse()
            for output, arrays in sends:
                if output in self.consumed:
                    await self.emit(output, arrays, t_sim=tick / p.rate_hz, tick=tick)
            tick += 1
            if not await self.sleep_until(t0 + tick * period):
                return
