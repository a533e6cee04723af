"""The output side of a Node: an XPUB socket and a shared-memory ring per output, and the
publishing of samples on them.

An output consumed on its own host and on another (a multi-host topology) has two
sockets, decided per edge by the supervisor: the host's consumers read the ring through
``endpoint``, the other host's get the same sample with its arrays inline on ``remote``
(tcp). Either consumer sees the same header but for where the arrays are."""
from __future__ import annotations

import asyncio
import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
import zmq

from .clock import now_ns
from . import curve
from .shm import RingWriter, packed_offsets
from .wire import dtype_to_wire, encode_header

SHM_MIN_BYTES = 64 * 1024        # smaller arrays go inline: a copy is cheaper than the bookkeeping
_SEND_MORE = zmq.SNDMORE | zmq.NOBLOCK


@dataclass
class _Output:
    name: str
    topic: bytes
    socket: Any
    ring: RingWriter | None
    subscribers_expected: int
    remote: Any = None              # XPUB for the consumers on other hosts: arrays inline
    remote_expected: int = 0
    subscribers: int = 0
    remote_subscribers: int = 0
    seq: int = 0
    pending: tuple | None = None    # (slot, arrays dict, descriptors) of a reservation


class Outputs:
    """An actor's outputs: their sockets, rings, subscriber counts and sequence numbers."""

    def __init__(self, actor_name: str) -> None:
        self.name = actor_name
        self.ports: dict[str, _Output] = {}

    def bind(self, specs: dict, ctx: zmq.Context, token: str | None = None) -> None:
        """Bind every output; tcp endpoints as CURVE servers keyed by the run's token."""
        for out, o in specs.items():
            sock = _xpub(ctx, o["hwm"], o["endpoint"], token)
            if o.get("inproc"):   # consumers in this process (a process group) connect here
                sock.bind(o["inproc"])
            remote = _xpub(ctx, o["hwm"], o["remote"], token) if o.get("remote") else None
            ring = RingWriter(o["ring"], o["slots"]) if o.get("ring") else None
            self.ports[out] = _Output(out, f"{self.name}/{out}".encode(), sock, ring,
                                      o["subscribers"], remote,
                                      o.get("remote_subscribers", 0) if remote else 0)

    # ------------------------------------------------------------------ subscriptions
    async def await_subscribers(self, timeout_s: float) -> None:
        """Ready only once every consumer's subscription has reached our XPUB sockets."""
        deadline = time.monotonic() + timeout_s
        for out in self.ports.values():
            while (out.subscribers < out.subscribers_expected
                   or out.remote_subscribers < out.remote_expected):
                self.drain_subscriptions(out)
                if (out.subscribers >= out.subscribers_expected
                        and out.remote_subscribers >= out.remote_expected):
                    break
                if time.monotonic() > deadline:
                    far = (f", {out.remote_subscribers}/{out.remote_expected} on other hosts"
                           if out.remote is not None or out.remote_expected else "")
                    raise TimeoutError(
                        f"output {out.name!r}: {out.subscribers}/{out.subscribers_expected} "
                        f"consumers subscribed{far} after {timeout_s:.0f} s")
                await asyncio.sleep(0.005)

    def drain_subscriptions(self, out: _Output) -> None:
        out.subscribers = count_subscriptions(out.socket, out.subscribers)
        if out.remote is not None:
            out.remote_subscribers = count_subscriptions(out.remote, out.remote_subscribers)

    def watch_subscriptions(self) -> None:
        loop = asyncio.get_running_loop()
        for out in self.ports.values():
            for sock in (out.socket, out.remote):
                if sock is not None:
                    loop.add_reader(sock.FD, self.drain_subscriptions, out)
            self.drain_subscriptions(out)

    def stop_watching(self) -> None:
        loop = asyncio.get_running_loop()
        for out in self.ports.values():
            for sock in (out.socket, out.remote):
                if sock is not None:
                    loop.remove_reader(sock.FD)

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
            return self.ports[output]
        except KeyError:
            raise ValueError(f"actor {self.name!r} has no output {output!r} "
                             f"(declared: {', '.join(self.ports) or 'none'})") from None

    def emit(self, output, arrays, *, meta=None, t_sim=None, tick=None, parent=None) -> None:
        send_ns = now_ns()
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
                    _inline(name, a, descs, buffers)
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
        _send(out.socket, out.topic, header, buffers)
        if out.remote is not None and out.remote_subscribers:
            descs, buffers = [], []
            for name, a in arrays.items():
                _inline(name, a, descs, buffers)
            header = encode_header(source=self.name, output=output, seq=out.seq, t_sim=t_sim,
                                   tick=tick, stamps=stamps, arrays=descs, meta=meta)
            _send(out.remote, out.topic, header, buffers)
        out.seq += 1

    def stats(self) -> dict:
        return {n: {"sent": o.seq, "subscribers": o.subscribers,
                    **({"remote_subscribers": o.remote_subscribers} if o.remote else {})}
                for n, o in self.ports.items()}

    def close(self) -> None:
        """Unlink our rings and close the sockets."""
        for out in self.ports.values():
            if out.ring is not None:
                out.ring.close(unlink=True)
            out.socket.close(linger=0)
            if out.remote is not None:
                out.remote.close(linger=0)


def _inline(name: str, a, descs: list, buffers: list) -> None:
    """Describe ``a`` as an inline array and queue its bytes as a frame of their own."""
    a = np.ascontiguousarray(a)
    descs.append([name, dtype_to_wire(a.dtype), list(a.shape), None])
    buffers.append(a.data.cast("B") if a.nbytes else b"")  # len() = bytes


def _xpub(ctx: zmq.Context, hwm: int, endpoint: str, token: str | None = None):
    # XPUB rather than PUB: it tells us of each subscription, so we can wait for them
    sock = ctx.socket(zmq.XPUB)
    sock.setsockopt(zmq.XPUB_VERBOSE, 1)
    sock.setsockopt(zmq.SNDHWM, hwm)
    sock.setsockopt(zmq.LINGER, 0)
    curve.serve(sock, endpoint, token)
    sock.bind(endpoint)
    return sock


def _send(sock, topic: bytes, header: bytes, buffers: list) -> None:
    """Frame by frame rather than send_multipart, whose per-frame checks cost more than
    the sends themselves. PUB never blocks: at the high-water mark ZeroMQ drops the
    message and the receiver counts the gap."""
    sock.send(topic, _SEND_MORE)
    sock.send(header, _SEND_MORE if buffers else zmq.NOBLOCK)
    for i, buf in enumerate(buffers, 1):
        # zero-copy only pays for large buffers: ZeroMQ must track their release
        sock.send(buf, _SEND_MORE if i < len(buffers) else zmq.NOBLOCK,
                  copy=len(buf) < SHM_MIN_BYTES)


def count_subscriptions(sock, count: int) -> int:
    """``count`` after the (un)subscriptions queued on an XPUB socket (read off it here)."""
    while True:
        try:
            frame = sock.recv(zmq.NOBLOCK)
        except zmq.Again:
            return count
        delta = 1 if frame[:1] == b"\x01" else -1 if frame[:1] == b"\x00" else 0
        count = max(0, count + delta)
