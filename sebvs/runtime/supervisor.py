"""The supervisor: one process per actor (or per process group), a run directory, ready
handshake, clean stop.

    runs/<name>-<time>-<id>/run.json        endpoints, pids, status (rewritten atomically)
    runs/<name>-<time>-<id>/logs/<process>.log   (an isolated actor's process has its name;
                                            a group member's <actor>.log links to it)
    <tmp>/sebvs-<id>/                       ipc sockets, process specs (each removed by
                                            its worker once read); removed at the end

A topology with [hosts.<name>] tables runs one supervisor per host (``host=``): each
spawns its own host's actors; the first listed host's (the primary) also waits for the
other hosts' actors to be ready, starts them all, estimates each host's clock offset
(``clocksync.py``, refreshed during the run) and lists every actor in its run.json, so
`sebvs profile` attached to it sees the whole topology on one clock.

An actor that exits with code 0 has finished its job (a recorder that wrote its
episodes, a source that ran out): the run then ends. An actor that dies otherwise is
reported with its exit code and the end of its log, then restarted or the run stopped,
as the topology's ``restart`` says. Actors that share a process (``process = "G"``,
``runtime/group.py``) are restarted together; the group's worker names the member that
ended it in ``<process>.exit.json`` next to its spec before it exits.
"""
from __future__ import annotations

import json
import os
import secrets
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Callable

import msgpack
import zmq

from . import curve
from .clocksync import measure_offset
from .params import clip, short_repr
from .ports import TcpPorts
from .shm import ShmFull, check_budget, remove_run_rings, ring_bytes
from .stalls import STALL_PERIOD_S, StallWatch, format_losses, losses, query_all
from .topology import (Topology, TopologyError, check_cpus_available, load_topology,
                       message_sizes)
from .worker import realtime_refused

STOP_GRACE_S = 1.0      # after `stop`, before SIGTERM
TERM_GRACE_S = 0.5      # after SIGTERM, before SIGKILL
POLL_S = 0.05
MAX_RING_SLOTS = 256
LOG_TAIL_LINES = 20
TOKEN_ENV = "SEBVS_RUN_TOKEN"   # shared by the supervisors of a multi-host run
MIN_TOKEN_CHARS = 16
CLOCK_REFRESH_S = 5.0           # the primary re-estimates the other hosts' clock offsets
REMOTE_PING_S = 0.1             # a remote actor's answer to `ping`, while waiting for it


class RunFailed(RuntimeError):
    """An actor died (or never became ready) and the run was stopped."""


def runs_root(runs_dir: str | Path | None = None) -> Path:
    return Path(runs_dir or os.environ.get("SEBVS_RUNS_DIR", "runs"))


def run_directory(root: Path, name: str, suffix: str) -> Path:
    """``root/<name>-<suffix>``, refused unless it is a direct child of ``root``.

    The topology loader already restricts names; a Topology built in code is not
    loaded, so the check is here too.
    """
    root = root.resolve()
    rundir = (root / f"{name}-{suffix}").resolve()
    if rundir.parent != root:
        raise TopologyError(f"run name {short_repr(name)} would put the run directory "
                            f"outside {root}")
    return rundir


def socket_root() -> Path:
    return Path(tempfile.gettempdir())


def log_tail(path: Path, n: int = LOG_TAIL_LINES) -> str:
    try:
        lines = path.read_text(errors="replace").splitlines()
    except FileNotFoundError:
        return "(no log)"
    return "\n".join(lines[-n:])


