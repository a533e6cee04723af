"""Run shards of episodes in parallel: a local pool of worker processes, or Ray tasks.

The pool runs any picklable job through a worker function (`fan_out`'s `worker`, default
`run_task`: a topology run); training sweeps (sebvs/policy/sweep.py) give it one training
point per shard, with nothing to retry. What follows is the episode case it was built for.

A *shard* is episodes [first, stop) of a job (a recording, or one evaluation run). Each
shard becomes a `Task`: a topology file plus overrides (a nested mapping of plain JSON
values, sebvs/runtime/overrides.py: what pickles and travels to a Ray node as it is) that
a worker runs to its end
through the runtime's Supervisor, in a run directory and with sockets of its own (every
Supervisor draws a fresh run id, which names its run directory, ipc sockets and
shared-memory rings, so concurrent runs never share an endpoint). The caller says what
its shards are (`task_of`) and, after each one ran, which of its episodes are still
missing (`collect`, which also merges what the shard finished); this module runs them,
retries the missing episodes of a failed or lost worker up to `max_attempts` times, and
raises `ShardsLost` naming what is still missing after that.

Workers write nothing the caller has to wait for: results are files the caller merges.
Seeds do not depend on the split: episode k of a run is seeded from (topology seed, k)
whichever worker plays it (actors/sim.py `first_episode`), so any worker count gives the
same episodes.

Backends:
  local  `workers` worker processes. Spawned by default (multiprocessing "spawn": a fresh
         interpreter, nothing of the driver's inherited). Topology runs ask for "fork"
         (`start`) on Linux: the driver has imported the actor classes to check the
         topology, and a forked worker skips importing them again (about 0.4 s of a
         worker's start, on the path to its first episode). The driver holds no ZeroMQ
         context or GL context by then, and the child touches nothing of its other thread
         (tqdm's monitor). Training sweeps stay spawned: torch's thread pools do not
         survive a fork. A worker that dies without a result is lost; a worker whose
         driver died stops its run (it watches its parent pid).
         With `cpu_sets`, each worker process pins itself to one of them (its slot's),
         so N workers with T threads each do not compete for the same cores.
  ray    Ray tasks on the cluster at `ray` (or a local one started for the call, when
         ray == ""): ``pip install -e .[ray]``; Ray is imported here only. Paths in a Task
         are absolute and each task changes to the driver's working directory, so a
         cluster needs the checkout and the output directory at the same paths on every
         node (a shared filesystem). Each task asks Ray for `ray_resources` (default one
         CPU; a training point: its threads, or GPUs).
"""
from __future__ import annotations

import os
import signal
import sys
import time
import traceback
from collections import deque
from dataclasses import dataclass, field, replace
from typing import Any, Callable

from sebvs.runtime.stalls import format_losses

POLL_S = 0.25           # how often the driver looks at its workers and calls on_poll
STOP_WAIT_S = 10.0      # after Ctrl-C, how long workers get to stop their runs
# passed on to every worker: what selects MuJoCo's GL backend and the runs directory
ENV_KEYS = ("MUJOCO_GL", "PYOPENGL_PLATFORM", "SEBVS_RUNS_DIR")


class ShardsLost(RuntimeError):
    """Episodes still missing after every retry; `missing` maps job -> episode indices."""

    def __init__(self, message: str, missing: dict):
        super().__init__(message)
        self.missing = missing


class RayMissing(RuntimeError):
    """--ray was asked for and Ray is not installed."""


@dataclass(frozen=True)
class Task:
    """What a worker runs: picklable, every path absolute."""
    label: str                         # for messages: "nominal/indoor/expert [0, 5)"
    topology: str
    overrides: dict                    # {"sim": {"first_episode": 5}, ...}: JSON values
    runs_dir: str
    cwd: str = field(default_factory=os.getcwd)
    env: tuple[tuple[str, str], ...] = field(
        default_factory=lambda: tuple((k, os.environ[k]) for k in ENV_KEYS if k in os.environ))
    timeout_s: float | None = None
    parent_pid: int | None = None      # local pool: stop the run when this process is gone


@dataclass(frozen=True)
class Shard:
    """Episodes [first, stop) of `job` (the caller's key), on its `attempt`-th try."""
    job: Any
    first: int
    stop: int
    attempt: int = 1

    def __str__(self) -> str:
        return f"{self.job} [{self.first}, {self.stop})"


