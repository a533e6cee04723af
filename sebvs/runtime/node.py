"""The process side of an actor: sockets, rings, stamps, control, telemetry.

One ``Node`` per actor process. It binds an XPUB per output (XPUB, so it can count the
subscriptions that reached it before declaring itself ready: no slow-joiner loss), a SUB
per input, a ROUTER for control and an XPUB for telemetry (records are packed and sent
only while someone is subscribed). The inputs (``inputs.py``) and the outputs
(``outputs.py``) are each an object of their own; the Node composes them.
"""
from __future__ import annotations

import asyncio
import hmac
import logging
import os
import signal
from typing import Any

import msgpack
import numpy as np
import zmq
import zmq.asyncio

from . import curve
from .clock import now_ns
from .inputs import TELEMETRY_MAX_RECORDS, InputStats, Inputs
from .outputs import Outputs, count_subscriptions
from .params import clip, params_to_dict

__all__ = ["Node", "InputStats"]

TELEMETRY_PERIOD_S = 0.1
MAX_CONTROL_BYTES = 1 << 20     # a control request is a few keys; ZeroMQ drops a bigger one
MAX_ERROR_CHARS = 500           # an error reply names the problem, it does not echo the input

log = logging.getLogger("sebvs.node")


class Node:
    def __init__(self, spec: dict, actor_factory, ctx: zmq.asyncio.Context | None = None):
        """``ctx``: a context shared with the other Nodes of a process group (runtime/group.py),
        so their inproc endpoints reach each other; the group owns it, and it also
        installs the signal handlers. None: this Node's own, as in a process of its own."""
        self.spec = spec
        self.name = spec["name"]
        self.token = spec.get("token")    # None: a Node built without a supervisor (tools)
        self.owns_ctx = ctx is None
        self.ctx = zmq.asyncio.Context() if ctx is None else ctx   # control (not latency critical)
        self.sync_ctx = zmq.Context.shadow(self.ctx.underlying)  # data paths: no futures
        self.outputs = Outputs(self.name)
        self.inputs = Inputs()
        # the actor calls these once per sample: bound here, they reach Outputs with no
        # extra call in between
        self.reserve = self.outputs.reserve
        self.emit = self.outputs.emit
        self.started = asyncio.Event()
        self.ready = False      # told the supervisor so (a remote host's primary asks `ping`)
        self.finished_reason: str | None = None
        self.events: list = []
        self.telemetry_subscribers = 0
        self._served: set[str] = set()     # endpoints of our server sockets
        self.actor = actor_factory(self)
        self.tasks: list[asyncio.Task] = []

    # ------------------------------------------------------------------ sockets
    def _bind_sockets(self) -> None:
        spec = self.spec
        self.outputs.bind(spec["outputs"], self.sync_ctx, self.token)
        self.inputs.connect(spec["inputs"], self.sync_ctx, self.actor, spec["run_id"],
                            self.token)
        self.control = self.ctx.socket(zmq.ROUTER)
        self.control.setsockopt(zmq.LINGER, 0)
        self.control.setsockopt(zmq.MAXMSGSIZE, MAX_CONTROL_BYTES)
        curve.serve(self.control, spec["control"], self.token)
        self.control.bind(spec["control"])
        self.telemetry_socket = self.sync_ctx.socket(zmq.XPUB)
        self.telemetry_socket.setsockopt(zmq.XPUB_VERBOSE, 1)
        self.telemetry_socket.setsockopt(zmq.SNDHWM, 64)
        self.telemetry_socket.setsockopt(zmq.LINGER, 0)
        curve.serve(self.telemetry_socket, spec["telemetry"], self.token)
        self.telemetry_socket.bind(spec["telemetry"])
        self._served = {spec["control"], spec["telemetry"]} | {
            ep for o in spec["outputs"].values() for ep in (o["endpoint"], o.get("remote"))
            if ep}

    def _watch_subscriptions(self) -> None:
        self.outputs.watch_subscriptions()
        asyncio.get_running_loop().add_reader(self.telemetry_socket.FD,
                                              self._drain_telemetry_subscriptions)
        self._drain_telemetry_subscriptions()

    def _drain_telemetry_subscriptions(self) -> None:
        self.telemetry_subscribers = count_subscriptions(self.telemetry_socket,
                                                         self.telemetry_subscribers)

    # ------------------------------------------------------------------ control
    def stats(self) -> dict:
        stats = {"actor": self.name, "pid": os.getpid(), "started": self.started.is_set(),
                 "inputs": self.inputs.stats(), "outputs": self.outputs.stats(),
                 "actor_stats": self.actor.stats()}
        # clients that offered a key not of this run, on this actor's own endpoints (a
        # group's context serves its other members' too)
        refused = {ep: n for ep, n in curve.refused(self.ctx).items() if ep in self._served}
        if refused:
            stats["refused_clients"] = refused
        return stats

    async def _handle_control(self, req: Any) -> dict:
        if not isinstance(req, dict) or not isinstance(req.get("cmd"), str):
            raise ValueError("a control request is a map with a 'cmd' string")
        if self.token is not None and not (
                isinstance(req.get("token"), str)
                and hmac.compare_digest(req["token"].encode(), self.token.encode())):
            raise PermissionError("control requests carry the run's token (run.json 'token')")
        cmd = req["cmd"]
        if cmd == "ping":
            return {"actor": self.name, "started": self.started.is_set(), "ready": self.ready,
                    "host": self.spec.get("host"), "topology": self.spec.get("topology_digest")}
        if cmd == "clock":      # clocksync.py: the stamp clock, read as late as possible
            return {"t_ns": now_ns()}
        if cmd == "start":
            self.started.set()
            return {"started_ns": now_ns()}
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
            self.event("set", {"key": req["key"][:100], "result": result})
            return result
        raise ValueError(f"unknown command {cmd!r} (get, set, stats, stop, ping, clock)")

    async def _serve_control(self) -> None:
        while True:
            frames = await self.control.recv_multipart()
            ident, payload = frames[0], frames[-1]
            try:
                req = msgpack.unpackb(payload, raw=False)
                reply = {"ok": True, "result": await self._handle_control(req)}
            except Exception as exc:  # a bad request is answered, never fatal
                reply = {"ok": False,
                         "error": clip(f"{type(exc).__name__}: {exc}", MAX_ERROR_CHARS)}
            try:
                body = msgpack.packb(reply, use_bin_type=True, default=_to_builtin)
            except Exception as exc:
                body = msgpack.packb({"ok": False, "error": f"unencodable reply: {exc}"})
            await self.control.send_multipart([ident, body])

    # ------------------------------------------------------------------ telemetry
    def event(self, kind: str, fields: dict) -> None:
        if len(self.events) < TELEMETRY_MAX_RECORDS:
            self.events.append([kind, now_ns(), fields])

    async def _publish_telemetry(self) -> None:
        while True:
            await asyncio.sleep(TELEMETRY_PERIOD_S)
            self._flush_telemetry()

    def _flush_telemetry(self) -> None:
        records = self.inputs.take_records()
        events, self.events = self.events, []
        if self.telemetry_subscribers <= 0:
            return  # nobody listens: packing would be wasted work
        payload = {"actor": self.name, "t_ns": now_ns(), "records": records,
                   "events": events, "skipped": self.inputs.records_skipped,
                   "drops": self.inputs.drops()}
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
        if self.owns_ctx:   # alone in its process; a group stops all its members itself
            for sig in (signal.SIGTERM, signal.SIGINT):
                loop.add_signal_handler(sig, self.finish, f"signal {sig.name}")
        self._bind_sockets()
        control_task = asyncio.create_task(self._serve_control())
        self.tasks.append(control_task)
        # A signal or a stop request sets `stopping` at any time, so the start's long steps
        # give way to it: an actor whose supervisor died mid-start (the kernel's parent-death
        # SIGTERM) ends now, not once its setup and its consumers' subscriptions are done.
        set_up = await self._unless_stopping(self.actor.setup())
        if set_up and await self._unless_stopping(
                self.outputs.await_subscribers(ready_timeout_s)):
            self._watch_subscriptions()
            if supervisor_endpoint:
                await self._say_ready(supervisor_endpoint)
            else:
                self.started.set()
        await self._unless_stopping(self.started.wait())
        if not self.actor.stopping.is_set():
            self.inputs.start()
            self.tasks.append(asyncio.create_task(self._publish_telemetry()))
            runner = getattr(self.actor, "run", None)
            if runner is not None:
                self.tasks.append(asyncio.create_task(self._run_source(runner)))
            await self.actor.stopping.wait()
        return await self._shutdown(set_up)

    async def _unless_stopping(self, step) -> bool:
        """Await the coroutine ``step`` unless the actor is told to stop first; then cancel
        it. True when ``step`` finished (its exceptions propagate)."""
        task = asyncio.ensure_future(step)
        stop = asyncio.create_task(self.actor.stopping.wait())
        try:
            await asyncio.wait([task, stop], return_when=asyncio.FIRST_COMPLETED)
        finally:
            stop.cancel()
            if not task.done():
                task.cancel()
                await asyncio.gather(task, return_exceptions=True)
        if task.cancelled():
            return False
        task.result()
        return True

    async def _say_ready(self, endpoint: str) -> None:
        push = self.ctx.socket(zmq.PUSH)
        push.setsockopt(zmq.LINGER, 1000)
        curve.client(push, endpoint, self.token)
        push.connect(endpoint)
        # queued at once (ZMQ_IMMEDIATE is off), even for a supervisor that is gone
        await push.send(msgpack.packb({"event": "ready", "actor": self.name,
                                       "pid": os.getpid()}))
        push.close()
        self.ready = True

    async def _run_source(self, runner) -> None:
        try:
            await runner()
        except asyncio.CancelledError:
            raise
        except Exception as exc:
            log.exception("run() of actor %r failed", self.name)
            self.finish(clip(f"run() raised {type(exc).__name__}: {exc}", MAX_ERROR_CHARS))
            self.exit_code = 1
            return
        self.event("source_done", {})

    async def _shutdown(self, set_up: bool) -> int:
        self.inputs.stop_reading()
        self.outputs.stop_watching()
        asyncio.get_running_loop().remove_reader(self.telemetry_socket.FD)
        await self.inputs.cancel_handlers()
        for task in self.tasks:
            if task is not self.tasks[0]:  # control stays up to answer the stop request
                task.cancel()
        await asyncio.gather(*self.tasks[1:], return_exceptions=True)
        if set_up:  # a setup cut short by a stop cleans up after itself (CancelledError)
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
        # the shadow context's sockets are closed first: term() below would wait on them
        self.outputs.close()
        self.inputs.close()
        self.telemetry_socket.close(linger=0)
        if self.owns_ctx:
            self.ctx.destroy(linger=0)
        else:       # the group's context: its other members still use it
            self.control.close(linger=0)


def _to_builtin(obj):
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (set, frozenset, tuple)):
        return list(obj)
    raise TypeError(f"cannot encode {type(obj).__name__}")
