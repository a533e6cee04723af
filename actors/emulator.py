"""The event emulator actor: luma frames in, event packets out (sebvs.dvs.emulator).

Input   luma    {"luma": uint8 [H, W]} from the camera at its dvs rate; t_sim -> timestamp
Output  events  {"events": EVENT_DTYPE [N]} (x, y, t ns, p), time-sorted, emitted with the
                input's tick and meta, plus event_sensor [w, h] and frame [W, H]
A new episode (meta `episode` changes) restarts the stream: the scene jumps, and a jump
is not a brightness change the sensor would see.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from sebvs.dvs.emulator import EventEmulator
from sebvs.dvs.params import preset
from sebvs.runtime import Actor, Message


class Emulator(Actor):
    inputs = ("luma",)
    outputs = ("events",)

    @dataclass
    class Params:
        preset: Literal["paper", "clean", "noisy"] = "paper"
        overrides: dict = field(default_factory=dict)   # e.g. { downsample = 1.0 }

    async def setup(self) -> None:
        self.emulator = EventEmulator(preset(self.params.preset,
                                             **{"seed": self.seed, **self.params.overrides}))
        self.episode = None
        self.events_out = 0
        self.bad_frames = 0

    async def on_luma(self, msg: Message) -> None:
        episode = msg.meta.get("episode")
        if episode != self.episode:
            self.emulator.reset()
            self.episode = episode
        t_ns = round((msg.t_sim or 0.0) * 1e9)
        try:
            events = self.emulator.step(msg.arrays["luma"], t_ns)
        except (ValueError, KeyError) as exc:
            self.bad_frames += 1
            self.log.error("frame at tick %s refused: %s", msg.tick, exc)
            return
        h, w = self.emulator.shape
        luma = msg.arrays["luma"]
        self.events_out += events.size
        await self.emit("events", {"events": events}, parent=msg,
                        meta={**msg.meta, "event_sensor": [w, h],
                              "frame": [luma.shape[1], luma.shape[0]]})

    def stats(self) -> dict:
        return {"events": self.events_out, "frames": self.emulator.frames,
                "bad_frames": self.bad_frames}
