"""Topology files: which actors run, with what parameters, wired how.

Everything is validated before a process starts; an error names the file, the table and
the key. Actors whose outputs nobody consumes are pruned (an actor without outputs is a
sink and stays).
"""
from __future__ import annotations

import hashlib
import importlib
import importlib.util
import json
import operator
import os
import re
import tomllib
import zlib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal, Union

from .overrides import (REPLACE, Overrides, TopologyError, is_replacement, layers, leaves,
                        merge, resolved)
# the one parser of `actor.key=value`, importable from here as it always was
from .overrides import parse_override  # noqa: F401
from .params import Range, build_params, clip, coerce_param, short_repr

MAX_QUEUE = 100_000
QUEUE = Union[Annotated[int, Range(ge=1, le=MAX_QUEUE)], Literal["latest"]]
# one message on an input, in bytes (ZeroMQ's MAXMSGSIZE): 256 MiB unless an input raises it
MAX_BYTES = Annotated[int, Range(ge=1024, le=1 << 40)]
DEFAULT_MAX_BYTES = 256 << 20
# [topology] keys, checked by the same rules as actor parameters
# topology seeds: the range on which actor_seed is one-to-one, so that no two accepted
# seeds give an actor the same seed (a seed that wrapped around would play another seed's
# episodes, a held-out split's among them: sebvs/data/splits.py)
SEED_LIMIT = 2 ** 31
SEED = Annotated[int, Range(ge=0, lt=SEED_LIMIT)]
TOPOLOGY_KEYS = {"name": str, "clock": Literal["lockstep", "realtime"],
                 "seed": SEED, "restart": Literal["stop", "restart"],
                 "max_restarts": Annotated[int, Range(ge=0)],
                 "transport": Literal["ipc", "tcp"], "host": str, "description": str,
                 "queue": QUEUE, "ready_timeout_s": Annotated[float, Range(gt=0)],
                 "placement": Literal["grouped", "isolated", "single", "auto"]}
# the name becomes a directory under the runs directory: no separators, no leading dot
RUN_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.-]{0,99}")
ACTOR_RESERVED = {"run", "inputs", "keep", "cpus", "process", "host", "priority"}
# `priority`: a nice value (-20 highest .. 19 lowest; below 0 needs CAP_SYS_NICE), or
# "realtime": SCHED_FIFO at REALTIME_PRIORITY (needs CAP_SYS_NICE or an rtprio limit)
NICE_RANGE = (-20, 19)
REALTIME_PRIORITY = 10
# [hosts.<name>] keys: where that host's actors bind (its address as the other hosts reach
# it) and the first of the consecutive tcp ports they use (docs/scale.md, "Several hosts")
HOST_KEYS = {"address": str, "port": Annotated[int, Range(ge=1024, le=65535)]}
DEFAULT_HOST_PORT = 47000
DEFAULT_QUEUE = 32
# `placement = "auto"` runs every actor in one process when the run has one CPU to itself,
# honours the actors' `process` groups when it has at most AUTO_GROUP_MAX_CPUS, and runs
# every actor alone on more (docs/runtime.md, "Process groups")
AUTO_GROUP_MAX_CPUS = 4
# the one process of `placement = "single"`
SINGLE_PROCESS = "all"
# how many CPUs a run may count on, when several runs share the machine (the local pool of
# `--workers N` sets it to its share for each worker); unset: the CPUs this process may use
CPUS_ENV = "SEBVS_CPUS"


@dataclass
class InputSpec:
    name: str
    producer: str
    output: str
    queue: int | str = DEFAULT_QUEUE   # N messages, or "latest"
    max_bytes: int = DEFAULT_MAX_BYTES  # one message; ZeroMQ drops a peer that sends more

    @property
    def source(self) -> str:
        return f"{self.producer}/{self.output}"


@dataclass
class ActorSpec:
    name: str
    run: str
    cls: type
    inputs: dict[str, InputSpec]
    params: dict[str, Any]
    keep: bool = False
    pruned: bool = False
    cpus: tuple[int, ...] = ()      # pin the process (all its threads) to these CPUs; () = OS's choice
    process: str | None = None      # the process group it shares with others; None = its own
    host: str | None = None         # the [hosts] entry it runs on; None = a one-host topology
    priority: int | str | None = None   # nice value or "realtime"; None = inherited
    loop_priority: bool = False         # `priority` is the topology's loop_priority


