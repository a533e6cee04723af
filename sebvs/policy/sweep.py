"""Training sweeps: `sebvs train` over a grid (sweep_grid.py), one checkpoint directory per
point, on one process, local worker processes or Ray tasks (sebvs/scale/pool.py's pool).

    summary = run_sweep(load_grid("nav_sweep.toml"), "out/sweep_nav", workers=8, threads=2)
    points, records = plan_sweep(grid, "out/sweep_nav")   # what is trained already

Each point calls `train` exactly as `sebvs train` does, into ``<out>/<point name>/`` (its
checkpoint, config, loss CSV and plot, and ``train.log``: the epoch lines, and the
traceback of a failure); ``<out>/sweep.json`` and ``sweep.md`` are rewritten as each point
ends (sweep_table.py). A point whose checkpoint and config exist is skipped, after
checking that it was trained with the point's settings; a failed or interrupted point has
no config and is trained again. Placement (one process; workers pinned to disjoint CPU
sets where the machine has them; a Ray task per point asking for CPUs or GPUs) changes no
weight: on the CPU with the same threads a point gives one `sebvs train`'s weights.
docs/scale.md, "Sweeps".
"""
from __future__ import annotations

import json
import math
import os
import signal
import sys
import threading
import time
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from .checkpoint import checkpoint_paths
from .sweep_grid import Grid, Point
from .sweep_table import write_summary
from .train import RECIPE_FIELDS

POINT_LOG = "train.log"
# settings handed to `train` as they are (TrainSettings fields of the same names)
TRAIN_KEYS = ("epochs", "batch", "seed", "max_frames", "lr", "patience", "val_fraction", "stem",
              *RECIPE_FIELDS)
# settings a checkpoint config records, and where: how a resumed point is checked
RECORDED = {"modality": ("modality",), "size": ("size",), "stem": ("stem",),
            "event_clip": ("normalisation", "event_clip"), "lr": ("training", "lr"),
            "weight_decay": ("training", "weight_decay"), "loss": ("training", "loss"),
            "batch": ("training", "batch"), "epochs": ("training", "epochs"),
            "patience": ("training", "patience"), "seed": ("training", "seed"),
            "max_frames": ("training", "max_frames"), "memory": ("memory",),
            **{k: ("training", "recipe", k) for k in RECIPE_FIELDS if k != "memory"}}


class SweepError(ValueError):
    """A sweep that cannot start as asked; the message says what and why."""


@dataclass(frozen=True)
class PointJob:
    """What a worker trains: picklable, every path absolute (Ray nodes share the paths)."""
    label: str              # the point's name
    task: str
    data: str
    out: str                # the point's directory
    settings: dict          # the grid's settings for this point
    threads: int
    device: str
    progress: bool          # tqdm bars and epoch lines on stderr (one point at a time only)
    parent_pid: int | None = None   # set by the local pool: stop when the driver is gone


def train_overrides(settings: dict, threads: int, device: str) -> dict:
    """A point's settings as `train`'s keyword arguments, as `sebvs train` passes its
    options (unset ones None: `train` keeps its defaults for them)."""
    from .inputs import Normalisation
    norm = Normalisation(**{k: settings[k] for k in ("size", "event_clip") if k in settings})
    return {**{k: settings.get(k) for k in TRAIN_KEYS}, "num_workers": 0,
            "threads": threads, "device": device, "norm": norm}


def resolved_settings(task: str, settings: dict) -> dict:
    """Every setting a point trains with, defaults filled in (what sweep.json records)."""
    from .train import settings_for
    s = settings_for(task, **train_overrides(settings, 0, "cpu"))
    return {"modality": settings["modality"], "lr": s.lr, "weight_decay": s.weight_decay,
            "loss": s.loss, "epochs": s.epochs, "batch": s.batch, "patience": s.patience,
            "plateau": s.plateau, "val_fraction": s.val_fraction, "seed": s.seed,
            "max_frames": s.max_frames, "size": s.norm.size, "event_clip": s.norm.event_clip,
            "stem": s.stem, **{k: getattr(s, k) for k in RECIPE_FIELDS}}


