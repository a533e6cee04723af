"""The actor base class: what an actor's own code sees of the runtime.

An actor declares its inputs, outputs and parameters and implements handlers; the
process-level machinery (sockets, rings, stamps, control, telemetry) lives in
``sebvs.runtime.node`` and is reached only through the methods below.
"""
from __future__ import annotations

import asyncio
import dataclasses
import logging
import time
from typing import Any, ClassVar

import numpy as np

from .params import coerce_param, param_fields, short_repr
from .wire import Message


class Actor:
    """Base class of every actor. See docs/actor_api.md for a worked example."""

    inputs: ClassVar[tuple[str, ...]] = ()
    outputs: ClassVar[tuple[str, ...]] = ()
    # output -> input whose messages it passes on unchanged in size (a relay): the loader
    # carries the producer's known message size through it
    forwards: ClassVar[dict[str, str]] = {}

    @classmethod
    def message_bytes(cls, params: Any) -> dict[str, int]:
        """The largest array payload (bytes) each output sends, where the parameters alone
        say it. The topology loader compares it with a consumer's `max_bytes` on an edge
        that carries arrays inline (tcp), before any process starts."""
        return {}

    @dataclasses.dataclass
    class Params:
        pass

    def __init__(self, name: str, params: Any, *, seed: int = 0, clock: str = "realtime",
                 consumed: frozenset = frozenset(), connected: frozenset = frozenset(),
                 node=None):
        self.name = name
        self.params = params
        self.seed = seed
        self.clock = clock
        self.consumed = frozenset(consumed)     # outputs that some actor subscribes to
        self.connected = frozenset(connected)   # inputs wired in the topology
        self.log = logging.getLogger(f"sebvs.actor.{name}")
        self.stopping = asyncio.Event()
        self._node = node
        self._sleepers: set[asyncio.Future] = set()

    # --- lifecycle hooks, overridden by actors -------------------------------------
    async def setup(self) -> None:
        """Runs before the ready handshake."""

    async def teardown(self) -> None:
        """Runs once after the actor stops (normal end, Ctrl-C, `ctl stop`)."""

    # `async def run(self)` is optional: sources define it; it starts with the clock.

    # --- publishing ----------------------------------------------------------------
    def reserve(self, output: str, specs: dict[str, tuple]) -> dict[str, np.ndarray]:
        """Writable arrays inside the next shared-memory slot of ``output``.

        ``specs`` maps array name -> (shape, dtype). Fill the arrays, then pass the dict to
        ``emit``: the bytes are never copied.
        """
        return self._node.reserve(output, specs)

    async def emit(self, output: str, arrays: dict[str, np.ndarray] | None = None, *,
                   meta: dict | None = None, t_sim: float | None = None,
                   tick: int | None = None, parent: Message | None = None) -> None:
        """Publish one sample on ``output``; with ``parent`` its t_sim, tick, meta and stamps carry on."""
        self._node.emit(output, arrays, meta=meta, t_sim=t_sim, tick=tick, parent=parent)

    def telemetry(self, kind: str, **fields) -> None:
        """Publish an event (an inference latency, a modality swap, an episode end...)."""
        self._node.event(kind, fields)

    async def sleep_until(self, t_ns: int) -> bool:
        """Sleep until monotonic time ``t_ns``; returns False if the actor is stopping.

        One future and one timer, woken early by a stop: a paced source calls this after
        every send, so it must cost next to nothing.
        """
        delay = (t_ns - time.monotonic_ns()) / 1e9
        if delay > 0 and not self.stopping.is_set():
            loop = asyncio.get_running_loop()
            wake = loop.create_future()
            timer = loop.call_later(delay, _resolve, wake)
            self._sleepers.add(wake)
            try:
                await wake
            finally:
                timer.cancel()
                self._sleepers.discard(wake)
        return not self.stopping.is_set()

    def _wake_sleepers(self) -> None:
        for wake in list(self._sleepers):
            _resolve(wake)

    def request_stop(self, reason: str = "") -> None:
        """End this actor (and, as a finished source, let the supervisor end the run)."""
        self._node.finish(reason)

    # --- control -------------------------------------------------------------------
    async def control(self, key: str, value: Any) -> dict:
        """Handle ``sebvs ctl RUN ACTOR set key=value``; raise ValueError to refuse.

        The value passes the same check as in a topology (type, Range, finite floats)
        before it is set: a refused one leaves the running value as it was.
        """
        fields = param_fields(type(self.params))
        if key not in fields:
            raise ValueError(f"unknown key {short_repr(key)} for actor {self.name!r} "
                             f"(known: {', '.join(sorted(fields)) or 'none'})")
        new = coerce_param(fields[key], value, where=f"actor {self.name!r} key {key!r}")
        setattr(self.params, key, new)
        return {key: new}

    def stats(self) -> dict:
        """Extra numbers for ``sebvs ctl RUN ACTOR stats``."""
        return {}


def _resolve(future: asyncio.Future) -> None:
    if not future.done():
        future.set_result(None)
