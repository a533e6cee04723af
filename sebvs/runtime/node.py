"""The process side of an actor: sockets, rings, stamps, control, telemetry.

One ``Node`` per actor process. It binds an XPUB per output (XPUB, so it can count the
subscriptions that reached it before declaring itself ready: no slow-joiner loss), a SUB
per input, a ROUTER for control and an XPUB for telemetry (records are packed and sent
only while someone is subscribed).
"""
from __future__ import annotations

import asyncio
import collections
import logging
import math
import os
import signal
import time
import types
from dataclasses import dataclass, field
from typing import Any

import msgpack
import numpy as np
import zmq
import zmq.asyncio

from .params import params_to_dict
from .shm import RingReader, RingWriter, packed_offsets
from .stats import summarize
from .wire import (Message, WireError, array_spec, decode_header, dtype_to_wire,
                   encode_header)

SHM_MIN_BYTES = 64 * 1024        # smaller arrays go inline: a copy is cheaper than the bookkeeping
TELEMETRY_PERIOD_S = 0.1
TELEMETRY_MAX_RECORDS = 4096     # per period; beyond it records are counted, not kept
HANDLER_WINDOW = 2048            # handler times kept for `stats`
DRAIN_BATCH = 64                 # messages per reader callback before yielding to the loop
DRAIN_BUDGET_NS = 5_000_000      # ... or this much handler time, whichever comes first
_SEND_MORE = zmq.SNDMORE | zmq.NOBLOCK

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
class _Output:
    name: str
    topic: bytes
    socket: Any
    ring: RingWriter | None
    subscribers_expected: int
    subscribers: int = 0
    seq: int = 0
    pending: tuple | None = None    # (slot, arrays dict, descriptors) of a reservation


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


