"""``sebvs record TOPOLOGY --episodes N --out DIR``: run a recording topology to N episodes.

Runs the topology with the runtime's Supervisor, overriding the recorder's ``out``,
``episodes`` and ``topology`` params, and shows a progress bar (episodes, frames, speed in
simulated seconds per wall second) from the recorder's ``stats`` on its control socket.
The recorder ends the run after N finished episodes; numbering resumes in an existing
dataset, and so do the seed's episodes: a dataset holding M episodes gets episodes M..
of the seed (the sim's ``first_episode``), so a resumed or extended recording never
repeats a scene under a new number. A topology seed in the test split's range
(sebvs/data/splits.py) is refused before anything starts: held-out episodes stay held
out only if no recording ever makes them.

Overrides: the recorder's ``overrides`` get what the user asked for beyond the file, in
order: the ``--sensor`` pair and the ``--condition`` / ``--scenario`` (sebvs/conditions.py:
one named condition, the randomised mix off) as mappings, then the ``--set`` lines as
typed; it applies them to the file's content it stores and stores them beside it, so each
episode says what ran and what was asked.

Fan-out (``--workers N``, ``--ray [ADDRESS]``; docs/scale.md): the run's episodes
[M, M + N) (M: the dataset's next number) are split into contiguous ranges [a, b), one
per worker (sebvs/scale). A worker runs the topology with the sim's ``first_episode = a``
and ``episodes = b - a``, so episode k is seeded episode_seed(topology seed, k) and
numbered k whatever the split, and its recorder writes into a staging directory of its
own, ``<out>/.staging/<shard>/`` (same filesystem: moves are renames). The driver adopts
each finished file as soon as it appears: it reads the file's ``sim_episode`` attribute
(k), renames it to ``episode_<base + k>.h5`` in the dataset (base 0 from this version
on; a staging directory of an older driver names its own) and adds it to index.json
(atomic rewrite, in number order). A worker that fails or is lost is run again for the
episodes still missing, a bounded number of times. A driver that dies loses nothing
finished: the next ``sebvs record`` into the dataset first adopts what the staging
directories hold (each names its base in shard.json), then numbers on from there.

Filling (``--fill``): a stopped fan-out leaves holes, one at the end of each worker's range,
and numbering on from the highest would skip them. ``--fill --episodes N`` records exactly
the numbers below N the dataset lacks, as shards over those ranges, so the dataset ends
holding episodes 0..N-1, each episode k the one an unbroken run would have recorded.

A share of hard conditions (``--hard-share F [--hard-conditions a,b,c]``, the assignment in
sebvs/data/condition_mix.py): the dataset is to hold episodes 0..N-1 (as with --fill),
round(F * N) of them, interleaved by number, each under one hard condition (taking turns),
the rest under the randomised mix. A condition's overrides hold for a whole run, so each
maximal run of consecutive numbers under one condition is a shard of its own, whose
overrides are the condition's (those of ``--condition``) but for the randomised mix: a hard
shard keeps the topology's ``randomise`` table less what the condition and ``--scenario``
fix (condition_mix.mix_left), so its episodes still draw the scene variant, target speed
or belt, blur, ... the condition leaves open, where ``--condition`` records one scene. The
driver stamps each file's ``condition`` attribute (the condition's name, or "randomised")
as it adopts it. The plan (share, conditions, scenario, and ``mix_kept``) is kept in
index.json under "condition_mix": a rerun records the missing numbers, each under the
condition the plan gives it, and a recording that asks for another plan (or none) is
refused in one line while the dataset holds episodes, as is a dataset whose plan lacks
``mix_kept`` (an earlier version's hard episodes, recorded without the mix).
"""
from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import json
import os
import secrets
import shutil
import signal
import sys
import time
from pathlib import Path

RECORDER_CLASS = "actors.recorder:Recorder"
STAGING = ".staging"        # <out>/.staging/<shard>/: where fan-out workers record
SHARD_INFO = "shard.json"   # in each: {"base", "first", "stop"}


def find_recorder(topo) -> str:
    # actors.recorder:Recorder or :LockstepRecorder (or a user's subclass named *Recorder)
    names = [n for n, a in topo.actors.items() if a.run.split(":")[-1].endswith("Recorder")]
    if len(names) != 1:
        raise LookupError(f"{topo.path if hasattr(topo, 'path') else 'topology'}: expected "
                          f"one recorder actor ({RECORDER_CLASS}), found {names or 'none'}")
    return names[0]