@dataclass
class HostSpec:
    """One machine of a multi-host topology: its actors bind tcp ports port, port + 1, ...
    on ``address`` for whatever another host reaches (control, telemetry, outputs
    consumed there); what stays on the host uses ipc and shared memory."""
    name: str
    address: str = "127.0.0.1"
    port: int = DEFAULT_HOST_PORT


@dataclass
class Topology:
    path: Path
    name: str
    clock: str = "realtime"
    seed: int = 0
    restart: str = "stop"
    max_restarts: int = 3
    transport: str = "ipc"
    host: str = "127.0.0.1"
    queue: int | str = DEFAULT_QUEUE     # every input's default: N messages, or "latest"
    ready_timeout_s: float = 60.0
    # "grouped": the actors' `process` keys say which share a process; "isolated": every
    # actor alone, whatever they say; "auto": grouped on small machines, else isolated
    placement: str = "grouped"
    # on the realtime clock, the priority of a closed loop's actors that ask for none
    # (None: leave them at the default); docs/runtime.md, "The loop's priority"
    loop_priority: int | str | None = "realtime"
    description: str = ""
    actors: dict[str, ActorSpec] = field(default_factory=dict)
    # several hosts: each runs `sebvs run FILE --host NAME`; the first listed is the primary
    # (it starts the clock, estimates the others' clock offsets, and its run.json lists all)
    hosts: dict[str, HostSpec] = field(default_factory=dict)
    # the file and its --set overrides, hashed: every host's supervisor must run the same
    digest: str = ""

    @property
    def primary(self) -> str | None:
        return next(iter(self.hosts), None)

    @property
    def active(self) -> dict[str, ActorSpec]:
        return {n: a for n, a in self.actors.items() if not a.pruned}

    def consumers(self, producer: str, output: str) -> list[tuple[str, InputSpec]]:
        return [(a.name, i) for a in self.active.values() for i in a.inputs.values()
                if i.producer == producer and i.output == output]

    def resolved_placement(self, cpus_available: int | None = None) -> str:
        """"grouped", "isolated" or "single": what `placement` means on this machine.

        `"auto"` is "single" when the run has one CPU to itself (``cpus_available``,
        default: `run_cpus()`) and its actors can share a process (one host, the same
        `cpus` and `priority`), "grouped" up to AUTO_GROUP_MAX_CPUS, else "isolated".
        """
        if self.placement != "auto":
            return self.placement
        cpus = run_cpus() if cpus_available is None else cpus_available
        if cpus <= 1 and not self.hosts and _group_conflict(list(self.active.values())) is None:
            return "single"
        return "grouped" if cpus <= AUTO_GROUP_MAX_CPUS else "isolated"

    def processes(self, cpus_available: int | None = None) -> dict[str, list[str]]:
        """Process name -> the active actors it runs, in topology order.

        An actor with `process = "G"` runs in process G with the others that name G; one
        without runs alone in a process of its own name. `placement = "isolated"` runs
        every actor alone whatever its `process` says, `"single"` all of them in one
        process (SINGLE_PROCESS), and `"auto"` picks by the CPUs the run may count on
        (`resolved_placement`): on few of them actors mostly wait for each other's
        processes to wake up, and a process per CPU wastes the least.
        """
        placement = self.resolved_placement(cpus_available)
        if placement == "single":
            return {SINGLE_PROCESS: list(self.active)}
        groups: dict[str, list[str]] = {}
        for a in self.active.values():
            if placement == "grouped" and a.process is not None:
                groups.setdefault(a.process, []).append(a.name)
            else:
                groups[a.name] = [a.name]
        return groups

    def actor_seed(self, name: str) -> int:
        """A per-actor seed derived from the topology seed, stable across runs: for each
        name a bijection of [0, SEED_LIMIT) (1,000,003 is odd, so invertible modulo 2**31),
        which is why seeds outside it are refused (`check_seed`)."""
        return (check_seed(self.seed) * 1_000_003 + zlib.crc32(name.encode())) % SEED_LIMIT