class Node:
    def __init__(self, spec: dict, actor_factory):
        self.spec = spec
        self.name = spec["name"]
        self.ctx = zmq.asyncio.Context()                  # control (not latency critical)
        self.sync_ctx = zmq.Context.shadow(self.ctx.underlying)  # data paths: no futures
        self.outputs: dict[str, _Output] = {}
        self.inputs: dict[str, _Input] = {}
        self.reader = RingReader()
        self.started = asyncio.Event()
        self.finished_reason: str | None = None
        self.records: list = []
        self.records_skipped = 0
        self.events: list = []
        self.telemetry_subscribers = 0
        self.malformed_logged = 0
        self.actor = actor_factory(self)
        self.tasks: list[asyncio.Task] = []

    # ------------------------------------------------------------------ sockets
    def _bind_sockets(self) -> None:
        spec = self.spec
        for out, o in spec["outputs"].items():
            sock = self.sync_ctx.socket(zmq.XPUB)
            sock.setsockopt(zmq.XPUB_VERBOSE, 1)
            sock.setsockopt(zmq.SNDHWM, o["hwm"])
            sock.setsockopt(zmq.LINGER, 0)
            sock.bind(o["endpoint"])
            ring = RingWriter(o["ring"], o["slots"]) if o.get("ring") else None
            self.outputs[out] = _Output(out, f"{self.name}/{out}".encode(), sock, ring,
                                        o["subscribers"])
        for inp, i in spec["inputs"].items():
            sock = self.sync_ctx.socket(zmq.SUB)
            sock.setsockopt(zmq.RCVHWM, i["hwm"])
            sock.setsockopt(zmq.LINGER, 0)
            sock.setsockopt(zmq.RECONNECT_IVL, 10)
            sock.setsockopt(zmq.SUBSCRIBE, i["topic"].encode())
            sock.connect(i["endpoint"])
            handler = getattr(self.actor, f"on_{inp}")
            self.inputs[inp] = _Input(inp, handler, sock, i["queue"] == "latest")
        self.control = self.ctx.socket(zmq.ROUTER)
        self.control.setsockopt(zmq.LINGER, 0)
        self.control.bind(spec["control"])
        self.telemetry_socket = self.sync_ctx.socket(zmq.XPUB)
        self.telemetry_socket.setsockopt(zmq.XPUB_VERBOSE, 1)
        self.telemetry_socket.setsockopt(zmq.SNDHWM, 64)
        self.telemetry_socket.setsockopt(zmq.LINGER, 0)
        self.telemetry_socket.bind(spec["telemetry"])

    async def _await_subscribers(self, timeout_s: float) -> None:
        """Ready only once every consumer's subscription has reached our XPUB sockets."""
        deadline = time.monotonic() + timeout_s
        for out in self.outputs.values():
            while out.subscribers < out.subscribers_expected:
                self._drain_subscriptions(out.socket, out)
                if out.subscribers >= out.subscribers_expected:
                    break
                if time.monotonic() > deadline:
                    raise TimeoutError(
                        f"output {out.name!r}: {out.subscribers}/{out.subscribers_expected} "
                        f"consumers subscribed after {timeout_s:.0f} s")
                await asyncio.sleep(0.005)

    def _drain_subscriptions(self, sock, out: _Output | None) -> None:
        """Count (un)subscriptions queued on an XPUB socket (telemetry when ``out`` is None)."""
        while True:
            try:
                frame = sock.recv(zmq.NOBLOCK)
            except zmq.Again:
                return
            delta = 1 if frame[:1] == b"\x01" else -1 if frame[:1] == b"\x00" else 0
            if out is None:
                self.telemetry_subscribers = max(0, self.telemetry_subscribers + delta)
            else:
                out.subscribers = max(0, out.subscribers + delta)

    def _watch_subscriptions(self) -> None:
        loop = asyncio.get_running_loop()
        for out in self.outputs.values():
            loop.add_reader(out.socket.FD, self._drain_subscriptions, out.socket, out)
            self._drain_subscriptions(out.socket, out)
        loop.add_reader(self.telemetry_socket.FD, self._drain_subscriptions,
                        self.telemetry_socket, None)
        self._drain_subscriptions(self.telemetry_socket, None)

    # ------------------------------------------------------------------ publishing
    def reserve(self, output: str, specs: dict[str, tuple]) -> dict[str, np.ndarray]:
        out = self._output(output)
        if out.ring is None:  # tcp: no shared memory; the arrays go inline at emit
            arrays = {n: np.empty(shape, dtype) for n, (shape, dtype) in specs.items()}
            out.pending = (None, arrays, None)
            return arrays
        layout = [(n, [int(d) for d in shape], np.dtype(dt)) for n, (shape, dt) in specs.items()]
        sizes = [math.prod(shape) * dt.itemsize for _, shape, dt in layout]
        offsets, total = packed_offsets(sizes)
        slot, view = out.ring.reserve(total)
        arrays, descs = {}, []
        for (n, shape, dt), off, size in zip(layout, offsets, sizes):
            arrays[n] = np.ndarray(shape, dt, buffer=view[off:off + size])
            # the descriptor is complete but for the generation, known at commit: built
            # here so that emit, which the hop's latency counts from, only fills that in
            descs.append([n, dtype_to_wire(dt), shape, [out.ring.name, slot, off, 0]])
        out.pending = (slot, arrays, descs)
        return arrays

    def _output(self, output: str) -> _Output:
        try:
            return self.outputs[output]
        except KeyError:
            raise ValueError(f"actor {self.name!r} has no output {output!r} "
                             f"(declared: {', '.join(self.outputs) or 'none'})") from None

    def emit(self, output, arrays, *, meta=None, t_sim=None, tick=None, parent=None) -> None:
        send_ns = time.monotonic_ns()
        out = self._output(output)
        arrays = arrays or {}
        descs, buffers = [], []
        pending, out.pending = out.pending, None
        reserved = pending is not None and pending[1] is arrays
        if reserved and pending[0] is not None:
            gen = out.ring.commit(pending[0])
            descs = pending[2]
            for desc in descs:
                desc[3][3] = gen
        else:
            to_ring = []
            for name, a in arrays.items():
                a = np.asarray(a)
                loc = parent.shm_locs.get(name) if parent is not None else None
                if loc is not None and out.ring is not None and parent.arrays.get(name) is a:
                    # forwarding an upstream slot untouched: pass its location on
                    descs.append([name, dtype_to_wire(a.dtype), list(a.shape), loc])
                elif out.ring is not None and a.nbytes >= SHM_MIN_BYTES:
                    to_ring.append((name, a))
                else:
                    a = np.ascontiguousarray(a)
                    descs.append([name, dtype_to_wire(a.dtype), list(a.shape), None])
                    buffers.append(a.data.cast("B") if a.nbytes else b"")  # len() = bytes
            if to_ring:
                offsets, total = packed_offsets([a.nbytes for _, a in to_ring])
                slot, view = out.ring.reserve(total)
                for (name, a), off in zip(to_ring, offsets):
                    np.ndarray(a.shape, a.dtype, buffer=view[off:off + a.nbytes])[...] = a
                gen = out.ring.commit(slot)
                for (name, a), off in zip(to_ring, offsets):
                    descs.append([name, dtype_to_wire(a.dtype), list(a.shape),
                                  [out.ring.name, slot, off, gen]])
        if parent is not None:
            stamps = parent.stamps + [[self.name, parent.recv_ns, send_ns]]
            if t_sim is None:
                t_sim = parent.t_sim
            if tick is None:
                tick = parent.tick
            if meta is None:
                meta = parent.meta
        else:
            stamps = [[self.name, 0, send_ns]]
        header = encode_header(source=self.name, output=output, seq=out.seq, t_sim=t_sim,
                               tick=tick, stamps=stamps, arrays=descs, meta=meta)
        out.seq += 1
        # Frame by frame rather than send_multipart, whose per-frame checks cost more than
        # the sends themselves. PUB never blocks: at the high-water mark ZeroMQ drops the
        # message and the receiver counts the gap.
        sock = out.socket
        sock.send(out.topic, _SEND_MORE)
        sock.send(header, _SEND_MORE if buffers else zmq.NOBLOCK)
        for i, buf in enumerate(buffers, 1):
            # zero-copy only pays for large buffers: ZeroMQ must track their release
            sock.send(buf, _SEND_MORE if i < len(buffers) else zmq.NOBLOCK,
                      copy=len(buf) < SHM_MIN_BYTES)

    # ------------------------------------------------------------------ receiving
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

    def _start_input(self, inp: _Input) -> None:
        loop = asyncio.get_running_loop()
        loop.add_reader(inp.socket.FD, self._drain, inp)
        loop.call_soon(self._drain, inp)  # the FD is edge-triggered: read what is queued

    def _drain(self, inp: _Input) -> None:
        """Read and dispatch queued messages straight from the event loop's reader callback.

        Handlers start eagerly, without a task or future per message: most finish without
        suspending. One that suspends continues as a task, and this input waits for it, so
        each input's messages are handled in order. At most DRAIN_BATCH messages per call,
        (or DRAIN_BUDGET_NS) per call, so one busy input cannot starve the others or the
        control socket.
        """
        if inp.busy is not None or self.actor.stopping.is_set():
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
        asyncio.get_running_loop().call_soon(self._drain, inp)

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
        if not self.actor.stopping.is_set():
            asyncio.get_running_loop().call_soon(self._drain, inp)

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

    # ------------------------------------------------------------------ control
    def stats(self) -> dict:
        inputs = {}
        for name, inp in self.inputs.items():
            d = dict(vars(inp.stats))
            d["handler_us"] = summarize(inp.handler_ns, 1e-3)
            inputs[name] = d
        return {"actor": self.name, "pid": os.getpid(), "started": self.started.is_set(),
                "inputs": inputs,
                "outputs": {n: {"sent": o.seq, "subscribers": o.subscribers}
                            for n, o in self.outputs.items()},
                "actor_stats": self.actor.stats()}

    async def _handle_control(self, req: Any) -> dict:
        if not isinstance(req, dict) or not isinstance(req.get("cmd"), str):
            raise ValueError("a control request is a map with a 'cmd' string")
        cmd = req["cmd"]
        if cmd == "ping":
            return {"actor": self.name, "started": self.started.is_set()}
        if cmd == "start":
            self.started.set()
            return {"started_ns": time.monotonic_ns()}
        if cmd == "stop":
            self.finish("stop requested")
            return {"stopping": True}
        if cmd == "stats":
            return self.stats()
        if cmd == "get":
            params = params_to_dict(self.actor.params)
            key = req.get("key")
            if key is None:
                return params
            if key not in params:
                raise ValueError(f"unknown key {key!r} (known: {', '.join(sorted(params))})")
            return {key: params[key]}
        if cmd == "set":
            if not isinstance(req.get("key"), str) or "value" not in req:
                raise ValueError("'set' needs 'key' and 'value'")
            result = await self.actor.control(req["key"], req["value"])
            self.event("set", {"key": req["key"], "value": req["value"], "result": result})
            return result
        raise ValueError(f"unknown command {cmd!r} (get, set, stats, stop, ping)")

    async def _serve_control(self) -> None:
        while True:
            frames = await self.control.recv_multipart()
            ident, payload = frames[0], frames[-1]
            try:
                req = msgpack.unpackb(payload, raw=False)
                reply = {"ok": True, "result": await self._handle_control(req)}
            except Exception as exc:  # a bad request is answered, never fatal
                reply = {"ok": False, "error": f"{type(exc).__name__}: {exc}"}
            try:
                body = msgpack.packb(reply, use_bin_type=True, default=_to_builtin)
            except Exception as exc:
                body = msgpack.packb({"ok": False, "error": f"unencodable reply: {exc}"})
            await self.control.send_multipart([ident, body])

    # ------------------------------------------------------------------ telemetry
    def event(self, kind: str, fields: dict) -> None:
        if len(self.events) < TELEMETRY_MAX_RECORDS:
            self.events.append([kind, time.monotonic_ns(), fields])

    async def _publish_telemetry(self) -> None:
        while True:
            await asyncio.sleep(TELEMETRY_PERIOD_S)
            self._flush_telemetry()

    def _flush_telemetry(self) -> None:
        records, self.records = self.records, []
        events, self.events = self.events, []
        if self.telemetry_subscribers <= 0:
            return  # nobody listens: packing would be wasted work
        payload = {"actor": self.name, "t_ns": time.monotonic_ns(), "records": records,
                   "events": events, "skipped": self.records_skipped,
                   "drops": {n: vars(i.stats) for n, i in self.inputs.items()}}
        try:
            body = msgpack.packb(payload, use_bin_type=True, default=_to_builtin)
            self.telemetry_socket.send_multipart([self.name.encode(), body],
                                                 flags=zmq.NOBLOCK)
        except (zmq.Again, TypeError, ValueError) as exc:
            log.debug("telemetry batch dropped: %s", exc)

    # ------------------------------------------------------------------ lifecycle
    def finish(self, reason: str) -> None:
        if self.finished_reason is None:
            self.finished_reason = reason or "finished"
        self.actor.stopping.set()
        self.actor._wake_sleepers()

    async def run(self, supervisor_endpoint: str | None, ready_timeout_s: float = 60) -> int:
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGTERM, signal.SIGINT):
            loop.add_signal_handler(sig, self.finish, f"signal {sig.name}")
        self._bind_sockets()
        control_task = asyncio.create_task(self._serve_control())
        self.tasks.append(control_task)
        await self.actor.setup()
        await self._await_subscribers(ready_timeout_s)
        self._watch_subscriptions()
        if supervisor_endpoint:
            push = self.ctx.socket(zmq.PUSH)
            push.setsockopt(zmq.LINGER, 1000)
            push.connect(supervisor_endpoint)
            await push.send(msgpack.packb({"event": "ready", "actor": self.name,
                                           "pid": os.getpid()}))
            push.close()
        else:
            self.started.set()
        start_wait = asyncio.create_task(self.started.wait())
        stop_wait = asyncio.create_task(self.actor.stopping.wait())
        await asyncio.wait([start_wait, stop_wait], return_when=asyncio.FIRST_COMPLETED)
        start_wait.cancel()
        stop_wait.cancel()
        if not self.actor.stopping.is_set():
            for inp in self.inputs.values():
                self._start_input(inp)
            self.tasks.append(asyncio.create_task(self._publish_telemetry()))
            runner = getattr(self.actor, "run", None)
            if runner is not None:
                self.tasks.append(asyncio.create_task(self._run_source(runner)))
            await self.actor.stopping.wait()
        return await self._shutdown()

    async def _run_source(self, runner) -> None:
        try:
            await runner()
        except asyncio.CancelledError:
            raise
        except Exception:
            log.exception("run() of actor %r failed", self.name)
            self.finish("run() raised")
            self.exit_code = 1
            return
        self.event("source_done", {})

    async def _shutdown(self) -> int:
        loop = asyncio.get_running_loop()
        for sock in [i.socket for i in self.inputs.values()] + \
                [o.socket for o in self.outputs.values()] + [self.telemetry_socket]:
            loop.remove_reader(sock.FD)
        busy = [i.busy for i in self.inputs.values() if i.busy is not None]
        for task in busy:
            task.cancel()
        await asyncio.gather(*busy, return_exceptions=True)
        for task in self.tasks:
            if task is not self.tasks[0]:  # control stays up to answer the stop request
                task.cancel()
        await asyncio.gather(*self.tasks[1:], return_exceptions=True)
        try:
            await asyncio.wait_for(self.actor.teardown(), 5)
        except Exception:
            log.exception("teardown of actor %r failed", self.name)
        self._flush_telemetry()
        await asyncio.sleep(0.01)  # let the reply to `stop` leave
        self.tasks[0].cancel()
        await asyncio.gather(self.tasks[0], return_exceptions=True)
        self.close()
        return getattr(self, "exit_code", 0)

    def close(self) -> None:
        """Unlink our rings, unmap the ones we read, close every socket: shutdown's last step."""
        for out in self.outputs.values():
            if out.ring is not None:
                out.ring.close(unlink=True)
        self.reader.close()
        for sock in [i.socket for i in self.inputs.values()] + \
                [o.socket for o in self.outputs.values()] + [self.telemetry_socket]:
            sock.close(linger=0)  # the shadow context's sockets: term() below would wait on them
        self.ctx.destroy(linger=0)


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


def _to_builtin(obj):
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (set, frozenset, tuple)):
        return list(obj)
    raise TypeError(f"cannot encode {type(obj).__name__}")
