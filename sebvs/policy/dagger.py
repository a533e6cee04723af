"""DAgger rounds (Ross, Gordon and Bagnell 2011): the learner drives, the privileged expert
labels every tick it visits, the labelled ticks join the data, the learner trains again.

    sebvs train-dagger --task nav --modality rgb --data datasets/nav --out out/dagger \\
        --rounds 3 --episodes 10 --workers 4

    run_dagger(DaggerSettings("nav", "rgb", ("datasets/nav",), 10), "out/dagger",
               rounds=3, workers=4)      # the same, from Python

Round 0 trains the modality on the base dataset(s) into ``<out>/round-0/checkpoints``
(``init``, a folder holding ``<task>-<modality>.pt``, drives round 1 instead). Then each
round r = 1..R:

1. records ``episodes`` episodes of ``topologies/nav_dagger.toml`` with ``sebvs record
   --fill`` (a subprocess; ``--workers`` passed on for its fan-out) into
   ``<out>/round-<r>/data``: the policy actor loads round r-1's checkpoint of the one
   modality and drives the sim, the LockstepRecorder records the expert's command as the
   label (actors/recorder.py, input ``drive``), on topology seed ``round_seed(first_seed,
   r) = first_seed + r - 1``;
2. checks that dataset (sebvs/data/check.py, `check_dataset`) and that a policy of the
   modality drove every episode: any problem stops the run, in one line;
3. trains the modality on the base dataset(s) plus rounds 1..r together (train.train with
   several datasets) into ``<out>/round-<r>/checkpoints``;
4. adds the round to the ledger ``<out>/dagger.json`` (written atomically).

Seeds: every round's topology seed must lie in the train split (0-999,
sebvs/data/splits.py) and must not be one the base datasets were recorded with (their
episodes' ``topology`` attribute), else the run is refused before anything starts. The
default first seed, 500, keeps rounds 1..500 inside the train split and clear of the seeds
0-8 the shipped datasets used; distinct topology seeds give distinct episodes.

Ledger: {"version", "settings" (everything that decides the results: task, modality, the
base datasets with their hashes, episodes, episode_s, first_seed, topology, the --set lines,
init, the train settings), "rounds": one record per finished round (round, seed, driver,
data {path, hash, episodes, frames}, disagreement: the mean |policy command - expert label|
over the round's ticks, datasets trained on {path, hash}, checkpoint, best_val_loss,
record_s, train_s, wall_s)}. A second call goes on at the first round the ledger lacks: a
finished round is never recorded or trained again, an unfinished one resumes where it
stopped (its recording fills the episodes it lacks, its training goes on from its resume
state, and a checkpoint it finished before a crash is taken as it is when it was trained
on the same datasets). An ``out`` made by other settings is refused in one line: its
rounds' episodes are recordings, which no command writes again (sebvs/output_guard.py), so
there is no starting over in place; give another ``out``.
"""
from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

LEDGER = "dagger.json"
LEDGER_VERSION = 1
DEFAULT_FIRST_SEED = 500
# the topology each task's rounds record with (the arm has none: its scene holds HOME and
# only grasps the last pose, so a policy's poses change no frame the expert labels)
TOPOLOGIES = {"nav": "topologies/nav_dagger.toml"}
# training settings that change no result: left out of the ledger's comparison
NOT_RESULTS = ("num_workers", "cache", "threads")


class DaggerError(ValueError):
    """A DAgger run that cannot go on; the message, one line, says why and where."""


@dataclass(frozen=True)
class DaggerSettings:
    """What decides a DAgger run's results (the ledger keeps them; a resume must agree).

    Parameters:
        task: "nav" (the one task with a DAgger topology; any with ``topology``).
        modality: the one modality that drives and trains ("rgb", "event", ...).
        base: the base dataset directories (the expert's recordings), at least one.
        episodes: episodes recorded per round (>= 2: a round's own split needs two).
        episode_s: the recording's episode length, seconds (None: the topology's).
        first_seed: round 1's topology seed; round r records on first_seed + r - 1.
        topology: the recording topology (None: TOPOLOGIES[task]).
        sets: --set lines for every round's recording (sizes, sensor settings).
        init: a checkpoint folder whose ``<task>-<modality>.pt`` drives round 1 (None:
            round 0 trains one on the base datasets).
        train: train.train's overrides (TrainSettings fields; None keeps the paper's).
    """
    task: str
    modality: str
    base: tuple[str, ...]
    episodes: int
    episode_s: float | None = None
    first_seed: int = DEFAULT_FIRST_SEED
    topology: str | None = None
    sets: tuple[str, ...] = ()
    init: str | None = None
    train: dict = field(default_factory=dict)

    def topology_path(self) -> str:
        """The recording topology: the one given, else the task's."""
        if self.topology:
            return self.topology
        if self.task not in TOPOLOGIES:
            raise DaggerError(f"no DAgger topology for task {self.task!r} (only "
                              f"{', '.join(TOPOLOGIES)}): the arm holds HOME and grasps its "
                              f"last pose, so a policy's poses change no frame the expert "
                              f"labels; give --topology for a scene of your own")
        return TOPOLOGIES[self.task]