def split_episodes(first: int, stop: int, parts: int) -> list[tuple[int, int]]:
    """[first, stop) in at most `parts` contiguous ranges whose sizes differ by one at most
    (contiguous: each worker starts one run, and resumes where its range was cut)."""
    n = stop - first
    parts = max(1, min(parts, n))
    if n <= 0:
        return []
    bounds = [first + (n * i) // parts for i in range(parts + 1)]
    return [(a, b) for a, b in zip(bounds, bounds[1:]) if b > a]


# ---------------------------------------------------------------------- the worker side
def run_task(task: Task) -> dict:
    """Run one topology to its end (the shard's episodes done, a failure or the timeout).

    Returns {"label", "code" (0: ended cleanly), "failure" (the Supervisor's report or
    None), "rundir", "wall_s"}. SIGINT / SIGTERM stop the run cleanly (actors stopped,
    sockets and rings removed) and the function still returns.
    """
    from sebvs.runtime.supervisor import Supervisor
    from sebvs.runtime.topology import load_topology

    t0 = time.monotonic()
    os.chdir(task.cwd)
    if task.cwd not in sys.path:
        sys.path.insert(0, task.cwd)      # topologies may name actors of the checkout (tests.*)
    os.environ.update(dict(task.env))
    sup = Supervisor(load_topology(task.topology, task.overrides),
                     runs_dir=task.runs_dir, echo=lambda text: None)
    previous = {}
    if _main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            previous[sig] = signal.signal(
                sig, lambda s, f: sup.interrupt(signal.Signals(s).name))

    def watch_parent(dt: float) -> None:
        time.sleep(dt)
        if task.parent_pid is not None and os.getppid() != task.parent_pid:
            sup.interrupt("the driver is gone")

    try:
        sup.start()
        code = sup.wait(task.timeout_s, watch_parent)
    except BaseException:
        sup.stop()
        raise
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return {"label": task.label, "code": code, "failure": sup.failure,
            "rundir": str(sup.rundir), "wall_s": time.monotonic() - t0,
            "losses": sup.info.get("losses")}


def _main_thread() -> bool:
    import threading
    return threading.current_thread() is threading.main_thread()


def disjoint_cpu_sets(workers: int, threads: int) -> list[tuple[int, ...]] | None:
    """One disjoint set of `threads` CPUs per worker, from the CPUs this process may use,
    or None when there are fewer than workers x threads of them (pinning would then put
    two workers on one core while others idle: better leave placement to the kernel)."""
    cpus = sorted(os.sched_getaffinity(0))
    if workers < 1 or threads < 1 or len(cpus) < workers * threads:
        return None
    return [tuple(cpus[i * threads:(i + 1) * threads]) for i in range(workers)]


def cpu_share(workers: int) -> int:
    """CPUs each of `workers` workers on this machine may count on (at least one)."""
    from sebvs.runtime.topology import run_cpus
    return max(1, run_cpus() // max(1, workers))


def _shared_cpus(worker: Callable[[Any], dict], task: Any, cpus: int) -> dict:
    """Run `worker(task)` telling what it starts how many CPUs it may count on ($SEBVS_CPUS,
    read by `placement = "auto"`: a worker with one CPU runs its topology in one process,
    as a topology's 5-7 processes would otherwise compete with the other workers')."""
    from sebvs.runtime.topology import CPUS_ENV
    os.environ[CPUS_ENV] = str(cpus)
    return worker(task)


def _local_worker(worker: Callable[[Any], dict], task: Any, conn,
                  cpus: tuple[int, ...] | None, share: int) -> None:
    """Entry of a worker process: pin it to `cpus` (before torch or anything else
    starts threads, which inherit the mask), run the task with `share` CPUs to count on,
    send its result (or the error)."""
    try:
        if cpus:
            os.sched_setaffinity(0, cpus)
        result = _shared_cpus(worker, task, len(cpus) if cpus else share)
    except BaseException as exc:       # noqa: BLE001 - reported to the driver, which retries
        result = {"label": getattr(task, "label", None), "code": None, "rundir": None,
                  "failure": f"{type(exc).__name__}: {exc}\n{traceback.format_exc(limit=8)}"}
    try:
        conn.send(result)
    finally:
        conn.close()


# ---------------------------------------------------------------------- the driver side
def fan_out(shards: list[Shard], task_of: Callable[[Shard], Any],
            collect: Callable[[Shard, dict | None], list[int]], *, workers: int = 1,
            ray: str | None = None, max_attempts: int = 3,
            on_poll: Callable[[], None] | None = None,
            echo: Callable[[str], None] = lambda text: print(text, file=sys.stderr),
            worker: Callable[[Any], dict] = run_task,
            cpu_sets: list[tuple[int, ...]] | None = None,
            ray_resources: dict | None = None, start: str = "spawn") -> None:
    """Run every shard; retry the episodes `collect` reports missing; raise ShardsLost.

    `collect(shard, result)` runs in the driver after each shard's worker ended: result
    is run_task's dict, or None when the worker was lost (died, or Ray lost it). It
    merges what the shard finished and returns the shard's episodes still missing.
    `workers`: shards run at once (with Ray: at most that many tasks in flight; None
    there means one per CPU of the cluster). `ray`: None for the local pool, "" to start
    a local Ray, or a cluster address. `on_poll` is called every POLL_S (progress).

    `worker(task)` is what runs a shard, in the worker process or Ray task; it must be a
    module-level function (spawned workers import it, Ray pickles it by reference), and a local
    worker's task a dataclass with a `parent_pid` field, which the pool sets to its own
    pid so the worker can stop when the driver is gone. `cpu_sets` (local pool only, see
    `disjoint_cpu_sets()`): one per worker slot, each worker pinned to its slot's CPUs.
    `ray_resources`: what each Ray task asks for (default {"num_cpus": 1}). `start`: how
    the local pool starts a worker, "spawn" or "fork" (where the platform forks safely,
    Linux; spawn elsewhere); see the module's docstring.
    """
    if max_attempts < 1:
        raise ValueError(f"max_attempts must be at least 1, got {max_attempts}")
    backend = (_RayBackend(ray, workers, worker, ray_resources) if ray is not None else
               _LocalBackend(workers or 1, worker, cpu_sets, start))
    queue: deque[Shard] = deque(shards)
    lost: dict = {}
    try:
        while queue or backend.running():
            while queue and backend.has_room():
                shard = queue.popleft()
                backend.submit(shard, task_of(shard))
            for shard, result in backend.finished(POLL_S):
                for line in format_losses((result or {}).get("losses") or {}):
                    echo(f"sebvs: {shard}: {line}")    # the worker's run said nothing
                missing = collect(shard, result)
                if not missing:
                    continue
                why = "worker lost" if result is None else \
                    (result.get("failure") or "ended early").strip().splitlines()[0]
                if shard.attempt >= max_attempts:
                    lost.setdefault(shard.job, []).extend(missing)
                    echo(f"sebvs: {shard}: episodes {_ranges(missing)} lost after "
                         f"{shard.attempt} attempt(s): {why}")
                    continue
                # contiguous from the first missing one: a worker plays a range
                retry = replace(shard, first=min(missing), attempt=shard.attempt + 1)
                echo(f"sebvs: {shard}: {len(missing)} episode(s) missing ({why}); "
                     f"retrying {retry} (attempt {retry.attempt} of {max_attempts})")
                queue.append(retry)
            if on_poll is not None:
                on_poll()
    except BaseException:
        backend.stop_all()
        for shard, result in backend.drain():
            collect(shard, result)        # keep what the stopped workers finished
        raise
    finally:
        backend.close()
    if lost:
        listed = "; ".join(f"{job}: episodes {_ranges(sorted(ks))}" for job, ks in lost.items())
        raise ShardsLost(f"episodes lost after {max_attempts} attempt(s): {listed} "
                         f"(see the run directories' logs)", lost)


def _ranges(ks: list[int]) -> str:
    """[0, 1, 2, 5] -> "0-2, 5"."""
    out, ks = [], sorted(set(ks))
    i = 0
    while i < len(ks):
        j = i
        while j + 1 < len(ks) and ks[j + 1] == ks[j] + 1:
            j += 1
        out.append(str(ks[i]) if i == j else f"{ks[i]}-{ks[j]}")
        i = j + 1
    return ", ".join(out)


class _LocalBackend:
    """Worker processes (spawned or forked), one per shard, at most `workers` alive at
    once; with `cpu_sets`, the worker of slot i (a slot is free again when its worker ends)
    pinned to cpu_sets[i]."""

    def __init__(self, workers: int, worker: Callable[[Any], dict] = run_task,
                 cpu_sets: list[tuple[int, ...]] | None = None, start: str = "spawn"):
        import multiprocessing
        if start not in ("spawn", "fork"):
            raise ValueError(f"start must be 'spawn' or 'fork', got {start!r}")
        if start == "fork" and not sys.platform.startswith("linux"):
            start = "spawn"     # macOS: system frameworks are not fork-safe
        if workers < 1:
            raise ValueError(f"--workers must be at least 1, got {workers}")
        if cpu_sets is not None and len(cpu_sets) < workers:
            raise ValueError(f"{len(cpu_sets)} CPU sets for {workers} workers")
        self.workers = workers
        self.worker = worker
        self.cpu_sets = cpu_sets
        self.share = cpu_share(workers)
        self.ctx = multiprocessing.get_context(start)
        self.procs: dict = {}       # sentinel -> (process, receiving end, shard, slot)

    def running(self) -> bool:
        return bool(self.procs)

    def has_room(self) -> bool:
        return len(self.procs) < self.workers

    def submit(self, shard: Shard, task: Any) -> None:
        recv, send = self.ctx.Pipe(duplex=False)
        task = replace(task, parent_pid=os.getpid())
        slot = min(set(range(self.workers)) - {p[3] for p in self.procs.values()})
        cpus = self.cpu_sets[slot] if self.cpu_sets else None
        proc = self.ctx.Process(target=_local_worker,
                                args=(self.worker, task, send, cpus, self.share),
                                name=f"sebvs-worker {shard}", daemon=False)
        proc.start()
        send.close()                # the child holds the only sending end now
        self.procs[proc.sentinel] = (proc, recv, shard, slot)

    def finished(self, timeout_s: float) -> list[tuple[Shard, dict | None]]:
        from multiprocessing.connection import wait
        if not self.procs:
            time.sleep(timeout_s)
            return []
        done = []
        for sentinel in wait(list(self.procs), timeout_s):
            proc, recv, shard, _ = self.procs.pop(sentinel)
            proc.join()
            result = None
            try:
                if recv.poll():
                    result = recv.recv()
            except (EOFError, OSError):
                result = None       # died mid-send: lost
            recv.close()
            done.append((shard, result))
        return done

    def stop_all(self) -> None:
        """SIGTERM every worker: each stops its run cleanly and sends what it has."""
        for proc, *_ in self.procs.values():
            if proc.is_alive():
                proc.terminate()

    def drain(self) -> list[tuple[Shard, dict | None]]:
        deadline = time.monotonic() + STOP_WAIT_S
        out = []
        while self.procs and time.monotonic() < deadline:
            try:
                out += self.finished(min(POLL_S, max(0.0, deadline - time.monotonic())))
            except KeyboardInterrupt:
                break               # a second Ctrl-C: stop waiting
        for proc, recv, shard, _ in self.procs.values():
            proc.kill()
            proc.join()
            recv.close()
            out.append((shard, None))
        self.procs.clear()
        return out

    def close(self) -> None:
        if self.procs:
            self.stop_all()
            self.drain()


class _RayBackend:
    """Ray tasks (one per shard) on a cluster, or on a local Ray started for this call."""

    def __init__(self, address: str, workers: int | None,
                 worker: Callable[[Any], dict] = run_task, resources: dict | None = None):
        try:
            import ray
        except ImportError:
            raise RayMissing("--ray needs Ray, which is not installed: "
                             "pip install -e .[ray]") from None
        self.ray = ray
        if address:
            ray.init(address=address, include_dashboard=False, log_to_driver=False)
        else:
            ray.init(include_dashboard=False, log_to_driver=False)
        cpus = int(ray.cluster_resources().get("CPU", 1))
        self.workers = workers if workers and workers > 1 else max(1, cpus)
        # no Ray-level retries: a lost task's missing episodes are retried by fan_out, which
        # knows which of them the lost worker had already finished
        resources = resources or {"num_cpus": 1}
        self.worker = worker
        self.share = max(1, int(resources.get("num_cpus", 1)))
        self.remote = ray.remote(max_retries=0, **resources)(_shared_cpus)
        self.refs: dict = {}        # ObjectRef -> shard

    def running(self) -> bool:
        return bool(self.refs)

    def has_room(self) -> bool:
        return len(self.refs) < self.workers

    def submit(self, shard: Shard, task: Any) -> None:
        self.refs[self.remote.remote(self.worker, task, self.share)] = shard

    def finished(self, timeout_s: float) -> list[tuple[Shard, dict | None]]:
        if not self.refs:
            time.sleep(timeout_s)
            return []
        ready, _ = self.ray.wait(list(self.refs), num_returns=len(self.refs),
                                 timeout=timeout_s)
        done = []
        for ref in ready:
            shard = self.refs.pop(ref)
            try:
                done.append((shard, self.ray.get(ref)))
            except self.ray.exceptions.RayError:
                done.append((shard, None))      # the task raised, or its worker was lost
        return done

    def stop_all(self) -> None:
        for ref in self.refs:
            self.ray.cancel(ref)        # KeyboardInterrupt in the task: it stops its run

    def drain(self) -> list[tuple[Shard, dict | None]]:
        deadline = time.monotonic() + STOP_WAIT_S
        out = []
        while self.refs and time.monotonic() < deadline:
            try:
                out += self.finished(POLL_S)
            except KeyboardInterrupt:
                break
        out += [(shard, None) for shard in self.refs.values()]
        self.refs.clear()
        return out

    def close(self) -> None:
        if self.refs:
            self.stop_all()
            self.drain()
        self.ray.shutdown()
