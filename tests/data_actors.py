"""A test source for the recorder: rgb, events, action and episode streams with ticks.

Importable by the runtime's worker as ``tests.data_actors``. No MuJoCo: frames are numpy.
Frame k of the run (global tick k) is filled with value k % 256, so a test can check that
rows were joined from the same tick: rgb[..] == events[..] == tick % 256, and the action is
[tick / 1000, -tick / 1000] (the pose [tick / 1000, 0, 0, 0, 0, 0]).
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Literal

import numpy as np

from sebvs.runtime import Actor


RAW_DTYPE = np.dtype([("x", "<u2"), ("y", "<u2"), ("t", "<i8"), ("p", "i1")])


def expected_action(tick: int, task: str = "nav") -> np.ndarray:
    if task == "nav":
        return np.array([tick / 1000, -tick / 1000], np.float32)
    return np.array([tick / 1000, 0, 0, 0, 0, 0], np.float32)


class DataSource(Actor):
    """Episodes of `frames` control ticks at `rate_hz`, like the sim + camera + accumulator +
    expert chain would deliver them. Emits rgb, events, action (or pose) and episode markers."""
    outputs = ("rgb", "events", "raw", "action", "episode")

    @dataclass
    class Params:
        width: int = 32
        height: int = 24
        rate_hz: float = 200.0
        frames: int = 10              # control ticks per episode
        episodes: int = 0             # 0: until stopped
        task: Literal["nav", "arm"] = "nav"
        between: int = 1              # rgb samples with control=False between ticks (skipped)
        raw_events: int = 0           # raw events per control packet on `raw` (0: none), plus
                                      # a 2-event packet between ticks, as the emulator's
        episode_meta: bool = True     # rgb meta carries the episode number, as the camera's

    async def setup(self) -> None:
        self.tick = 0
        self.episode = 0

    async def run(self) -> None:
        p = self.params
        period = int(1e9 / p.rate_hz)
        t0, n = time.monotonic_ns(), 0
        k = 0
        while not self.stopping.is_set() and (p.episodes <= 0 or k < p.episodes):
            self.episode = k
            info = {"episode": k, "seed": 1000 + k, "scene": "test",
                    "config": {"variant": "unit", "k": k}}
            await self.emit("episode", meta={"event": "start", "reason": "", **info},
                            tick=self.tick, t_sim=self.tick / p.rate_hz)
            for _ in range(p.frames):
                await self._tick()
                n += 1
                if not await self.sleep_until(t0 + n * period):
                    return
            await self.emit("episode", meta={"event": "end", "reason": "time_limit", **info},
                            tick=self.tick - 1, t_sim=(self.tick - 1) / p.rate_hz)
            k += 1
        # let the last messages reach the recorder before the run ends with this source
        await self.sleep_until(time.monotonic_ns() + 300_000_000)
        self.request_stop("episodes done")

    async def _tick(self) -> None:
        p, t = self.params, self.tick
        v = np.uint8(t % 256)
        t_sim = t / p.rate_hz
        for _ in range(p.between):
            await self.emit("rgb", {"rgb": np.full((p.height, p.width, 3), 7, np.uint8)},
                            tick=t, t_sim=t_sim, meta={"control": False})
        truth = {"centroid": [float(t), float(-t)], "bbox": [0.0, 1.0, 2.0, 3.0],
                 "visible": True}
        await self.emit("rgb", {"rgb": np.full((p.height, p.width, 3), v, np.uint8)},
                        tick=t, t_sim=t_sim, meta={"control": True, "truth": truth,
                                                   **({"episode": self.episode}
                                                      if p.episode_meta else {})})
        ev = {"frame": np.full((2, p.height // 2, p.width // 2), v, np.uint8)}
        if p.raw_events:
            # the packet ending at tick t (control), then one after it (belongs to t + 1)
            for n, control, t_ns in ((p.raw_events, True, t * 1000), (2, False, t * 1000 + 500)):
                pk = np.zeros(n, RAW_DTYPE)
                pk["x"], pk["y"], pk["t"], pk["p"] = np.arange(n), 1, t_ns, 1
                await self.emit("raw", {"events": pk}, tick=t, t_sim=t_sim,
                                meta={"control": control})
        await self.emit("events", ev, tick=t, t_sim=t_sim,
                        meta={"control": True, "event_scale": 0.5, "event_offset": [0.0, 0.0],
                              "emulator": {"pos_thres": 0.3, "neg_thres": 0.3}})
        name = "action" if p.task == "nav" else "pose"
        await self.emit("action", {name: expected_action(t, p.task)}, tick=t, t_sim=t_sim,
                        meta={"modality": "rgb"})
        self.tick += 1

    def stats(self) -> dict:
        return {"tick": self.tick}
