#!/usr/bin/env python3
"""The sensor study of issue 38, as research/sensors/plan.md fixes it: every recording,
training, evaluation and reading of the plan, in its order, resumable.

    research/sensors/sensor_study.py plan                 # every command, nothing run
    research/sensors/sensor_study.py run [--steps record,train,eval,read] [--only nav10,arm30]
    research/sensors/sensor_study.py status               # what is done, what is left
    research/sensors/sensor_study.py smoke --only nav30   # every command shrunk to minutes

The commands are built from the plan's tables below (PLAN_*), which must say what the
plan says; nothing here chooses anything. `run` skips what is already done, so a session
that ends mid-study loses at most the step in flight:

record  a dataset whose index holds the planned episode count is done, and one whose
        cell's trainings are all done is not needed (a dataset feeds only them); one
        that holds episodes 0..k-1 is extended by the episodes missing (`sebvs record`
        resumes its numbering at k); one with holes (an interrupted fan-out leaves them)
        is filled with `sebvs record --fill`, the same episodes an unbroken run records
train   a checkpoint file <task>-<modality>.pt in the seed's directory is done
eval    an evaluation directory with results.json is done (`sebvs eval` itself resumes
        the finished runs of an interrupted one, unless the ledger says it was
        interrupted on another CPU or GL stack: then it starts again, so that it runs
        whole on one)
read    `sebvs eval table` per task and rate, RGB+Event against RGB+Diff by the plan's
        rule, into OUT/read/<task><rate>.json and .png (nav joins each seed's two
        evaluation groups); research/sensors/sensor_report.py then builds the report's tables

`run` goes cell by cell (nav 10 Hz, nav 30 Hz, arm 10 Hz, arm 30 Hz): the kinds of step
asked for, in order, for one task and rate before the next, so that a study spread over
sessions finishes whole cells first (and the evaluation meets real checkpoints early).

Stop it with Ctrl-C, or SIGTERM to it or its process group (a job started in the
background by a script ignores SIGINT): the steps in flight are stopped and log how long
they ran (`status` counts it), `sebvs record` keeps every finished episode, a training
goes on from its last finished epoch, and a step that fails or is stopped stops the
steps after it. Trainings run two at a time (--parallel,
one thread each, as the recipe says);
recordings and evaluations use --workers (default 2), on Ray with --ray (a cluster's
ADDRESS, or a local Ray): the same episodes and results either way.

Output under --out (default research/sensors/outputs, which the repository tracks) and the datasets
under datasets/ (which it does not: they are gigabytes, and the driver records them again
from the plan's commands; $SEBVS_STUDY_DATASETS puts them elsewhere). Every run of a step
appends a line to OUT/steps.jsonl (its
label, start, seconds, exit code, CPU and GL stack; `status` times the steps from it);
with --commit, each step that finishes is committed at once, its outputs and that line,
so that a study spread over sessions survives a new checkout: what it needs again is
then only the datasets of the trainings still to run. A stop (SIGTERM or Ctrl-C) with
--commit commits the ledger and the trainings' resume states, which go on over those
datasets made again (their content is the same: sebvs/policy/resume.py). The driver's
log, OUT/log.txt (each step's start and exit), and each step's own output,
OUT/logs/<step>.txt, are not tracked.
"""
from __future__ import annotations

import argparse
import functools
import json
import os
import platform
import shlex
import shutil
import signal
import subprocess
import sys
import threading
import time
import tomllib
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import dataclass, replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from sebvs.data.index import DatasetIndex  # noqa: E402
from sebvs.policy.resume import RESUME_SUFFIX, resume_path  # noqa: E402

LEDGER = "steps.jsonl"


@dataclass(frozen=True)
class Recording:
    """A plan's recording of one task and rate: `sebvs record TOPOLOGY --episodes N` with
    these --set lines and other options."""
    episodes: int
    sets: tuple[str, ...]           # --set lines: topology.seed's, the episode length's, ...
    options: tuple[str, ...] = ()   # other `sebvs record` options (e.g. --hard-share)


@dataclass(frozen=True)
class Plan:
    """What a study's plan fixes, as data: this driver builds every command from it and
    chooses nothing. SENSORS is this file's study; another study's script gives its own
    Plan to main() (research/event_policies/study.py)."""
    name: str                       # in the driver's messages: "sensor study"
    plan_file: str                  # the plan, relative to the repository
    out: Path                       # the outputs (tracked)
    smoke_out: Path                 # the smoke run's (not tracked)
    dataset_prefix: str             # datasets/<prefix><task><rate>
    topology: dict                  # task -> its recording topology
    recordings: dict                # (task, rate) -> Recording
    recipe: dict                    # (task, modality) -> `sebvs train` options, --epochs in them
    seeds: dict                     # rate -> modality -> training seeds
    test_seed: dict                 # task -> `sebvs eval --seed` of the test split
    episodes_per_cell: int
    eval_groups: dict               # task -> [(group, conditions, scenarios)]
    eval_sets: dict                 # task -> `sebvs eval` --set lines
    read_rule: tuple[str, ...]      # `sebvs eval table`'s rule
    read_metric: dict               # task -> its metric (None: the task's first)

    @property
    def readings(self) -> dict:
        """The plan's task and rate pairs, in its order, by the name a reading goes by
        ("nav10")."""
        return {f"{t}{r}": (t, r) for t, r in self.recordings}


# ------------------------------------------------------------------ the plan, as written
# the frame camera's own sub-frames, exposed to 5 ms before each tick: the study's frames
# were made before the one light stream and the frames made ahead of their tick became the
# defaults (docs/sensors.md); the topologies pin emulator preset version 1
PHYS = ['camera.sensor="physical"', 'emulator.preset="physical"',
        'camera.frame_light="subframes"', 'camera.frame_ready="tick"']
