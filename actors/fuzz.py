"""Actors of tools/checks/fuzz_run.py: a hostile producer and the sink it attacks.

HostileSource  output `frames`: rounds of every hostile class of sebvs.runtime.hostile,
               each round followed by a valid probe (meta {"probe": k}); every
               `oversize_every` rounds one message over the sink's max_bytes, then a pause
               for the input to reconnect. Writes what it sent, per class, to `report`.
ProbeSink      input `frames`: counts the probes it handled, and at the end writes them,
               its input's counters and its memory (RSS at the first probe and at the end)
               to `report`.
Both are test tools: a topology of production actors never needs them.
"""
from __future__ import annotations

import asyncio
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

from sebvs.runtime import Actor, Message, Range
from sebvs.runtime.hostile import ROUND, HostileFactory


def rss_bytes() -> int:
    """This process's resident memory (Linux /proc), 0 where unknown."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) * 1024
    except OSError:
        pass
    return 0


class HostileSource(Actor):
    outputs = ("frames",)

    @dataclass
    class Params:
        messages: Annotated[int, Range(ge=1, le=10_000_000)] = 10_000   # hostile ones
        oversize_every: Annotated[int, Range(ge=0)] = 200     # rounds; 0: none
        oversize_bytes: Annotated[int, Range(ge=1)] = 65_536  # the sink's max_bytes
        reconnect_wait_s: Annotated[float, Range(ge=0, le=10)] = 0.6
        report: str = ""

    async def run(self) -> None:
        p = self.params
        sock = self._node.outputs.ports["frames"].socket
        make = HostileFactory(self.name, "frames", self.seed)
        sent = {c: 0 for c in ROUND} | {"oversize": 0, "probe": 0}
        total, rounds = 0, 0
        # a first probe: the input has a sequence to go back from before any round
        sock.send_multipart(make.valid(meta={"probe": 0}))
        sent["probe"] += 1
        await asyncio.sleep(0.01)
        while total < p.messages and not self.stopping.is_set():
            for kind in ROUND:
                sock.send_multipart(make.make(kind))
                sent[kind] += 1
                total += 1
            rounds += 1
            if p.oversize_every and rounds % p.oversize_every == 0:
                sock.send_multipart(make.make("oversize", p.oversize_bytes))
                sent["oversize"] += 1
                total += 1
                await asyncio.sleep(p.reconnect_wait_s)   # what is sent meanwhile is lost
            sock.send_multipart(make.valid(meta={"probe": sent["probe"]}))
            sent["probe"] += 1
            # the sink must keep up: a PUB drops what its peer's queue cannot take
            await asyncio.sleep(0.002 if rounds % 20 else 0.02)
        await asyncio.sleep(1.0)                      # the sink drains what is queued
        if p.report:
            Path(p.report).write_text(json.dumps({"sent": sent, "total": total,
                                                  "rounds": rounds}))
        self.request_stop(f"{total} hostile messages sent")


class ProbeSink(Actor):
    inputs = ("frames",)

    @dataclass
    class Params:
        report: str = ""

    async def setup(self) -> None:
        self.probes: list[int] = []
        self.rss_first = 0

    async def on_frames(self, msg: Message) -> None:
        probe = msg.meta.get("probe")
        if isinstance(probe, int):
            if not self.probes:
                self.rss_first = rss_bytes()
            self.probes.append(probe)

    async def teardown(self) -> None:
        if self.params.report:
            Path(self.params.report).write_text(json.dumps({
                "probes": len(self.probes), "last_probe": self.probes[-1] if self.probes
                else None, "rss_first": self.rss_first, "rss_end": rss_bytes(),
                "input": self._node.inputs.stats()["frames"]}))
