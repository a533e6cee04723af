"""`sebvs eval`'s runner: plays an EvalPlan's runs and writes results.json and the report.

    from sebvs.eval.plan import EvalPlan
    from sebvs.eval.run import evaluate
    results = evaluate(EvalPlan(task="arm", modalities=["rgb"], conditions=["hdr"],
                                episodes=5, out=Path("out/eval")))

Each run (sebvs/eval/plan.py: one condition, scenario and modality) is one topology run of
N seeded episodes; the tracker sink appends one JSON line per finished episode; this
module supervises the runs with a progress bar and aggregates.

Resuming: a (condition, scenario, modality) whose episode file already holds N episodes of
this topology seed is skipped; one that holds fewer is run again from its first episode
(runs are short and episodes are seeded, so the numbers are the same). With `video`, a
run whose videos are missing is run again too.

Fan-out (`workers`, `ray`; docs/scale.md): the runs' episodes are played as shards on
worker processes or Ray tasks (`run_fanout`), each shard episodes [a, b) of one run with
the seeds and numbers one process would give them, merged in episode order: the same
results.json for any worker count.

Run health: each episode line carries the sim's and the tracker's counters (actors/
tracker.py, "health"); the handler errors, which only the actors' stats hold, are kept per
run in <out>/episodes/<run>.health.json (summed over a fan-out's shards), so a resumed
evaluation still has them. results.json "runs" sums both per run; a run whose sim applied
no command at all ("never_acted") makes `sebvs eval` exit 1.
"""
from __future__ import annotations

import json
import math
import os
import secrets
import sys
import time
from pathlib import Path

from tqdm import tqdm

from ..runtime.overrides import merge
from ..runtime.supervisor import RunFailed, Supervisor
from ..runtime.topology import load_topology
# the plan's names, importable from here as they always were (tools, users' scripts)
from .plan import BASELINE, MODALITIES, EvalPlan, Run, condition_sensor  # noqa: F401
from .report import TRACES, write_outputs

# an episode line's "health" counters (actors/tracker.py); lines written before them read 0
HEALTH_COUNTERS = ("commands", "rejected", "action_timeouts", "deadline_misses", "actions",
                   "nonfinite_actions")


def _read_episodes(path: Path, seed: int | None = None) -> list[dict]:
    """The episode lines of a run; with `seed`, only up to the first line of another
    topology seed (or of none: written before lines named it), so that an output directory
    reused with another split or seed never passes one split's episodes off as another's."""
    if not path.exists():
        return []
    out = []
    for line in path.read_text().splitlines():
        try:
            rec = json.loads(line)
        except json.JSONDecodeError:
            break   # a line cut by an interruption: what follows is not trusted
        if seed is not None and rec.get("topology_seed") != seed:
            break
        out.append(rec)
    return out


def handler_errors(losses: dict | None) -> dict[str, int]:
    """{"actor.input": n} of the inputs whose handler raised, from a Supervisor's losses
    (run.json "losses", sebvs/runtime/stalls.py)."""
    return {name: int(lost["errors"]) for name, lost in (losses or {}).items()
            if isinstance(lost, dict) and lost.get("errors")}


def _write_health(plan: EvalPlan, run: Run, errors: dict[str, int]) -> None:
    path = plan.health_file(run)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(json.dumps({"topology_seed": plan.seed,
                               "handler_errors": dict(sorted(errors.items()))}) + "\n")
    os.replace(tmp, path)


def _read_health(plan: EvalPlan, run: Run) -> dict[str, int]:
    """The run's handler errors as written after it; {} where none were written (a run
    of an older version) or they are another seed's."""
    try:
        saved = json.loads(plan.health_file(run).read_text())
    except (OSError, ValueError):
        return {}
    if not isinstance(saved, dict) or saved.get("topology_seed") != plan.seed \
            or not isinstance(saved.get("handler_errors"), dict):
        return {}
    return {str(k): int(v) for k, v in saved["handler_errors"].items()
            if isinstance(v, int) and v > 0}


def run_health(plan: EvalPlan, run: Run, episodes: list[dict]) -> dict:
    """One run's counters summed over its episodes, its handler errors, and whether it
    never acted: the sim applied none of its commands (all rejected, or none came)."""
    sums = dict.fromkeys(HEALTH_COUNTERS, 0)
    counted = 0
    for rec in episodes:
        health = rec.get("health")
        if not isinstance(health, dict):
            continue            # a line written before the counters: zeros
        counted += 1
        for k in HEALTH_COUNTERS:
            v = health.get(k)
            sums[k] += int(v) if isinstance(v, (int, float)) and math.isfinite(v) else 0
    return {"condition": run.condition, "scenario": run.scenario, "modality": run.modality,
            "episodes": len(episodes), **sums, "handler_errors": _read_health(plan, run),
            "never_acted": counted > 0 and sums["commands"] - sums["rejected"] <= 0}