class Progress:
    """Polls the recorder's stats every `every_s` while the supervisor waits."""

    def __init__(self, sup, recorder: str, episodes: int, every_s: float = 0.5,
                 enabled: bool = True):
        from tqdm import tqdm
        self.sup, self.recorder, self.every_s = sup, recorder, every_s
        self.t0 = time.monotonic()
        self.next_poll = 0.0
        self.last: dict = {}
        self.bar = tqdm(total=episodes, unit="ep", desc="recording", disable=not enabled,
                        dynamic_ncols=True)

    def __call__(self, poll_s: float) -> None:
        time.sleep(poll_s)
        now = time.monotonic()
        if now < self.next_poll:
            return
        self.next_poll = now + self.every_s
        self.refresh()

    def refresh(self) -> None:
        if self.recorder not in self.sup.specs:
            return
        reply = self.sup.request(self.recorder, {"cmd": "stats"}, 0.5)
        if not reply or not reply.get("ok"):
            return
        st = reply["result"].get("actor_stats", {})
        if not st:
            return
        self.last = st
        wall = time.monotonic() - self.t0
        self.bar.n = min(st["episodes"], self.bar.total or st["episodes"])
        self.bar.set_postfix(frames=st["frames"] + st["frames_in_progress"],
                             speed=f"{st['sim_s'] / max(wall, 1e-9):.1f}x",
                             lost_ticks=st["incomplete_ticks"], refresh=False)
        self.bar.refresh()

    def close(self) -> None:
        self.bar.close()


def is_recording(path: Path) -> bool:
    """A folder `sebvs record` may add to: a dataset, or what a recording leaves before its
    index exists (episode files, a .partial, a fan-out's staging folder)."""
    from sebvs.dataset_files import EPISODE_RE
    from sebvs.output_guard import is_dataset_dir
    return is_dataset_dir(path) or all(
        EPISODE_RE.match(q.name) or q.name == STAGING or q.name.startswith(".index.json.")
        for q in path.iterdir())


def requested_overrides(args, keep_mix: bool = False) -> list:
    """What the user asked `sebvs record` to change, as override layers in order: the
    sensor pair (--sensor), the condition and scenario (--condition, --scenario: a named
    condition of sebvs/conditions.py in place of the topology's randomised mix), then the
    --set lines as typed. The recorder keeps them as the episodes' provenance.

    Parameters:
        args: the parsed command line (callers building their own may leave out sensor,
            condition and scenario).
        keep_mix: a hard shard's (hard_share_jobs): the condition keeps what the
            randomised mix draws beyond it (condition_overrides).

    Returns:
        The layers. ValueError, in one line, for an unknown condition or scenario (the
        known ones listed) or a condition of another sensor pair than --sensor.
    """
    from sebvs.sensor_pairs import sensor_overrides
    from sebvs.runtime.topology import load_topology
    sensor = getattr(args, "sensor", None)
    condition, scenario = getattr(args, "condition", None), getattr(args, "scenario", None)
    given: list = [sensor_overrides(sensor)] if sensor else []
    if scenario and not condition:
        raise ValueError("--scenario needs --condition (the topology's randomised mix "
                         "draws its own scenes)")
    if condition:
        topo = load_topology(args.topology, [*given, *args.set])
        given.append(condition_overrides(topo, condition, scenario, sensor, keep_mix))
    return [*given, *args.set]


def condition_overrides(topo, condition: str, scenario: str | None = None,
                        sensor: str | None = None, keep_mix: bool = False) -> dict:
    """A recording topology made to record one named condition (and scenario) of its
    task instead of its randomised mix (`--condition`: one condition, one scene), or, with
    `keep_mix`, under it within the mix (a --hard-share shard).

    Parameters:
        topo: the recording topology (its sim's scene names the task; its sim's
            `randomise` the mix).
        condition: a condition of the task (sebvs/conditions.py).
        scenario: one of its scenarios; None: the topology's scene as written.
        sensor: the --sensor pair given beside it, which the condition must agree with.
        keep_mix: False: no randomisation. True: the topology's randomise table less the
            sim config keys these overrides set and the keys qualifying them
            (condition_mix.mix_left: an hdr shard of nav_record still draws variant,
            target_speed and rgb_blur, not lighting or flicker_hz).

    Returns:
        The overrides: the sim's randomise table (replaced whole), the condition's (its
        event sensor where the topology has an emulator), the scenario's. ValueError, in
        one line, otherwise.
    """
    from sebvs.conditions import task
    from sebvs.runtime.overrides import lookup, merge, replace
    from .condition_mix import mix_left
    sim = first_episode_actor(topo)
    spec = task(topo.actors[sim].params.get("scene", "nav"))
    chosen = spec.condition(condition)
    if sensor is not None and chosen.sensor != sensor:
        raise ValueError(f"condition {condition!r} is the {chosen.sensor} sensor pair's, "
                         f"not --sensor {sensor}'s")
    layers = [chosen.overrides()]
    if any(a.run.endswith(":Emulator") for a in topo.actors.values()):
        layers.append(chosen.event_sensor_overrides())
    if scenario is not None:
        layers.append(spec.scenario(scenario).overrides())
    sets = merge(*layers)
    mix = mix_left(topo.actors[sim].params.get("randomise") or {},
                   lookup(sets, sim, "config", default={})) if keep_mix else {}
    return merge({sim: {"randomise": replace(mix)}}, sets)