RANDOMISE = {
    "nav": ('sim.randomise={variant=["indoor","outdoor"], lighting=["nominal","nominal",'
            '"low","dusk","hdr","flicker"], flicker_hz={uniform=[5.0,20.0]}, '
            'target_speed=["slow","nominal","nominal","fast"]}'),
    "arm": ('sim.randomise={conveyor=["static","moving"], belt_speed=[0.08,0.15,0.25], '
            'objects=[1,3], lighting=["nominal","nominal","low","dusk","hdr","flicker"], '
            'flicker_hz={uniform=[5.0,20.0]}}'),
}
RATE_SETS = {10: [], 30: ["sim.control_hz=30.0", "sim.render_hz=120.0", "camera.dvs_hz=120.0",
                          "sim.physics_hz=1080.0",
                          "accumulator.window_s=0.03333333333333333"]}
TOPOLOGY = {"nav": "topologies/nav_record.toml", "arm": "topologies/arm_record.toml"}
RECIPE = {
    "nav": ["--epochs", "10", "--patience", "3", "--stem", "conv", "--lr", "5e-4"],
    "arm": ["--epochs", "16", "--stem", "conv", "--lr", "5e-4"],
}
MODALITIES = ("rgb+event", "rgb+diff", "rgb", "event")
PLAN_SEEDS = {  # rate -> modality -> training seeds
    10: {"rgb+event": (0, 1, 2), "rgb+diff": (0, 1, 2), "rgb": (0, 1, 2), "event": (0,)},
    30: {"rgb+event": (0, 1, 2), "rgb+diff": (0, 1, 2), "rgb": (0,), "event": (0,)},
}
READ_RULE = ("--a", "rgb+event", "--b", "rgb+diff", "--min-diff", "10", "--min-ahead", "3")


def _recording(task: str, rate: int, seed: int, episodes: int, extra: list[str]) -> Recording:
    return Recording(episodes, tuple([*extra, f"topology.seed={seed}", *PHYS, *RATE_SETS[rate],
                                      RANDOMISE[task]]))


SENSORS = Plan(
    name="sensor study", plan_file="research/sensors/plan.md",
    out=ROOT / "research" / "sensors" / "outputs",      # tracked: see its README.md
    smoke_out=ROOT / "out" / "study_sensors" / "smoke", dataset_prefix="study_",
    topology=TOPOLOGY,
    recordings={("nav", 10): _recording("nav", 10, 20, 120, ["sim.episode_s=20.0"]),
                ("nav", 30): _recording("nav", 30, 21, 120, ["sim.episode_s=20.0"]),
                ("arm", 10): _recording("arm", 10, 22, 1500, []),
                ("arm", 30): _recording("arm", 30, 23, 1500, [])},
    recipe={(t, m): tuple(RECIPE[t]) for t in TOPOLOGY for m in MODALITIES},
    seeds=PLAN_SEEDS, test_seed={"nav": 100_100, "arm": 100_200},
    episodes_per_cell=20,       # 30 in the plan, 20 after its step 0 (plan, "Step 0, measured")
    # (name, conditions, scenarios): nav runs as two evaluations, flicker indoors only
    eval_groups={"nav": [("main", "nominal_physical,hdr,dusk,dusk_fast", "indoor,outdoor"),
                         ("flicker", "flicker_100,flicker_120", "indoor")],
                 "arm": [("main", "nominal_physical,fast_physical,hdr,dusk_moving",
                          "single,multi")]},
    eval_sets={"nav": ["sim.episode_s=10"], "arm": []},
    read_rule=READ_RULE,
    read_metric={"nav": "strict_success", "arm": None})   # arm: the task's first, grasp

# the study this driver runs: SENSORS unless main() is given another plan (use_plan)
PLAN = SENSORS
# the sensor study's tables by the names its report and readers import
STUDY_DIR, PLAN_FILE, READINGS = SENSORS.out, SENSORS.plan_file, SENSORS.readings
EVAL_GROUPS, READ_METRIC = SENSORS.eval_groups, SENSORS.read_metric


def use_plan(plan: Plan) -> None:
    """Drive ``plan`` from here on: one study per process (its script's main)."""
    global PLAN
    PLAN = plan


@dataclass(frozen=True)
class Step:
    kind: str           # record | train | eval | read
    label: str
    argv: tuple[str, ...]
    done: Path          # exists (and is complete) when the step is done
    want: int = 0       # record: the episodes the dataset must hold
    task: str = ""      # nav | arm
    rate: int = 0       # control rate, Hz
    group: str = ""     # eval: the plan's condition group (EVAL_GROUPS)


def sets(values: list[str]) -> list[str]:
    return [a for v in values for a in ("--set", v)]


DATASETS_ENV = "SEBVS_STUDY_DATASETS"


def dataset_dir(task: str, rate: int) -> Path:
    """Where the study's recording of a task and rate lives: datasets/<the plan's
    prefix><task><rate> (study_nav10), under $SEBVS_STUDY_DATASETS instead of datasets/
    when it is set (another disk; the tests, which must never touch a study's real
    recordings)."""
    root = os.environ.get(DATASETS_ENV)
    return (Path(root) if root else ROOT / "datasets") / f"{PLAN.dataset_prefix}{task}{rate}"


def checkpoint_dir(out: Path, task: str, rate: int, seed: int) -> Path:
    return out / "checkpoints" / f"{task}{rate}" / f"seed{seed}"


def eval_dir(out: Path, task: str, rate: int, seed: int, group: str) -> Path:
    return out / "eval" / f"{task}{rate}" / f"seed{seed}" / group