def check_seed(seed: Any, where: str = "topology seed") -> int:
    """``seed`` as an int if it is a topology seed (0 <= seed < SEED_LIMIT), else ValueError
    (one line): a larger one would wrap around onto a smaller seed's episodes.

    Parameters:
        seed: the value given.
        where: what it was given as, for the message ("--seed", "reset(seed=...)").

    Returns:
        The seed.
    """
    try:
        value = None if isinstance(seed, bool) else operator.index(seed)   # numpy ints too
    except TypeError:
        value = None
    if value is None or not 0 <= value < SEED_LIMIT:
        raise ValueError(f"{where} {seed!r}: expected an integer 0 <= seed < 2**31 "
                         f"({SEED_LIMIT:,}); a larger one would replay a smaller one's "
                         f"episodes")
    return value


def apply_overrides(doc: dict, overrides: Overrides, path: str | Path = "topology") -> dict:
    """A parsed topology document with overrides merged in, layer by layer (merge():
    later wins, a mapping merges into a table key by key, anything else replaces).

    An override names an existing actor, or adds one: a new actor's table needs its
    `run` ("module:Class"; a --set line `NAME.run=...` first). A key path through a value
    that is not a table is refused rather than replaced.

    Parameters:
        doc: the document as tomllib read it (not changed).
        overrides: a mapping, or layers in order: mappings, or --set lines as typed.
        path: the file, for the messages of a mapping's errors.

    Returns:
        The new document. TopologyError, in one line naming the --set line (or the file
        and the override's key path), where an override cannot apply.
    """
    for mapping, line in layers(overrides):
        doc = _apply_layer(doc, mapping, line, path)
    return doc


def _apply_layer(doc: dict, mapping: Mapping, line: str | None, path) -> dict:
    def where(keys: tuple) -> str:
        return f"--set {short_repr(line)}" if line is not None else \
            f"{path}: override {clip('.'.join(map(str, keys)))}"

    shaped: dict = {}
    for name, table in mapping.items():
        if name in ("topology", "hosts"):
            shaped[name] = table
        else:
            shaped.setdefault("actors", {})[name] = table
    actors = doc.get("actors", {})
    for name, table in shaped.get("actors", {}).items():
        content = table[REPLACE] if is_replacement(table) else table
        if not isinstance(actors, dict) or name in actors:
            continue
        if not (isinstance(content, Mapping) and "run" in content):
            first = next(iter(content), "run") if isinstance(content, Mapping) else "run"
            # a --set line says which line to give; a mapping, what its table lacks
            how = (f"add one with {clip(name)}.run=\"module:Class\" first" if line is not None
                   else "a new actor's table needs its 'run' = \"module:Class\"")
            raise TopologyError(f"{where((name, first))}: no actor {short_repr(name)} "
                                f"(actors: {', '.join(actors) or 'none'}; {how})")
    _check_tables(doc, shaped, (), where)
    return resolved(merge(doc, shaped))


def _check_tables(base: Mapping, over: Mapping, keys: tuple, where) -> None:
    """A mapping of keys may only merge into a table: `sim.episode_s.x=1` is refused."""
    for key, value in over.items():
        # the document's "actors" level has no part in an override's key path
        here = keys if (not keys and key == "actors") else (*keys, key)
        if is_replacement(value) or not isinstance(value, Mapping) or key not in base:
            continue
        if not isinstance(base[key], Mapping):
            below = next(leaves(value), ((), None))[0]     # the key path it was given
            raise TopologyError(f"{where((*here, *below))}: {short_repr(key)} is not a table")
        _check_tables(base[key], value, here, where)


def import_actor_module(name: str):
    """The module a `run = "module:Class"` names. ``actors.X`` is the historical spelling of
    ``sebvs_actors.X``, the package the project's actors/ folder installs as: the one module
    either way (actors/__init__.py makes the names one in a checkout), so no actor class is
    loaded twice. A module sebvs_actors lacks is imported as written (a project's own
    ``actors`` package)."""
    head, dot, rest = name.partition(".")
    if head == "actors":
        canonical = "sebvs_actors" + dot + rest
        try:
            found = importlib.util.find_spec(canonical) is not None
        except ImportError:     # sebvs_actors not installed (a bare checkout: as written)
            found = False
        if found or importlib.util.find_spec("actors") is None:
            name = canonical
    return importlib.import_module(name)