def round_seed(first_seed: int, r: int) -> int:
    """Round r's topology seed (r >= 1): first_seed + r - 1."""
    return first_seed + r - 1


def round_dir(out: str | Path, r: int) -> Path:
    return Path(out) / f"round-{r}"


# ---------------------------------------------------------------------------- ledger
def _flat(settings: dict) -> dict:
    """Train settings as flat JSON-able pairs: a dataclass's fields as "<name>.<field>"
    (norm.size), so that a refusal can name the one that differs."""
    flat = {}
    for k, v in settings.items():
        if dataclasses.is_dataclass(v) and not isinstance(v, type):
            flat.update({f"{k}.{f}": x for f, x in dataclasses.asdict(v).items()})
        else:
            flat[k] = v
    return flat


def ledger_settings(s: DaggerSettings) -> dict:
    """The settings as the ledger keeps them: base datasets resolved and hashed, the
    topology resolved, the init checkpoint hashed, the train settings that change results.

    Parameters:
        s: the run's settings.

    Returns:
        A JSON-able dict.
    """
    from sebvs.dataset_files import file_sha256
    from sebvs.shipped import shipped_path
    from .checkpoint import checkpoint_paths
    from .dataset import dataset_hash, load_index
    base = []
    for b in s.base:
        root = Path(b).resolve()
        base.append({"path": str(root), "hash": dataset_hash(root, load_index(root, s.task))})
    init = None
    if s.init is not None:
        pt = checkpoint_paths(s.init, s.task, s.modality)[0]
        if not pt.exists():
            raise DaggerError(f"--init {s.init}: no {pt.name} in it (the modality "
                              f"{s.modality}'s checkpoint of task {s.task})")
        init = {"path": str(pt.resolve()), "sha256": file_sha256(pt)}
    train = {k: v for k, v in sorted(_flat(s.train).items())
             if v is not None and k not in NOT_RESULTS}
    return {"task": s.task, "modality": s.modality, "base": base, "episodes": s.episodes,
            "episode_s": s.episode_s, "first_seed": s.first_seed,
            "topology": str(shipped_path(s.topology_path()).resolve()),
            "sets": list(s.sets), "init": init, "train": train}


# what each settings key is on the command line, for the refusal
FLAGS = {"task": "--task", "modality": "--modality", "base": "--data", "episodes": "--episodes",
         "episode_s": "--episode-s", "first_seed": "--first-seed", "topology": "--topology",
         "sets": "--set", "init": "--init", "train": "the training options"}


def read_ledger(out: Path, settings: dict) -> dict:
    """The ledger of ``out`` (a fresh one where there is none), refused when it was made
    by other settings.

    Parameters:
        out: the run's folder.
        settings: `ledger_settings` of this call.

    Returns:
        The ledger. DaggerError, one line, naming the first setting that differs.
    """
    path = out / LEDGER
    if not path.exists():
        return {"version": LEDGER_VERSION, "settings": settings, "rounds": []}
    try:
        ledger = json.loads(path.read_text())
        before = ledger["settings"]
        ledger["rounds"]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise DaggerError(f"{path}: unreadable ({type(exc).__name__}: {exc}); give "
                          f"another --out") from None
    for key in settings:
        if before.get(key) != settings[key]:
            was, now = before.get(key), settings[key]
            what = FLAGS[key]
            if key == "base":
                was, now = ([f"{b['path']} (hash {b['hash'][:12]})" for b in v or []]
                            for v in (was, now))
            elif key == "train":
                was, now = was or {}, now
                what = "training setting " + next(k for k in sorted(set(was) | set(now))
                                                  if was.get(k) != now.get(k))
                was, now = (v.get(what.split()[-1], "the default") for v in (was, now))
            raise DaggerError(f"{out}: made by other settings ({what} was {was}, now "
                              f"{now}); its finished rounds are recordings that no command "
                              f"writes again: give another --out")
    return ledger


