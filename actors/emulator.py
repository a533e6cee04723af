"""The event emulator actor: luma frames in, event packets out (sebvs.dvs.emulator).

Input   luma    {"luma": uint8 [H, W]} from the camera at its dvs rate; t_sim -> timestamp;
                or, from a camera with sensor "physical", float32 luminance in cd/m^2
                (meta units "cd/m2"), read as linear light (EventEmulator.step_luminance)
Output  events  {"events": EVENT_DTYPE [N]} (x, y, t ns, p), time-sorted, emitted with the
                input's tick and meta, plus event_sensor [w, h] and frame [W, H]
A new episode (meta `episode` changes) restarts the stream: the scene jumps, and a jump
is not a brightness change the sensor would see. A frame the emulator refuses (ValueError:
a bad timestamp or array) is counted in bad_frames and dropped; the stream goes on. A gap
over the emulator's max_gap_s, forward or back, restarts the sensor and is counted in
gap_restarts (one corrupt far-future timestamp costs one restart, not the episode).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from sebvs.dvs.params import preset
from sebvs.dvs.stream import SensorStream
from sebvs.runtime import Actor, Message


class Emulator(Actor):
    inputs = ("luma",)
    outputs = ("events",)

    @dataclass
    class Params:
        preset: Literal["paper", "clean", "noisy", "physical"] = "paper"
        overrides: dict = field(default_factory=dict)   # e.g. { downsample = 1.0 }

    async def setup(self) -> None:
        # the episode restarts and the fixed pattern per episode: sebvs.dvs.stream
        self.stream = SensorStream(preset(self.params.preset,
                                          **{"seed": self.seed, **self.params.overrides}))
        self.emulator = self.stream.emulator
        self.events_out = 0
        self.bad_frames = 0
        self.gap_restarts = 0

    async def on_luma(self, msg: Message) -> None:
        restarts, prev_t = self.emulator.gap_restarts, self.emulator.t_ns
        try:
            frame = msg.arrays["luma"]
            events = self.stream.frame(frame, msg.t_sim, msg.meta.get("episode"),
                                       msg.meta.get("units"))
        except (ValueError, KeyError, OverflowError) as exc:
            self.bad_frames += 1
            # a stream stuck on bad frames (e.g. time went back) must not flood the log
            if self.bad_frames <= 10 or self.bad_frames % 1000 == 0:
                self.log.error("frame at tick %s refused (%d so far): %s",
                               msg.tick, self.bad_frames, exc)
            return
        if self.emulator.gap_restarts > restarts:
            self.gap_restarts += 1
            self.log.warning("tick %s: %.3g s from the previous frame, beyond max_gap_s "
                             "either way; the sensor restarts from this frame", msg.tick,
                             (self.emulator.t_ns - prev_t) * 1e-9)
        self.events_out += events.size
        await self.emit("events", {"events": events}, parent=msg,
                        meta={**msg.meta, **self.stream.geometry_meta(frame)})

    def stats(self) -> dict:
        return {"events": self.events_out, "frames": self.emulator.frames,
                "bad_frames": self.bad_frames, "gap_restarts": self.gap_restarts}