def _camera_sensor(topo) -> str | None:
    """The sensor pair the topology's camera records through (its `sensor` parameter, or
    the parameter's default), None without a camera."""
    for actor in topo.actors.values():
        if actor.run.endswith(":Camera") and not actor.pruned:
            fields = {f.name: f for f in dataclasses.fields(actor.cls.Params)} \
                if dataclasses.is_dataclass(getattr(actor.cls, "Params", None)) else {}
            default = fields["sensor"].default if "sensor" in fields else None
            return actor.params.get("sensor", default)
    return None


def hard_share_mix(args, topo):
    """The share of hard conditions `args` asks for (--hard-share, --hard-conditions,
    --scenario), or None.

    Parameters:
        args: the parsed command line.
        topo: the recording topology with the run's overrides (its sim's scene names the
            task, whose default hard conditions apply without --hard-conditions).

    Returns:
        A ConditionMix, or None without --hard-share. ValueError, in one line, for a share
        out of range, an unknown condition or scenario, a condition of another sensor pair
        than the topology's camera records, or --hard-conditions without --hard-share.
    """
    from sebvs.conditions import task
    from .condition_mix import (ConditionMix, default_conditions, parse_conditions,
                                parse_share)
    share, names = getattr(args, "hard_share", None), getattr(args, "hard_conditions", None)
    if share is None:
        if names is not None:
            raise ValueError("--hard-conditions needs --hard-share (the share of episodes "
                             "recorded under them)")
        return None
    spec = task(topo.actors[first_episode_actor(topo)].params.get("scene", "nav"))
    conditions = parse_conditions(names) if names is not None else default_conditions(
        spec.name)
    scenario = getattr(args, "scenario", None)
    if scenario is not None:
        spec.scenario(scenario)
    sensor = _camera_sensor(topo)
    flag = "--hard-conditions" if names is not None else \
        f"--hard-share (the {spec.name} task's default hard conditions)"
    for name in conditions:
        try:
            chosen = spec.condition(name)
        except ValueError as exc:
            raise ValueError(f"{flag}: {exc}") from None
        if sensor is not None and chosen.sensor != sensor:
            raise ValueError(f"{flag}: {name!r} is the {chosen.sensor} sensor "
                             f"pair's, and the topology's camera records {sensor} (give "
                             f"--sensor {chosen.sensor}, or the {sensor} pair's conditions: "
                             f"{', '.join(spec.names(sensor))})")
    return ConditionMix(parse_share(share), conditions, scenario)


def recorder_overrides(args, recorder: str, out: Path, given: list,
                       condition: str | None = None) -> list:
    """`given` and, last, the recorder's own settings for a run of `sebvs record`: it
    applies `given` to the file it stores, so the episodes say what ran, and stores
    `condition` (a --condition run's name, or a hard share's job: hard_share_jobs) as
    each episode's ``condition`` attribute."""
    own = {"out": str(out), "episodes": args.episodes,
           "topology": str(Path(args.topology).resolve()), "overrides": list(given)}
    if condition or getattr(args, "condition", None):
        own["condition"] = condition or args.condition
    return [*given, {recorder: own}]