def write_ledger(out: Path, ledger: dict) -> None:
    from sebvs.data.index import write_json_atomic
    write_json_atomic(out / LEDGER, ledger)


# ---------------------------------------------------------------------------- checks
def recorded_seeds(root: str | Path) -> set[int]:
    """The topology seeds a dataset's episodes were recorded with (their ``topology``
    attribute; episodes without one say nothing)."""
    from sebvs.data.episode import open_episode
    from .dataset import episode_path, load_index
    seeds = set()
    for e in load_index(root, verify=False):
        with open_episode(episode_path(root, e)) as ep:
            topo = ep.attrs.get("topology")
        seed = ((topo or {}).get("content") or {}).get("topology", {}).get("seed") \
            if isinstance(topo, dict) else None
        if isinstance(seed, int):
            seeds.add(seed)
    return seeds


def check_seeds(s: DaggerSettings, rounds: int) -> list[int]:
    """Rounds 1..rounds' topology seeds; DaggerError, one line, for one outside the train
    split or one a base dataset was recorded with."""
    from sebvs.data.splits import SPLITS, split_of
    seeds = [round_seed(s.first_seed, r) for r in range(1, rounds + 1)]
    for r, seed in enumerate(seeds, 1):
        if split_of(seed) != "train":
            raise DaggerError(f"round {r}'s topology seed {seed} (--first-seed "
                              f"{s.first_seed} + {r - 1}) is outside the train split "
                              f"({SPLITS['train']}): lower --first-seed or --rounds")
    for b in s.base:
        used = recorded_seeds(b) & set(seeds)
        if used:
            seed = min(used)
            raise DaggerError(f"round {seeds.index(seed) + 1}'s topology seed {seed} is one "
                              f"base dataset {b} was recorded with: its scenes would repeat; "
                              f"give another --first-seed")
    return seeds


def check_topology(s: DaggerSettings) -> None:
    """DaggerError, one line, unless the topology loads with the run's --set lines and its
    recorder has `drive` wired (else the expert, not the policy, would drive)."""
    from sebvs.data.record import find_recorder
    from sebvs.runtime.topology import TopologyError, load_topology
    from sebvs.shipped import shipped_path
    path = shipped_path(s.topology_path())
    try:
        topo = load_topology(path, list(s.sets))
        recorder = topo.actors[find_recorder(topo)]
    except (TopologyError, LookupError, OSError, ValueError) as exc:
        raise DaggerError(f"{path}: {' '.join(str(exc).split())}") from None
    if "drive" not in recorder.inputs:
        raise DaggerError(f"{path}: its recorder [actors.{recorder.name}] has no 'drive' "
                          f"input wired: the expert would drive, not the policy "
                          f"(topologies/nav_dagger.toml wires drive = \"policy/action\")")


def check_round_data(root: Path, s: DaggerSettings, r: int) -> tuple[dict, float]:
    """The round's dataset checked (sebvs data check) and summarised.

    Parameters:
        root: the round's dataset; s: the settings; r: the round.

    Returns:
        ({"path", "hash", "episodes", "frames"}, the disagreement: the mean absolute
        difference between the driving policy's command and the expert's label over every
        tick and command dimension). DaggerError, one line, for a problem `sebvs data
        check` reports, too few episodes, or an episode that a policy of the modality did
        not drive.
    """
    import numpy as np

    from sebvs.data.check import check_dataset
    from sebvs.data.episode import open_episode
    from .dataset import dataset_hash, load_index
    rep = check_dataset(root)
    if not rep.ok:
        raise DaggerError(f"round {r}: {root} fails `sebvs data check`: {rep.lines()[0]}")
    if rep.episodes < s.episodes:
        raise DaggerError(f"round {r}: {root} holds {rep.episodes} episode(s), the round "
                          f"records {s.episodes}")
    episodes = load_index(root, s.task)
    diffs, frames = [], 0
    for e in episodes:
        with open_episode(root / e["file"]) as ep:
            driver = str(ep.attrs.get("driver", ""))
            if ep.drive is None or not driver.endswith(f":{s.modality}"):
                raise DaggerError(f"round {r}: {root / e['file']} was driven by "
                                  f"{driver or 'an unnamed actor'}, not a {s.modality} policy")
            diffs.append(np.abs(ep.drive[:] - ep.target[:]).sum(axis=0))
            frames += len(ep)
    dim = diffs[0].size
    return {"path": str(root), "hash": dataset_hash(root, episodes), "episodes": len(episodes),
            "frames": frames}, round(float(np.sum(diffs) / max(frames * dim, 1)), 6)