def reading_path(out: Path, task: str, rate: int) -> Path:
    """Where the read step keeps `sebvs eval table`'s JSON of a task and rate (its plot beside)."""
    return out / "read" / f"{task}{rate}.json"


def plan_steps(out: Path, workers: int, cells: set[str] | None,
               ray: str | None = None) -> list[Step]:
    """Every step of the plan, in its order: recordings, trainings, evaluations, readings.
    ray: None, or the recordings and evaluations go to Ray (`--ray [ADDRESS]`, "" for a
    local Ray; `workers` is then their tasks in flight); the results are the same."""
    sebvs = [sys.executable, "-m", "sebvs.cli"]
    ray_args = [] if ray is None else ["--ray"] + ([ray] if ray else [])
    fan_out = ["--workers", str(workers), *ray_args]
    plan = PLAN
    keys = [key for name, key in plan.readings.items() if cells is None or name in cells]
    steps = []
    for task, rate in keys:
        rec = plan.recordings[(task, rate)]
        data = dataset_dir(task, rate)
        steps.append(Step("record", f"record {task} {rate} Hz", tuple(
            sebvs + ["record", plan.topology[task], "--episodes", str(rec.episodes),
                     "--out", str(data), *fan_out, "--quiet", *rec.options,
                     *sets(list(rec.sets))]), data / "index.json", rec.episodes,
            task=task, rate=rate))
    for task, rate in keys:
        for modality, seeds in plan.seeds[rate].items():
            for seed in seeds:
                ckpt = checkpoint_dir(out, task, rate, seed)
                steps.append(Step("train", f"train {task} {rate} Hz {modality} seed {seed}", tuple(
                    sebvs + ["train", "--task", task, "--modality", modality, "--data",
                             str(dataset_dir(task, rate)), "--out", str(ckpt), "--seed",
                             str(seed), "--threads", "1", "--no-progress",
                             *plan.recipe[(task, modality)]]),
                    ckpt / f"{task}-{modality}.pt", task=task, rate=rate))
    for task, rate in keys:
        seeds = sorted({s for ss in plan.seeds[rate].values() for s in ss})
        for seed in seeds:
            modalities = [m for m, ss in plan.seeds[rate].items() if seed in ss]
            # the expert and no-action rows do not depend on a training seed: seed 0's run
            rows = [] if seed == 0 else ["--no-expert", "--no-baseline"]
            rate_args = [] if rate == 10 else ["--control-hz", str(rate)]
            for group, conditions, scenarios in plan.eval_groups[task]:
                d = eval_dir(out, task, rate, seed, group)
                steps.append(Step("eval", f"eval {task} {rate} Hz seed {seed} {group}", tuple(
                    sebvs + ["eval", "--task", task, "--modalities", ",".join(modalities),
                             "--checkpoints", str(checkpoint_dir(out, task, rate, seed)),
                             "--split", "test", "--seed", str(plan.test_seed[task]),
                             "--episodes", str(plan.episodes_per_cell),
                             "--conditions", conditions,
                             "--scenarios", scenarios, *rate_args, *rows,
                             *fan_out, "--out", str(d),
                             *sets(plan.eval_sets[task])]), d / "results.json",
                    task=task, rate=rate, group=group))
    for task, rate in keys:
        read = reading_path(out, task, rate)
        steps.append(Step("read", f"read {task} {rate} Hz", tuple(
            sebvs + ["eval", "table", *read_arguments(out, task, rate), "--json", str(read),
                     "--plot", str(read.with_suffix(".png")), "--force"]),
            read, task=task, rate=rate))
    return steps


def read_arguments(out: Path, task: str, rate: int) -> list[str]:
    """`sebvs eval table`'s arguments for a task and rate's reading: each training seed's
    evaluations (NAME=DIR), the plan's rule and metric."""
    plan = PLAN
    flags = dict(zip(plan.read_rule[::2], plan.read_rule[1::2]))
    fused = {flags["--a"], flags["--b"]}          # the two rows the rule compares
    seeds = sorted({s for m, ss in plan.seeds[rate].items() if m in fused for s in ss})
    runs = [f"seed{s}={eval_dir(out, task, rate, s, g)}" for s in seeds
            for g, _, _ in plan.eval_groups[task]]
    metric = ["--metric", plan.read_metric[task]] if plan.read_metric[task] else []
    return [*runs, *plan.read_rule, *metric]


SMOKE_SEEDS = (0, 1)     # two training seeds: the fewest a seed table reads


def _set_arg(argv: list[str], flag: str, value: str) -> None:
    argv[argv.index(flag) + 1] = value


def smoke_steps(out: Path, workers: int, cells: set[str] | None) -> list[Step]:
    """The plan's training, evaluation and reading commands, shrunk so that all of them
    run end to end in minutes, into ``out``: one epoch on 64 frames, training seeds 0 and
    1 only, one episode per cell on the dev seed 1000 (never a test seed), 2 s nav
    episodes, the rule over two seeds. It checks that the commands and their hand-offs
    work (checkpoints found, evaluation groups joined, the rate's options accepted)
    before hours go into them; its numbers mean nothing. The datasets are the study's,
    read only."""
    steps = []
    for step in plan_steps(out, workers, cells):
        argv = list(step.argv)
        if step.kind == "record":
            continue
        if step.kind == "train":
            if int(argv[argv.index("--seed") + 1]) not in SMOKE_SEEDS:
                continue
            _set_arg(argv, "--epochs", "1")
            argv += ["--max-frames", "64"]
        elif step.kind == "eval":
            if int(step.done.parent.parent.name.removeprefix("seed")) not in SMOKE_SEEDS:
                continue
            split = argv.index("--split")
            del argv[split:split + 2]
            _set_arg(argv, "--seed", "1000")
            _set_arg(argv, "--episodes", "1")
            if argv[argv.index("--task") + 1] == "nav":
                argv += ["--set", "sim.episode_s=2"]
        elif step.kind == "read":
            argv = [a for a in argv if not a.startswith(tuple(
                f"seed{s}=" for s in range(3) if s not in SMOKE_SEEDS))]
            _set_arg(argv, "--min-ahead", str(len(SMOKE_SEEDS)))
        steps.append(replace(step, label=f"smoke: {step.label}", argv=tuple(argv)))
    return steps