def hard_share_jobs(args, recorder: str, out: Path, given: list, mix) -> dict:
    """Each condition's overrides for a --hard-share recording, as one mapping per job.

    Parameters:
        args: the parsed command line (topology, sensor, set, episodes).
        recorder: the recorder actor's name.
        out: the dataset.
        given: the run's own override layers (requested_overrides without a condition).
        mix: the ConditionMix.

    Returns:
        {condition name: overrides}: RANDOMISED's are the run's own (`given`), each hard
        condition's those of `--condition NAME --scenario S` with the same --sensor and
        --set lines, except that the sim keeps the randomised mix less what the condition
        and scenario fix (condition_overrides with keep_mix). ValueError, in one line,
        where a --set line puts a fixed key back into the mix (it would draw over the
        condition).
    """
    from sebvs.runtime.overrides import as_mapping, lookup
    from sebvs.runtime.topology import load_topology
    from .condition_mix import RANDOMISED
    jobs = {RANDOMISED: as_mapping(recorder_overrides(args, recorder, out, given,
                                                      RANDOMISED))}
    sim = first_episode_actor(load_topology(args.topology, given))
    for name in dict.fromkeys(mix.conditions):
        one = argparse.Namespace(**{**vars(args), "condition": name,
                                    "scenario": mix.scenario})
        layers = requested_overrides(one, keep_mix=True)
        jobs[name] = as_mapping(recorder_overrides(args, recorder, out, layers, name))
        # the condition's layer holds the mix it leaves; the --set lines come after it
        condition_layer = layers[len(layers) - len(args.set) - 1]
        left = lookup(condition_layer, sim, "randomise", default={})
        drawn = lookup(jobs[name], sim, "randomise", default={}) or {}
        over = sorted(set(drawn) - set(left))
        if over:
            raise ValueError(f"--set puts {', '.join(over)} into {sim}.randomise, which hard "
                             f"condition {name!r} fixes; give the randomised episodes' mix in "
                             f"a copy of the topology file instead")
    return jobs


def dataset_plan(out: Path) -> tuple[dict | None, int]:
    """A dataset's stored condition-mix plan (None: none) and how many episodes it holds
    (indexed, or files on disk, .partial ones included)."""
    from .condition_mix import PLAN_KEY
    from .index import EPISODE_RE, DatasetIndex
    if not out.is_dir():
        return None, 0
    index = DatasetIndex(out)
    numbers = index.numbers() | {int(m.group(1)) for p in out.iterdir()
                                 if (m := EPISODE_RE.match(p.name))}
    return index.data.get(PLAN_KEY), len(numbers)