def play_to_end(topology, overrides, runs_dir: Path, bar: tqdm, what: str) -> Supervisor:
    """Run a topology to its end, its tracker's finished episodes moving `bar` on.

    Parameters:
        topology, overrides: what load_topology reads (a path and override layers).
        runs_dir: where the run's directory goes.
        bar: the progress bar, moved by the tracker actor's episodes_finished.
        what: the run as an error names it.

    Returns:
        The stopped supervisor (its info, rundir).

    Raises:
        RunFailed: the run did not end cleanly, naming `what` and the failure.
    """
    sup = Supervisor(load_topology(topology, overrides), runs_dir=runs_dir,
                     echo=lambda text: tqdm.write(text))
    done_before = bar.n
    last_poll = [0.0]

    def poll(dt: float) -> None:
        time.sleep(dt)
        if time.monotonic() - last_poll[0] < 0.5:
            return
        last_poll[0] = time.monotonic()
        reply = sup.request("tracker", {"cmd": "stats"}, 0.5)
        if reply and reply.get("ok"):
            n = reply["result"]["actor_stats"]["episodes_finished"]
            bar.update(done_before + n - bar.n)

    try:
        sup.start()
        code = sup.wait(None, poll)
    except BaseException:
        sup.stop()
        raise
    if code != 0:
        raise RunFailed(f"{what}: {sup.failure}")
    return sup


def run_one(plan: EvalPlan, run: Run, bar: tqdm) -> list[dict]:
    path = plan.episode_file(run)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.unlink(missing_ok=True)
    plan.health_file(run).unlink(missing_ok=True)
    if plan.video:      # a rerun with fewer --video-episodes leaves no stale files behind
        for old in (plan.out / "videos").glob(f"{run.key}__ep*"):
            old.unlink()
    topology, overrides = plan.overrides(run)
    done_before = bar.n
    sup = play_to_end(topology, overrides, plan.out / "runs", bar, str(run))
    # the live actors' last stats, queried as the run stopped (an actor that ended
    # first, the sim, counts as of the supervisor's last stall round)
    _write_health(plan, run, handler_errors(sup.info.get("losses")))
    episodes = _read_episodes(path, plan.seed)
    bar.update(done_before + len(episodes) - bar.n)
    if len(episodes) < plan.episodes:
        raise RunFailed(f"{run}: {len(episodes)} of {plan.episodes} episodes finished "
                        f"(see {sup.rundir}/logs)")
    return episodes


