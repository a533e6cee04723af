"""Actors for the benchmarks: a paced payload source and a sink that logs hop latency
(tools/bench/bench_hops.py), and a tap that keeps an emulator's events (tools/bench/bench_sim.py)."""
from __future__ import annotations

import asyncio
import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import numpy as np

from sebvs.runtime import Actor, Message, Range


class PayloadSource(Actor):
    """Sends `count` payloads of `nbytes`, one every `interval_ms`, then ends the run.

    Each payload is written in place into the output's shared-memory slot before `emit`
    (as a renderer does), so what the hop costs is the runtime's, not a copy's.
    """
    outputs = ("payload",)

    @dataclass
    class Params:
        nbytes: Annotated[int, Range(ge=1, le=1 << 30)] = 1_228_800
        count: Annotated[int, Range(ge=0)] = 2000
        interval_ms: Annotated[float, Range(ge=0, le=60_000)] = 1.0
        warmup: Annotated[int, Range(ge=0)] = 50

    async def run(self) -> None:
        p = self.params
        pattern = np.arange(p.nbytes, dtype=np.uint8)
        period = int(p.interval_ms * 1e6)
        t_next = time.monotonic_ns()
        for i in range(p.warmup + p.count):
            out = self.reserve("payload", {"data": ((p.nbytes,), np.uint8)})
            out["data"][...] = pattern
            if p.nbytes >= 8:
                out["data"][:8] = np.frombuffer(np.int64(i).tobytes(), np.uint8)
            await self.emit("payload", out, tick=i, meta={"warmup": i < p.warmup})
            t_next += period
            if not await self.sleep_until(t_next):
                return
        await asyncio.sleep(0.3)  # let the last ones arrive before the run ends
        self.request_stop("all payloads sent")


class LatencySink(Actor):
    """Records, per message, send stamp of the producer -> this handler's start, in ns."""
    inputs = ("payload",)

    @dataclass
    class Params:
        path: str = "latency.npy"

    async def setup(self) -> None:
        self.latencies: list[int] = []
        self.bad = 0

    async def on_payload(self, msg: Message) -> None:
        data = msg.arrays["data"]
        if data.size >= 8 and int(data[:8].view(np.int64)[0]) != msg.tick:
            self.bad += 1  # the bytes are not the ones sent with this header
        if not msg.meta.get("warmup"):
            self.latencies.append(msg.recv_ns - msg.stamps[-1][2])

    async def teardown(self) -> None:
        np.save(Path(self.params.path), np.asarray(self.latencies + [-self.bad - 1], np.int64))


class EventTap(Actor):
    """Keeps every event the emulator sends and writes them once the run ends:
    `<path>.npy` (EVENT_DTYPE, in arrival order) and `<path>.json` ({"packets": n,
    "sensor": [w, h]}). tools/bench/bench_sim.py compares two runs' streams with
    sebvs.dvs.fidelity.

    With `action` wired (the expert's) and the sim's action taken from this tap's, it paces
    a lockstep run to the event chain: the action of tick k goes on once the emulator's
    packet of tick k's control sample has come, so no luma frame is overwritten in the
    camera's ring while the emulator runs behind (a 1 kHz camera outruns it), and the run's
    speed is that of the whole chain."""
    inputs = ("events", "action")
    outputs = ("action",)

    @dataclass
    class Params:
        path: str = "events"

    async def setup(self) -> None:
        self.packets: list[np.ndarray] = []
        self.sensor = None
        self.done_tick = -1                 # the newest tick whose control packet came
        self.waiting: list[Message] = []    # actions of ticks not done yet

    async def on_events(self, msg: Message) -> None:
        self.packets.append(np.array(msg.arrays["events"]))   # out of the sender's slot
        self.sensor = msg.meta.get("event_sensor", self.sensor)
        if msg.meta.get("control") and msg.tick is not None:
            self.done_tick = max(self.done_tick, msg.tick)
            ready = [m for m in self.waiting if m.tick <= self.done_tick]
            self.waiting = [m for m in self.waiting if m.tick > self.done_tick]
            for m in ready:
                await self.emit("action", m.arrays, parent=m)

    async def on_action(self, msg: Message) -> None:
        if msg.tick is None or msg.tick <= self.done_tick:
            await self.emit("action", msg.arrays, parent=msg)
        else:
            self.waiting.append(msg)

    async def teardown(self) -> None:
        from sebvs.dvs.emulator import EVENT_DTYPE
        path = Path(self.params.path)
        events = np.concatenate(self.packets) if self.packets else np.zeros(0, EVENT_DTYPE)
        np.save(path.with_suffix(".npy"), events)
        path.with_suffix(".json").write_text(json.dumps({"packets": len(self.packets),
                                                         "sensor": self.sensor}))

    def stats(self) -> dict:
        return {"packets": len(self.packets), "waiting": len(self.waiting)}
