"""The input side of a Node: SUB sockets read from the event loop, each message decoded
and handed to the actor's handler.

No message can stop an input: one that does not decode is counted in `malformed` (and
per kind in `malformed_kinds`), one whose handler raises in `errors` (per exception type
in `error_kinds`); each kind is logged the first time and then rarely, and the input reads
on. A message over the input's `max_bytes` (ZeroMQ's MAXMSGSIZE) makes ZeroMQ drop the
connection and never reconnect it; a monitor on each input's socket sees a drop that no
retry follows, counts it in `oversize`, logs it with the limit, and connects again, so
one oversized frame costs that frame, not the input. Per-input state is bounded: only the producer's own topic is accepted, and the
sequence bookkeeping is one number.
"""
from __future__ import annotations

import asyncio
import collections
import logging
import types
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import zmq

from . import curve
from .clock import now_ns
from .shm import RingReader
from .stats import summarize
from .wire import Message, WireError, array_spec, decode_header

TELEMETRY_MAX_RECORDS = 4096     # per period; beyond it records are counted, not kept
HANDLER_WINDOW = 2048            # handler times kept for `stats`
DRAIN_BATCH = 64                 # messages per reader callback before yielding to the loop
DRAIN_BUDGET_NS = 5_000_000      # ... or this much handler time, whichever comes first
# ZeroMQ's MAXMSGSIZE per input when the spec gives none (topology key `max_bytes`): large
# arrays travel in shared memory, so only tcp inputs carry them inline; a peer sending more
# is disconnected by ZeroMQ before we allocate
MAX_MESSAGE_BYTES = 256 << 20
# a forward jump larger than this is not a loss (a queue holds at most 100,000) but a
# forged or corrupt seq: counted apart, so `dropped_gap` stays a count of lost messages
MAX_SEQ_GAP = 1 << 20
MAX_KINDS = 32                   # distinct exception types counted by name per input
# ZeroMQ retries a lost connection after RECONNECT_IVL (10 ms here); a disconnection no
# retry follows within this long was a refused (oversized) message
RETRY_WAIT_S = 0.25

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
    seq_resets: int = 0           # seq went back: the producer restarted
    seq_jumps: int = 0            # seq leapt further than any queue could lose (MAX_SEQ_GAP)
    oversize: int = 0             # ZeroMQ dropped the peer for a message over max_bytes
                                  # (and would not reconnect): reconnected each time
    malformed_kinds: dict = field(default_factory=dict)   # WireError kind -> count
    error_kinds: dict = field(default_factory=dict)       # exception type -> count


@dataclass
class _Input:
    name: str
    handler: Any
    socket: Any
    latest: bool
    topic: bytes = b""             # the one topic this input reads (its producer's output)
    endpoint: str = ""
    max_bytes: int = 0
    monitor: Any = None            # the socket's monitor: disconnections and retries
    disconnects: int = 0
    retried: int = 0               # the disconnection count when ZeroMQ last retried
    stats: InputStats = field(default_factory=InputStats)
    busy: asyncio.Task | None = None   # a handler that suspended and runs on as a task
    last_seq: int | None = None
    handler_ns: collections.deque = field(
        default_factory=lambda: collections.deque(maxlen=HANDLER_WINDOW))


class LoopClock:
    """When the event loop last went to sleep in ``select()`` and when it woke from it.

    Installed around the running loop's selector by ``Inputs.start`` (CPython's selector
    event loops call ``self._selector.select(timeout)`` once per iteration): two
    ``monotonic_ns`` reads per loop iteration, so the profiler can tell the time a message
    waited while its consumer slept (a wake-up) from the time it waited while the consumer
    was busy with other work (queueing). 0 until installed (a Node driven by hand, tools).
    """

    def __init__(self, selector=None) -> None:
        self._selector = selector
        self.slept_ns = 0      # select() entered: the loop had nothing ready to run
        self.woke_ns = 0       # select() returned: the loop runs this iteration's callbacks

    def select(self, timeout=None):
        self.slept_ns = now_ns()
        try:
            return self._selector.select(timeout)
        finally:
            self.woke_ns = now_ns()

    def __getattr__(self, name):       # register, modify, unregister, get_map, close...
        return getattr(self._selector, name)

    @classmethod
    def install(cls, loop) -> "LoopClock":
        """The loop's clock, wrapping its selector once (several Nodes may share a loop)."""
        current = getattr(loop, "_selector", None)
        if isinstance(current, cls):
            return current
        if current is None or not hasattr(current, "select"):
            return cls()      # not a selector loop: stamps stay 0, the profiler says so
        loop._selector = clock = cls(current)
        return clock