# ---------------------------------------------------------------------------- steps
def record_round(s: DaggerSettings, driver_dir: Path, data: Path, seed: int,
                 workers: int | None, progress: bool, log) -> float:
    """Step 1: `sebvs record --fill` of the round's episodes, driven by the checkpoint in
    ``driver_dir``; returns the wall seconds. DaggerError when the recording fails."""
    from sebvs.runtime.overrides import set_lines
    from sebvs.shipped import shipped_path
    m = s.modality
    round_overrides = {"topology": {"seed": seed},
                       "policy": {"task": s.task, "directory": str(driver_dir.resolve()),
                                  "modality": m, "modalities": [m]}}
    if s.episode_s is not None:
        round_overrides["sim"] = {"episode_s": float(s.episode_s)}
    cmd = [sys.executable, "-m", "sebvs.cli", "record",
           str(shipped_path(s.topology_path()).resolve()), "--episodes", str(s.episodes),
           "--out", str(data), "--fill", "--runs-dir", str(data.parent / "runs"),
           *(["--workers", str(workers)] if workers else []),
           *([] if progress else ["--quiet"]),
           *(a for line in [*s.sets, *set_lines(round_overrides)] for a in ("--set", line))]
    t0 = time.monotonic()
    done = subprocess.run(cmd, stdout=None if progress else subprocess.PIPE,
                          stderr=None if progress else subprocess.STDOUT, text=True)
    if done.returncode != 0:
        tail = (done.stdout or "").strip().splitlines()[-3:]
        raise DaggerError(f"recording into {data} failed (exit {done.returncode})"
                          + (f": {' | '.join(tail)}" if tail else ""))
    return time.monotonic() - t0


def train_round(s: DaggerSettings, datasets: list[Path], ckdir: Path, progress: bool,
                log) -> tuple[dict, float]:
    """Step 3: train the modality on ``datasets`` into ``ckdir``; (its config, the wall
    seconds). A checkpoint finished there before a crash, on the same datasets, is taken
    as it is."""
    from .checkpoint import checkpoint_paths
    from .dataset import dataset_hash, load_index
    from .train import train
    pt, js = checkpoint_paths(ckdir, s.task, s.modality)
    want = [{"path": str(d), "hash": dataset_hash(d, load_index(d, s.task, verify=False))}
            for d in datasets]
    if pt.exists() and js.exists():
        try:
            cfg = json.loads(js.read_text())
            had = [{"path": d["path"], "hash": d["hash"]} for d in cfg["dataset"]["datasets"]]
        except (OSError, ValueError, KeyError, TypeError):
            had = None
        if had == want:
            log(f"  {pt.name} was finished before on these datasets; taken as it is")
            return cfg, 0.0
    t0 = time.monotonic()
    results = train([str(d) for d in datasets], ckdir, s.task, [s.modality],
                    progress=progress, log=log, **s.train)
    return next(iter(results.values())), time.monotonic() - t0


