"""Actors used only by the runtime tests (importable by the worker as tests.runtime_actors)."""
from __future__ import annotations

import asyncio
from dataclasses import dataclass

import msgpack
import numpy as np

from sebvs.runtime import Actor
from sebvs.runtime.wire import SCHEMA_VERSION, encode_header


class GarbageSource(Actor):
    """Sends good frames with malformed messages in between, straight onto its socket."""
    outputs = ("frames",)

    @dataclass
    class Params:
        good_before: int = 3
        good_after: int = 3

    def malformed(self) -> list[list[bytes]]:
        topic = f"{self.name}/frames".encode()
        hdr = dict(source=self.name, output="frames", seq=100, t_sim=0.0, tick=0,
                   stamps=[[self.name, 0, 1]], meta={})
        return [
            [topic, b"\xc1\xff garbage bytes \x00"],                                  # not msgpack
            [topic, msgpack.packb({"v": SCHEMA_VERSION + 7, "src": "x"})],          # wrong schema
            [topic, encode_header(arrays=[["a", "|u1", [1000], None]], **hdr)],      # buffer missing
            [topic, encode_header(arrays=[["a", "|u1", [1000], None]], **hdr), b"short"],  # truncated
            [topic, encode_header(arrays=[["a", "<f8", [10, 1024, 1024, 128], None]], **hdr),
             b"x"],                                                                 # claims 10 GB
            [topic, encode_header(arrays=[["a", "|u1", [64], ["sebvs-nope", 0, 0, 2]]], **hdr)],
            [topic],                                                                # no header
        ]

    async def run(self) -> None:
        sock = self._node.outputs.ports["frames"].socket
        for i in range(self.params.good_before):
            await self.emit("frames", {"rgb": np.full((8, 8, 3), i, np.uint8)}, tick=i)
            await asyncio.sleep(0.01)
        for frames in self.malformed():
            sock.send_multipart(frames)
            await asyncio.sleep(0.01)
        for i in range(self.params.good_after):
            await self.emit("frames", {"rgb": np.full((8, 8, 3), 50 + i, np.uint8)}, tick=50 + i)
            await asyncio.sleep(0.01)


class StuckSink(Actor):
    """Takes one message, then its handler waits forever: the input reads nothing more."""
    inputs = ("frames",)

    @dataclass
    class Params:
        pass

    async def on_frames(self, msg) -> None:
        await asyncio.Event().wait()


class SlowSetupSink(Actor):
    """Writes ``marker`` as its setup begins, then takes ``setup_s`` to get ready."""
    inputs = ("frames",)

    @dataclass
    class Params:
        marker: str = ""
        setup_s: float = 2.0

    async def setup(self) -> None:
        if self.params.marker:
            with open(self.params.marker, "w") as f:
                f.write("setup begun\n")
        await asyncio.sleep(self.params.setup_s)

    async def on_frames(self, msg) -> None:
        pass
