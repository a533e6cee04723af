"""The input side of a Node: SUB sockets read from the event loop, each message decoded
and handed to the actor's handler."""
from __future__ import annotations

import asyncio
import collections
import logging
import time
import types
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import zmq

from .shm import RingReader
from .stats import summarize
from .wire import Message, WireError, array_spec, decode_header

TELEMETRY_MAX_RECORDS = 4096     # per period; beyond it records are counted, not kept
HANDLER_WINDOW = 2048            # handler times kept for `stats`
DRAIN_BATCH = 64                 # messages per reader callback before yielding to the loop
DRAIN_BUDGET_NS = 5_000_000      # ... or this much handler time, whichever comes first

log = logging.getLogger("sebvs.node")


@dataclass
class InputStats:
    received: int = 0
    handled: int = 0
    dropped_gap: int = 0          # sequence gaps: lost to a full queue upstream
    dropped_overwritten: int = 0  # the ring slot was reused before we read it
    dropped_latest: int = 0       # skipped on purpose by a `latest` input
    malformed: int = 0
    torn: int = 0                 # slot reused while the handler was reading it
    errors: int = 0               # the handler raised


@dataclass
class _Input:
    name: str
    handler: Any
    socket: Any
    latest: bool
    stats: InputStats = field(default_factory=InputStats)
    busy: asyncio.Task | None = None   # a handler that suspended and runs on as a task
    last_seq: dict = field(default_factory=dict)
    handler_ns: collections.deque = field(
        default_factory=lambda: collections.deque(maxlen=HANDLER_WINDOW))