# ---------------------------------------------------------------------- the worker side
def run_point(job: PointJob) -> dict:
    """Train one point (in this process, a spawned worker or a Ray task).

    Returns {"status": "trained" | "failed" | "interrupted", "wall_s", and the config's
    numbers or "error"}. A failure is reported, not raised: one bad point must not end
    the others. Ctrl-C (SIGINT, or the SIGTERM the local pool sends) ends it as
    "interrupted".
    """
    t0 = time.monotonic()
    if job.parent_pid is not None:      # a local pool's worker process
        signal.signal(signal.SIGTERM, _interrupt)
        _stop_when_orphaned(job.parent_pid)
    out = Path(job.out)
    modality = job.settings["modality"]
    try:
        out.mkdir(parents=True, exist_ok=True)
        log_file = open(out / POINT_LOG, "w", encoding="utf-8")
    except OSError as exc:
        return {"status": "failed", "error": _one_line(exc), "wall_s": _since(t0)}
    with log_file:
        def log(line: str) -> None:
            log_file.write(line + "\n")
            log_file.flush()
            if job.progress:
                print(line, file=sys.stderr)
        try:
            from .train import train
            configs = train(job.data, out, job.task, [modality], progress=job.progress,
                            log=log, **train_overrides(job.settings, job.threads, job.device))
        except KeyboardInterrupt:
            log("interrupted")
            return {"status": "interrupted", "wall_s": _since(t0)}
        except Exception as exc:       # noqa: BLE001 - recorded as the point's failure
            log(traceback.format_exc())
            return {"status": "failed", "error": _one_line(exc), "wall_s": _since(t0)}
    return {"status": "trained", **outcome(configs[modality]), "wall_s": _since(t0)}


def _interrupt(signum, frame) -> None:
    raise KeyboardInterrupt(signal.Signals(signum).name)


def _stop_when_orphaned(parent_pid: int) -> None:
    """A worker whose driver died stops training (its point is then trained again by the
    next run) instead of running on for hours unseen."""
    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(1.0)
        os.kill(os.getpid(), signal.SIGTERM)
    threading.Thread(target=watch, name="watch-driver", daemon=True).start()


def _since(t0: float) -> float:
    return round(time.monotonic() - t0, 2)


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def outcome(config: dict) -> dict:
    """A trained point's numbers, from its checkpoint config (the best loss None when no
    epoch gave a finite one)."""
    t = config.get("training", {})
    best = t.get("best_val_loss")
    finite = isinstance(best, (int, float)) and math.isfinite(best)
    return {"best_val_loss": best if finite else None, "epochs_run": t.get("epochs_run"),
            "seconds": t.get("seconds"), "parameters": config.get("parameters")}


