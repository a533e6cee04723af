"""Finding runs: live ones through their socket directories, any through run.json."""
from __future__ import annotations

import json
import os
import shutil
import time
from pathlib import Path

from .params import clip, short_repr
from .shm import remove_run_rings
from .supervisor import socket_root

STALE_GRACE_S = 10   # a run being set up has a pointer before its run.json
RUN_KEYS = ("name", "run_id", "rundir", "started_at")


class RunInfoError(ValueError):
    """A run.json that `ctl` or `profile` cannot use; the message names the file."""


def _alive(pid) -> bool:
    # a pid <= 0 would ask about a whole process group
    if not isinstance(pid, int) or isinstance(pid, bool) or pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except (ProcessLookupError, OverflowError):
        return False
    except PermissionError:
        return True
    return True


def run_info_problem(info) -> str | None:
    """What makes ``info`` unusable as a run.json (None when nothing): the keys the
    commands read, and endpoints ZeroMQ can connect to."""
    if not isinstance(info, dict):
        return "not a JSON object"
    for key in RUN_KEYS:
        if not isinstance(info.get(key), str):
            return f"key {key!r} missing or not a string"
    actors = info.get("actors")
    if not isinstance(actors, dict):
        return "key 'actors' missing or not an object"
    for name, actor in actors.items():
        if not isinstance(actor, dict):
            return f"actor {short_repr(name)}: not an object"
        for key in ("control", "telemetry"):
            endpoint = actor.get(key)
            if not (isinstance(endpoint, str) and endpoint.startswith(("ipc://", "tcp://"))):
                return f"actor {short_repr(name)}: {key!r} is not an ipc:// or tcp:// endpoint"
    return None


def read_run_info(path: Path) -> dict:
    """A run directory's run.json, or RunInfoError naming the file and what is wrong."""
    try:
        info = json.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise RunInfoError(f"{path}: cannot read: {exc.strerror or exc}") from None
    except UnicodeDecodeError:
        raise RunInfoError(f"{path}: not UTF-8 text") from None
    except ValueError as exc:   # json.JSONDecodeError, and numbers too large to read
        raise RunInfoError(f"{path}: not valid JSON ({clip(str(exc))})") from None
    problem = run_info_problem(info)
    if problem:
        raise RunInfoError(f"{path}: not a usable run.json: {problem}")
    return info


def live_runs(collect_stale: bool = True) -> list[dict]:
    """run.json of every run whose supervisor is alive, newest first.

    A socket directory whose supervisor died without cleaning up (kill -9) is removed,
    together with any shared-memory ring of that run.
    """
    runs = []
    for pointer in socket_root().glob("sebvs-*/rundir"):
        try:
            info = json.loads((Path(pointer.read_text().strip()) / "run.json").read_text())
        except (OSError, ValueError):
            info = {}
        if not isinstance(info, dict):
            info = {}
        if _alive(info.get("supervisor_pid")):
            if info.get("status") in ("starting", "running") and not run_info_problem(info):
                runs.append(info)
        elif collect_stale and time.time() - pointer.stat().st_mtime > STALE_GRACE_S:
            run_id = pointer.parent.name.removeprefix("sebvs-")
            remove_run_rings(run_id)
            shutil.rmtree(pointer.parent, ignore_errors=True)
    runs.sort(key=lambda i: i.get("started_at", ""), reverse=True)
    return runs


def resolve_run(run: str | None) -> dict:
    """A run's run.json from its directory, its name, its id, or (None) the newest live run."""
    if run:
        path = Path(run)
        if (path / "run.json").is_file():
            return read_run_info(path / "run.json")
        matches = [i for i in live_runs()
                   if run in (i["name"], i["run_id"], Path(i["rundir"]).name)]
        if matches:
            return matches[0]
        raise LookupError(f"no live run named {run!r} and no run.json in {run!r} "
                          f"(see `sebvs ps`)")
    runs = live_runs()
    if not runs:
        raise LookupError("no live run (start one with `sebvs run TOPOLOGY`)")
    return runs[0]
