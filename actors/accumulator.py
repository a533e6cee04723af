"""The accumulator actor: event packets in, an event frame per control tick out.

Input   events  {"events": EVENT_DTYPE [N]} from the emulator; meta control marks the
                packet that ends at a control tick, event_sensor / frame give the geometry
Output  frames  {"frame": [C, H, W]} at the RGB (frame) resolution for the window
                [t - window_s, t]; uint8 counts (float32 for voxel; time_surface: uint8
                [2, H, W] 255 exp(-age / window_s) of each pixel's newest event, any age);
                tick = the control tick;
                meta: representation, bins, window_s, event_scale / event_offset (sensor -> RGB)
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated, Literal

from sebvs.dvs.stream import FrameStream
from sebvs.runtime import Actor, Message, Range

OutSide = Annotated[int, Range(ge=0, le=4096)]   # px; 0: the emulator's frame size


class Accumulator(Actor):
    inputs = ("events",)
    outputs = ("frames",)

    @dataclass
    class Params:
        representation: Literal["counts", "histogram", "voxel", "time_surface"] = "counts"
        # one control period at 10 Hz; for time_surface, window_s is the decay constant tau
        window_s: Annotated[float, Range(gt=0, le=3600)] = 0.1
        bins: Annotated[int, Range(ge=1, le=256)] = 5
        clip: Annotated[int, Range(ge=1, le=255)] = 255      # counts are uint8
        out_width: OutSide = 0           # 0: the frame size the emulator reports
        out_height: OutSide = 0

    async def setup(self) -> None:
        p = self.params
        # geometry, episodes and frames: sebvs.dvs.stream, which sebvs.envs runs too
        self.stream = FrameStream(p.representation, p.window_s, p.bins, p.clip,
                                  p.out_width, p.out_height)
        self.frames_out = 0

    @property
    def acc(self):
        return self.stream.acc

    async def on_events(self, msg: Message) -> None:
        # a copy: the packet outlives this handler
        self.stream.add(msg.arrays["events"].copy(), msg.meta.get("episode"), msg.meta)
        if not msg.meta.get("control"):
            return
        frame = self.stream.frame(msg.t_sim)
        out = self.reserve("frames", {"frame": (frame.shape, frame.dtype)})
        out["frame"][...] = frame
        self.frames_out += 1
        meta = {k: v for k, v in msg.meta.items() if k not in ("event_sensor", "frame")}
        await self.emit("frames", out, parent=msg, meta={**meta, **self.stream.frame_meta()})

    def stats(self) -> dict:
        return {"frames": self.frames_out,
                "recounts": self.acc.recounts if self.acc is not None else 0}