def _import_actor(run: str, where: str) -> type:
    from .actor import Actor
    module_name, _, cls_name = run.partition(":") if isinstance(run, str) else ("", "", "")
    # relative (".mod") and empty module names make importlib raise TypeError/ValueError
    if not (all(part.isidentifier() for part in module_name.split("."))
            and cls_name.isidentifier()):
        raise TopologyError(f"{where} key 'run': expected \"package.module:Class\", "
                            f"got {short_repr(run)}")
    try:
        module = import_actor_module(module_name)
    except ImportError as exc:
        raise TopologyError(f"{where} key 'run': cannot import {module_name!r}: "
                            f"{_first_line(exc)}") from None
    except Exception as exc:  # the module's own code failed (a SyntaxError, a bad import...)
        raise TopologyError(f"{where} key 'run': importing {module_name!r} failed: "
                            f"{type(exc).__name__}: {_first_line(exc)}") from None
    cls = getattr(module, cls_name, None)
    if not (isinstance(cls, type) and issubclass(cls, Actor)):
        raise TopologyError(f"{where} key 'run': {short_repr(run)} is not an Actor class")
    return cls


def _first_line(exc: BaseException) -> str:
    lines = str(exc).strip().splitlines()
    return clip(lines[0]) if lines else ""


def _parse_input(spec: Any, where: str,
                 default_queue: int | str) -> tuple[str, int | str, int]:
    """(source, queue, max_bytes) of one input: "actor/output" or a table."""
    if isinstance(spec, str):
        return spec, default_queue, DEFAULT_MAX_BYTES
    if isinstance(spec, dict):
        unknown = set(spec) - {"from", "queue", "max_bytes"}
        if unknown:
            raise TopologyError(f"{where}: unknown key {short_repr(sorted(unknown)[0])} "
                                f"(from, queue, max_bytes)")
        if not isinstance(spec.get("from"), str):
            raise TopologyError(f"{where}: 'from' = \"actor/output\" is required")
        try:
            queue = coerce_param(QUEUE, spec.get("queue", default_queue),
                                 where=f"{where} key 'queue'")
            max_bytes = coerce_param(MAX_BYTES, spec.get("max_bytes", DEFAULT_MAX_BYTES),
                                     where=f"{where} key 'max_bytes'")
        except ValueError as exc:
            raise TopologyError(str(exc)) from None
        return spec["from"], queue, max_bytes
    raise TopologyError(f"{where}: expected \"actor/output\" or a table, "
                        f"got {short_repr(spec)}")


def _parse_cpus(value: Any, where: str, here: bool = True) -> tuple[int, ...]:
    """The `cpus` key: distinct CPU numbers this process may run on (checked here, before any
    process starts, so a topology written for a bigger machine fails with its name).

    ``here`` False (a multi-host topology, whose actors may run elsewhere): only the form
    is checked; each host's supervisor checks its own actors (``check_cpus_available``)."""
    if not (isinstance(value, list) and value
            and all(isinstance(c, int) and not isinstance(c, bool) and c >= 0 for c in value)
            and len(set(value)) == len(value)):
        raise TopologyError(f"{where} key 'cpus': expected a non-empty list of distinct CPU "
                            f"numbers such as [0] or [2, 3], got {short_repr(value)}")
    if here:
        check_cpus_available(tuple(value), where)
    return tuple(value)


def check_cpus_available(value: tuple[int, ...], where: str) -> None:
    if not hasattr(os, "sched_setaffinity"):
        raise TopologyError(f"{where} key 'cpus': CPU pinning is not supported on this platform")
    available = os.sched_getaffinity(0)
    missing = sorted(set(value) - available)
    if missing:
        raise TopologyError(f"{where} key 'cpus': CPU {', '.join(map(str, missing))} not "
                            f"available here (available: {', '.join(map(str, sorted(available)))})")