def run_dagger(s: DaggerSettings, out: str | Path, rounds: int, workers: int | None = None,
               progress: bool = True, log=print, force: bool = False) -> dict:
    """Run rounds up to ``rounds`` (the module docstring), going on from the ledger.

    Parameters:
        s: the settings; out: the run's folder; rounds: the last round to finish (>= 1).
        workers: `sebvs record --workers` for each round's recording (None: its default).
        progress: the recording's bar and training's tqdm bars; log: takes each line.
        force: write into a non-empty folder that holds no ledger (output_guard).

    Returns:
        The ledger. DaggerError (a ValueError), one line, for settings or data that
        cannot be used; nothing is written then.
    """
    from sebvs.output_guard import OutputRefused, check_output_dir
    from .checkpoint import checkpoint_paths
    from .dataset import load_datasets
    from .inputs import Modality
    out = Path(out).resolve()
    if rounds < 1:
        raise DaggerError(f"--rounds must be at least 1, got {rounds}")
    if s.episodes < 2:
        raise DaggerError(f"--episodes must be at least 2 (a round's split by episode needs "
                          f"two), got {s.episodes}")
    if workers is not None and workers < 1:
        raise DaggerError(f"--workers must be at least 1, got {workers}")
    Modality.parse(s.modality)
    try:
        check_output_dir(out, inputs=[*s.base, *([s.init] if s.init else [])], force=force,
                         owns=lambda p: (p / LEDGER).exists(), what="DAgger run")
    except OutputRefused as exc:
        raise DaggerError(str(exc)) from None
    check_topology(s)
    load_datasets(list(s.base), s.task)          # tasks agree, indexes whole: before round 0
    seeds = check_seeds(s, rounds)
    ledger = read_ledger(out, ledger_settings(s))
    done = {rec["round"] for rec in ledger["rounds"]}
    out.mkdir(parents=True, exist_ok=True)
    write_ledger(out, ledger)   # first: a run stopped in round 0 is this command's to resume
    name = f"{s.task}-{s.modality}"
    base = [Path(b["path"]) for b in ledger["settings"]["base"]]
    if s.init is not None:
        driver, label = Path(ledger["settings"]["init"]["path"]).parent, "--init"
    else:
        label = "round 0"
        driver = round_dir(out, 0) / "checkpoints"
        if 0 not in done:
            log(f"dagger round 0/{rounds}: training {name} on the base data "
                f"({len(base)} dataset(s))")
            t0 = time.monotonic()
            cfg, train_s = train_round(s, base, driver, progress, log)
            ledger["rounds"].append({
                "round": 0, "datasets": [{"path": d["path"], "hash": d["hash"]}
                                         for d in cfg["dataset"]["datasets"]],
                "checkpoint": str(checkpoint_paths(driver, s.task, s.modality)[0]),
                "best_val_loss": cfg["training"]["best_val_loss"],
                "train_s": round(train_s, 2), "wall_s": round(time.monotonic() - t0, 2)})
            write_ledger(out, ledger)
            log(f"dagger round 0/{rounds} done: best val loss "
                f"{cfg['training']['best_val_loss']:.5g}")
    rounds_data = [Path(rec["data"]["path"]) for rec in ledger["rounds"] if rec["round"] > 0]
    for r in range(1, rounds + 1):
        here = round_dir(out, r)
        if r in done:
            driver, label = here / "checkpoints", f"round {r}"
            continue
        t0 = time.monotonic()
        seed, data = seeds[r - 1], here / "data"
        log(f"dagger round {r}/{rounds}: recording {s.episodes} episode(s) on topology seed "
            f"{seed}, {name} of {label} driving")
        here.mkdir(parents=True, exist_ok=True)
        record_s = record_round(s, driver, data, seed, workers, progress, log)
        summary, disagreement = check_round_data(data, s, r)
        log(f"dagger round {r}/{rounds}: {summary['episodes']} episode(s), "
            f"{summary['frames']} frames checked; policy-expert disagreement "
            f"{disagreement:.4f}")
        datasets = [*base, *rounds_data, data]
        log(f"dagger round {r}/{rounds}: training {name} on {len(datasets)} datasets "
            f"(base + round{f's 1-{r}' if r > 1 else ' 1'})")
        cfg, train_s = train_round(s, datasets, here / "checkpoints", progress, log)
        ledger["rounds"].append({
            "round": r, "seed": seed,
            "driver": str(checkpoint_paths(driver, s.task, s.modality)[0]),
            "data": summary, "disagreement": disagreement,
            "datasets": [{"path": d["path"], "hash": d["hash"]}
                         for d in cfg["dataset"]["datasets"]],
            "checkpoint": str(checkpoint_paths(here / "checkpoints", s.task, s.modality)[0]),
            "best_val_loss": cfg["training"]["best_val_loss"],
            "record_s": round(record_s, 2), "train_s": round(train_s, 2),
            "wall_s": round(time.monotonic() - t0, 2)})
        write_ledger(out, ledger)
        rounds_data.append(data)
        driver, label = here / "checkpoints", f"round {r}"
        log(f"dagger round {r}/{rounds} done in {time.monotonic() - t0:.0f} s: best val "
            f"loss {cfg['training']['best_val_loss']:.5g}; {ledger['rounds'][-1]['checkpoint']}")
    if done >= set(range(1, rounds + 1)):
        log(f"dagger: round{f's 1-{rounds}' if rounds > 1 else ' 1'} finished before "
            f"({out / LEDGER})")
    return ledger
