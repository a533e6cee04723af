"""Entry point of one actor process: ``python -m sebvs.runtime.worker SPEC.json``.

The supervisor writes the spec (actor class, parameters, endpoints, the run's token) and
starts this module with the actor's log file as stdout/stderr. A spec that says
``"remove_after_read"`` (every one the supervisor writes) is removed as soon as it is
read; the supervisor writes it again for a restart. A group spec (``"members"``: several
actor specs) runs all of them in this one process (``group.py``).
"""
from __future__ import annotations

import asyncio
import ctypes
import json
import logging
import os
import signal
import sys
import threading

from .params import build_params
from .topology import REALTIME_PRIORITY, import_actor_module

PR_SET_PDEATHSIG = 1


def _die_with_parent(parent_pid: int) -> None:
    """Ask the kernel to SIGTERM us if the supervisor dies, so no actor is orphaned."""
    try:
        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGTERM)
    except (OSError, AttributeError):
        pass
    if os.getppid() != parent_pid:  # it died before we asked
        os._exit(1)


def _threads() -> list[int]:
    try:
        return [int(t) for t in os.listdir("/proc/self/task")]
    except FileNotFoundError:
        return [0]


def pin_process(cpus: list[int]) -> None:
    """Pin every thread of this process to ``cpus``.

    Threads started at import (numpy's BLAS pool) are pinned one by one; the ones started
    later (ZeroMQ's I/O thread when the Node makes its context, torch's pool) inherit the
    main thread's affinity, which is why this runs before the Node exists.
    """
    for tid in _threads():
        try:
            os.sched_setaffinity(tid, cpus)
        except ProcessLookupError:
            pass  # a thread that ended meanwhile


def set_priority(priority: int | str) -> str | None:
    """Give every thread of this process ``priority`` (a nice value, or "realtime":
    SCHED_FIFO at topology.REALTIME_PRIORITY); threads started later inherit it, as with
    pin_process. Returns why it was not granted (the actor then runs at the default, with
    a warning in its log), or None."""
    for tid in _threads():
        try:
            if priority == "realtime":
                os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(REALTIME_PRIORITY))
            else:
                os.setpriority(os.PRIO_PROCESS, tid, int(priority))
        except ProcessLookupError:
            pass
        except (PermissionError, OSError, AttributeError) as exc:
            need = "CAP_SYS_NICE or `ulimit -r`" if priority == "realtime" else \
                "CAP_SYS_NICE or `ulimit -e`"
            return f"priority {priority!r} not granted ({exc}); needs {need}"
    return None


def realtime_refused() -> str | None:
    """Why this process may not give a thread SCHED_FIFO (None: it may), tried on a
    short-lived thread of its own so nothing else changes."""
    why: list[str | None] = [None]

    def probe() -> None:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(REALTIME_PRIORITY))
        except (PermissionError, OSError, AttributeError) as exc:
            why[0] = f"SCHED_FIFO not granted ({exc}); needs CAP_SYS_NICE or `ulimit -r`"

    t = threading.Thread(target=probe, name="sebvs-rt-probe")
    t.start()
    t.join()
    return why[0]


def load_class(path: str):
    module_name, _, cls_name = path.partition(":")
    return getattr(import_actor_module(module_name), cls_name)   # as the topology loader


def actor_factory(spec: dict):
    """The function a Node calls with itself to build the actor of ``spec``."""
    cls = load_class(spec["run"])
    params = build_params(cls.Params, spec["params"], where=f"actor {spec['name']!r}")

    def make_actor(node):
        return cls(spec["name"], params, seed=spec["seed"], clock=spec["clock"],
                   consumed=frozenset(spec["consumed"]), connected=frozenset(spec["inputs"]),
                   node=node)
    return make_actor


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    with open(argv[0]) as f:
        spec = json.load(f)
    if spec.get("remove_after_read"):
        try:
            os.unlink(argv[0])
        except FileNotFoundError:
            pass
    _die_with_parent(spec["supervisor_pid"])
    label = spec["process"] if "members" in spec else spec["name"]
    logging.basicConfig(level=getattr(logging, spec.get("log_level", "INFO")),
                        format=f"%(asctime)s {label} %(levelname)s %(name)s: %(message)s",
                        stream=sys.stderr)
    from .node import Node  # after logging is configured
    if spec.get("cpus"):
        pin_process(spec["cpus"])
    if spec.get("priority") is not None:
        refused = set_priority(spec["priority"])
        if refused:     # a topology written for another machine still runs here
            logging.getLogger("sebvs.worker").warning("%s: %s", label, refused)
    if "members" in spec:
        from .group import run_group
        return run_group(spec, argv[0], actor_factory)

    make_actor = actor_factory(spec)

    async def amain() -> int:
        node = Node(spec, make_actor)
        return await node.run(spec.get("supervisor"))

    code = asyncio.run(amain())
    logging.getLogger("sebvs.worker").info("actor %s exits with %d", spec["name"], code)
    return code


if __name__ == "__main__":
    sys.exit(main())
