"""Finding runs: live ones through their socket directories, any through run.json."""
from __future__ import annotations

import json
import os
from pathlib import Path

from .supervisor import socket_root


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


def live_runs() -> list[dict]:
    """run.json of every run whose supervisor is alive, newest first."""
    runs = []
    for pointer in socket_root().glob("sebvs-*/rundir"):
        try:
            info = json.loads((Path(pointer.read_text().strip()) / "run.json").read_text())
        except (OSError, ValueError):
            continue
        if _alive(info.get("supervisor_pid")) and info.get("status") in ("starting", "running"):
            runs.append(info)
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
