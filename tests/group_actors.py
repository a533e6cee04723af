"""Actors for the process-group tests (importable by the worker as tests.group_actors)."""
from __future__ import annotations

import asyncio
from dataclasses import dataclass

from sebvs.runtime import Actor, Message


class Flaky(Actor):
    """A relay whose handler raises on every `every`-th message and forwards the others."""
    inputs = ("frames",)
    outputs = ("frames",)

    @dataclass
    class Params:
        every: int = 2

    async def setup(self) -> None:
        self.seen = 0

    async def on_frames(self, msg: Message) -> None:
        self.seen += 1
        if self.seen % self.params.every == 0:
            raise ValueError(f"flaky on message {self.seen}")
        await self.emit("frames", msg.arrays, parent=msg)


class Crasher(Actor):
    """A source that sends `frames_before` ticks, then its run() raises: the actor fails."""
    outputs = ("frames",)

    @dataclass
    class Params:
        frames_before: int = 5

    async def run(self) -> None:
        for tick in range(self.params.frames_before):
            await self.emit("frames", {}, tick=tick, meta={"n": tick})
            await asyncio.sleep(0.01)
        raise RuntimeError("crasher blew up on purpose")
