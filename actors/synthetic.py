"""Synthetic actors: a pattern source, a relay and sinks, for demos, tests and benchmarks.

They need no MuJoCo: the source draws a moving pattern with numpy.
"""
from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

import numpy as np

from sebvs.runtime import Actor, Message, Range

# px; at 4096 one RGB frame is 50 MB, times a ring's dozens of slots in /dev/shm
Side = Annotated[int, Range(ge=1, le=4096)]


def _texture(height: int, width: int, seed: int) -> np.ndarray:
    """A smooth colour texture twice as wide as the frame, so a window can slide over it."""
    rng = np.random.default_rng(seed)
    x = np.linspace(0, 4 * np.pi, 2 * width, dtype=np.float32)
    y = np.linspace(0, 4 * np.pi, height, dtype=np.float32)[:, None]
    phase = rng.uniform(0, 2 * np.pi, 3).astype(np.float32)
    tex = np.empty((height, 2 * width, 3), np.uint8)
    for c in range(3):
        tex[..., c] = (127.5 + 127.5 * np.sin(x * (c + 1) / 2 + phase[c]) * np.cos(y + phase[c]))
    return tex


class PatternSource(Actor):
    """Publishes a moving pattern: RGB on `frames` at `rate_hz`, luma on `luma` at `luma_hz`.

    Luma samples taken at an RGB tick carry meta `control: True` and that tick, as the
    camera's do, so the event accumulator can close its windows on them. Frames are drawn
    straight into the shared-memory slot.
    """
    outputs = ("frames", "luma")

    @classmethod
    def message_bytes(cls, params) -> dict[str, int]:
        return {"frames": params.width * params.height * 3,
                "luma": params.width * params.height}

    @dataclass
    class Params:
        width: Side = 640
        height: Side = 640
        # from 1 mHz: the frame period in ns must stay a finite number
        rate_hz: Annotated[float, Range(ge=1e-3, le=100_000)] = 30.0
        luma_hz: Annotated[float, Range(ge=0, le=100_000)] = 0.0   # 0: luma at rate_hz
        speed_px_s: float = 120.0      # horizontal drift of the pattern
        square: bool = True            # a bright square moving across the texture
        max_frames: Annotated[int, Range(ge=0)] = 0   # control ticks; 0: until stopped

    async def setup(self) -> None:
        p = self.params
        if p.width <= 0 or p.height <= 0 or p.rate_hz <= 0:
            raise ValueError("width, height and rate_hz must be positive")
        self._make_texture()
        self.sent = 0

    def _make_texture(self) -> None:
        p = self.params
        self.texture = _texture(p.height, p.width, self.seed)
        self.texture_luma = self.texture.mean(axis=2).astype(np.uint8)

    async def control(self, key: str, value) -> dict:
        result = await super().control(key, value)
        if key in ("width", "height"):
            self._make_texture()    # frames are windows of the texture: it must fit them
        return result

    def _draw(self, t: float, rgb: np.ndarray | None, luma: np.ndarray | None) -> None:
        p = self.params
        shift = int(t * p.speed_px_s) % p.width
        if rgb is not None:
            rgb[...] = self.texture[:, shift:shift + p.width]
        if luma is not None:
            luma[...] = self.texture_luma[:, shift:shift + p.width]
        if p.square:
            side = max(4, min(p.width, p.height) // 8)
            cx = int((0.5 + 0.4 * np.sin(2 * np.pi * 0.25 * t)) * (p.width - side))
            cy = int((0.5 + 0.4 * np.cos(2 * np.pi * 0.25 * t)) * (p.height - side))
            for img in (rgb, luma):
                if img is not None:
                    img[cy:cy + side, cx:cx + side] = 255

    async def run(self) -> None:
        p = self.params
        luma_hz = p.luma_hz or p.rate_hz
        per_tick = max(1, round(luma_hz / p.rate_hz))
        period_ns = int(1e9 / (p.rate_hz * per_tick))
        t0 = time.monotonic_ns()
        k = 0   # luma sample index
        while not self.stopping.is_set():
            t_sim = k * period_ns / 1e9
            tick, control = divmod(k, per_tick)
            control = control == 0
            if "luma" in self.consumed:
                out = self.reserve("luma", {"luma": ((p.height, p.width), np.uint8)})
                self._draw(t_sim, None, out["luma"])
                await self.emit("luma", out, t_sim=t_sim, tick=tick, meta={"control": control})
            if control:
                if "frames" in self.consumed:
                    out = self.reserve("frames", {"rgb": ((p.height, p.width, 3), np.uint8)})
                    self._draw(t_sim, out["rgb"], None)
                    await self.emit("frames", out, t_sim=t_sim, tick=tick,
                                    meta={"control": True})
                self.sent += 1          # control ticks, whichever outputs are consumed
                if p.max_frames and self.sent >= p.max_frames:
                    self.request_stop("max_frames reached")
                    return
            k += 1
            if not await self.sleep_until(t0 + k * period_ns):
                return

    def stats(self) -> dict:
        return {"frames_sent": self.sent}


class Relay(Actor):
    """Passes frames on: `forward` re-publishes the upstream slot (no copy), `copy` copies it."""
    inputs = ("frames",)
    outputs = ("frames",)
    forwards = {"frames": "frames"}

    @dataclass
    class Params:
        mode: Literal["forward", "copy"] = "forward"

    async def on_frames(self, msg: Message) -> None:
        if self.params.mode == "forward":
            await self.emit("frames", msg.arrays, parent=msg)
            return
        out = self.reserve("frames", {k: (a.shape, a.dtype) for k, a in msg.arrays.items()})
        for k, a in msg.arrays.items():
            out[k][...] = a
        await self.emit("frames", out, parent=msg)


class Sink(Actor):
    """Consumes frames and keeps a running checksum, proving the bytes were read."""
    inputs = ("frames",)

    @dataclass
    class Params:
        # simulated processing time per frame (a slow consumer); it blocks the actor
        work_ms: Annotated[float, Range(ge=0, le=60_000)] = 0.0

    async def setup(self) -> None:
        self.count = 0
        self.checksum = 0

    async def on_frames(self, msg: Message) -> None:
        for a in msg.arrays.values():
            self.checksum = (self.checksum + int(a.reshape(-1)[:: max(1, a.size // 64)].sum())) \
                % (1 << 61)
        self.count += 1
        if self.params.work_ms:
            time.sleep(self.params.work_ms / 1e3)  # a blocking consumer, on purpose

    def stats(self) -> dict:
        return {"frames": self.count, "checksum": self.checksum}


class Probe(Actor):
    """A test sink that saves what it receives, for tests and quick looks.

    On teardown writes `<path>.json` (one entry per message: input, source, seq, t_sim,
    tick, meta, stamps, array shapes and dtypes) and `<path>.npz` (arrays of the first
    `max_arrays` messages, keys `<index>.<input>.<name>`).
    """
    inputs = ("frames", "events", "luma", "state", "rgb", "action", "episode", "other")

    @dataclass
    class Params:
        path: str = "probe"
        max_arrays: Annotated[int, Range(ge=0)] = 200

    async def setup(self) -> None:
        self.entries: list[dict] = []
        self.arrays: dict[str, np.ndarray] = {}

    async def _record(self, msg: Message) -> None:
        i = len(self.entries)
        self.entries.append({"input": msg.input, "source": msg.source, "output": msg.output,
                             "seq": msg.seq, "t_sim": msg.t_sim, "tick": msg.tick,
                             "meta": msg.meta, "stamps": msg.stamps, "recv_ns": msg.recv_ns,
                             "arrays": {k: [list(a.shape), a.dtype.str]
                                        for k, a in msg.arrays.items()}})
        if i < self.params.max_arrays:
            for k, a in msg.arrays.items():
                self.arrays[f"{i}.{msg.input}.{k}"] = np.array(a)  # copy out of shared memory

    on_frames = on_events = on_luma = on_state = on_rgb = on_action = on_episode = on_other = \
        _record

    async def teardown(self) -> None:
        path = Path(self.params.path)
        path.parent.mkdir(parents=True, exist_ok=True)
        np.savez(path.with_suffix(".npz"), **self.arrays)
        path.with_suffix(".json").write_text(json.dumps(self.entries, default=_plain))

    def stats(self) -> dict:
        return {"messages": len(self.entries)}


def _plain(obj):
    if isinstance(obj, np.generic):
        return obj.item()
    raise TypeError(type(obj).__name__)
