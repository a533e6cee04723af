"""Actors used only by the sim/camera actor tests (importable by workers as tests.sim_actors)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sebvs.runtime import Actor, Message


class Driver(Actor):
    """A toy closed-loop controller: on each control RGB frame, turn toward the target's
    true centroid (from meta truth) and creep forward; emits `action` with the frame's tick.
    On tick `nan_at_tick` it sends NaN instead (the sim must reject it)."""
    inputs = ("rgb",)
    outputs = ("action",)

    @dataclass
    class Params:
        gain: float = 2.0
        nan_at_tick: int = -1

    async def on_rgb(self, msg: Message) -> None:
        if not msg.meta.get("control"):
            return
        truth = msg.meta.get("truth") or {}
        w = 0.0
        if truth.get("visible"):
            width = truth["image"][0]
            w = float(np.clip(self.params.gain * (0.5 - truth["centroid"][0] / width), -1, 1))
        cmd = np.array([0.3, w])
        if msg.tick == self.params.nan_at_tick:
            cmd = np.array([np.nan, 0.0])
        await self.emit("action", {"action": cmd}, tick=msg.tick, t_sim=msg.t_sim,
                        meta={"episode": msg.meta.get("episode")})