# ---------------------------------------------------------------------- the driver side
def finished_config(point_dir: Path, task: str, modality: str) -> dict | None:
    """The config of a point trained before, or None: no checkpoint, no config, or a config
    cut short (a worker killed while writing it: the point is trained again)."""
    pt, js = checkpoint_paths(point_dir, task, modality)
    if not (pt.is_file() and js.is_file()):
        return None
    try:
        config = json.loads(js.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return config if isinstance(config, dict) and "training" in config else None


def check_resumed(point_dir: Path, config: dict, settings: dict, data: str) -> None:
    """Refuse a trained point whose config says it was trained otherwise than the grid now
    asks (the grid was edited; the point's name does not show every setting)."""
    for key, where in RECORDED.items():
        recorded = config
        for part in where:
            recorded = recorded.get(part) if isinstance(recorded, dict) else None
        if recorded is not None and key in settings and recorded != settings[key]:
            raise SweepError(
                f"{point_dir}: trained before with {key}={recorded!r}, but the grid now asks "
                f"for {key}={settings[key]!r}; give another --out, or delete that directory "
                f"to train the point again")
    trained_on = config.get("dataset", {}).get("path")
    if trained_on is not None and trained_on != data:
        raise SweepError(f"{point_dir}: trained before on {trained_on}, but the grid's data "
                         f"is {data}; give another --out, or delete that directory")


def plan_sweep(grid: Grid, out: str | Path) -> tuple[list[Point], dict]:
    """The grid's points and a record per point: "skipped" (trained before, numbers from
    its config) or "pending"."""
    out = Path(out).resolve()
    points = grid.points()
    records = {}
    for p in points:
        settings = resolved_settings(grid.task, p.settings)
        record = {"name": p.name, "dir": p.name, "status": "pending", "axes": p.axes,
                  "settings": settings, "best_val_loss": None, "epochs_run": None,
                  "seconds": None, "parameters": None, "wall_s": None, "error": None}
        config = finished_config(out / p.name, grid.task, p.settings["modality"])
        if config is not None:
            check_resumed(out / p.name, config, settings, grid.data)
            record.update(status="skipped", **outcome(config))
        records[p.name] = record
    return points, records


def run_sweep(grid: Grid, out: str | Path, *, workers: int = 1, ray: str | None = None,
              threads: int | None = None, device: str = "cpu",
              gpus_per_task: float | None = None, progress: bool = True,
              echo: Callable[[str], None] = lambda text: print(text, file=sys.stderr)
              ) -> dict:
    """Train every point not trained yet; returns the summary written to sweep.json.

    `workers`: points at once on this machine (1: in this process, one after another);
    with `ray` (None: no Ray; "": a local Ray started for the call; else a cluster
    address), Ray tasks in flight (1: as many as the cluster has CPUs; Ray also queues
    tasks by the CPUs and GPUs they ask for). `threads`: torch threads per point (default:
    locally this machine's CPUs shared among the workers, on Ray 1).
    """
    gpus = _check_sweep(grid, workers, threads, device, ray, gpus_per_task)
    out = Path(out).resolve()
    points, records = plan_sweep(grid, out)
    todo = [p for p in points if records[p.name]["status"] == "pending"]
    place = _placement(len(todo), workers, threads, ray, gpus)

    from .train import paper_settings
    summary = {"grid": grid.path, "task": grid.task, "data": grid.data,
               "loss": paper_settings(grid.task).loss, "train": grid.base, "axes": grid.axes,
               "run": {"workers": workers, "ray": ray, "threads": place.threads,
                       "device": device, "gpus_per_task": gpus or None,
                       "cpu_sets": [list(c) for c in place.pinned] if place.pinned else None},
               "points": [records[p.name] for p in points]}
    echo(f"sebvs train-sweep: {len(points)} point(s), {len(points) - len(todo)} trained before "
         f"(skipped), " + (f"{len(todo)} to train on {place.where}" if todo
                           else "nothing to train"))
    out.mkdir(parents=True, exist_ok=True)
    write_summary(out, summary)
    if todo:
        _train_points(grid, out, todo, records, summary, place, device, progress, echo)
    return summary


def _check_sweep(grid: Grid, workers: int, threads: int | None, device: str,
                 ray: str | None, gpus_per_task: float | None) -> float:
    """SweepError, one line, for options that cannot run or a grid whose dataset is
    missing or wrong (one error, not a failure per point); else the GPUs per Ray task."""
    from .dataset import load_index
    if workers < 1:
        raise SweepError(f"--workers must be at least 1, got {workers}")
    if threads is not None and threads < 1:
        raise SweepError(f"--threads must be at least 1, got {threads}")
    gpus = _gpus_per_task(device, ray, gpus_per_task)
    try:
        load_index(grid.data, grid.task)
    except (FileNotFoundError, ValueError) as exc:
        raise SweepError(f"grid {grid.path}: data: {exc}") from None
    return gpus


@dataclass(frozen=True)
class Placement:
    """Where a sweep's points train (`_placement`)."""
    workers: int                  # as asked (run_sweep's)
    ray: str | None               # as asked (run_sweep's)
    gpus: float                   # GPUs per Ray task (0: none asked)
    running: int                  # points at once (Ray: tasks in flight, as asked)
    threads: int                  # torch threads per point
    parallel: bool                # more than one point at once (or on Ray)
    pinned: list | None           # a CPU set per local worker, where the machine has them
    where: str                    # the above in words, for the first line


def _placement(todo: int, workers: int, threads: int | None, ray: str | None,
               gpus: float) -> Placement:
    """The placement of ``todo`` points: `run_sweep`'s options resolved (threads by
    default this machine's CPUs shared among the local workers, 1 on Ray)."""
    from sebvs.scale import disjoint_cpu_sets
    running = min(workers, todo) if ray is None else workers
    if threads is None:
        threads = 1 if ray is not None else \
            max(1, len(os.sched_getaffinity(0)) // max(1, running))
    parallel = ray is not None or running > 1
    pinned = disjoint_cpu_sets(running, threads) if ray is None and running > 1 else None
    where = (f"Ray ({ray or 'local'}), {threads} CPU(s)" + (f" and {gpus:g} GPU(s)" if gpus
                                                             else "") + " per task"
             if ray is not None else
             f"{running} local worker(s), {threads} torch thread(s) each" +
             (", CPUs " + " | ".join(",".join(map(str, c)) for c in pinned) if pinned else
              ", not pinned" if running > 1 else ""))
    return Placement(workers, ray, gpus, running, threads, parallel, pinned, where)


def _train_points(grid: Grid, out: Path, todo: list[Point], records: dict, summary: dict,
                  place: Placement, device: str, progress: bool,
                  echo: Callable[[str], None]) -> None:
    """Train the ``todo`` points as ``place`` says, each point's record updated and the
    summary rewritten as it ends (and once more at the end, however it ends)."""
    from sebvs.scale import Shard, fan_out
    jobs = {p.name: PointJob(p.name, grid.task, grid.data, str(out / p.name), p.settings,
                             place.threads, device, progress and not place.parallel)
            for p in todo}
    finished = []

    def collect(name: str, result: dict | None) -> None:
        record = records[name]
        if result is None:
            result = {"status": "failed", "error": f"worker lost: it died without a result "
                                                   f"(see {out / name / POINT_LOG})"}
        elif "status" not in result:    # the pool's report of a worker that raised
            failure = (result.get("failure") or "worker failed").strip().splitlines()
            result = {"status": "failed", "error": failure[0]}
        record.update({k: v for k, v in result.items() if k in record and k != "name"})
        finished.append(name)
        write_summary(out, summary)
        echo(f"sebvs train-sweep: [{len(finished)}/{len(todo)}] {name}: {_result_line(record)}")

    def collect_shard(shard, result: dict | None) -> list[int]:
        collect(shard.job, result)
        return []       # nothing to retry: a failed point is recorded, the next run retries it

    ray, workers, gpus = place.ray, place.workers, place.gpus
    try:
        if not place.parallel:
            for p in todo:
                collect(p.name, run_point(jobs[p.name]))
                if records[p.name]["status"] == "interrupted":
                    raise KeyboardInterrupt
        else:
            resources = {"num_cpus": place.threads, **({"num_gpus": gpus} if gpus else {})}
            fan_out([Shard(name, 0, 1) for name in jobs], lambda shard: jobs[shard.job],
                    collect_shard,
                    workers=workers if ray is None else (workers if workers > 1 else None),
                    ray=ray, max_attempts=1, worker=run_point, cpu_sets=place.pinned,
                    ray_resources=resources, echo=echo)
    finally:
        write_summary(out, summary)


def _gpus_per_task(device: str, ray: str | None, gpus_per_task: float | None) -> float:
    cuda = device.startswith("cuda")
    if gpus_per_task is not None:
        if not cuda or ray is None:
            raise SweepError("--gpus-per-task is for --ray with --device cuda (Ray gives each "
                             "task its GPUs); local workers all use this machine's device")
        if not (gpus_per_task > 0 and math.isfinite(gpus_per_task)):
            raise SweepError(f"--gpus-per-task must be positive, got {gpus_per_task}")
        return gpus_per_task
    return 1.0 if cuda and ray is not None else 0.0


def _result_line(record: dict) -> str:
    if record["status"] != "trained":
        return record["status"].upper() + (f": {record['error']}" if record["error"] else "")
    best = record["best_val_loss"]
    epochs = record["epochs_run"]
    return (f"best val loss {best:.5g}" if best is not None else "no finite validation loss") + \
        f" ({epochs} epoch{'s' if epochs != 1 else ''}, {record['wall_s']:.1f} s)"