class Inputs:
    """An actor's inputs, the rings they read and the record of every handled message."""

    def __init__(self) -> None:
        self.ports: dict[str, _Input] = {}
        self.reader = RingReader()
        self.stopping: asyncio.Event | None = None   # the actor's, set at connect
        self.records: list = []
        self.records_skipped = 0
        self.malformed_logged = 0

    def connect(self, specs: dict, ctx: zmq.Context, actor) -> None:
        """A SUB socket per input of the spec, each bound to the actor's ``on_<input>``."""
        self.stopping = actor.stopping
        for inp, i in specs.items():
            sock = ctx.socket(zmq.SUB)
            sock.setsockopt(zmq.RCVHWM, i["hwm"])
            sock.setsockopt(zmq.LINGER, 0)
            sock.setsockopt(zmq.RECONNECT_IVL, 10)
            sock.setsockopt(zmq.SUBSCRIBE, i["topic"].encode())
            sock.connect(i["endpoint"])
            handler = getattr(actor, f"on_{inp}")
            self.ports[inp] = _Input(inp, handler, sock, i["queue"] == "latest")

    def start(self) -> None:
        loop = asyncio.get_running_loop()
        for inp in self.ports.values():
            loop.add_reader(inp.socket.FD, self.drain, inp)
            loop.call_soon(self.drain, inp)  # the FD is edge-triggered: read what is queued

    def drain(self, inp: _Input) -> None:
        """Read and dispatch queued messages straight from the event loop's reader callback.

        Handlers start eagerly, without a task or future per message: most finish without
        suspending. One that suspends continues as a task, and this input waits for it, so
        each input's messages are handled in order. At most DRAIN_BATCH messages per call,
        (or DRAIN_BUDGET_NS) per call, so one busy input cannot starve the others or the
        control socket.
        """
        if inp.busy is not None or self.stopping.is_set():
            return
        sock, st = inp.socket, inp.stats
        budget_end = time.monotonic_ns() + DRAIN_BUDGET_NS
        for _ in range(DRAIN_BATCH):
            if time.monotonic_ns() > budget_end:
                break
            try:
                frames = _recv_message(sock)
            except zmq.Again:
                if sock.getsockopt(zmq.EVENTS) & zmq.POLLIN:
                    continue
                return
            st.received += 1
            if inp.latest:
                while True:  # keep only the newest queued message
                    try:
                        frames = _recv_message(sock)
                    except zmq.Again:
                        break
                    st.received += 1
                    st.dropped_latest += 1
            msg = self._accept(inp, frames)
            if msg is not None and not self._dispatch(inp, msg):
                return  # the handler suspended; _resume reschedules us
        asyncio.get_running_loop().call_soon(self.drain, inp)

    def _decode(self, frames) -> Message:
        if len(frames) < 2:
            raise WireError(f"{len(frames)} frame(s), expected topic and header")
        h = decode_header(frames[1])
        topic = frames[0].decode("utf-8", "replace")
        msg = Message(topic=topic, source=h["src"], output=h["out"], seq=h["seq"],
                      t_sim=h["ts"], tick=h["tick"], stamps=h["st"], meta=h["m"])
        nxt = 2
        for desc in h["a"]:
            name, dt, shape, nbytes, loc = array_spec(desc)
            if loc is None:
                if nxt >= len(frames):
                    raise WireError(f"array {name!r}: buffer missing (truncated message)")
                buf = frames[nxt].buffer
                nxt += 1
                if len(buf) != nbytes:
                    raise WireError(f"array {name!r}: {len(buf)} bytes, header says {nbytes}")
            else:
                if not (isinstance(loc, list) and len(loc) == 4 and isinstance(loc[0], str)
                        and isinstance(loc[1], int) and isinstance(loc[2], int)
                        and isinstance(loc[3], int)):
                    raise WireError(f"array {name!r}: bad shared-memory location {loc!r}")
                try:
                    buf = self.reader.view(loc[0], loc[1], loc[2], nbytes, loc[3])
                except (OSError, ValueError) as exc:
                    raise WireError(f"array {name!r}: {exc}") from None
                if buf is None:
                    return None  # overwritten before we got to it
                msg.shm_locs[name] = loc
            msg.arrays[name] = np.frombuffer(buf, dt).reshape(shape) if nbytes else \
                np.empty(shape, dt)
        if nxt != len(frames):
            raise WireError(f"{len(frames) - nxt} unexpected extra frame(s)")
        return msg

    def _accept(self, inp: _Input, frames) -> Message | None:
        st = inp.stats
        try:
            msg = self._decode(frames)
        except WireError as exc:
            st.malformed += 1
            self.malformed_logged += 1
            if self.malformed_logged <= 10 or self.malformed_logged % 1000 == 0:
                log.warning("input %r: malformed message dropped (%d so far): %s",
                            inp.name, st.malformed, exc)
            return None
        if msg is None:
            st.dropped_overwritten += 1
            return None
        last = inp.last_seq.get(msg.topic)
        if last is not None and msg.seq > last + 1:
            st.dropped_gap += msg.seq - last - 1
        inp.last_seq[msg.topic] = msg.seq
        msg.input = inp.name
        return msg

    def _dispatch(self, inp: _Input, msg: Message) -> bool:
        """Run the handler eagerly; False if it suspended and continues as a task."""
        msg.recv_ns = start = time.monotonic_ns()
        coro = inp.handler(msg)
        try:
            yielded = coro.send(None)
        except StopIteration:
            self._handled(inp, msg, start, None)
            return True
        except Exception as exc:
            self._handled(inp, msg, start, exc)
            return True
        task = asyncio.ensure_future(_continue(coro, yielded))
        inp.busy = task
        task.add_done_callback(lambda t: self._resume(inp, msg, start, t))
        return False

    def _resume(self, inp: _Input, msg: Message, start: int, task: asyncio.Task) -> None:
        inp.busy = None
        exc = None if task.cancelled() else task.exception()
        self._handled(inp, msg, start, exc)
        if not self.stopping.is_set():
            asyncio.get_running_loop().call_soon(self.drain, inp)

    def _handled(self, inp: _Input, msg: Message, start: int, exc: BaseException | None) -> None:
        end = time.monotonic_ns()
        st = inp.stats
        st.handled += 1
        if exc is not None:
            st.errors += 1
            log.error("handler on_%s failed on %s seq %d", inp.name, msg.topic, msg.seq,
                      exc_info=exc)
        inp.handler_ns.append(end - start)
        if msg.shm_locs and not all(self.reader.still_valid(l[0], l[1], l[3])
                                    for l in msg.shm_locs.values()):
            st.torn += 1
        if len(self.records) < TELEMETRY_MAX_RECORDS:
            self.records.append([inp.name, msg.topic, msg.seq, msg.tick, msg.t_sim,
                                 msg.stamps, start, end])
        else:
            self.records_skipped += 1

    def take_records(self) -> list:
        """The records since the last call (telemetry sends each batch once)."""
        records, self.records = self.records, []
        return records

    def stats(self) -> dict:
        inputs = {}
        for name, inp in self.ports.items():
            d = dict(vars(inp.stats))
            d["handler_us"] = summarize(inp.handler_ns, 1e-3)
            inputs[name] = d
        return inputs

    def drops(self) -> dict:
        return {n: vars(i.stats) for n, i in self.ports.items()}

    def stop_reading(self) -> None:
        loop = asyncio.get_running_loop()
        for inp in self.ports.values():
            loop.remove_reader(inp.socket.FD)

    async def cancel_handlers(self) -> None:
        """Cancel the handlers that suspended and still run as tasks, and wait for them."""
        busy = [i.busy for i in self.ports.values() if i.busy is not None]
        for task in busy:
            task.cancel()
        await asyncio.gather(*busy, return_exceptions=True)

    def close(self) -> None:
        """Unmap the rings we read and close the sockets."""
        self.reader.close()
        for inp in self.ports.values():
            inp.socket.close(linger=0)


def _recv_message(sock) -> list:
    """One queued message: topic and header as bytes, array buffers as zero-copy frames.

    Raises zmq.Again if none is queued. Copying the small leading frames is cheaper than
    wrapping them in zmq.Frame objects, which recv_multipart(copy=False) would do.
    """
    frames = [sock.recv(zmq.NOBLOCK)]
    while sock.getsockopt(zmq.RCVMORE):
        frames.append(sock.recv(zmq.NOBLOCK, copy=len(frames) < 2))
    return frames


@types.coroutine
def _adopt(coro, yielded):
    """Hand a coroutine that already ran to its first suspension over to a Task.

    The Task sees the future the coroutine is blocked on, and we pass results and
    exceptions (cancellation included) back into the coroutine.
    """
    while True:
        try:
            value = yield yielded
        except BaseException as exc:
            try:
                yielded = coro.throw(exc)
            except StopIteration as stop:
                return stop.value
            continue
        try:
            yielded = coro.send(value)
        except StopIteration as stop:
            return stop.value


async def _continue(coro, yielded):
    return await _adopt(coro, yielded)