def cmd_record(args) -> int:
    from sebvs.runtime.overrides import as_mapping
    from sebvs.runtime.supervisor import RunFailed, Supervisor
    from sebvs.runtime.topology import load_topology
    from .condition_mix import check_dataset_plan
    from .index import DatasetIndex
    from .splits import check_recording_seed
    from sebvs.output_guard import OutputRefused, check_output_dir

    hard = getattr(args, "hard_share", None) is not None or \
        getattr(args, "hard_conditions", None) is not None
    try:
        if hard and getattr(args, "condition", None) is not None:
            raise ValueError("--hard-share and --condition: a hard share records its own "
                             "conditions beside the randomised mix; give one of them")
        # with --hard-share, --scenario is the hard episodes' (hard_share_jobs), not the run's
        given = requested_overrides(argparse.Namespace(**{**vars(args), "scenario": None})
                                    if hard else args)
    except (ValueError, LookupError) as exc:
        print(f"sebvs record: {exc}", file=sys.stderr)
        return 2
    name = find_recorder(load_topology(args.topology, given))
    out = Path(args.out)
    try:
        check_output_dir(out, inputs=[args.topology], force=getattr(args, "force", False),
                         owns=is_recording, what="dataset")
    except OutputRefused as exc:
        print(f"sebvs record: {exc}", file=sys.stderr)
        return 2
    overrides = recorder_overrides(args, name, out, given)
    topo = load_topology(args.topology, overrides)
    try:
        mix = hard_share_mix(args, topo)
        jobs = hard_share_jobs(args, name, out, given, mix) if mix is not None else None
    except (ValueError, LookupError) as exc:
        print(f"sebvs record: {exc}", file=sys.stderr)
        return 2
    # refused outright, with no flag to allow it: a test split that one flag can record from
    # is held out only by convention, and nothing a recording needs lies in that range
    try:
        warning = check_recording_seed(topo.seed)
    except ValueError as exc:
        print(f"sebvs record: {exc}", file=sys.stderr)
        return 2
    if warning:
        print(f"sebvs record: warning: {warning}", file=sys.stderr)
    if args.workers is not None and args.workers < 1:
        print(f"sebvs record: --workers must be at least 1, got {args.workers}",
              file=sys.stderr)
        return 2
    if args.ray is not None and importlib.util.find_spec("ray") is None:
        print("sebvs record: --ray needs Ray, which is not installed: pip install -e .[ray]",
              file=sys.stderr)
        return 2
    for adopted in adopt_staged(out):
        print(f"sebvs record: adopted {adopted}, finished by a worker of an earlier run",
              file=sys.stderr)
    try:
        # after the adoption: what a dead driver's workers finished was recorded under
        # the dataset's plan, whatever this command asks
        stored, held = dataset_plan(out)
        check_dataset_plan(stored, mix, episodes=held, where=str(out))
    except ValueError as exc:
        print(f"sebvs record: {exc}", file=sys.stderr)
        return 2
    if (args.workers or 1) > 1 or args.ray is not None or args.fill or mix is not None:
        # a fill plays ranges of numbers, not one run on from the highest: the fan-out's
        # shards, on one worker when no more are asked for; so does a hard share, whose
        # conditions are runs of their own
        if args.workers is None and args.ray is None:
            args.workers = 1
        return record_fanout(args, topo, name, out, as_mapping(overrides), mix=mix,
                             jobs=jobs)
    first = DatasetIndex(out).next_episode_number() if out.exists() else 0
    try:
        # the dataset's episode N is episode N of the seed: a recording into a dataset
        # that holds N episodes plays on from there, not episodes 0.. again (the same
        # scenes under new numbers, which a train/validation split would then straddle)
        topo = load_topology(args.topology,
                             [*overrides, {first_episode_actor(topo): {"first_episode": first}}])
    except LookupError:
        pass                # no episode source with first_episode: nothing to continue
    echo = (lambda s: None) if args.quiet else (lambda s: print(s, file=sys.stderr))
    sup = Supervisor(topo, runs_dir=args.runs_dir, echo=echo)
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda s, f: sup.interrupt(signal.Signals(s).name))
    progress = None
    t0 = time.monotonic()
    try:
        sup.start()
        print(f"sebvs record: {topo.name} -> {out} (first episode {first:04d}), run dir "
              f"{sup.rundir}", file=sys.stderr)
        progress = Progress(sup, name, args.episodes, enabled=not args.quiet)
        code = sup.wait(args.timeout, progress)
    except RunFailed as exc:
        print(f"sebvs record: {exc}", file=sys.stderr)
        sup.stop()
        return 1
    except BaseException:
        sup.stop()
        raise
    finally:
        if progress is not None and sup.status != "ended":
            progress.close()
    wall = time.monotonic() - t0
    if sup.failure:
        print(f"sebvs record: run stopped: {sup.failure.splitlines()[0]}", file=sys.stderr)
    stopped = write_stop_reason(sup.rundir)
    if stopped:
        print(f"sebvs record: {stopped}", file=sys.stderr)
    index = DatasetIndex(out) if (out / "index.json").exists() else None
    new = [e for e in (index.episodes() if index else [])
           if int(e["file"].split("_")[1].split(".")[0]) >= first]
    frames = sum(e["frames"] for e in new)
    if progress is not None:
        progress.bar.n = min(len(new), args.episodes)   # the last episode ends the run
        progress.bar.set_postfix(frames=frames, refresh=False)
        progress.close()
    print(f"sebvs record: {len(new)} of {args.episodes} episode(s) recorded, {frames} frames, "
          f"{wall:.1f} s wall; dataset {out} now holds "
          f"{len(index.episodes()) if index else 0} episode(s)")
    return 0 if code == 0 and len(new) >= args.episodes else 1


def write_stop_reason(rundir) -> str | None:
    """The recorder's line when a write failed and it stopped the recording (a full
    disk), from the run's logs; None when it did not."""
    from .recording import WRITE_STOPPED
    for log_file in sorted(Path(rundir, "logs").glob("*.log")) if rundir else ():
        try:
            text = log_file.read_text(errors="replace")
        except OSError:
            continue
        at = text.find(WRITE_STOPPED)
        if at >= 0:
            return text[at:].splitlines()[0]
    return None


# ------------------------------------------------------------------------- fan-out
def first_episode_actor(topo) -> str:
    """The topology's episode source: the actor with a ``first_episode`` parameter (the
    sim), which a fan-out worker tells where its range starts."""
    names = [n for n, a in topo.actors.items() if not a.pruned
             and dataclasses.is_dataclass(getattr(a.cls, "Params", None))
             and "first_episode" in {f.name for f in dataclasses.fields(a.cls.Params)}]
    if len(names) != 1:
        raise LookupError(f"{topo.path}: --workers and --ray need one episode source with a "
                          f"first_episode parameter (actors.sim:Sim), found "
                          f"{names or 'none'}")
    return names[0]


