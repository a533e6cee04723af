"""The accumulator actor: event packets in, an event frame per control tick out.

Input   events  {"events": EVENT_DTYPE [N]} from the emulator; meta control marks the
                packet that ends at a control tick, event_sensor / frame give the geometry
Output  frames  {"frame": [C, H, W]} at the RGB (frame) resolution for the window
                [t - window_s, t]; uint8 counts (float32 for voxel); tick = the control tick;
                meta: representation, bins, window_s, event_scale / event_offset (sensor -> RGB)
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated, Literal

from sebvs.dvs.accumulator import EventAccumulator, EventGeometry
from sebvs.runtime import Actor, Message, Range

OutSide = Annotated[int, Range(ge=0, le=4096)]   # px; 0: the emulator's frame size


class Accumulator(Actor):
    inputs = ("events",)
    outputs = ("frames",)

    @dataclass
    class Params:
        representation: Literal["counts", "histogram", "voxel"] = "counts"
        window_s: Annotated[float, Range(gt=0, le=3600)] = 0.1   # one control period at 10 Hz
        bins: Annotated[int, Range(ge=1, le=256)] = 5
        clip: Annotated[int, Range(ge=1, le=255)] = 255      # counts are uint8
        out_width: OutSide = 0           # 0: the frame size the emulator reports
        out_height: OutSide = 0

    async def setup(self) -> None:
        self.acc = None
        self.geometry_key = None       # (event_sensor, frame) meta the accumulator was built for
        self.episode = None
        self.frames_out = 0

    def _accumulator(self, meta: dict) -> EventAccumulator:
        # every packet carries the geometry; it changes only with the scene's image size
        key = (meta["event_sensor"], meta.get("frame"))
        if self.acc is not None and key == self.geometry_key:
            return self.acc
        p = self.params
        out = (p.out_width or meta["frame"][0], p.out_height or meta["frame"][1])
        geometry = EventGeometry(tuple(meta["event_sensor"]), out)
        if self.acc is None or self.acc.geometry != geometry:
            self.acc = EventAccumulator(geometry, p.representation, p.window_s, p.bins, p.clip)
        self.geometry_key = key
        return self.acc

    async def on_events(self, msg: Message) -> None:
        acc = self._accumulator(msg.meta)
        if msg.meta.get("episode") != self.episode:
            acc.clear()
            self.episode = msg.meta.get("episode")
        acc.add(msg.arrays["events"].copy())   # the packet outlives this handler
        if not msg.meta.get("control"):
            return
        frame = acc.frame(round((msg.t_sim or 0.0) * 1e9))
        out = self.reserve("frames", {"frame": (frame.shape, frame.dtype)})
        out["frame"][...] = frame
        self.frames_out += 1
        meta = {k: v for k, v in msg.meta.items() if k not in ("event_sensor", "frame")}
        await self.emit("frames", out, parent=msg,
                        meta={**meta, **acc.geometry.to_meta(),
                              "representation": acc.representation,
                              "bins": 1 if acc.representation == "counts" else acc.bins,
                              "window_s": self.params.window_s})

    def stats(self) -> dict:
        return {"frames": self.frames_out,
                "recounts": self.acc.recounts if self.acc is not None else 0}