def load_topology(path: str | Path, overrides: Overrides = ()) -> Topology:
    """The topology of a file with overrides applied, checked whole before anything starts.

    Parameters:
        path: the TOML file.
        overrides: a mapping (`{"sim": {"episode_s": 2.0}}`), or layers applied in order,
            each a mapping or a `--set` line as a user typed it (sebvs/runtime/overrides.py).

    Returns:
        The Topology. TopologyError, in one line naming the file, table and key (or the
        --set line), for anything that cannot run.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")     # TOML is UTF-8 whatever the locale
    except FileNotFoundError:
        raise TopologyError(f"{path}: no such topology file") from None
    except IsADirectoryError:
        raise TopologyError(f"{path}: is a directory, not a topology file") from None
    except UnicodeDecodeError as exc:
        raise TopologyError(f"{path}: not UTF-8 text (byte {exc.object[exc.start]:#04x} at "
                            f"offset {exc.start})") from None
    except OSError as exc:
        raise TopologyError(f"{path}: cannot read: {exc.strerror or exc}") from None
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:  # duplicate tables and keys end up here too
        raise TopologyError(f"{path}: {exc}") from None
    except RecursionError:
        raise TopologyError(f"{path}: arrays or tables nested too deeply") from None
    return build_topology(apply_overrides(doc, overrides, path), path)


def build_topology(doc: dict, path: Path) -> Topology:
    unknown = set(doc) - {"topology", "actors", "hosts"}
    if unknown:
        raise TopologyError(f"{path}: unknown table [{sorted(unknown)[0]}] "
                            f"(expected [topology], [actors.<name>] and [hosts.<name>])")
    top = doc.get("topology")
    if not isinstance(top, dict):
        raise TopologyError(f"{path}: missing [topology] table")
    top = dict(top)
    loop_priority = _parse_loop_priority(top.pop("loop_priority", "realtime"),
                                         f"{path}: [topology]")
    checked = _checked_keys(top, TOPOLOGY_KEYS, f"{path}: [topology]")
    if "name" not in checked:
        raise TopologyError(f"{path}: [topology] key 'name' is required")
    if not RUN_NAME.fullmatch(checked["name"]):
        raise TopologyError(f"{path}: [topology] key 'name': {short_repr(checked['name'])} is "
                            f"not a run name (up to 100 ASCII letters, digits, '_', '-' and '.', "
                            f"not starting with '.')")
    topo = Topology(path=path, loop_priority=loop_priority, **checked)
    topo.digest = hashlib.sha256(json.dumps(doc, sort_keys=True, default=str)
                                 .encode()).hexdigest()[:16]
    topo.hosts = _parse_hosts(doc.get("hosts", {}), path)
    actors = doc.get("actors", {})
    if not isinstance(actors, dict) or not actors:
        raise TopologyError(f"{path}: no [actors.<name>] tables")
    for name, table in actors.items():
        # names go into socket paths (about 100 bytes at most) and shared-memory names
        if not (name.replace("_", "").replace("-", "").isalnum() and len(name) <= 64):
            raise TopologyError(f"{path}: [actors] {short_repr(name)}: actor names use up to "
                                f"64 letters, digits, '_' and '-'")
        where = f"{path}: [actors.{name}]"
        if not isinstance(table, dict):
            raise TopologyError(f"{where}: expected a table")
        if "run" not in table:
            raise TopologyError(f"{where}: key 'run' = \"module:Class\" is required")
        cls = _import_actor(table["run"], where)
        raw_inputs = table.get("inputs", {})
        if not isinstance(raw_inputs, dict):
            raise TopologyError(f"{where} key 'inputs': expected a table")
        inputs = {}
        for inp, spec in raw_inputs.items():
            iwhere = f"{where} key 'inputs.{clip(inp)}'"
            if inp not in cls.inputs:
                raise TopologyError(f"{iwhere}: {table['run']} has no input {short_repr(inp)} "
                                    f"(inputs: {', '.join(cls.inputs) or 'none'})")
            source, queue, max_bytes = _parse_input(spec, iwhere, topo.queue)
            producer, _, output = source.partition("/")
            if not producer or not output:
                raise TopologyError(f"{iwhere}: {short_repr(source)} is not \"actor/output\"")
            inputs[inp] = InputSpec(inp, producer, output, queue, max_bytes)
        params = {k: v for k, v in table.items() if k not in ACTOR_RESERVED}
        try:
            built = build_params(cls.Params, params, where=where)
        except ValueError as exc:
            raise TopologyError(str(exc)) from None
        # parameters that need an input the table does not wire (the recorder's
        # raw_events): the actor class says so in one line, before any process starts
        check = getattr(cls, "check_wiring", None)
        problem = check(built, frozenset(inputs)) if check is not None else None
        if problem:
            raise TopologyError(f"{where}: {problem}")
        keep = table.get("keep", False)
        if not isinstance(keep, bool):
            raise TopologyError(f"{where} key 'keep': expected true or false")
        cpus = _parse_cpus(table["cpus"], where, here=not topo.hosts) if "cpus" in table else ()
        process = _parse_process(table["process"], where) if "process" in table else None
        host = _actor_host(table.get("host"), topo, where)
        priority = _parse_priority(table["priority"], where) if "priority" in table else None
        topo.actors[name] = ActorSpec(name, table["run"], cls, inputs, params, keep, cpus=cpus,
                                      process=process, host=host, priority=priority)
    for a in topo.actors.values():
        for inp in a.inputs.values():
            where = f"{path}: [actors.{a.name}] key 'inputs.{inp.name}'"
            producer = topo.actors.get(inp.producer)
            if producer is None:
                raise TopologyError(f"{where}: dangling input, no actor {inp.producer!r}")
            if inp.output not in producer.cls.outputs:
                raise TopologyError(f"{where}: actor {inp.producer!r} ({producer.run}) has no "
                                    f"output {inp.output!r} (outputs: "
                                    f"{', '.join(producer.cls.outputs) or 'none'})")
    _check_cycles(topo)
    _prune(topo)
    _apply_loop_priority(topo)
    _check_groups(topo)
    _check_inline_sizes(topo, path)
    return topo


def message_sizes(topo: "Topology") -> dict[tuple[str, str], int]:
    """(actor, output) -> the largest array payload it sends, where known: the actors'
    own `message_bytes`, carried through relays (`forwards`)."""
    sizes: dict[tuple[str, str], int] = {}
    for a in topo.actors.values():
        try:
            params = build_params(a.cls.Params, a.params, where=a.name)
            known = a.cls.message_bytes(params)
        except Exception:         # a size that cannot be told is simply not checked
            known = {}
        sizes.update({(a.name, out): int(n) for out, n in known.items()})
    for _ in range(len(topo.actors)):          # relays of relays
        for a in topo.actors.values():
            for out, inp in a.cls.forwards.items():
                spec = a.inputs.get(inp)
                if spec is not None and (spec.producer, spec.output) in sizes:
                    sizes.setdefault((a.name, out), sizes[(spec.producer, spec.output)])
    return sizes


def _check_inline_sizes(topo: "Topology", path: Path) -> None:
    """An input whose `max_bytes` is below what its producer is known to send on an edge
    that carries arrays inline (tcp: one transport for all, or two hosts) would have its
    peer dropped by ZeroMQ at the first message: refused here, in one line."""
    sizes = message_sizes(topo)
    for a in topo.active.values():
        for inp in a.inputs.values():
            producer = topo.actors[inp.producer]
            inline = topo.transport == "tcp" or (bool(topo.hosts) and producer.host != a.host)
            size = sizes.get((inp.producer, inp.output))
            if inline and size is not None and size + HEADER_MARGIN > inp.max_bytes:
                raise TopologyError(
                    f"{path}: [actors.{a.name}] key 'inputs.{inp.name}': max_bytes "
                    f"{inp.max_bytes:,} is below the {size:,}-byte arrays of "
                    f"{inp.producer}/{inp.output}, which this edge carries inline (tcp); "
                    f"ZeroMQ would drop every one: raise max_bytes to at least "
                    f"{size + HEADER_MARGIN:,}")

# room for the header beside the arrays, in the inline size check
HEADER_MARGIN = 4096


def _checked_keys(table: dict, known: dict, where: str) -> dict:
    """A table's keys, each known and coerced to its type, or the error naming it."""
    checked = {}
    for key, value in table.items():
        if key not in known:
            raise TopologyError(f"{where} unknown key {short_repr(key)} "
                                f"(known: {', '.join(known)})")
        try:
            checked[key] = coerce_param(known[key], value, where=f"{where} key {key!r}")
        except ValueError as exc:
            raise TopologyError(str(exc)) from None
    return checked