def _sim_episode(path: Path) -> int | None:
    from .episode import open_episode
    try:
        with open_episode(path) as ep:
            k = ep.attrs.get("sim_episode")
    except Exception:       # unreadable: left where it is, for `sebvs data check`
        return None
    return int(k) if isinstance(k, (int, float)) or str(k).isdigit() else None


def adopt_stage(stage: Path, index, have: set[int] | None = None) -> list[int]:
    """Move the finished episode files of one staging directory into the dataset.

    A file showing episode k of its run becomes ``episode_<base + k>.h5`` (base from the
    directory's shard.json) and is indexed after the rename, so a crash between the two
    leaves a whole, unindexed file that ``adopt_unindexed`` picks up. Files for episodes
    outside the shard's range, or for a number the dataset already has (a retried
    range), are deleted. A shard of a hard share (shard.json's "condition") has its name
    stamped into each file's ``condition`` attribute before the rename. Returns the
    episode indices k adopted.
    """
    from .index import EPISODE_RE, episode_name, make_entry
    info_path = stage / SHARD_INFO
    if not info_path.exists():
        return []
    info = json.loads(info_path.read_text())
    have = index.numbers() if have is None else have
    adopted = []
    for p in sorted(stage.iterdir()):
        m = EPISODE_RE.match(p.name)
        if not m or m.group(2):
            continue            # .partial: in progress, or lost with its worker
        k = _sim_episode(p)
        if k is None:
            continue
        number = info["base"] + k
        dest = index.root / episode_name(number)
        if not info["first"] <= k < info["stop"] or number in have or dest.exists():
            p.unlink()
            continue
        # a stage of a driver from before the recorder stored the condition itself
        # (2026-12-02) names it here instead
        if info.get("condition") is not None and not _has_condition(p):
            try:
                stamp_condition(p, info["condition"])
            except OSError:     # left in the stage (removed with it): recorded again
                continue
        os.replace(p, dest)
        index.insert(make_entry(dest))
        have.add(number)
        adopted.append(k)
    return adopted


def _has_condition(path: Path) -> bool:
    import h5py
    try:
        with h5py.File(path, "r") as f:
            return bool(f.attrs.get("condition"))
    except OSError:
        return False


def stamp_condition(path: Path, condition: str) -> None:
    """Set an episode file's ``condition`` attribute (the named condition it was recorded
    under, or "randomised") and fsync it; before it is indexed, so its hash is the final
    one."""
    import h5py
    with h5py.File(path, "r+") as f:
        f.attrs["condition"] = condition
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def adopt_staged(out: Path) -> list[str]:
    """Adopt what every staging directory of `out` holds (workers of a driver that died)
    and remove them; returns the dataset file names adopted."""
    from .index import DatasetIndex, episode_name
    root = out / STAGING
    if not root.is_dir():
        return []
    index = DatasetIndex(out)
    index.adopt_unindexed()
    names = []
    for stage in sorted(p for p in root.iterdir() if p.is_dir()):
        info = stage / SHARD_INFO
        base = json.loads(info.read_text())["base"] if info.exists() else 0
        names += [episode_name(base + k) for k in adopt_stage(stage, index)]
        shutil.rmtree(stage, ignore_errors=True)
    _remove_if_empty(root)
    return names


def _remove_if_empty(path: Path) -> None:
    try:
        path.rmdir()
    except OSError:
        pass