def recorded(index: Path) -> int:
    return len(DatasetIndex(index.parent).numbers())


def is_done(step: Step) -> bool:
    if step.kind == "record":
        return recorded(step.done) >= step.want
    return step.done.exists()


def dataset_needed(record: Step, planned: list[Step]) -> bool:
    """Whether a recording step must run: while a training of its cell is left. The
    datasets feed only the trainings, and a new checkout does not hold them, so a cell
    whose trainings are all done (committed) is not recorded again."""
    return any(s.kind == "train" and step_cell(s) == step_cell(record) and not is_done(s)
               for s in planned)


def command_of(step: Step) -> list[str]:
    """The step's argv; a partial recording finished with the episodes still missing: on
    from its end when it holds 0..k-1, else with `sebvs record --fill` (the holes an
    interrupted fan-out leaves, then the tail: the same episodes either way)."""
    argv = list(step.argv)
    if step.kind == "record":
        index = DatasetIndex(step.done.parent)
        have, resume = index.numbers(), index.next_episode_number()
        if resume == len(have):
            argv[argv.index("--episodes") + 1] = str(step.want - len(have))
        else:
            argv.append("--fill")
    return argv


def read_ledger(ledger: Path) -> list[dict]:
    """The ledger's records (OUT/steps.jsonl), each with a string "label"; a line that is
    not one (torn by a kill, or foreign) is skipped."""
    records = []
    if ledger.exists():
        for line in ledger.read_text().splitlines():
            try:
                rec = json.loads(line)
            except ValueError:
                continue
            if isinstance(rec, dict) and isinstance(rec.get("label"), str):
                records.append(rec)
    return records


def step_seconds(ledger: Path) -> dict[str, float]:
    """Wall seconds per step label from the ledger: the sum over every run of each step (a
    step resumed over sessions has several, a stopped run counts the time it ran). A start
    line (no seconds yet) adds nothing."""
    took: dict[str, float] = {}
    for rec in read_ledger(ledger):
        try:
            seconds = float(rec["seconds"])
        except (KeyError, TypeError, ValueError):
            continue
        took[rec["label"]] = took.get(rec["label"], 0.0) + seconds
    return took


def machine(cpuinfo: str | None = None) -> str:
    """The CPU a step ran on, as the float results depend on it: numpy and torch choose
    their kernels by the instruction set, so one machine kind with another CPU emulates
    other event timestamps and trains other weights (docs/scale.md). E.g. "AMD EPYC
    (family 25, model 17), avx512f, 2 CPUs"; cpuinfo: /proc/cpuinfo's text (read when
    None; "" where there is none)."""
    if cpuinfo is None:
        try:
            cpuinfo = Path("/proc/cpuinfo").read_text()
        except OSError:
            cpuinfo = ""
    fields: dict[str, str] = {}
    for line in cpuinfo.splitlines():
        key, _, value = line.partition(":")
        fields.setdefault(key.strip(), value.strip())
    name = fields.get("model name") or platform.processor() or platform.machine() or "unknown"
    if "cpu family" in fields and "model" in fields:
        name += f" (family {fields['cpu family']}, model {fields['model']})"
    widest = next((f for f in ("avx512f", "avx2", "avx", "neon", "asimd")
                   if f in fields.get("flags", fields.get("Features", "")).split()), None)
    return ", ".join([name, *([widest] if widest else []), f"{os.cpu_count()} CPUs"])


# Opens a context the way sebvs renders (sebvs.sim.render sets MUJOCO_GL's default) and
# prints the renderer and version OpenGL reports.
GL_PROBE = """
import sebvs.sim.render
import mujoco
from OpenGL import GL
ctx = mujoco.GLContext(1, 1)
ctx.make_current()
print(GL.glGetString(GL.GL_RENDERER).decode(), GL.glGetString(GL.GL_VERSION).decode(), sep=", ")
ctx.free()
"""


@functools.cache
def gl_stack() -> str | None:
    """The OpenGL the steps render with, as a context opened with the driver's environment
    reports it (renders differ between GL stacks as events do between CPUs, so no reading
    may mix them either), e.g. "llvmpipe (LLVM 15.0.6, 256 bits), 4.5 (Compatibility
    Profile) Mesa 22.3.6"; None, said once on stderr, where no context opens. Asked once
    per driver: the stack does not change under a running driver."""
    try:
        probe = subprocess.run([sys.executable, "-c", GL_PROBE], capture_output=True,
                               text=True, timeout=120, cwd=ROOT)
    except (OSError, subprocess.TimeoutExpired) as e:
        reason = str(e)
    else:
        found = probe.stdout.strip().splitlines()
        if probe.returncode == 0 and found:
            return found[-1]
        reason = (probe.stderr.strip().splitlines() or [f"exit code {probe.returncode}"])[-1]
    print(f"{PLAN.name}: the ledger cannot name the GL stack: {reason}", file=sys.stderr)
    return None