def _parse_hosts(table: Any, path: Path) -> dict[str, HostSpec]:
    """[hosts.<name>] tables, in file order (the first is the primary)."""
    if not isinstance(table, dict):
        raise TopologyError(f"{path}: [hosts] expected tables [hosts.<name>]")
    hosts = {}
    for name, spec in table.items():
        where = f"{path}: [hosts.{clip(name)}]"
        if not (name.replace("_", "").replace("-", "").isalnum() and len(name) <= 64):
            raise TopologyError(f"{where}: host names use up to 64 letters, digits, '_' "
                                f"and '-'")
        if not isinstance(spec, dict):
            raise TopologyError(f"{where}: expected a table with 'address' and 'port'")
        hosts[name] = HostSpec(name, **_checked_keys(spec, HOST_KEYS, where))
    return hosts


def _actor_host(value: Any, topo: Topology, where: str) -> str | None:
    """The `host` key: one of [hosts]; an actor without it runs on the primary."""
    if value is None:
        return topo.primary
    if not topo.hosts:
        raise TopologyError(f"{where} key 'host': this topology has no [hosts.<name>] "
                            f"tables to place actors on")
    if value not in topo.hosts:
        raise TopologyError(f"{where} key 'host': no host {short_repr(value)} "
                            f"(hosts: {', '.join(topo.hosts)})")
    return value