def run_fanout(plan: EvalPlan, runs: list[Run], bar: tqdm) -> None:
    """Every run's episodes as shards on workers (sebvs/scale), merged in episode order.

    A run is split into ceil(workers / runs) contiguous episode ranges (several runs fill
    the workers first, each started once), queued longest first; a shard plays episodes
    [a, b) of its run (sim.first_episode = a: the seeds and episode numbers of one
    process) and its tracker writes
    <out>/episodes/.shards/<run>.<token>.<a>-<b>.try<n>.jsonl. The driver keeps
    the lines of the shard's episodes and, once a run has all N, writes the run's episode
    file sorted by episode (tmp file + rename): the same lines whatever the split or the
    order the workers finished in. A run that is not complete is rerun whole on resume,
    as without workers.
    """
    from ..scale import RayMissing, Shard, ShardsLost, Task, fan_out, split_episodes
    if not runs:
        return
    shard_dir = (plan.out / "episodes" / ".shards").resolve()
    shard_dir.mkdir(parents=True, exist_ok=True)
    token = secrets.token_hex(3)
    workers = plan.workers or (os.cpu_count() or 1)
    parts = max(1, -(-workers // len(runs)))
    lines: dict[Run, dict[int, dict]] = {run: {} for run in runs}
    errors: dict[Run, dict[str, int]] = {run: {} for run in runs}
    live: dict[Shard, Path] = {}
    shards = []
    for run in runs:
        plan.episode_file(run).unlink(missing_ok=True)
        plan.health_file(run).unlink(missing_ok=True)
        if plan.video:      # as run_one: a rerun leaves no stale videos behind
            for old in (plan.out / "videos").glob(f"{run.key}__ep*"):
                old.unlink()
        shards += [Shard(run, a, b) for a, b in split_episodes(0, plan.episodes, parts)]
    # longest first: a worker that starts a long shard last keeps the others idle at the
    # end. A shard's work is taken as episodes x the actors its topology runs (an event
    # chain adds two), a learned policy counted twice (torch: its import and a network per
    # tick); sorted stably, so equal shards keep the order of the runs
    weight = {run: len(load_topology(*plan.overrides(run)).active)
              + (run.modality in MODALITIES) for run in runs}
    shards.sort(key=lambda s: -(s.stop - s.first) * weight[s.job])

    def task_of(shard: Shard) -> Task:
        path = shard_dir / (f"{shard.job.key}.{token}.{shard.first}-{shard.stop}"
                            f".try{shard.attempt}.jsonl")
        path.unlink(missing_ok=True)
        live[shard] = path
        topology, overrides = plan.overrides(shard.job)
        shard_sets = {"tracker": {"path": str(path)},
                      "sim": {"first_episode": shard.first,
                              "episodes": shard.stop - shard.first}}
        return Task(str(shard), str(Path(topology).resolve()), merge(overrides, shard_sets),
                    str((plan.out / "runs").resolve()))

    def progress() -> None:
        running = sum(len(_read_episodes(p, plan.seed)) for p in live.values())
        done = sum(len(v) for v in lines.values())
        delta = skipped + done + running - bar.n
        if delta > 0:       # an update of 0 would redraw the bar every poll
            bar.update(delta)

    def collect(shard: Shard, result: dict | None) -> list[int]:
        path = live.pop(shard)
        have = lines[shard.job]
        # every attempt's: a retried shard's errors happened in this evaluation too
        for name, n in handler_errors((result or {}).get("losses")).items():
            errors[shard.job][name] = errors[shard.job].get(name, 0) + n
        for rec in _read_episodes(path, plan.seed):
            k = rec.get("episode")
            if isinstance(k, int) and shard.first <= k < shard.stop:
                have.setdefault(k, rec)
        path.unlink(missing_ok=True)
        if len(have) == plan.episodes:
            # before the episodes: a complete episode file is what resume skips on
            _write_health(plan, shard.job, errors[shard.job])
            _write_lines_atomic(plan.episode_file(shard.job),
                                [have[k] for k in sorted(have)])
        progress()
        return [k for k in range(shard.first, shard.stop) if k not in have]

    skipped = bar.n             # episodes of the runs finished before (resume)
    try:
        fan_out(shards, task_of, collect, workers=plan.workers, ray=plan.ray,
                max_attempts=plan.max_attempts, on_poll=progress,
                echo=lambda text: tqdm.write(text), start="fork")
    except (ShardsLost, RayMissing) as exc:
        raise RunFailed(str(exc)) from None
    finally:
        for path in live.values():
            path.unlink(missing_ok=True)
        try:
            shard_dir.rmdir()
        except OSError:
            pass


def _write_lines_atomic(path: Path, records: list[dict]) -> None:
    """JSON lines as the tracker writes them, replacing `path` whole or not at all."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text("".join(json.dumps(rec) + "\n" for rec in records))
    os.replace(tmp, path)


def evaluate(plan: EvalPlan) -> dict:
    plan.validate()
    plan.out.mkdir(parents=True, exist_ok=True)
    for note in plan.event_frame_notes():
        print(f"sebvs eval: note: {note}", file=sys.stderr)
    runs = plan.runs()
    bar = tqdm(total=len(runs) * plan.episodes, unit="episode", desc="eval")
    todo = []
    for run in runs:
        have = _read_episodes(plan.episode_file(run), plan.seed)
        if len(have) >= plan.episodes and not plan.videos_missing(run):
            bar.update(plan.episodes)
            continue
        todo.append(run)
    if plan.fans_out:
        run_fanout(plan, todo, bar)
    else:
        for run in todo:
            bar.set_postfix_str(str(run))
            run_one(plan, run, bar)
    bar.close()
    rng = plan.seed_range
    results = {"task": plan.task, "clock": plan.clock, "split": plan.split,
               "seed_range": [rng.first, rng.last], "seed": plan.seed,
               "scenarios": list(plan.scenarios), "episodes_per_run": plan.episodes,
               "episodes": []}
    if plan.extra:      # the overrides every run had (an ablation among them), as given
        results["overrides"] = plan.extra_given()
    sensors = plan.event_sensors()
    if sensors:         # the event rows' emulator, as their topologies ran it
        results["event_sensor"] = sensors
    trace = TRACES[plan.task].key
    results["runs"] = []
    for run in runs:
        records = _read_episodes(plan.episode_file(run), plan.seed)[:plan.episodes]
        results["runs"].append(run_health(plan, run, records))
        for rec in records:
            results["episodes"].append({"modality": run.modality, "condition": run.condition,
                                        "scenario": run.scenario,
                                        "seed": rec["seed"], "metrics": rec["metrics"],
                                        trace: rec.get(trace, []),
                                        "inference_ms": rec.get("inference_ms", [])})
    if plan.video:
        results["videos"] = [str(q.relative_to(plan.out)) for run in runs
                             for p in plan.video_files(run)
                             for q in (p, p.with_suffix(".avi")) if q.exists()]
    write_outputs(results, plan.out)
    return results