def append_ledger(ledger: Path, step: Step, started: float, seconds: float | None = None,
                  code: int | None = None) -> None:
    """A line for a run of a step, written whole in one append (trainings run side by side),
    with the machine it ran on (machine(), and gl_stack() where it is known): at its start
    without seconds and exit code (so that a run killed before it could write its end
    still names its machine), at its end with them."""
    rec = {"label": step.label, "started": time.strftime("%Y-%m-%d %H:%M:%S",
                                                         time.localtime(started)),
           "machine": machine()}
    gl = gl_stack()
    if gl is not None:
        rec["gl"] = gl
    if seconds is not None:
        rec.update(seconds=round(seconds, 1), exit=code)
    with ledger.open("a") as f:
        f.write(json.dumps(rec) + "\n")


def outputs_of(step: Step) -> list[Path]:
    """What a finished step leaves in OUT that the repository keeps: a training's directory
    (checkpoint, its JSON record and losses; the resume state is ignored), an evaluation's
    directory (results.json, report and plots; its per-run files are ignored), a reading's
    JSON and figure. A recording's dataset is not kept."""
    if step.kind in ("train", "eval"):
        return [step.done.parent]
    if step.kind == "read":
        return [p for p in (step.done, step.done.with_suffix(".png")) if p.exists()]
    return []


def _git(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True)


def commit_outputs(step: Step, out: Path, attempts: int = 10) -> str | None:
    """Commit the step's outputs and the ledger (only those paths, whatever else is staged);
    None on success, else what git said. Retried while another git command holds the
    index lock."""
    paths = [p for p in [*outputs_of(step), out / LEDGER] if p.exists()]
    return _commit(paths, f"study: {step.label} done; its outputs kept so that a new "
                          f"checkout resumes after it", attempts)


def resume_states(out: Path) -> list[Path]:
    """The trainings' resume states under OUT that a stop keeps: those on disk, and those
    committed earlier and gone since (their training finished), whose removal is kept."""
    on_disk = set(out.glob(f"checkpoints/**/*{RESUME_SUFFIX}"))
    tracked = _git("ls-files", "-z", "--", str(out.relative_to(ROOT) / "checkpoints"))
    gone = {ROOT / name for name in tracked.stdout.split("\0")
            if name.endswith(RESUME_SUFFIX)} - on_disk
    return sorted(on_disk | gone)


def commit_at_stop(out: Path, attempts: int = 10) -> str | None:
    """At a stop with --commit: commit the ledger (the stopped steps' lines) and the
    resume states of the trainings in flight, so that a new checkout, which must record
    their dataset again, continues each one from its last finished epoch (a state goes on
    where the recording made again has the same content: sebvs/policy/resume.py) instead
    of from nothing. The states are ignored files, added by force; a few MB each."""
    paths = [p for p in (out / LEDGER,) if p.exists()] + resume_states(out)
    return _commit(paths, "study: stopped; the ledger and the resume states of the trainings "
                          "in flight kept, so that a new checkout continues them", attempts,
                   force=True)


def _commit(paths: list[Path], message: str, attempts: int, force: bool = False
            ) -> str | None:
    """Stage and commit only ``paths`` (new, changed or removed; ``force``: ignored ones
    too); None when done or when nothing changed, else what git said."""
    names = [str(p.relative_to(ROOT)) for p in paths]
    if not names:
        return None
    said = ""
    for attempt in range(attempts):
        run = _git("add", "--all", *(["--force"] if force else []), "--", *names)
        if run.returncode == 0:
            run = _git("diff", "--cached", "--quiet", "--", *names)   # 1: something to commit
            if run.returncode == 0:
                return None                                          # nothing new to keep
            if run.returncode == 1:
                run = _git("commit", "--quiet", "-m", message, "--only", "--", *names)
                if run.returncode == 0:
                    return None
        said = (run.stderr or run.stdout).strip()
        if "index.lock" not in said:
            break
        time.sleep(3 * (attempt + 1))
    return said or "git failed"


def training_record(step: Step) -> dict | None:
    """A finished training's own record (the "training" block of the JSON beside its
    checkpoint): its wall seconds over every resumed part and the epochs it ran, which
    early stopping can make fewer than planned. None before it finishes."""
    sidecar = step.done.with_suffix(".json")
    if step.kind != "train" or not step.done.exists() or not sidecar.exists():
        return None
    try:
        training = json.loads(sidecar.read_text()).get("training", {})
    except (OSError, ValueError, AttributeError):
        return None
    if not isinstance(training.get("seconds"), (int, float)) or \
            not isinstance(training.get("epochs_run"), int):
        return None
    return training


def resume_state_of(step: Step) -> Path:
    """Where a training step keeps its resume state (named as the training names it)."""
    return resume_path(step.done.parent, step.task,
                       step.argv[step.argv.index("--modality") + 1])


def epochs_kept(step: Step) -> int:
    """The epochs a stopped training's resume state holds (0 with none, or one that cannot
    be read): a training that goes on from it has only the rest to run. Read as the
    training reads it (weights_only); whether it matches the data is the training's to
    decide when it starts."""
    if step.kind != "train":
        return 0
    state_file = resume_state_of(step)
    if not state_file.exists():
        return 0
    import torch
    try:
        state = torch.load(state_file, weights_only=True)
    except Exception:            # torn by a kill, or not a state: the training starts over
        return 0
    epoch = state.get("epoch") if isinstance(state, dict) else None
    return epoch if isinstance(epoch, int) and epoch > 0 else 0


def planned_frames(task: str, rate: int) -> int:
    """The labelled frames the plan's recording of a task and rate holds, before it exists
    (a new checkout has no datasets): episodes x (episode seconds x rate + 1), one per
    control tick and one at the start (nav 10 Hz: 120 x 201 = 24,120, as recorded)."""
    rec = PLAN.recordings[(task, rate)]
    return rec.episodes * (round(episode_seconds(task, tuple(sets(list(rec.sets))), "record")
                                 * rate) + 1)