def _parse_priority(value: Any, where: str) -> int | str:
    """The `priority` key: a nice value, or "realtime" (runtime/worker.py applies it)."""
    if value == "realtime":
        return value
    lo, hi = NICE_RANGE
    if isinstance(value, int) and not isinstance(value, bool) and lo <= value <= hi:
        return value
    raise TopologyError(f"{where} key 'priority': expected a nice value from {lo} (highest) "
                        f"to {hi} (lowest) or \"realtime\" (SCHED_FIFO), got "
                        f"{short_repr(value)}")


def _parse_loop_priority(value: Any, where: str) -> int | str | None:
    """The [topology] key `loop_priority`: a priority as an actor's, or "none"."""
    if value == "none":
        return None
    try:
        return _parse_priority(value, where)
    except TopologyError:
        raise TopologyError(f"{where} key 'loop_priority': expected \"realtime\" (the "
                            f"default), a nice value from {NICE_RANGE[0]} to {NICE_RANGE[1]}, "
                            f"or \"none\", got {short_repr(value)}") from None


def loop_members(topo: "Topology") -> set[str]:
    """The active actors on a closed loop (sensor to action and back to the sim)."""
    active = topo.active
    edges = {n: {i.producer for i in a.inputs.values() if i.producer in active}
             for n, a in active.items()}
    return {n for comp in _strong_components(edges)
            if len(comp) > 1 or comp[0] in edges[comp[0]] for n in comp}


def _apply_loop_priority(topo: "Topology") -> None:
    """On the realtime clock the loop's latency is the figure that matters, so its actors
    that ask for no priority get `loop_priority` (docs/runtime.md: SCHED_FIFO halves the
    chain's tail on a loaded machine). A process is one priority: an actor sharing one with
    a loop member follows it, unless some member of that group asked for its own."""
    if topo.clock != "realtime" or topo.loop_priority is None:
        return
    chosen = loop_members(topo)
    groups: dict[str, list[ActorSpec]] = {}
    for a in topo.active.values():
        if a.process is not None:
            groups.setdefault(a.process, []).append(a)
    for members in groups.values():
        if any(a.name in chosen for a in members):
            if any(a.priority is not None for a in members):
                chosen -= {a.name for a in members}
            else:
                chosen |= {a.name for a in members}
    for name in chosen:
        a = topo.actors[name]
        if a.priority is None:
            a.priority = topo.loop_priority
            a.loop_priority = True