def record_fanout(args, topo, recorder: str, out: Path, overrides: dict, mix=None,
                  jobs: dict | None = None) -> int:
    """`sebvs record` over workers: see the module docstring.

    Parameters:
        args: the command line (topology, episodes, fill, workers, ray, timeout, ...).
        topo: the topology as it will run (its episode source is found in it).
        recorder: the recorder actor's name.
        out: the dataset.
        overrides: everything a worker's run gets before its shard's own settings.
        mix: the --hard-share plan (sebvs/data/condition_mix.py), None without; stored in
            the dataset's index before anything is recorded.
        jobs: with `mix`, each condition's overrides in place of `overrides`
            (hard_share_jobs).

    Returns:
        The exit status.
    """
    from tqdm import tqdm

    from sebvs.scale import RayMissing, ShardsLost, fan_out
    from .condition_mix import PLAN_KEY
    from .index import DatasetIndex, write_json_atomic

    try:
        sim = first_episode_actor(topo)
    except LookupError as exc:
        print(f"sebvs record: {exc}", file=sys.stderr)
        return 2
    out = out.resolve()
    index = DatasetIndex(out)
    index.adopt_unindexed()
    if mix is not None and index.data.get(PLAN_KEY) != mix.to_json():
        # before the first episode: a run stopped at any point leaves the plan its
        # episodes were recorded under
        out.mkdir(parents=True, exist_ok=True)
        index.data[PLAN_KEY] = mix.to_json()
        write_json_atomic(index.path, index.data)
    planned = plan_shards(args, index, mix)
    if planned is None:
        print(f"sebvs record: {out} already holds episodes 0-{args.episodes - 1}; "
              f"nothing to fill", file=sys.stderr)
        return 0
    wanted, shards = planned
    if mix is not None:
        print(f"sebvs record: hard share {mix.share} of episodes 0-{args.episodes - 1}: "
              + ", ".join(f"{c} {n}" for c, n in mix.counts(args.episodes).items()),
              file=sys.stderr)
    bar = tqdm(total=len(wanted), unit="ep", desc="recording", disable=args.quiet,
               dynamic_ncols=True)
    staging = StagedShards(
        index, topology=str(Path(args.topology).resolve()), overrides=overrides,
        recorder=recorder, sim=sim, timeout_s=args.timeout, bar=bar,
        runs_dir=str(Path(args.runs_dir or os.environ.get("SEBVS_RUNS_DIR", "runs")).resolve()),
        jobs=jobs)
    where = f"Ray ({args.ray or 'local'})" if args.ray is not None else \
        f"{args.workers} local workers"
    first = (f"filling {len(wanted)} missing episode(s) of 0-{args.episodes - 1}"
             if args.fill or mix is not None else f"first episode {wanted[0]:04d}")
    print(f"sebvs record: {topo.name} -> {out} ({first}), {len(shards)} "
          f"shard(s) on {where}", file=sys.stderr)
    t0 = time.monotonic()
    code = 0
    previous = signal.signal(signal.SIGTERM, _raise_interrupt)
    try:
        fan_out(shards, staging.task_of, staging.collect, workers=args.workers, ray=args.ray,
                max_attempts=getattr(args, "max_attempts", 3), on_poll=staging.poll,
                echo=lambda text: tqdm.write(text, file=sys.stderr), start="fork")
    except (ShardsLost, RayMissing) as exc:
        print(f"sebvs record: {exc}", file=sys.stderr)
        code = 1
    except KeyboardInterrupt:
        print("sebvs record: interrupted; finished episodes kept", file=sys.stderr)
        code = 1
    finally:
        signal.signal(signal.SIGTERM, previous)
        bar.close()
        staging.close()
    recorded = _report_recorded(out, set(wanted), time.monotonic() - t0)
    return code if code else (0 if recorded >= len(wanted) else 1)


def plan_shards(args, index, mix=None) -> tuple[list[int], list] | None:
    """The episode numbers a fan-out records and its shards, or None when a fill finds
    nothing missing.

    Without --fill: episodes [base, base + N) of the seed (base: the dataset's next
    number), as one process plays them, split over the workers. With --fill: the numbers
    below N the dataset lacks, as contiguous ranges, each split over the workers in
    proportion to its length. With a hard share (`mix`): as with --fill, the ranges being
    the runs of consecutive missing numbers under one condition, each shard's job that
    condition's name (condition_mix.RANDOMISED for the randomised mix).
    """
    from sebvs.scale import Shard, split_episodes
    from .condition_mix import condition_runs
    parts = args.workers if args.workers else (os.cpu_count() or 1)
    if args.fill or mix is not None:
        have = index.numbers()
        wanted = [k for k in range(args.episodes) if k not in have]
        if not wanted:
            return None
        runs = condition_runs(mix.assign(wanted)) if mix is not None else \
            [("recording", lo, hi) for lo, hi in contiguous_ranges(wanted)]
        return wanted, [Shard(job, a, b) for job, lo, hi in runs
                        for a, b in split_episodes(lo, hi, max(1, round(parts * (hi - lo)
                                                                        / len(wanted))))]
    base = index.next_episode_number()
    return (list(range(base, base + args.episodes)),
            [Shard("recording", a, b) for a, b in split_episodes(base, base + args.episodes,
                                                                 parts)])


