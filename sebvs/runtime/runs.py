"""Finding runs: live ones through their socket directories, any through run.json."""
from __future__ import annotations

import json
import os
import shutil
import time
from pathlib import Path

from .shm import remove_run_rings
from .supervisor import socket_root

STALE_GRACE_S = 10   # a run being set up has a pointer before its run.json


def _alive(pid: int | None) -> bool:
    if not pid:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


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
        if _alive(info.get("supervisor_pid")):
            if info.get("status") in ("starting", "running"):
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
            return json.loads((path / "run.json").read_text())
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