def step_work(step: Step, epochs: float | None = None) -> float:
    """A step's size in the unit its time scales with: a training's frames (the dataset's,
    as indexed, once it holds the plan's episodes; the plan's while it is not recorded or
    still being recorded) times its epochs (those it ran once done, else ``epochs``, else
    the planned), an evaluation's simulated seconds over all its rows (modalities, and
    the expert and no action where it has them)."""
    argv = step.argv
    if step.kind == "train":
        data = Path(argv[argv.index("--data") + 1])
        episodes = DatasetIndex(data).episodes() if (data / "index.json").exists() else []
        frames = (sum(e.get("frames", 0) for e in episodes)
                  if len(episodes) >= PLAN.recordings[(step.task, step.rate)].episodes else
                  planned_frames(step.task, step.rate))
        record = training_record(step)
        if record is not None:
            epochs = record["epochs_run"]
        elif epochs is None:
            epochs = int(argv[argv.index("--epochs") + 1])
        return float(frames * epochs)
    if step.kind == "eval":
        task = argv[argv.index("--task") + 1]
        rows = len(argv[argv.index("--modalities") + 1].split(","))
        rows += 0 if "--no-expert" in argv else 1
        rows += 0 if "--no-baseline" in argv else 1
        cells = (len(argv[argv.index("--conditions") + 1].split(","))
                 * len(argv[argv.index("--scenarios") + 1].split(",")))
        return float(rows * cells * int(argv[argv.index("--episodes") + 1])
                     * episode_seconds(task, argv))
    return 1.0


