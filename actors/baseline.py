"""The no-action baseline: at every control tick, the scene's idle command.

Input   rgb     from the camera: only its tick is used (samples with meta control=False,
                taken between control ticks, are ignored), so the baseline answers on the
                same clock as a policy and a lockstep sim waits for it the same way
Output  action  arrays {"action": float32 [2]} (nav: [0, 0], the robot holds still) or
                {"pose": float32 [6]} (arm: HOME, the arm stays home and grasps nothing),
                tick = the input tick, meta {"modality": "no_action"}

`sebvs eval` runs it in place of the policy on the same seeds: it is what each metric
gives for free, the row every policy figure is read against.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from sebvs.runtime import Actor, Message

MODALITY = "no_action"


class NoAction(Actor):
    inputs = ("rgb",)
    outputs = ("action",)

    @dataclass
    class Params:
        task: Literal["nav", "arm"] = "nav"

    async def setup(self) -> None:
        from sebvs.sim import make_scene
        scene = make_scene(self.params.task)   # built, never compiled: only its idle command
        self.command = {scene.command_name: scene.idle_command().astype(np.float32)}
        self.emitted = 0

    async def on_rgb(self, msg: Message) -> None:
        if msg.tick is None:
            raise ValueError(f"rgb message from {msg.source} has no tick")
        if msg.meta.get("control") is False:
            return
        await self.emit("action", self.command, meta={"modality": MODALITY},
                        t_sim=msg.t_sim, tick=msg.tick, parent=msg)
        self.emitted += 1

    def stats(self) -> dict:
        return {"emitted": self.emitted}