def write_json_atomic(path: Path, data: dict) -> None:
    """Write, then rename over ``path``; readable by its owner only (run.json holds the
    run's control token)."""
    tmp = path.with_suffix(path.suffix + ".tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write(json.dumps(data, indent=2, default=str))
    os.replace(tmp, path)


@dataclass
class _Proc:
    """One OS process: an isolated actor (``members == [name]``, a plain actor spec) or a
    process group (a group spec listing its members' specs)."""
    name: str
    spec_path: Path
    log_path: Path
    spec_text: str = ""     # written at each spawn: the worker removes it once read
    members: list[str] = field(default_factory=list)
    grouped: bool = False
    popen: subprocess.Popen | None = None
    ready: bool = False
    ready_members: set = field(default_factory=set)
    restarts: int = 0
    exit_code: int | None = None

    @property
    def outcome_path(self) -> Path:
        """Where a group's worker says which member ended it (group.py writes it)."""
        return self.spec_path.with_suffix(".exit.json")

    def outcome(self) -> dict:
        """The group worker's account of its end: {"actor", "code", "reason"}, or {}."""
        try:
            data = json.loads(self.outcome_path.read_text())
        except (OSError, ValueError):
            return {}
        return data if isinstance(data, dict) and data.get("actor") in self.members else {}


class Supervisor:
    def __init__(self, topo: Topology, runs_dir: str | Path | None = None,
                 log_level: str = "INFO", echo: Callable[[str], None] | None = None,
                 host: str | None = None):
        """``host``: which of a multi-host topology's [hosts] this supervisor runs (required
        there, refused elsewhere)."""
        self.topo = topo
        self.host = _check_host(topo, host)
        self.primary = self.host is None or self.host == topo.primary
        self.echo = echo or (lambda text: print(text, file=sys.stderr, flush=True))
        self.run_id = secrets.token_hex(4)
        # every control request carries it: over tcp anyone who can reach a port could
        # otherwise query, reconfigure or stop an actor
        self.token = _run_token(topo, self.host, self.primary)
        stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
        self.rundir = run_directory(runs_root(runs_dir), topo.name, f"{stamp}-{self.run_id}")
        self.sockdir = socket_root() / f"sebvs-{self.run_id}"
        self.log_level = log_level
        self.ctx = zmq.Context()
        # the supervisor only asks: a request no actor took is dropped at close, never
        # waited for (a context collected with one pending would block its collector);
        # the default of every socket made here
        self.ctx.setsockopt(zmq.LINGER, 0)
        self.ports = TcpPorts(topo.host)        # a tcp run's endpoints, none twice
        self.procs: dict[str, _Proc] = {}       # by process name
        # other hosts' actors (the primary's alone lists them): their control endpoints
        self.remote: dict[str, str] = {}
        self._next_clock_refresh = 0.0
        self.proc_of: dict[str, _Proc] = {}     # by actor name
        self.info: dict = {}
        self.status = "new"
        self.failure: str | None = None
        self._interrupted: str | None = None
        self.last_stats: dict[str, dict] = {}   # each actor's last stats reply

    # ------------------------------------------------------------------ planning
    def _endpoint(self, stem: str) -> str:
        if self.topo.transport == "tcp":
            return f"tcp://{self.topo.host}:{self.ports.one()}"
        return f"ipc://{self.sockdir}/{stem}"

    def _is_local(self, actor: str) -> bool:
        return self.host is None or self.topo.actors[actor].host == self.host

    def _plan(self) -> dict[str, dict]:
        """The specs of this host's actors; ``self.endpoints`` has every active actor's
        control and telemetry endpoints (the other hosts' from their [hosts] ports)."""
        topo = self.topo
        active = topo.active
        processes = topo.processes()
        self.groups = {g: m for g, m in processes.items() if self._is_local(m[0])}
        process_of = {a: g for g, members in processes.items() for a in members}
        host_of = {n: a.host for n, a in active.items()}
        far_ports = _host_ports(topo)
        outputs = {}
        for a in active.values():
            for out in a.cls.outputs:
                consumers = topo.consumers(a.name, out)
                depth = max([i.queue for _, i in consumers if i.queue != "latest"] or [2])
                same = [c for c, _ in consumers if process_of[c] == process_of[a.name]]
                near = [c for c, _ in consumers if host_of[c] == host_of[a.name]]
                far = far_ports.get((a.name, out))  # consumed on another host: tcp, inline
                if not self._is_local(a.name):      # only its tcp endpoint matters here
                    outputs[(a.name, out)] = {"far": far}
                    continue
                local = bool(near) or far is None
                outputs[(a.name, out)] = {
                    # the host's own consumers: ipc and the ring; or, with none, the tcp one
                    "endpoint": self._endpoint(f"{a.name}.{out}") if local else far,
                    # consumers in the producer's own process connect here: ZeroMQ's
                    # inproc pipes, no I/O thread, no kernel socket (the shared context
                    # is the group's); the others connect to `endpoint`
                    "inproc": f"inproc://{a.name}.{out}" if same else None,
                    "ring": None if topo.transport == "tcp" or not local
                    else f"sebvs-{self.run_id}-{a.name}-{out}",
                    "slots": min(2 * depth + 4, MAX_RING_SLOTS),
                    "hwm": depth,
                    "subscribers": len(near) if local else len(consumers),
                    "remote": far if local and far is not None else None,
                    "remote_subscribers": len(consumers) - len(near) if local else 0,
                    "far": far,
                }
        self.supervisor_endpoint = self._endpoint("supervisor")
        self.endpoints = {
            n: {"control": far_ports.get((n, "ctl")) or self._endpoint(f"{n}.ctl"),
                "telemetry": far_ports.get((n, "tel")) or self._endpoint(f"{n}.tel")}
            for n in active if self.primary or self._is_local(n)}
        specs = {}
        for a in active.values():
            if not self._is_local(a.name):
                continue
            if a.cpus and self.host is not None:    # the loader left this to each host
                check_cpus_available(a.cpus, f"{topo.path}: [actors.{a.name}]")
            specs[a.name] = {
                "name": a.name, "run": a.run, "params": a.params, "cpus": list(a.cpus),
                "priority": a.priority,
                "seed": topo.actor_seed(a.name), "clock": topo.clock, "run_id": self.run_id,
                "consumed": [o for o in a.cls.outputs if topo.consumers(a.name, o)],
                "process": process_of[a.name],
                "inputs": {i.name: {"endpoint": _input_endpoint(
                                        outputs[(i.producer, i.output)],
                                        process_of[i.producer] == process_of[a.name],
                                        host_of[i.producer] == host_of[a.name]),
                                    "topic": f"{i.producer}/{i.output}", "queue": i.queue,
                                    "max_bytes": i.max_bytes,
                                    "hwm": 2 if i.queue == "latest" else i.queue}
                           for i in a.inputs.values()},
                "outputs": {o: {k: v for k, v in outputs[(a.name, o)].items() if k != "far"}
                            for o in a.cls.outputs},
                "control": self.endpoints[a.name]["control"],
                "token": self.token,
                "telemetry": self.endpoints[a.name]["telemetry"],
                "host": a.host, "topology_digest": self.topo.digest,
                "supervisor": self.supervisor_endpoint,
                "supervisor_pid": os.getpid(),
                "log_level": self.log_level,
            }
        return specs

    # ------------------------------------------------------------------ run.json
    def _write_info(self) -> None:
        self.info["status"] = self.status
        self.info["failure"] = self.failure
        for name, p in self.procs.items():
            for member in p.members:
                entry = self.info["actors"][member]
                entry["pid"] = p.popen.pid if p.popen else None
                entry["restarts"] = p.restarts
                entry["exit_code"] = p.exit_code
            self.info["processes"][name].update(pid=p.popen.pid if p.popen else None,
                                                restarts=p.restarts, exit_code=p.exit_code)
        write_json_atomic(self.rundir / "run.json", self.info)

    # ------------------------------------------------------------------ lifecycle
    def _start_local(self) -> None:
        """Start this host's actors: all at once (one round trip, not one per actor: 0.36 s
        of a worker's start-up at two workers here, tools/bench/bench_scale.py), the clock
        sources (actors with run()) after everything that reads them."""
        sources = [n for n in self.specs if hasattr(self.topo.actors[n].cls, "run")]
        for group in ([n for n in self.specs if n not in sources], sources):
            replies = query_all(self.ctx, {n: self.specs[n]["control"] for n in group},
                                {"cmd": "start", "token": self.token}, 2.0)
            for name in group:
                if not (replies.get(name) or {}).get("ok"):
                    self.request(name, {"cmd": "start"})    # busy: once more, waited for

    def _say_priority_refused(self) -> None:
        """One line when the actors that ask for SCHED_FIFO here will not get it (each
        actor's log says so too, but nobody reads those before the figures look wrong)."""
        wanted = [n for n, a in self.topo.active.items()
                  if a.priority == "realtime" and self._is_local(n)]
        why = realtime_refused() if wanted else None
        if why:
            source = "the loop's default" if all(self.topo.actors[n].loop_priority
                                                 for n in wanted) else "asked for"
            self.echo(f"sebvs: {', '.join(wanted)} run at the default priority, not "
                      f"realtime ({source}): {why}; docs/runtime.md, \"The loop's priority\"")

    def _check_ring_budget(self, specs: dict) -> None:
        """Every ring whose message size the topology tells, all at once against the free
        /dev/shm: refused here, in one line, rather than an actor dying at its first frame."""
        sizes = message_sizes(self.topo)
        rings = {f"{n}/{o}": ring_bytes(v["slots"], sizes[(n, o)])
                 for n, s in specs.items() for o, v in s["outputs"].items()
                 if v.get("ring") and (n, o) in sizes}
        try:
            check_budget(rings)
        except ShmFull as exc:
            raise RunFailed(exc.strerror) from None

    def start(self) -> None:
        """Spawn the actors, wait until each is ready, start the clock. A start that
        fails stops what it had started before it raises: a caller without a `stop()` in
        a `finally` leaks no actor, socket directory or zmq context."""
        try:
            self._start()
        except BaseException as exc:
            # run.json says why (an actor's death report is already there)
            self.failure = self.failure or f"start failed: {exc!r}"
            try:
                self.stop()
            except Exception as also:   # the start's error is the one to see
                exc.add_note(f"stopping what had started failed too: {also!r}")
            raise

    def _start(self) -> None:
        (self.rundir / "logs").mkdir(parents=True, exist_ok=True)
        self.sockdir.mkdir(mode=0o700, parents=True)
        (self.sockdir / "rundir").write_text(str(self.rundir))
        try:
            curve_on = curve.enabled()
        except ValueError as exc:
            raise RunFailed(str(exc)) from None
        specs = self._plan()
        self.specs = specs
        self._check_ring_budget(specs)
        self.pull = self.ctx.socket(zmq.PULL)
        # over tcp anyone could otherwise report an actor ready before it is
        curve.serve(self.pull, self.supervisor_endpoint, self.token)
        self.pull.bind(self.supervisor_endpoint)
        self.info = {
            "name": self.topo.name, "run_id": self.run_id, "topology": str(self.topo.path),
            "rundir": str(self.rundir), "sockdir": str(self.sockdir), "token": self.token,
            "curve": curve_on,
            "supervisor_pid": os.getpid(), "clock": self.topo.clock,
            "started_at": datetime.now().isoformat(timespec="seconds"),
            "pruned": [n for n, a in self.topo.actors.items() if a.pruned],
            "actors": {n: {"run": s["run"], "control": s["control"],
                           "telemetry": s["telemetry"], "consumed": s["consumed"],
                           "cpus": s["cpus"], "priority": s["priority"],
                           "process": s["process"],
                           "outputs": {o: v["endpoint"] for o, v in s["outputs"].items()},
                           "inputs": {i: v["topic"] for i, v in s["inputs"].items()},
                           "log": str(self.rundir / "logs" / f"{s['process']}.log")}
                       for n, s in specs.items()},
            # as written ("auto") and as resolved on this machine
            "placement": self.topo.placement,
            "placement_resolved": self.topo.resolved_placement(),
            "processes": {g: {"actors": members} for g, members in self.groups.items()},
        }
        if self.host is not None:
            self._describe_hosts(specs)
        self._say_priority_refused()
        if not self.info["curve"] and any(
                str(ep).startswith("tcp://") for s in specs.values()
                for ep in (s["control"], s["telemetry"])):
            self.echo("sebvs: SEBVS_CURVE=off: this run's tcp endpoints are unencrypted and "
                      "open to any process that can reach them")
        for name, members in self.groups.items():
            spec_path = self.sockdir / f"{name}.json"
            # an actor alone under its own name runs as before; anything else is a group
            grouped = members != [name]
            spec = {"process": name, "members": [specs[m] for m in members],
                    "cpus": specs[members[0]]["cpus"], "supervisor_pid": os.getpid(),
                    "priority": specs[members[0]]["priority"],
                    "log_level": self.log_level} if grouped else specs[name]
            # it holds the token: on disk only from its spawn until the worker has read it,
            # so a kill -9 of anything after the start leaves none behind
            spec = {**spec, "remove_after_read": True}
            self.procs[name] = p = _Proc(name, spec_path, self.rundir / "logs" / f"{name}.log",
                                         spec_text=json.dumps(spec),
                                         members=list(members), grouped=grouped)
            for m in members:
                self.proc_of[m] = p
                if m != name:   # logs/<actor>.log stays a name to read an actor's log by
                    (self.rundir / "logs" / f"{m}.log").symlink_to(f"{name}.log")
        self.status = "starting"
        # when the actors were started and when each said it was ready (unix seconds:
        # a pool's driver compares them with its own clock; tools/bench/bench_scale.py)
        self.info["spawned_at"] = time.time()
        self.info["ready_at"] = {}
        for p in self.procs.values():
            self._spawn(p)
        self._write_info()
        if self.remote:
            others = sorted({self.topo.actors[n].host for n in self.remote})
            token = ("the same SEBVS_RUN_TOKEN" if os.environ.get(TOKEN_ENV) else
                     f"SEBVS_RUN_TOKEN set to this run's ('token' in {self.rundir}/run.json)")
            self.echo(f"sebvs: waiting for host(s) {', '.join(others)}: start `sebvs run "
                      f"{self.topo.path} --host NAME` on each, with {token}")
        self._await_ready()
        if self.primary:
            self._refresh_offsets()
            self._start_local()
            if self.remote:
                query_all(self.ctx, self.remote, {"cmd": "start", "token": self.token}, 2.0)
        else:
            self.echo(f"sebvs: host {self.host!r} ready; the primary "
                      f"({self.topo.primary!r}) starts the clock")
        self.status = "running"
        self.info["clock_started_at"] = time.time()
        self.stalls = StallWatch({(a.name, i.name): (i.producer, i.output)
                                  for a in self.topo.active.values() if a.name in self.specs
                                  for i in a.inputs.values() if i.producer in self.specs})
        self._next_stall_check = time.monotonic() + STALL_PERIOD_S
        self._write_info()

    def _describe_hosts(self, specs: dict) -> None:
        """run.json of a multi-host run: each actor's host; the primary's also lists the
        other hosts' actors (their endpoints, for `ctl` and `profile`) and, per host, the
        clock offset it estimates (``_refresh_offsets``)."""
        self.remote = {n: e["control"] for n, e in self.endpoints.items() if n not in specs}
        for name, entry in self.info["actors"].items():
            entry["host"] = self.topo.actors[name].host
        for name in self.remote:
            a = self.topo.actors[name]
            self.info["actors"][name] = {
                "run": a.run, "host": a.host, **self.endpoints[name],
                "consumed": [o for o in a.cls.outputs if self.topo.consumers(name, o)],
                "inputs": {i: v.source for i, v in a.inputs.items()}}
        self.info["host"] = self.host
        self.info["primary"] = self.topo.primary
        self.info["topology_digest"] = self.topo.digest
        self.info["hosts"] = {
            h.name: {"address": h.address, "port": h.port,
                     # the primary's clock is the run's: offsets are the others' against it
                     "clock": {"offset_ns": 0, "uncertainty_ns": 0} if h.name == self.host
                     else None}
            for h in self.topo.hosts.values()
            if h.name == self.host or (self.primary and
                                       any(self.topo.actors[n].host == h.name
                                           for n in self.remote))}

    def _refresh_offsets(self) -> None:
        """Estimate every other host's clock offset (one actor of each answers; a host's
        processes share its clock) and write them into run.json."""
        if not self.remote:
            return
        if time.monotonic() < self._next_clock_refresh:
            return
        self._next_clock_refresh = time.monotonic() + CLOCK_REFRESH_S
        for host, entry in self.info["hosts"].items():
            if host == self.host:
                continue
            actors = [n for n in self.remote if self.topo.actors[n].host == host]
            measured = None
            for name in actors:     # the first that answers
                measured = measure_offset(self.ctx, self.remote[name], self.token)
                if measured is not None:
                    break
            if measured is None:
                self.echo(f"sebvs: host {host!r}: no actor answered the clock exchange; "
                          f"its offset stays {entry['clock']}")
                continue
            entry["clock"] = dict(measured.to_dict(), measured_at=datetime.now().isoformat(
                timespec="seconds"))
        self._write_info()

    def _query_stats(self, endpoints: dict[str, str]) -> dict[str, dict]:
        """`stats` of these actors at once ({actor: result} of those that answered), also
        kept as each one's last (`last_stats`)."""
        replies = query_all(self.ctx, endpoints, {"cmd": "stats", "token": self.token})
        stats = {n: r["result"] for n, r in replies.items()
                 if isinstance(r, dict) and r.get("ok")}
        self.last_stats.update(stats)
        return stats

    def _report_losses(self) -> None:
        """At the end of a run, one line per input that lost data (ring overwrites, gaps,
        malformed, ...), also in run.json ("losses"): the actors count them, but without a
        profiler attached nobody would see a lockstep run lose a frame. The live actors'
        last counters, else those of the last stall round (an actor that ended first)."""
        live = {n: s["control"] for n, s in getattr(self, "specs", {}).items()
                if self.proc_of.get(n) is not None and self.proc_of[n].popen is not None
                and self.proc_of[n].popen.poll() is None}
        if live:
            self._query_stats(live)
        found = losses(self.last_stats)
        for line in format_losses(found):
            self.echo(f"sebvs: {line}")
        if found:
            self.info["losses"] = found

    def _check_stalls(self) -> None:
        """Report inputs that receive nothing while their producers send (stalls.py)."""
        if time.monotonic() < self._next_stall_check or not self.stalls.producers:
            return
        self._next_stall_check = time.monotonic() + STALL_PERIOD_S
        found = self.stalls.update(
            self._query_stats({n: s["control"] for n, s in self.specs.items()}))
        for text in found:
            self.echo(f"sebvs: {text}")
        if found:
            self.info["stalled"] = sorted(f"{a}.{i}" for a, i in self.stalls.stalled)
            self._write_info()

    def _spawn(self, p: _Proc) -> None:
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        cwd = os.getcwd()
        env["PYTHONPATH"] = cwd + os.pathsep + env.get("PYTHONPATH", "") if \
            env.get("PYTHONPATH") else cwd  # users' own actor modules next to the topology
        p.outcome_path.unlink(missing_ok=True)     # a restarted group's previous account
        fd = os.open(p.spec_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        with os.fdopen(fd, "w") as f:
            f.write(p.spec_text)
        with open(p.log_path, "ab") as log:
            p.popen = subprocess.Popen([sys.executable, "-m", "sebvs.runtime.worker",
                                        str(p.spec_path)], stdout=log, stderr=subprocess.STDOUT,
                                       stdin=subprocess.DEVNULL, env=env,
                                       start_new_session=True)  # Ctrl-C reaches only us
        p.ready = False
        p.ready_members = set()
        p.exit_code = None

    def _await_ready(self) -> None:
        deadline = time.monotonic() + self.topo.ready_timeout_s
        waiting_remote = set(self.remote)
        while waiting_remote or not all(p.ready for p in self.procs.values()):
            if waiting_remote:
                waiting_remote -= self._remote_ready(waiting_remote)
            if self._interrupted:
                raise RunFailed(f"interrupted ({self._interrupted}) before all actors were ready")
            dead = self._reap()
            if dead:
                self.failure = self._death_report(dead[0], "before it was ready")
                self.info["failed_actor"] = self._failed_actor(dead[0])
                self.info["failed_process"] = dead[0].name
                raise RunFailed(self.failure)
            if time.monotonic() > deadline:
                waiting = [p.name for p in self.procs.values() if not p.ready]
                hosts = sorted({self.topo.actors[n].host for n in waiting_remote})
                far = (f"; on other hosts: {', '.join(sorted(waiting_remote))} (is "
                       f"`sebvs run {self.topo.path} --host NAME` running on "
                       f"{', '.join(hosts)}, with the same token?)" if waiting_remote else "")
                raise RunFailed(f"actors not ready after {self.topo.ready_timeout_s:.0f} s: "
                                f"{', '.join(waiting) or 'none here'}{far}")
            self._poll_ready(POLL_S)

    def _remote_ready(self, names: set) -> set:
        """The actors among ``names`` (other hosts') that answer `ping` as ready; a host
        running another topology, or refusing the token, ends the run with that said."""
        replies = query_all(self.ctx, {n: self.remote[n] for n in names},
                            {"cmd": "ping", "token": self.token}, REMOTE_PING_S)
        ready = set()
        for name, reply in replies.items():
            host = self.topo.actors[name].host
            if not isinstance(reply, dict):
                continue
            if not reply.get("ok"):
                if "PermissionError" in str(reply.get("error")):
                    raise RunFailed(f"host {host!r} refuses this run's token: start every "
                                    f"host with the same {TOKEN_ENV}")
                continue
            result = reply.get("result") or {}
            if result.get("topology") != self.topo.digest:
                raise RunFailed(f"host {host!r} runs another topology (digest "
                                f"{result.get('topology')!r}, here {self.topo.digest!r}): "
                                f"start every host with the same file and --set options")
            if result.get("ready"):
                ready.add(name)
        return ready

    def _poll_ready(self, timeout_s: float) -> list[str]:
        ready = []
        if self.pull.poll(int(timeout_s * 1000)):
            while True:
                try:
                    msg = msgpack.unpackb(self.pull.recv(zmq.NOBLOCK))
                except zmq.Again:
                    break
                actor = msg.get("actor") if isinstance(msg, dict) else None
                p = self.proc_of.get(actor) if isinstance(actor, str) else None
                if p is not None and msg.get("event") == "ready":
                    self.info.setdefault("ready_at", {})[actor] = time.time()
                    p.ready_members.add(actor)
                    p.ready = len(p.ready_members) == len(p.members)
                    ready.append(actor)
        return ready

    def request(self, actor: str, request: dict, timeout_s: float = 2.0) -> dict | None:
        """One control request to an actor of this run (its reply, or None on time-out)."""
        return control_request(self.ctx, self.specs[actor]["control"], request, timeout_s,
                               token=self.token)

    def _reap(self) -> list[_Proc]:
        dead = []
        for p in self.procs.values():
            if p.popen is not None and p.exit_code is None:
                code = p.popen.poll()
                if code is not None:
                    p.exit_code = code
                    p.spec_path.unlink(missing_ok=True)    # died before it read its spec
                    dead.append(p)
        return dead

    def _remove_rings_of(self, p: _Proc) -> None:
        """A dead producer's rings: readers that still map them keep their pages."""
        for member in p.members:
            for out, o in self.specs[member]["outputs"].items():
                if o["ring"]:
                    remove_run_rings(self.run_id, f"{member}-{out}-{p.popen.pid}-*")

    def _death_report(self, p: _Proc, when: str = "") -> str:
        code = p.exit_code
        how = f"signal {signal.Signals(-code).name}" if code is not None and code < 0 \
            else f"exit code {code}"
        tail = f"; last lines of {p.log_path}:\n" + _indent(log_tail(p.log_path))
        if not p.grouped:
            return f"actor {p.name!r} died {when} ({how})" + tail
        members = ", ".join(p.members)
        when = f" {when}" if when else ""
        outcome = p.outcome()
        if outcome:   # the group's worker said which member ended it, and why
            return (f"actor {outcome['actor']!r} died{when} ({clip(str(outcome.get('reason')))}"
                    f"); its process group {p.name!r} ({members}) exited with {how}" + tail)
        # killed from outside (a signal, os._exit): the worker could not say which member
        return (f"process group {p.name!r} died{when} ({how}); it ran actors {members}; "
                f"which one ended it is not known (see its log)" + tail)

    def _failed_actor(self, p: _Proc) -> str | None:
        """The actor a failure is put down to: the process's own, or the member the group
        reported; None when a group died without saying."""
        return p.name if not p.grouped else p.outcome().get("actor")

    def wait(self, duration_s: float | None = None,
             on_poll: Callable[[float], None] | None = None) -> int:
        """Supervise until ``duration_s`` passes, Ctrl-C, an actor finishes or one fails."""
        t_end = None if duration_s is None else time.monotonic() + duration_s
        while True:
            if self._interrupted:
                self.echo(f"sebvs: {self._interrupted}: stopping {self.topo.name}")
                break
            if t_end is not None and time.monotonic() >= t_end:
                break
            for p in self._reap():
                self._remove_rings_of(p)
                if p.exit_code == 0:
                    who = p.outcome().get("actor", p.name) if p.grouped else p.name
                    self.echo(f"sebvs: actor {who!r} finished; ending the run")
                    return self.stop()
                self.echo("sebvs: " + self._death_report(p))
                if self.topo.restart == "restart" and p.restarts < self.topo.max_restarts:
                    p.restarts += 1
                    self.echo(f"sebvs: restarting {p.name!r} "
                              f"({p.restarts}/{self.topo.max_restarts})")
                    self._spawn(p)
                    self._write_info()
                else:
                    self.failure = self._death_report(p)
                    self.info["failed_actor"] = self._failed_actor(p)
                    self.info["failed_process"] = p.name
                    return self.stop()
            for name in self._poll_ready(0) if any(not p.ready for p in self.procs.values()) \
                    else []:
                self.request(name, {"cmd": "start"})  # a restarted actor joins the clock
            self._check_stalls()
            self._refresh_offsets()
            if on_poll is not None:
                on_poll(POLL_S)
            else:
                time.sleep(POLL_S)
        return self.stop()

    def interrupt(self, reason: str) -> None:
        self._interrupted = reason

    def stop(self) -> int:
        """Stop every actor within STOP_GRACE_S + TERM_GRACE_S; remove sockets and rings."""
        if self.status == "ended":
            return 1 if self.failure else 0
        self.status = "stopping"
        self._report_losses()
        if self.remote:
            # the other hosts' actors end, and their supervisors with them
            query_all(self.ctx, self.remote, {"cmd": "stop", "token": self.token}, 1.0)
        live = [p for p in self.procs.values() if p.popen and p.popen.poll() is None]
        sockets = []
        for p in live:  # ask all at once, then wait for all
            for member in p.members:
                s = self.ctx.socket(zmq.DEALER)
                curve.client(s, self.specs[member]["control"], self.token)
                s.connect(self.specs[member]["control"])
                s.send(msgpack.packb({"cmd": "stop", "token": self.token}))
                sockets.append(s)
        for sig, grace in ((None, STOP_GRACE_S), (signal.SIGTERM, TERM_GRACE_S),
                           (signal.SIGKILL, 1.0)):
            live = [p for p in live if p.popen.poll() is None]
            if sig is not None:
                for p in live:
                    try:
                        os.killpg(p.popen.pid, sig)
                    except ProcessLookupError:
                        pass
            deadline = time.monotonic() + grace
            while live and time.monotonic() < deadline:
                live = [p for p in live if p.popen.poll() is None]
                time.sleep(0.01)
            if not live:
                break
        for s in sockets:
            s.close()
        for p in self.procs.values():
            if p.popen is not None and p.exit_code is None:
                p.exit_code = p.popen.poll()
        self.cleanup()
        self.status = "ended"
        self.info["ended_at"] = datetime.now().isoformat(timespec="seconds")
        self._write_info()
        return 1 if self.failure else 0

    def cleanup(self) -> None:
        try:
            self.pull.close()
        except AttributeError:
            pass
        remove_run_rings(self.run_id)
        shutil.rmtree(self.sockdir, ignore_errors=True)
        self.ctx.term()


def control_request(ctx: zmq.Context, endpoint: str, request: dict,
                    timeout_s: float = 2.0, *, token: str | None = None) -> dict | None:
    """One request/reply on an actor's control socket; None when it does not answer in time.

    ``token`` is the run's (Supervisor.token, run.json "token"): actors refuse requests
    without it.
    """
    if token is not None:
        request = {**request, "token": token}
    s = ctx.socket(zmq.DEALER)
    s.setsockopt(zmq.LINGER, 0)
    try:
        curve.client(s, endpoint, request.get("token"))
        s.connect(endpoint)
        s.send(msgpack.packb(request, use_bin_type=True))
        if not s.poll(int(timeout_s * 1000)):
            return None
        return msgpack.unpackb(s.recv(), raw=False)
    finally:
        s.close()


def _input_endpoint(output: dict, same_process: bool, same_host: bool = True) -> str:
    """Where a consumer connects: the producer's inproc endpoint from its own process, its
    tcp one from another host."""
    if not same_host:
        return output["far"]
    return output["inproc"] if same_process and output["inproc"] else output["endpoint"]


def _check_host(topo: Topology, host: str | None) -> str | None:
    if not topo.hosts:
        if host is not None:
            raise TopologyError(f"{topo.path}: --host {short_repr(host)}: this topology has "
                                f"no [hosts.<name>] tables; it runs on one machine")
        return None
    if host is None:
        raise TopologyError(f"{topo.path}: places actors on hosts {', '.join(topo.hosts)}: "
                            f"start one supervisor per host with --host NAME (the primary, "
                            f"{topo.primary!r}, starts the clock)")
    if host not in topo.hosts:
        raise TopologyError(f"{topo.path}: --host {short_repr(host)}: no such host "
                            f"(hosts: {', '.join(topo.hosts)})")
    return host


def _run_token(topo: Topology, host: str | None, primary: bool) -> str:
    """A fresh token, or on a multi-host run the one all its supervisors share
    (``SEBVS_RUN_TOKEN``; the primary makes one when it is not set)."""
    shared = os.environ.get(TOKEN_ENV, "")
    if host is None or (primary and not shared):
        return secrets.token_hex(16)
    if len(shared) < MIN_TOKEN_CHARS:
        raise TopologyError(
            f"{topo.path}: host {host!r} needs the run's token: set {TOKEN_ENV} (at least "
            f"{MIN_TOKEN_CHARS} characters) to the same secret on every host, or to the "
            f"primary's (its run.json 'token')")
    return shared


def _host_ports(topo: Topology) -> dict[tuple[str, str], str]:
    """tcp endpoints of a multi-host topology, the same on every host: per host, in
    topology order, each actor's control and telemetry, then each of its outputs that
    another host consumes, on consecutive ports from the host's `port`.

    Keys: (actor, "ctl"), (actor, "tel"), (actor, output)."""
    endpoints = {}
    active = topo.active
    for host in topo.hosts.values():
        port = host.port
        for a in active.values():
            if a.host != host.name:
                continue
            names = ["ctl", "tel"] + [o for o in a.cls.outputs
                                      if any(active[c].host != host.name
                                             for c, _ in topo.consumers(a.name, o))]
            for name in names:
                if port > 65535:
                    raise TopologyError(f"{topo.path}: [hosts.{host.name}] port "
                                        f"{host.port}: its actors need ports beyond 65535")
                endpoints[(a.name, name)] = f"tcp://{host.address}:{port}"
                port += 1
    return endpoints


def _indent(text: str) -> str:
    return "\n".join("    " + line for line in text.splitlines())


def run_topology(path: str | Path, overrides: list[str] | tuple = (),
                 duration_s: float | None = 5.0, runs_dir: str | Path | None = None,
                 echo: Callable[[str], None] | None = None) -> Path:
    """Run a topology to its end (or for ``duration_s``) and return its run directory.

    Raises RunFailed when an actor died, naming it with the end of its log.
    """
    topo = load_topology(path, overrides)
    sup = Supervisor(topo, runs_dir=runs_dir, echo=echo or (lambda text: None))
    try:
        sup.start()
        code = sup.wait(duration_s)
    except BaseException:
        sup.stop()
        raise
    if code != 0:
        raise RunFailed(sup.failure or f"run ended with code {code}")
    return sup.rundir