def _parse_process(value: Any, where: str) -> str:
    """The `process` key: the name of the process group the actor shares (it names the
    group's log file and socket paths, so it follows the actor-name rules)."""
    if not (isinstance(value, str) and value
            and value.replace("_", "").replace("-", "").isalnum() and len(value) <= 64):
        raise TopologyError(f"{where} key 'process': expected a group name of up to 64 "
                            f"letters, digits, '_' and '-' such as \"vision\", got "
                            f"{short_repr(value)}")
    return value


def run_cpus() -> int:
    """The CPUs a run may count on: $SEBVS_CPUS when a pool shares the machine out (a
    positive integer; anything else is ignored), else the CPUs this process may use."""
    share = os.environ.get(CPUS_ENV, "")
    if share.isdigit() and int(share) > 0:
        return int(share)
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


def _group_conflict(actors: list[ActorSpec]) -> str | None:
    """Why these actors cannot share one process (None: they can): a process runs on one
    host, at one priority, pinned to one set of CPUs."""
    hosts = sorted({a.host for a in actors if a.host is not None})
    if len(hosts) > 1:
        return f"are placed on hosts {', '.join(hosts)}; a process runs on one host"
    if len({a.priority for a in actors}) > 1:
        shown = ", ".join(f"{a.name}: {a.priority}" for a in actors)
        return f"ask for different priorities ({shown}); a priority is the whole process's"
    if len({a.cpus for a in actors}) > 1:
        shown = ", ".join(f"{a.name}: {list(a.cpus) or 'unpinned'}" for a in actors)
        return (f"pin different CPUs ({shown}); `cpus` pins the whole process, so give "
                f"them the same list or none")
    return None


def _check_groups(topo: Topology) -> None:
    """A process group's members must agree on what is per process (`_group_conflict`),
    and its name must not be another actor's (logs and processes are named after both).
    `placement = "single"` makes every actor a member of one group."""
    if topo.placement == "single":
        problem = _group_conflict(list(topo.active.values()))
        if problem is not None:
            raise TopologyError(f"{topo.path}: [topology] key 'placement': \"single\" runs "
                                f"every actor in one process, but the actors {problem}")
        return
    members: dict[str, list[ActorSpec]] = {}
    for a in topo.actors.values():
        if a.process is not None:
            members.setdefault(a.process, []).append(a)
    for group, actors in members.items():
        where = f"{topo.path}: [actors.{actors[0].name}] key 'process'"
        names = {a.name for a in actors}
        if group in topo.actors and group not in names:
            raise TopologyError(f"{where}: group {group!r} has the name of actor {group!r}, "
                                f"which is not in it; name the group apart")
        problem = _group_conflict(actors)
        if problem is not None:
            raise TopologyError(f"{where}: the members of group {group!r} {problem}")


def _prune(topo: Topology) -> None:
    """Drop actors none of whose outputs is consumed, until nothing changes."""
    changed = True
    while changed:
        changed = False
        for a in topo.active.values():
            if a.keep or not a.cls.outputs:
                continue
            if not any(topo.consumers(a.name, out) for out in a.cls.outputs):
                a.pruned = True
                changed = True


def _strong_components(edges: dict[str, set[str]]) -> list[list[str]]:
    """Tarjan's strongly connected components of the graph {node: its predecessors}."""
    index, low, stack, on_stack, comps = {}, {}, [], set(), []

    def strongconnect(v, counter=[0]):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in edges[v]:
            if w not in index:
                strongconnect(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            comps.append(comp)

    for v in edges:
        if v not in index:
            strongconnect(v)
    return comps


def _check_cycles(topo: Topology) -> None:
    """A cycle must contain a clock source (an actor with run()), or nothing would start it."""
    edges = {n: {i.producer for i in a.inputs.values()} for n, a in topo.actors.items()}
    comps = _strong_components(edges)
    for comp in comps:
        if len(comp) == 1 and comp[0] not in edges[comp[0]]:
            continue
        if not any(hasattr(topo.actors[n].cls, "run") for n in comp):
            raise TopologyError(f"{topo.path}: cycle {' -> '.join(sorted(comp))} has no clock "
                                f"source (no actor in it defines run())")