def epoch_shares(records: list[tuple[Step, dict]]) -> dict[str, float]:
    """Per task, the median share of their planned epochs that its done trainings ran
    (each with its training_record): a training left to run is expected to run that share
    of its plan (each task stops early on its own patience: nav after 3 epochs without a
    better validation loss, the arm after 4). A task with no training done has no entry."""
    shares: dict[str, list[float]] = {}
    for s, record in records:
        task = s.argv[s.argv.index("--task") + 1]
        planned = int(s.argv[s.argv.index("--epochs") + 1])
        shares.setdefault(task, []).append(record["epochs_run"] / planned)
    return {task: sorted(v)[len(v) // 2] for task, v in shares.items()}


def episode_seconds(task: str, argv: tuple[str, ...], topology: str = "policy") -> float:
    """A command's episode length: its last `--set sim.episode_s=`, else its topology's
    (`sebvs eval` runs <task>_policy.toml, a recording <task>_record.toml)."""
    sets = [v.split("=", 1)[1] for k, v in zip(argv, argv[1:])
            if k == "--set" and v.startswith("sim.episode_s=")]
    if sets:
        return float(sets[-1])
    topology = ROOT / "topologies" / f"{task}_{topology}.toml"
    return float(tomllib.loads(topology.read_text())["actors"]["sim"]["episode_s"])


def status_text(steps: list[Step], kinds: list[str], took: dict[str, float],
                parallel: int = 2) -> str:
    """What is done (with its wall time) and what is left, each left step with an
    estimate: the median time per unit of work (step_work) of the done steps of its kind,
    task, rate (and evaluation group), times its work; a training with none of those done
    is scaled from every done training, an evaluation with none from those of its task and
    group at a slower control rate (a lower bound, marked >=). A done training is timed by
    its own record (every
    resumed part, see training_record), which the log misses for a part stopped before
    the driver wrote exit lines; one left is sized by the epochs its task's done ones
    ran, less those its resume state keeps. Trainings run ``parallel`` at once."""
    def group(step: Step) -> tuple:
        return step.kind, step.task, step.rate, step.group

    def slower_like(done: Step, left: Step) -> bool:
        """An evaluation of the same task and group at a slower control rate: a tick
        costs the same or less there, so scaling by simulated seconds gives a lower
        bound."""
        return done.task == left.task and done.group == left.group and done.rate < left.rate

    records = [(s, r) for s in steps if (r := training_record(s)) is not None]
    took = {**took, **{s.label: float(r["seconds"]) for s, r in records}}
    shares = epoch_shares(records)

    kept = {s.label: epochs_kept(s) for s in steps
            if s.kind == "train" and "train" in kinds and not is_done(s)}

    def epochs_left(step: Step) -> float:
        share = shares.get(step.argv[step.argv.index("--task") + 1], 1.0)
        expected = share * int(step.argv[step.argv.index("--epochs") + 1])
        return max(expected - kept.get(step.label, 0), 0.0)

    work = {s.label: step_work(s, epochs_left(s) if s.kind == "train" else None)
            for s in steps if s.kind in kinds}                      # reads indexes once

    def rate(done: list[Step]) -> float | None:
        per = sorted(took[d.label] / work[d.label] for d in done
                     if d.label in took and work[d.label] > 0)
        return per[len(per) // 2] if per else None

    lines, total, unknown, bounds = [], 0.0, 0, 0
    for kind in kinds:
        mine = [s for s in steps if s.kind == kind]
        done = [s for s in mine if is_done(s)]
        lines.append(f"{kind:>6}: {len(done)}/{len(mine)} done")
        for s in done:
            if s.label in took:
                lines.append(f"        done: {s.label} ({took[s.label] / 60:.0f} min)")
        for s in mine:
            if s in done:
                continue
            like = [d for d in done if group(d) == group(s) and d.label in took]
            per, how, about = rate(like), f"from {len(like)} done like it", "~"
            if per is None and kind == "train":
                scaled = [d for d in done if d.label in took]
                per, how = rate(scaled), f"scaled by frames from {len(scaled)} done trainings"
            if per is None and kind == "eval":
                slower = [d for d in done if d.label in took and slower_like(d, s)]
                per, how, about = rate(slower), (f"scaled by simulated seconds from "
                                                 f"{len(slower)} done at a slower rate"), ">= "
                bounds += per is not None
            guess = per * work[s.label] if per is not None else None
            if guess is None:
                unknown += 1
            else:
                total += guess / (parallel if kind == "train" else 1)
            if kept.get(s.label):
                how += f"; {kept[s.label]} epochs kept in its resume state"
            lines.append(f"        left: {s.label}" + (
                f" ({about}{guess / 60:.0f} min, {how})" if guess is not None else ""))
    lines.append(f"estimated wall time left: {'at least ' if bounds else ''}"
                 f"{total / 3600:.1f} h (trainings {parallel} at once)"
                 + (f"; {bounds} evaluation estimates are lower bounds (no evaluation has "
                    f"run at their control rate yet)" if bounds else "")
                 + (f"; {unknown} steps have no estimate yet" if unknown else ""))
    return "\n".join(lines)


_RUNNING: set[subprocess.Popen] = set()
_RUNNING_LOCK = threading.Lock()
STOPPING = threading.Event()


def stop_running(signum: int, frame) -> None:
    """SIGTERM or SIGINT to the driver: its steps are stopped (each writes its exit line,
    so that the time it ran still counts) and no other step starts."""
    STOPPING.set()
    with _RUNNING_LOCK:
        for proc in _RUNNING:
            if proc.poll() is None:
                proc.send_signal(signum)


def ledger_machines(ledger: Path, label: str, key: str = "machine") -> set[str]:
    """What the ledger says earlier runs of this step ran on: their CPUs (key "machine"),
    or their GL stacks (key "gl"; runs from before the ledger named them have none)."""
    return {rec[key] for rec in read_ledger(ledger)
            if rec["label"] == label and isinstance(rec.get(key), str)}


def start_on_this_machine(step: Step, ledger: Path) -> str | None:
    """An evaluation runs whole on one CPU and GL stack: its RGB+Event and RGB+Diff rows
    are read as a pair, and another CPU plays other events, another GL stack renders
    other frames (docs/scale.md, "Determinism"). So when an earlier, stopped run of it was
    made on another CPU, or with another GL stack where both are known, the runs it
    finished (its episodes/ directory, which `sebvs eval` would resume from) are removed;
    returns what was done, for the log, or None."""
    episodes = step.done.parent / "episodes"
    if step.kind != "eval" or not episodes.exists():
        return None
    here = {"machine": machine(), "gl": gl_stack()}
    other = {key: ledger_machines(ledger, step.label, key) - {value}
             for key, value in here.items() if value is not None}
    said = [f"another {'CPU' if key == 'machine' else 'GL stack'} ({'; '.join(sorted(v))})"
            for key, v in other.items() if v]
    if not said:
        return None
    shutil.rmtree(episodes)
    return (f"its finished runs were made with {' and '.join(said)}: removed, the "
            f"evaluation starts again on this machine ({here['machine']}; {here['gl']})")


def step_log(log: Path, step: Step) -> Path:
    """The step's own output file, beside the driver's log: logs/<label, spaces as _>.txt
    (appended to by every run of the step)."""
    return log.parent / "logs" / (step.label.replace(" ", "_") + ".txt")


def run_step(step: Step, log: Path, stop: threading.Event) -> tuple[Step, int | None, float]:
    """Run one step, its output to its own file (step_log; trainings run side by side, and
    their lines would interleave in one), its start and exit to the driver's log and a
    line to the ledger beside it; (step, exit code, seconds), or a None code when an
    earlier step failed, or the driver was stopped, before this one started."""
    if stop.is_set() or STOPPING.is_set():
        return step, None, 0.0
    t0, started = time.monotonic(), time.time()
    argv = command_of(step)
    output = step_log(log, step)
    output.parent.mkdir(parents=True, exist_ok=True)
    header = f"\n=== {time.strftime('%Y-%m-%d %H:%M:%S')} {step.label}\n{shlex.join(argv)}\n"
    restarted = start_on_this_machine(step, log.parent / LEDGER)
    if restarted:
        header += f"(restarted: {restarted})\n"
    append_ledger(log.parent / LEDGER, step, started)
    with log.open("a") as f:
        f.write(header + f"(output: {output.relative_to(log.parent)})\n")
    with output.open("a") as out:
        out.write(header)
        out.flush()
        with _RUNNING_LOCK:
            proc = subprocess.Popen(argv, cwd=ROOT, stdout=out, stderr=subprocess.STDOUT)
            _RUNNING.add(proc)
        try:
            code = proc.wait()
        finally:
            with _RUNNING_LOCK:
                _RUNNING.discard(proc)
        took = time.monotonic() - t0
        out.write(f"=== exit {code} after {took:.0f} s\n")
    with log.open("a") as f:
        f.write(f"=== exit {code} after {took:.0f} s: {step.label}\n")
    append_ledger(log.parent / LEDGER, step, started, took, code)
    return step, code, took


def main(argv: list[str] | None = None, plan: Plan = SENSORS, doc: str | None = None) -> int:
    """The driver's command line, for ``plan`` (a study's script passes its own, and its
    docstring as ``doc``, the help's text)."""
    use_plan(plan)
    doc = __doc__ if doc is None else doc
    ap = argparse.ArgumentParser(description=doc.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog="\n\n".join(doc.split("\n\n")[1:]))
    ap.add_argument("action", choices=["plan", "run", "status", "smoke"],
                    help="smoke: the plan's commands shrunk to minutes (one epoch, one "
                         "episode per cell on a dev seed) into OUT/smoke, to check they "
                         "work end to end before the real run; its numbers mean nothing")
    ap.add_argument("--steps", default="record,train,eval,read",
                    help="which kinds of step, comma-separated (default all, in order)")
    known = list(plan.readings)
    ap.add_argument("--only", default=None, metavar="CELLS",
                    help=f"task and rate, comma-separated: {', '.join(known)}; `run` takes "
                         f"them in the order given (default: all, in that order)")
    ap.add_argument("--out", type=Path, default=None,
                    help=f"the study's outputs (default {plan.out.relative_to(ROOT)}, "
                         f"tracked; smoke: {plan.smoke_out.relative_to(ROOT)})")
    ap.add_argument("--commit", action="store_true",
                    help="commit each finished step's outputs and its ledger line at once "
                         "(git, only those paths), so that a new checkout resumes after it")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--parallel", type=int, default=2, help="trainings at once (default 2)")
    ap.add_argument("--ray", nargs="?", const="", default=None, metavar="ADDRESS",
                    help="recordings and evaluations on Ray: the cluster at ADDRESS, or a "
                         "local Ray without one (--workers is then their tasks in flight; "
                         "needs the [ray] extra); trainings stay here, --parallel at once")
    args = ap.parse_args(argv)
    kinds = args.steps.split(",")
    cells = set(args.only.split(",")) if args.only else None
    if cells and cells - set(known):
        ap.error(f"--only: unknown {', '.join(sorted(cells - set(known)))} (known: "
                 f"{', '.join(sorted(known))})")
    if set(kinds) - {"record", "train", "eval", "read"}:
        ap.error("--steps: give record, train, eval, read")
    if args.action == "smoke":
        args.out = plan.smoke_out if args.out is None else args.out / "smoke"
        planned = smoke_steps(args.out, args.workers, cells)     # records none
        steps = [s for s in planned if s.kind in kinds]
    else:
        args.out = plan.out if args.out is None else args.out
        planned = plan_steps(args.out, args.workers, cells, args.ray)
        steps = [s for s in planned if s.kind in kinds]
    if args.action == "plan":
        for s in steps:
            print(f"# {s.label}\n{shlex.join(command_of(s) if s.kind == 'record' else s.argv)}")
        return 0
    unneeded = [s for s in steps if s.kind == "record" and not is_done(s)
                and not dataset_needed(s, planned)]
    steps = [s for s in steps if s not in unneeded]
    notes = [f"{s.label}: not needed, every training of its cell is done (a dataset feeds "
             f"only the trainings)" for s in unneeded]
    if args.action == "status":
        print("\n".join([*notes, status_text(steps, kinds, step_seconds(args.out / LEDGER),
                                              args.parallel)]))
        return 0
    args.out.mkdir(parents=True, exist_ok=True)
    log = args.out / "log.txt"
    signal.signal(signal.SIGTERM, stop_running)
    if signal.getsignal(signal.SIGINT) is not signal.SIG_IGN:     # a background job's stays
        signal.signal(signal.SIGINT, stop_running)
    print(f"{plan.name} ({plan.plan_file}): log {log}", file=sys.stderr)
    gl_stack()      # asked here, before the steps' threads, so that it is asked (and a
                    # failure said) once, not by two trainings starting side by side
    for note in notes:
        print(note, file=sys.stderr)
    order = args.only.split(",") if args.only else list(dict.fromkeys(map(step_cell, steps)))
    for cell in dict.fromkeys(order):
        for kind in kinds:
            todo = [s for s in steps if step_cell(s) == cell and s.kind == kind
                    and not is_done(s)]
            if not run_together(todo, log, args.parallel if kind == "train" else 1,
                                commit=args.out if args.commit else None):
                print(f"{plan.name}: stopped; the step's output under {log.parent / 'logs'} "
                      f"says why", file=sys.stderr)
                if args.commit and STOPPING.is_set() and (said := commit_at_stop(args.out)):
                    print(f"{plan.name}: the ledger and resume states are not committed "
                          f"({said}); commit them by hand", file=sys.stderr)
                return 1
    return 0


def step_cell(step: Step) -> str:
    """The task and rate a step belongs to, e.g. "nav10" (from its label)."""
    words = step.label.removeprefix("smoke: ").split()
    return words[1] + words[2]


def run_together(todo: list[Step], log: Path, parallel: int,
                 commit: Path | None = None) -> bool:
    """Run the steps, ``parallel`` at once; False when one failed (those not yet started
    then never start; the running ones end). commit: the study's OUT, to commit each step
    that finishes (commit_outputs); a commit that fails is said, and the study goes on."""
    stop, failed = threading.Event(), False
    with ThreadPoolExecutor(parallel) as pool:
        futures = [pool.submit(run_step, s, log, stop) for s in todo]
        for future in as_completed(futures):
            step, code, took = future.result()
            if code is None:
                continue                     # never started: an earlier step failed
            state = ("done" if code == 0 and is_done(step) else
                     f"stopped (exit {code})" if STOPPING.is_set() else f"FAILED (exit {code})")
            print(f"{step.label}: {state} in {took / 60:.1f} min", file=sys.stderr)
            if commit is not None and state == "done" and (said := commit_outputs(step, commit)):
                print(f"{PLAN.name}: {step.label}: its outputs are not committed ({said}); "
                      f"commit them by hand", file=sys.stderr)
            if state != "done":
                stop.set()                   # nothing new starts; running ones end
                failed = True
    return not failed


if __name__ == "__main__":
    sys.exit(main())
