"""A test driver for the LockstepRecorder's `drive` input: at each control tick of
tests.data_actors' DataSource it sends a command of its own, distinct from the source's
expert label, so a test can tell which one reached the sim.

Importable by the runtime's worker as ``tests.dagger_actors``. No MuJoCo, no torch.
"""
from __future__ import annotations

import numpy as np

from sebvs.runtime import Actor, Message


def drive_command(tick: int, task: str = "nav") -> np.ndarray:
    """The driver's command at a tick: [0.5, -0.25 + tick / 1000] (nav), a pose (arm)."""
    if task == "nav":
        return np.array([0.5, -0.25 + tick / 1000], np.float32)
    return np.array([0.3, 0.2, 0.1, 0, 0, tick / 1000], np.float32)


class Driver(Actor):
    """Takes the source's control-tick rgb frames; sends `action` per tick, meta modality
    "event" (the source's label says "rgb"), as a policy would."""
    inputs = ("rgb",)
    outputs = ("action",)

    async def on_rgb(self, msg: Message) -> None:
        if msg.meta.get("control") is False or msg.tick is None:
            return
        await self.emit("action", {"action": drive_command(msg.tick)}, parent=msg,
                        meta={"modality": "event"})