class StagedShards:
    """The driver's side of a fan-out recording: each shard's staging directory (its
    worker's recorder writes there), its Task, and the adoption of what it finished into
    the dataset, as soon as it appears."""

    def __init__(self, index, *, topology: str, overrides: dict, recorder: str, sim: str,
                 runs_dir: str, timeout_s: float | None, bar, jobs: dict | None = None
                 ) -> None:
        # jobs (a hard share): each shard's job is a condition name, whose overrides
        # replace `overrides` and whose name each of its files is stamped with
        self.index, self.topology, self.overrides, self.jobs = index, topology, overrides, \
            jobs
        self.recorder, self.sim, self.runs_dir, self.timeout_s = recorder, sim, runs_dir, \
            timeout_s
        self.bar = bar
        self.have = index.numbers()
        self.token = secrets.token_hex(3)
        self.stages: dict = {}          # Shard -> its staging directory
        self.done: set[int] = set()

    def task_of(self, shard):
        """A fresh staging directory for the shard's attempt, and the worker's Task."""
        from sebvs.runtime.overrides import merge
        from sebvs.scale import Task
        from .index import INDEX, INDEX_VERSION, write_json_atomic
        index = self.index
        stage = index.root / STAGING / (f"{self.token}-{shard.first}-{shard.stop}"
                                        f"-try{shard.attempt}")
        stage.mkdir(parents=True, exist_ok=True)
        # shards cover [base, base + n) of the seed's episodes, so episode k is the
        # dataset's number k (base 0 here; a shard.json of an older driver may say
        # another base, which adopt_stage adds)
        # (a hard share's episodes carry their job's condition from the recorder itself)
        info = {"base": 0, "first": shard.first, "stop": shard.stop}
        (stage / SHARD_INFO).write_text(json.dumps(info))
        if index.task is not None:
            # the worker's recorder then refuses a stream of another task, as it would in
            # the dataset itself
            write_json_atomic(stage / INDEX, {"version": INDEX_VERSION, "task": index.task,
                                              "episodes": []})
        self.stages[shard] = stage
        size = shard.stop - shard.first
        shard_sets = {self.recorder: {"out": str(stage), "episodes": size},
                      self.sim: {"first_episode": shard.first, "episodes": size}}
        overrides = self.overrides if self.jobs is None else self.jobs[shard.job]
        return Task(str(shard), self.topology, merge(overrides, shard_sets),
                    self.runs_dir, timeout_s=self.timeout_s)

    def adopt(self, shard) -> None:
        self.done.update(adopt_stage(self.stages[shard], self.index, self.have))
        self.bar.update(len(self.done) - self.bar.n)

    def collect(self, shard, result: dict | None) -> list[int]:
        """After the shard's worker ended: adopt what it finished; the episodes missing."""
        self.adopt(shard)
        shutil.rmtree(self.stages.pop(shard), ignore_errors=True)
        return [k for k in range(shard.first, shard.stop) if k not in self.have]

    def poll(self) -> None:
        for shard in list(self.stages):
            self.adopt(shard)       # at once: a driver that dies now loses nothing finished

    def close(self) -> None:
        for stage in self.stages.values():
            shutil.rmtree(stage, ignore_errors=True)
        _remove_if_empty(self.index.root / STAGING)


def _report_recorded(out: Path, wanted: set[int], wall_s: float) -> int:
    """Print what a fan-out recorded; returns how many of the wanted episodes the
    dataset now holds."""
    from .index import DatasetIndex
    index = DatasetIndex(out)
    new = [e for e in index.episodes()
           if int(e["file"].split("_")[1].split(".")[0]) in wanted]
    frames = sum(e["frames"] for e in new)
    print(f"sebvs record: {len(new)} of {len(wanted)} episode(s) recorded, {frames} frames, "
          f"{wall_s:.1f} s wall; dataset {out} now holds {len(index.episodes())} "
          f"episode(s)")
    return len(new)


def contiguous_ranges(numbers: list[int]) -> list[tuple[int, int]]:
    """Sorted distinct numbers as [a, b) ranges of consecutive ones: [0, 1, 2, 5] -> [(0, 3),
    (5, 6)]."""
    ranges: list[tuple[int, int]] = []
    for k in numbers:
        if ranges and ranges[-1][1] == k:
            ranges[-1] = (ranges[-1][0], k + 1)
        else:
            ranges.append((k, k + 1))
    return ranges


def _raise_interrupt(signum, frame) -> None:
    raise KeyboardInterrupt(signal.Signals(signum).name)