class Inputs:
    """An actor's inputs, the rings they read and the record of every handled message."""

    def __init__(self) -> None:
        self.ports: dict[str, _Input] = {}
        self.loop_clock = LoopClock()                # the running loop's, from start()
        self.reader = RingReader()
        self.stopping: asyncio.Event | None = None   # the actor's, set at connect
        self.ring_prefix = "sebvs-"                   # narrowed to the run's at connect
        self.records: list = []
        self.records_skipped = 0

    def connect(self, specs: dict, ctx: zmq.Context, actor, run_id: str,
                token: str | None = None) -> None:
        """A SUB socket per input of the spec, each bound to the actor's ``on_<input>``.

        Rings are opened only under this run's prefix (a relay forwards its producer's
        ring locations, so any ring of the run may arrive on any input).
        """
        self.stopping = actor.stopping
        self.ring_prefix = f"sebvs-{run_id}-"
        for inp, i in specs.items():
            sock = ctx.socket(zmq.SUB)
            sock.setsockopt(zmq.RCVHWM, i["hwm"])
            sock.setsockopt(zmq.LINGER, 0)
            sock.setsockopt(zmq.RECONNECT_IVL, 10)
            max_bytes = i.get("max_bytes") or MAX_MESSAGE_BYTES
            sock.setsockopt(zmq.MAXMSGSIZE, max_bytes)
            sock.setsockopt(zmq.SUBSCRIBE, i["topic"].encode())
            monitor = sock.get_monitor_socket(
                zmq.EVENT_DISCONNECTED | zmq.EVENT_CONNECT_RETRIED | zmq.EVENT_CONNECTED
                | zmq.EVENT_CONNECT_DELAYED)
            curve.client(sock, i["endpoint"], token)     # tcp: the run's CURVE keys
            sock.connect(i["endpoint"])
            handler = getattr(actor, f"on_{inp}")
            self.ports[inp] = _Input(inp, handler, sock, i["queue"] == "latest",
                                     topic=i["topic"].encode(), endpoint=i["endpoint"],
                                     max_bytes=max_bytes, monitor=monitor)

    def start(self) -> None:
        loop = asyncio.get_running_loop()
        self.loop_clock = LoopClock.install(loop)
        for inp in self.ports.values():
            loop.add_reader(inp.socket.FD, self.drain, inp)
            loop.call_soon(self.drain, inp)  # the FD is edge-triggered: read what is queued
            if inp.monitor is not None:
                loop.add_reader(inp.monitor.FD, self.watch, inp)
                loop.call_soon(self.watch, inp)

    def watch(self, inp: _Input) -> None:
        """The socket's monitor. A producer that goes away is reconnected by ZeroMQ itself
        (a connect retry follows the disconnection); a peer dropped for a message over
        MAXMSGSIZE is not. So a disconnection that no retry follows within
        RETRY_WAIT_S is counted in `oversize`, logged with the limit, and connected again."""
        while True:
            try:
                frames = inp.monitor.recv_multipart(zmq.NOBLOCK)
            except (zmq.Again, zmq.ZMQError):         # none queued, or closed at shutdown
                return
            if not frames or len(frames[0]) < 2:
                continue
            event = int.from_bytes(frames[0][:2], "little")
            if event == zmq.EVENT_DISCONNECTED:
                inp.disconnects += 1
                asyncio.get_running_loop().call_later(RETRY_WAIT_S, self._check_retry, inp,
                                                      inp.disconnects)
            else:                                      # a retry, a delay or a connection
                inp.retried = inp.disconnects

    def _check_retry(self, inp: _Input, disconnects: int) -> None:
        if inp.retried >= disconnects or inp.disconnects != disconnects \
                or (self.stopping is not None and self.stopping.is_set()) \
                or inp.socket.closed:
            return
        inp.stats.oversize += 1
        n = inp.stats.oversize
        if _worth_logging(n):
            log.warning("input %r: ZeroMQ dropped the connection to %s and does not retry "
                        "(%d so far): a message over this input's max_bytes %d (the "
                        "topology's key) was refused; connecting again", inp.name,
                        inp.endpoint, n, inp.max_bytes)
        try:
            inp.socket.disconnect(inp.endpoint)
        except zmq.ZMQError:
            pass                                       # already gone from the socket
        inp.socket.connect(inp.endpoint)

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
        # the loop iteration this callback runs in: when the loop slept and woke (the
        # profiler's wake-up / queueing split), read once per callback
        clock = self.loop_clock
        slept, woke = clock.slept_ns, clock.woke_ns
        budget_end = now_ns() + DRAIN_BUDGET_NS
        for _ in range(DRAIN_BATCH):
            taken = now_ns()     # the budget check's clock read, kept as a stamp
            if taken > budget_end:
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
                    t = now_ns()
                    try:
                        frames = _recv_message(sock)
                    except zmq.Again:
                        break
                    taken = t               # the kept message may have come after the first
                    st.received += 1
                    st.dropped_latest += 1
            try:
                msg = self._accept(inp, frames)
            except Exception as exc:   # a decoder bug must not end this input: count it
                self._malformed(inp, WireError(f"{type(exc).__name__}: {exc}", "internal"))
                continue
            if msg is not None and not self._dispatch(inp, msg, (slept, woke, taken)):
                return  # the handler suspended; _resume reschedules us
        asyncio.get_running_loop().call_soon(self.drain, inp)

    def _decode(self, inp: _Input, frames) -> Message:
        if len(frames) < 2:
            raise WireError(f"{len(frames)} frame(s), expected topic and header", "frames")
        # SUB matches prefixes: "cam/rgb" would also take "cam/rgb2" or a flood of new ones
        if frames[0] != inp.topic:
            raise WireError(f"topic {frames[0][:80]!r}, expected {inp.topic!r}", "topic")
        h = decode_header(frames[1])
        topic = frames[0].decode("utf-8", "replace")
        msg = Message(topic=topic, source=h["src"], output=h["out"], seq=h["seq"],
                      t_sim=h["ts"], tick=h["tick"], stamps=h["st"], meta=h["m"])
        nxt = 2
        for desc in h["a"]:
            name, dt, shape, nbytes, loc = array_spec(desc)
            if loc is None:
                if nxt >= len(frames):
                    raise WireError(f"array {name!r}: buffer missing (truncated message)",
                                    "frames")
                buf = frames[nxt].buffer
                nxt += 1
                if len(buf) != nbytes:
                    raise WireError(f"array {name!r}: {len(buf)} bytes, header says {nbytes}",
                                    "frames")
            else:
                # only the producer's own rings: a header must not make us open any file
                if not loc[0].startswith(self.ring_prefix):
                    raise WireError(f"array {name!r}: ring {loc[0][:80]!r} is not this "
                                    f"run's ({self.ring_prefix}*)", "ring")
                try:
                    buf = self.reader.view(loc[0], loc[1], loc[2], nbytes, loc[3])
                except (OSError, ValueError) as exc:
                    raise WireError(f"array {name!r}: {exc}", "ring") from None
                if buf is None:
                    return None  # overwritten before we got to it
                msg.shm_locs[name] = loc
            msg.arrays[name] = np.frombuffer(buf, dt).reshape(shape) if nbytes else \
                np.empty(shape, dt)
        if nxt != len(frames):
            raise WireError(f"{len(frames) - nxt} unexpected extra frame(s)", "frames")
        return msg

    def _accept(self, inp: _Input, frames) -> Message | None:
        st = inp.stats
        try:
            msg = self._decode(inp, frames)
        except WireError as exc:
            self._malformed(inp, exc)
            return None
        if msg is None:
            st.dropped_overwritten += 1
            return None
        last = inp.last_seq
        if last is not None:
            gap = msg.seq - last - 1
            if gap < 0:
                st.seq_resets += 1
            elif gap > MAX_SEQ_GAP:
                st.seq_jumps += 1
            else:
                st.dropped_gap += gap
        inp.last_seq = msg.seq
        msg.input = inp.name
        return msg

    def _malformed(self, inp: _Input, exc: WireError) -> None:
        st = inp.stats
        st.malformed += 1
        n = _count_kind(st.malformed_kinds, exc.kind)
        if _worth_logging(n):
            log.warning("input %r: malformed message dropped (%s, %d of this kind, %d in "
                        "all): %s", inp.name, exc.kind, n, st.malformed, exc)

    def _dispatch(self, inp: _Input, msg: Message, arrival: tuple) -> bool:
        """Run the handler eagerly; False if it suspended and continues as a task.

        ``arrival`` = (slept_ns, woke_ns, taken_ns): the loop iteration's select() entry
        and return, and when this message was taken off the socket; telemetry only.
        """
        msg.recv_ns = start = now_ns()
        coro = inp.handler(msg)
        try:
            yielded = coro.send(None)
        except StopIteration:
            self._handled(inp, msg, start, None, arrival)
            return True
        except Exception as exc:
            self._handled(inp, msg, start, exc, arrival)
            return True
        task = asyncio.ensure_future(_continue(coro, yielded))
        inp.busy = task
        task.add_done_callback(lambda t: self._resume(inp, msg, start, t, arrival))
        return False

    def _resume(self, inp: _Input, msg: Message, start: int, task: asyncio.Task,
                arrival: tuple) -> None:
        inp.busy = None
        exc = None if task.cancelled() else task.exception()
        self._handled(inp, msg, start, exc, arrival)
        if not self.stopping.is_set():
            asyncio.get_running_loop().call_soon(self.drain, inp)

    def _handled(self, inp: _Input, msg: Message, start: int, exc: BaseException | None,
                 arrival: tuple) -> None:
        end = now_ns()
        st = inp.stats
        st.handled += 1
        if exc is not None:
            st.errors += 1
            n = _count_kind(st.error_kinds, type(exc).__name__)
            if _worth_logging(n):
                log.error("handler on_%s failed on %s seq %d (%s, %d of this kind, %d in "
                          "all)", inp.name, msg.topic, msg.seq, type(exc).__name__, n,
                          st.errors, exc_info=exc if n == 1 else None)
        inp.handler_ns.append(end - start)
        if msg.shm_locs and not all(self.reader.still_valid(l[0], l[1], l[3])
                                    for l in msg.shm_locs.values()):
            st.torn += 1
        if len(self.records) < TELEMETRY_MAX_RECORDS:
            # the record layout is the profiler's (profiler.RECORD_FIELDS)
            self.records.append([inp.name, msg.topic, msg.seq, msg.tick, msg.t_sim,
                                 msg.stamps, start, end, *arrival])
        else:
            self.records_skipped += 1

    def take_records(self) -> list:
        """The records since the last call (telemetry sends each batch once)."""
        records, self.records = self.records, []
        return records

    def stats(self) -> dict:
        inputs = {}
        for name, inp in self.ports.items():
            d = {k: dict(v) if isinstance(v, dict) else v for k, v in vars(inp.stats).items()}
            d["handler_us"] = summarize(inp.handler_ns, 1e-3)
            inputs[name] = d
        return inputs

    def drops(self) -> dict:
        return {n: vars(i.stats) for n, i in self.ports.items()}

    def stop_reading(self) -> None:
        loop = asyncio.get_running_loop()
        for inp in self.ports.values():
            loop.remove_reader(inp.socket.FD)
            if inp.monitor is not None:
                loop.remove_reader(inp.monitor.FD)

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
            if inp.monitor is not None:
                inp.socket.disable_monitor()
                inp.monitor.close(linger=0)
            inp.socket.close(linger=0)


def _count_kind(counts: dict, kind: str) -> int:
    """Count one more of ``kind``; past MAX_KINDS distinct kinds the rest share "other"."""
    if kind not in counts and len(counts) >= MAX_KINDS:
        kind = "other"
    counts[kind] = n = counts.get(kind, 0) + 1
    return n


def _worth_logging(n: int) -> bool:
    """The first three of a kind, then the 10th, 100th, 1000th...: a flood stays a trickle."""
    digits = str(n)
    return n <= 3 or digits == "1" + "0" * (len(digits) - 1)


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
