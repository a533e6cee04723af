"""A process group: several actors in one OS process, one event loop, one ZeroMQ context.

A topology puts actors together with ``process = "G"`` on each (or ``[topology] placement
= "auto"``, see ``Topology.processes``). The supervisor then writes one group spec
(``{"process": G, "members": [actor spec, ...], ...}``) and starts one worker for it,
which runs here: every member gets its own ``Node`` (its own sockets, rings, control
socket, telemetry, stamps: to the rest of the runtime it is the same actor as before), all
Nodes share the event loop and one context, so the supervisor's plan can wire edges
between members over ``inproc://`` (no I/O thread, no kernel socket, no process to wake).

Failure: a member whose handler raises is counted by its input and goes on, as alone. A
member whose ``setup()``, ``run()`` or ``teardown()`` fails ends the group: the others are
asked to stop, and before the process exits it writes ``<spec>.exit.json`` naming that
member, which the supervisor puts in its error and in run.json. A member that finishes
(exit code 0: a source that ran out, a recorder done) ends the group the same way, and so
the run. What cannot be put down to a member (a signal, ``os._exit``, a crash in C code)
is reported by the supervisor as the group's, with every member named.
"""
from __future__ import annotations

import asyncio
import json
import logging
import os
import signal
from pathlib import Path

import zmq
import zmq.asyncio

from .node import Node

# after the first member fails, how long the others get to stop before they are cancelled
# (one may still wait for a subscription the failed member will never make)
FAIL_GRACE_S = 1.0

log = logging.getLogger("sebvs.group")


class Group:
    """The members' Nodes and what ended the group."""

    def __init__(self, spec: dict, make_actor_for) -> None:
        """``make_actor_for(member_spec)`` -> the factory ``Node`` calls with itself."""
        self.name = spec["process"]
        self.spec = spec
        self.make_actor_for = make_actor_for
        self.outcome: dict | None = None   # {"actor", "code", "reason"} of the first to end
        self.nodes: list[Node] = []

    def _build(self) -> None:
        """A Node per member on the shared context, in the running loop."""
        self.ctx = zmq.asyncio.Context()
        for m in self.spec["members"]:
            try:   # an actor that cannot be imported or built is named like a failed one
                self.nodes.append(Node(m, self.make_actor_for(m), ctx=self.ctx))
            except Exception as exc:
                self.outcome = {"actor": m["name"], "code": 1,
                                "reason": f"{type(exc).__name__}: {exc}"}
                self.ctx.destroy(linger=0)
                raise

    def finish_all(self, reason: str) -> None:
        for node in self.nodes:
            node.finish(reason)

    async def run(self) -> int:
        self._build()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGTERM, signal.SIGINT):
            loop.add_signal_handler(sig, self.finish_all, f"signal {sig.name}")
        tasks = {asyncio.create_task(node.run(node.spec.get("supervisor"))): node
                 for node in self.nodes}
        pending = set(tasks)
        failed_at = None
        while pending:
            timeout = None if failed_at is None else \
                max(0.0, failed_at + FAIL_GRACE_S - loop.time())
            done, pending = await asyncio.wait(pending, timeout=timeout,
                                               return_when=asyncio.FIRST_COMPLETED)
            if not done:   # the grace after a failure is over
                for task in pending:
                    log.warning("actor %r did not stop in %.1f s; cancelled",
                                tasks[task].name, FAIL_GRACE_S)
                    task.cancel()
                await asyncio.gather(*pending, return_exceptions=True)
                break
            for task in done:
                code, reason = self._ended(tasks[task], task)
                if self.outcome is None or (code != 0 and self.outcome["code"] == 0):
                    self.outcome = {"actor": tasks[task].name, "code": code, "reason": reason}
                if code != 0 and failed_at is None:
                    failed_at = loop.time()
                # one member ending ends the group (a restart restarts all of it)
                self.finish_all(f"group member {tasks[task].name!r} ended")
        self.ctx.destroy(linger=0)
        return self.outcome["code"] if self.outcome else 0

    def _ended(self, node: Node, task: asyncio.Task) -> tuple[int, str]:
        """(exit code, reason) of one member's Node.run."""
        if task.cancelled():
            return 1, "cancelled"
        exc = task.exception()
        if exc is not None:
            log.error("actor %r failed", node.name, exc_info=exc)
            return 1, f"{type(exc).__name__}: {exc}"
        code = task.result()
        if code != 0:
            return code, node.finished_reason or f"exit code {code}"
        return 0, node.finished_reason or "finished"


def run_group(spec: dict, spec_path: str | Path, make_actor_for) -> int:
    """Run a group spec to its end; write who ended it next to the spec; the exit code."""
    group = Group(spec, make_actor_for)
    try:
        code = asyncio.run(group.run())
    finally:
        # written even when the loop itself died, so the supervisor can name the member
        if group.outcome is not None:
            write_outcome(Path(spec_path).with_suffix(".exit.json"), group.outcome)
    log.info("process group %s exits with %d (%s)", group.name, code, group.outcome)
    return code


def write_outcome(path: Path, outcome: dict) -> None:
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(outcome, default=str))
    os.replace(tmp, path)
