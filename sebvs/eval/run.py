"""`sebvs eval`: closed-loop evaluation through the real topology, every actor in the loop.

For each condition, scenario and modality (plus the expert as the reference row and the
no-action baseline, actors/baseline.py, as the floor) one run of the policy topology plays
N seeded episodes: the same topology seed gives every modality, the expert and the
baseline the same episode seeds and so the same target trajectories. The topology seed
is the first of a split's range (sebvs/data/splits.py: dev by default, test held out from
every recording) or an explicit one ("custom"); the nav task's scenarios are its two
scene variants, indoor and outdoor, the arm's one or three cubes. The tracker
sink appends one JSON line per finished episode; this module only chooses overrides,
supervises the runs with a progress bar, and aggregates.

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

Videos (`video`): the overrides add a video writer (actors/video.py) to the run, writing
<out>/videos/<condition>[__<scenario>]__<modality>__ep<k>.mp4 for the first `video_episodes`
episodes, with the event frames wired to it for the modalities that use them, and the sim
lingers past the writer's wait for an episode's trailing frames. Without `video` no such
actor starts and nothing else changes.
"""
from __future__ import annotations

import json
import math
import os
import secrets
import sys
import time
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from tqdm import tqdm

from ..data.splits import DEFAULT_EVAL_SPLIT, EVAL_SPLITS, SPLITS, SeedRange
from ..policy.checkpoint import checkpoint_paths, read_config
from ..policy.inputs import CONTROL_MODALITIES, MODALITY_INPUTS
from ..policy.inputs import MODALITIES as PAPER_MODALITIES
from ..runtime.supervisor import RunFailed, Supervisor
from ..runtime.topology import check_seed, load_topology, parse_override
from ..sensor_pairs import camera_override, emulator_override
from .report import plot_success, render_report

ROOT = Path(__file__).resolve().parents[2]
TOPOLOGIES = ROOT / "topologies"

# condition -> topology overrides: the scene's settings (sebvs/sim/nav.py and arm.py) and
# the camera's sensor, so that a condition runs the same whatever the topology's default.
# The 8-bit benchmark's conditions (the paper's, and docs/results_history.md): light in the
# render's 8-bit terms, for the ideal 8-bit sensor pair.
IDEAL8 = camera_override("ideal8")
NAV_CONDITIONS: dict[str, list[str]] = {
    "nominal": [IDEAL8],
    "fast": ['sim.config.target_speed="fast"', IDEAL8],
    "low_light": ['sim.config.lighting="low"', IDEAL8],
    "flicker": ['sim.config.lighting="flicker"', IDEAL8],
    "blur": ["sim.config.rgb_blur=8", IDEAL8],
    # the hardest pairing for a frame camera: fast motion under a flickering light
    "fast_flicker": ['sim.config.target_speed="fast"', 'sim.config.lighting="flicker"', IDEAL8],
}
ARM_CONDITIONS: dict[str, list[str]] = {
    "nominal": [IDEAL8],                                          # static conveyor
    "moving": ['sim.config.conveyor="moving"', IDEAL8],           # 8 cm/s
    "fast": ['sim.config.conveyor="moving"', "sim.config.belt_speed=0.25", IDEAL8],
    "low_light": ['sim.config.lighting="low"', IDEAL8],
    "flicker": ['sim.config.lighting="flicker"', IDEAL8],
    "blur": ['sim.config.conveyor="moving"', "sim.config.rgb_blur=8", IDEAL8],
}
# The physical conditions: light, flicker and motion as physical quantities (the scenes'
# photometry(), sebvs/sim/light.py; docs/sim.md, "Conditions in physical terms"), for
# cameras that model a sensor on physical light (camera.sensor="physical"): the default
# sensor pair's conditions (`--conditions all` with `--sensor physical`).
PHYSICAL = camera_override("physical")
# mains flicker (twice the supply frequency) needs the renders at >= 1 kHz, else it aliases
MAINS_RATES = ["sim.render_hz=1000.0", "camera.dvs_hz=1000.0"]
NAV_PHYSICAL_CONDITIONS: dict[str, list[str]] = {
    # the office (400 lux indoors, an overcast day outdoors): the physical sensors' baseline
    "nominal_physical": [PHYSICAL],
    # a backlit scene: windows (indoor) or the sky (outdoor) at 1e4 cd/m^2, target in shade
    "hdr": ['sim.config.lighting="hdr"', PHYSICAL],
    "dusk": ['sim.config.lighting="dusk"', PHYSICAL],                  # 3 lux
    "dusk_fast": ['sim.config.lighting="dusk"', 'sim.config.target_speed="fast"', PHYSICAL],
    "flicker_100": ['sim.config.lighting="flicker"', "sim.config.flicker_hz=100.0",
                    *MAINS_RATES, PHYSICAL],                             # 50 Hz mains
    "flicker_120": ['sim.config.lighting="flicker"', "sim.config.flicker_hz=120.0",
                    *MAINS_RATES, PHYSICAL],                             # 60 Hz mains
    "fast_hdr": ['sim.config.lighting="hdr"', 'sim.config.target_speed="fast"', PHYSICAL],
}
ARM_PHYSICAL_CONDITIONS: dict[str, list[str]] = {
    "nominal_physical": [PHYSICAL],                                     # 500 lux, static
    "fast_physical": ['sim.config.conveyor="moving"', "sim.config.belt_speed=0.25", PHYSICAL],
    "hdr": ['sim.config.lighting="hdr"', PHYSICAL],                    # lamp beside the belt
    "dusk_moving": ['sim.config.lighting="dusk"', 'sim.config.conveyor="moving"',
                    "sim.config.belt_speed=0.08", PHYSICAL],
    "fast_hdr": ['sim.config.lighting="hdr"', 'sim.config.conveyor="moving"',
                 "sim.config.belt_speed=0.25", PHYSICAL],
}
# scenario -> overrides: the nav scene's two variants (the shipped checkpoints were trained
# indoors only, so outdoor asks whether a policy transfers)
NAV_SCENARIOS: dict[str, list[str]] = {"indoor": ['sim.config.variant="indoor"'],
                                       "outdoor": ['sim.config.variant="outdoor"']}
# the arm's single- and multi-object (cluttered) scenes
ARM_SCENARIOS: dict[str, list[str]] = {"single": ["sim.config.objects=1"],
                                       "multi": ["sim.config.objects=3"]}


@dataclass(frozen=True)
class TaskEval:
    """What `sebvs eval` needs to know of a task: its conditions (the 8-bit benchmark's,
    "all") and physical conditions ("physical"), its scenarios, the two topologies, and the
    per-tick error trace its tracker records (episode key, the plot's file and label)."""
    conditions: dict[str, list[str]]
    scenarios: dict[str, list[str]]
    policy_topology: Path
    expert_topology: Path
    trace_key: str
    trace_png: str
    trace_label: str
    physical: dict[str, list[str]] = field(default_factory=dict)

    @property
    def known_conditions(self) -> dict[str, list[str]]:
        """Every condition a run may name: the benchmark's, then the physical ones."""
        return {**self.conditions, **self.physical}

    @property
    def output_files(self) -> str:
        return f"report.md, results.json, success.png, {self.trace_png}, latency.png"


TASKS = {
    "nav": TaskEval(NAV_CONDITIONS, NAV_SCENARIOS, TOPOLOGIES / "nav_policy.toml",
                    TOPOLOGIES / "nav_expert.toml", "trace_error_px", "centroid_error.png",
                    "centroid error (px); gaps: target out of view", NAV_PHYSICAL_CONDITIONS),
    "arm": TaskEval(ARM_CONDITIONS, ARM_SCENARIOS, TOPOLOGIES / "arm_policy.toml",
                    TOPOLOGIES / "arm_expert.toml", "trace_error_mm", "pose_error.png",
                    "position error against the task's pose (mm)", ARM_PHYSICAL_CONDITIONS),
}
# the learned rows: the paper's three, and the rgb+diff control when asked for by name
MODALITIES = PAPER_MODALITIES + CONTROL_MODALITIES
BASELINE = "no_action"
VIDEO_FINALIZE_S = 1.0         # the video writer's wait for an episode's trailing frames
VIDEO_DRAIN_MARGIN_S = 0.5     # the sim's linger beyond that wait
SHARED_SIM_KEYS = ("integrator", "physics_hz", "timestep", "control_hz", "render_hz",
                   "episode_s")
# an episode line's "health" counters (actors/tracker.py); lines written before them read 0
HEALTH_COUNTERS = ("commands", "rejected", "action_timeouts", "deadline_misses", "actions",
                   "nonfinite_actions")


def condition_sensor(task: str, condition: str) -> str:
    """The sensor pair a condition is defined for: "physical" or "ideal8"."""
    return "physical" if condition in TASKS[task].physical else "ideal8"


def event_sensor_overrides(task: str, condition: str) -> list[str]:
    """The event sensor a condition asks for: under the physical conditions the emulator's
    "physical" preset, the event sensor's own physics on linear light (slow and noisy at
    dusk); under the 8-bit benchmark's the paper's. The evaluation's event rows and the
    Gymnasium environments (sebvs.envs)."""
    return [emulator_override(condition_sensor(task, condition))]


@dataclass(frozen=True)
class Run:
    """One topology run: N seeded episodes of one condition, scenario and modality."""
    condition: str
    scenario: str
    modality: str

    @property
    def key(self) -> str:
        """File stem of its episode lines and videos ("single", the arm's one-cube scene,
        keeps the names it always had)."""
        parts = [self.condition] + ([self.scenario] if self.scenario != "single" else [])
        return "__".join(parts + [self.modality.replace("+", "_")])

    def __str__(self) -> str:
        return f"{self.condition}/{self.scenario}/{self.modality}"


@dataclass
class EvalPlan:
    task: str
    modalities: list[str]
    conditions: list[str]
    episodes: int
    out: Path
    clock: str = "lockstep"
    split: str | None = None    # dev | test; None: dev, or "custom" when seed is given
    seed: int | None = None     # None: the split's first seed
    checkpoints: str = "checkpoints"
    expert: bool = True
    baseline: bool = True                   # the no-action row
    scenarios: list[str] | None = None      # None: every scenario of the task
    policy_topology: Path | None = None     # None: the task's
    expert_topology: Path | None = None
    extra: list[str] = field(default_factory=list)
    control_hz: float | None = None   # None: the topologies' (10 Hz, the paper's)
    video: bool = False          # one MP4 per episode of each run ...
    video_episodes: int = 1      # ... for its first K episodes
    # fan-out (sebvs/scale, docs/scale.md): None / 1 runs one topology at a time, here
    workers: int | None = None
    ray: str | None = None       # "" a local Ray, else a cluster address
    max_attempts: int = 3        # per shard, then the evaluation stops naming its episodes

    def __post_init__(self) -> None:
        spec = TASKS.get(self.task)
        if spec is not None:
            self.scenarios = list(spec.scenarios) if self.scenarios is None else self.scenarios
            self.policy_topology = self.policy_topology or spec.policy_topology
            self.expert_topology = self.expert_topology or spec.expert_topology
        if self.split is None:
            self.split = "custom" if self.seed is not None else DEFAULT_EVAL_SPLIT
        if self.seed is None and self.split in EVAL_SPLITS:
            self.seed = SPLITS[self.split].first

    @property
    def seed_range(self) -> SeedRange:
        """The topology seeds this plan's split stands for (a custom seed: itself)."""
        return SPLITS[self.split] if self.split in EVAL_SPLITS \
            else SeedRange(self.split, self.seed, self.seed)

    def validate(self) -> None:
        if self.task not in TASKS:
            raise ValueError(f"unknown task {self.task!r} (one of {', '.join(TASKS)})")
        spec = TASKS[self.task]
        unknown = [m for m in self.modalities if m not in MODALITIES]
        if unknown:
            raise ValueError(f"unknown modality {unknown[0]!r} (one of {', '.join(MODALITIES)})")
        for kind, given, known in (("condition", self.conditions, spec.known_conditions),
                                   ("scenario", self.scenarios, spec.scenarios)):
            unknown = [c for c in given if c not in known]
            if unknown:
                raise ValueError(f"unknown {kind} {unknown[0]!r} for task {self.task} "
                                 f"(one of {', '.join(known)})")
        if self.control_hz is not None and not (isinstance(self.control_hz, (int, float))
                                                and 0 < self.control_hz <= 1000):
            raise ValueError(f"--control-hz must be in (0, 1000], got {self.control_hz!r}")
        if self.split not in (*EVAL_SPLITS, "custom"):
            raise ValueError(f"unknown split {self.split!r} (one of {', '.join(EVAL_SPLITS)})")
        if self.seed is None:
            raise ValueError("a custom split needs a topology seed (--seed)")
        # a custom seed past 2**31 would wrap onto another seed's episodes, a test seed's
        # among them, and be reported as "custom"
        check_seed(self.seed, "--seed")
        if self.split in EVAL_SPLITS and self.seed not in SPLITS[self.split]:
            raise ValueError(f"--seed {self.seed} is outside the {self.split} split's range "
                             f"({SPLITS[self.split]})")
        # results.json names the seed and each run's scenario: an extra override that
        # changed either would make it name episodes that were not run
        fixed = {("topology", "seed"): "--seed or --split"}
        if self.task == "nav":
            fixed[("sim", "config", "variant")] = "--scenarios"
        for text in self.extra:
            parts = tuple(parse_override(text)[0])
            if parts in fixed:
                raise ValueError(f"--set {text}: the evaluation sets {'.'.join(parts)} "
                                 f"itself (use {fixed[parts]})")
        if self.episodes < 1:
            raise ValueError("--episodes must be at least 1")
        if self.clock not in ("lockstep", "realtime"):
            raise ValueError(f"--clock {self.clock!r} is not lockstep or realtime")
        if self.video and self.video_episodes < 1:
            raise ValueError("--video-episodes must be at least 1")
        if self.workers is not None and self.workers < 1:
            raise ValueError(f"--workers must be at least 1, got {self.workers}")
        if self.max_attempts < 1:
            raise ValueError(f"--max-attempts must be at least 1, got {self.max_attempts}")

    @property
    def fans_out(self) -> bool:
        return (self.workers or 1) > 1 or self.ray is not None

    def runs(self) -> list[Run]:
        mods = ((["expert"] if self.expert else []) + ([BASELINE] if self.baseline else [])
                + list(self.modalities))
        return [Run(c, s, m) for c in self.conditions for s in self.scenarios for m in mods]

    def episode_file(self, run: Run) -> Path:
        return self.out / "episodes" / f"{run.key}.jsonl"

    def health_file(self, run: Run) -> Path:
        """The run's counters that its episode lines do not carry (handler errors)."""
        return self.out / "episodes" / f"{run.key}.health.json"

    def video_files(self, run: Run) -> list[Path]:
        """The videos a finished run leaves (.mp4; see EpisodeVideo for the .avi fallback)."""
        return [self.out / "videos" / f"{run.key}__ep{k}.mp4"
                for k in range(min(self.video_episodes, self.episodes))]

    def videos_missing(self, run: Run) -> bool:
        return self.video and not all(p.exists() or p.with_suffix(".avi").exists()
                                      for p in self.video_files(run))

    def video_overrides(self, run: Run) -> list[str]:
        if not self.video:
            return []
        # one frame per control tick: at the control rate the video plays in sim time
        hz = self.policy_sim().get("control_hz")
        for text in self.extra:
            parts, value = parse_override(text)
            if parts == ["sim", "control_hz"]:
                hz = value
        sets = ['video.run="actors.video:VideoWriter"',
                'video.inputs={rgb={from="camera/rgb", queue=256}, episode="sim/episode"}',
                f"video.directory={json.dumps(str(self.out / 'videos'))}",
                f"video.prefix={json.dumps(run.key)}",
                f"video.episodes={min(self.video_episodes, self.episodes)}",
                f"video.label={json.dumps(run.modality)}"]
        if isinstance(hz, (int, float)) and hz > 0:
            sets.append(f"video.fps={float(hz)}")
        if "events" in MODALITY_INPUTS.get(run.modality, ()):
            sets.append('video.inputs.events={from="accumulator/frames", queue=256}')
        # The run stops when the sim's linger ends, dropping what is still queued on the
        # writer's inputs; the writer waits VIDEO_FINALIZE_S for an episode's trailing
        # frames, so the sim lingers longer than that (a --set sim.linger_s still wins)
        sets += [f"video.finalize_after_s={VIDEO_FINALIZE_S}",
                 f"sim.linger_s={VIDEO_FINALIZE_S + VIDEO_DRAIN_MARGIN_S}"]
        return sets

    def rate_overrides(self, run: Run) -> list[str]:
        """The control rate as a variable: the sim's ticks, the tracker's, the event
        frames' window (one tick; overrides() puts a checkpoint's own after it), a render rate
        that is a whole multiple of the control rate (at least the one the topology or the
        condition asks for) and a physics rate that is a whole multiple of that (at least
        the topology's)."""
        if self.control_hz is None:
            return []
        hz = float(self.control_hz)
        render = float(self.policy_sim().get("render_hz", hz))
        for text in TASKS[self.task].known_conditions[run.condition]:
            parts, value = parse_override(text)
            if parts == ["sim", "render_hz"]:
                render = float(value)
        render = hz * max(1, math.ceil(render / hz - 1e-9))
        # and a physics rate that is a whole multiple of the render rate
        sim = self.policy_sim()
        physics = 1.0 / sim["timestep"] if sim.get("timestep") else \
            float(sim.get("physics_hz", 1000.0))
        physics = render * max(1, math.ceil(physics / render - 1e-9))
        sets = [f"sim.control_hz={hz}", f"sim.render_hz={render}", f"camera.dvs_hz={render}",
                f"tracker.control_hz={hz}",
                f"sim.timestep={1.0 / physics}" if sim.get("timestep")
                else f"sim.physics_hz={physics}"]
        if "events" in MODALITY_INPUTS.get(run.modality, ()):
            sets.append(f"accumulator.window_s={1.0 / hz}")
        return sets

    def shared_sim(self) -> list[str]:
        """The policy topology's physics and rates, imposed on the expert's run.

        The expert row is a reference only if the robot, the clock and the camera's
        sampling (which sets the blur exposure) are the same as the policies'.
        """
        sim = self.policy_sim()
        return [f"sim.{k}={json.dumps(sim[k])}" for k in SHARED_SIM_KEYS if k in sim]

    def policy_sim(self) -> dict:
        """The policy topology's [actors.sim] table, as written in its file."""
        return tomllib.loads(self.policy_topology.read_text())["actors"]["sim"]

    def overrides(self, run: Run) -> tuple[Path, list[str]]:
        spec = TASKS[self.task]
        path = self.episode_file(run)
        run_sets = [f"topology.seed={self.seed}", f'topology.clock="{self.clock}"',
                    f"sim.episodes={self.episodes}", f'tracker.path="{path}"',
                    f'tracker.label={{condition="{run.condition}", modality="{run.modality}", '
                    f'topology_seed={self.seed}}}']
        scene_sets = [*spec.known_conditions[run.condition], *spec.scenarios[run.scenario],
                      *self.video_overrides(run)]
        common = run_sets + scene_sets
        if run.modality == "expert":
            # the policies' rates first: a condition that sets its own (the mains flicker's
            # render_hz) sets them for the expert too
            return self.expert_topology, (run_sets + self.shared_sim() + scene_sets
                                          + self.rate_overrides(run) + self.extra)
        if run.modality == BASELINE:
            # the policy topology with the baseline answering each tick instead: the policy,
            # emulator and accumulator then feed nobody and are pruned
            sets = ['baseline.run="actors.baseline:NoAction"', f'baseline.task="{self.task}"',
                    'baseline.inputs={rgb={from="camera/rgb", queue=64}}',
                    'sim.inputs.action="baseline/action"',
                    'tracker.inputs.action={from="baseline/action", queue=256}']
            return self.policy_topology, common + sets + self.rate_overrides(run) + self.extra
        sets = [f'policy.modality="{run.modality}"', f'policy.directory="{self.checkpoints}"',
                f'policy.modalities=["{run.modality}"]']
        events = []
        if "events" not in MODALITY_INPUTS[run.modality]:   # no events wired: the
            sets.append('policy.inputs={rgb="camera/rgb"}')   # event chain is pruned
        else:   # after the rate's: a window the checkpoint learned from wins over one tick
            events = (self.event_frame_overrides(run.modality)
                      + event_sensor_overrides(self.task, run.condition))
        return self.policy_topology, (common + sets + self.rate_overrides(run) + events
                                      + self.extra)

    def event_frames(self, modality: str) -> dict | None:
        """The checkpoint config's "event_frames" (how its training data's event frames
        were made), or None where it has none or cannot be read (the policy actor then
        names what is wrong with the checkpoint)."""
        pt, _ = checkpoint_paths(self.checkpoints, self.task, modality)
        try:
            frames = read_config(pt).get("event_frames")
        except (OSError, ValueError):
            return None
        if not isinstance(frames, dict) or frames.get("representation") not in (
                "counts", "histogram"):
            return None
        return frames

    def event_frame_notes(self) -> list[str]:
        """One line per event modality whose checkpoint exists but does not say how its
        event frames were made (trained before checkpoints kept it): its events then
        come from the topology as written, which may be another sensor than it learned
        from (the nav topologies' went from 80 to 160 px on 2026-11-25)."""
        notes = []
        for m in self.modalities:
            _, config = checkpoint_paths(self.checkpoints, self.task, m)
            if ("events" in MODALITY_INPUTS.get(m, ()) and config.exists()
                    and self.event_frames(m) is None):
                notes.append(f"{config} does not say which event frames it was trained on; "
                             f"they are made as {self.policy_topology.name} says (to match "
                             f"an older checkpoint: --set camera.luma_scale=0.5 for the "
                             f"80 px sensor)")
        return notes

    def event_frame_overrides(self, modality: str) -> list[str]:
        """The camera and accumulator made to give the event frames the checkpoint was
        trained on (representation, time bins, window, sensor size: its config's
        "event_frames", taken from the training data). A checkpoint without them gets the
        topology as written; a --set of the user's comes later and wins."""
        frames = self.event_frames(modality)
        if frames is None:
            return []
        sets = [f'accumulator.representation={json.dumps(frames.get("representation"))}',
                f'accumulator.bins={int(frames.get("bins") or 1)}']
        if isinstance(frames.get("window_s"), (int, float)):
            sets.append(f'accumulator.window_s={float(frames["window_s"])}')
        sensor, output = frames.get("sensor"), frames.get("output")
        config = self.policy_sim().get("config", {})
        if sensor and output and list(output) == [config.get("width"), config.get("height")]:
            # the camera renders the emulator's luma at luma_scale x the RGB frame
            sets.append(f"camera.luma_scale={sensor[0] / output[0]}")
        return sets


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


def run_one(plan: EvalPlan, run: Run, bar: tqdm) -> list[dict]:
    path = plan.episode_file(run)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.unlink(missing_ok=True)
    plan.health_file(run).unlink(missing_ok=True)
    if plan.video:      # a rerun with fewer --video-episodes leaves no stale files behind
        for old in (plan.out / "videos").glob(f"{run.key}__ep*"):
            old.unlink()
    topology, overrides = plan.overrides(run)
    sup = Supervisor(load_topology(topology, overrides), runs_dir=plan.out / "runs",
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
        raise RunFailed(f"{run}: {sup.failure}")
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
        return Task(str(shard), str(Path(topology).resolve()),
                    (*overrides, f"tracker.path={json.dumps(str(path))}",
                     f"sim.first_episode={shard.first}",
                     f"sim.episodes={shard.stop - shard.first}"),
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
    if plan.extra:      # the --set overrides every run had (an ablation among them)
        results["overrides"] = list(plan.extra)
    trace = TASKS[plan.task].trace_key
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


def write_outputs(results: dict, out: Path) -> None:
    (out / "results.json").write_text(json.dumps(results, indent=1))
    (out / "report.md").write_text(render_report(results) + "\n")
    plot_success(results, out / "success.png")
    spec = TASKS[results["task"]]
    plot_traces(results, out / spec.trace_png, spec.trace_key, spec.trace_label)
    plot_latency(results, out / "latency.png")


def plot_traces(results: dict, path: Path, key: str, what: str) -> None:
    """A per-tick error trace against time (`key` of each episode: nav centroid error px,
    arm position error mm), one panel per condition and scenario, the first episode of
    each modality."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    groups = sorted({(e["condition"], e.get("scenario", "single"))
                     for e in results["episodes"]})
    fig, axes = plt.subplots(len(groups) or 1, 1, figsize=(7, 2.4 * max(1, len(groups))),
                             squeeze=False)
    for ax, (cond, scen) in zip(axes[:, 0], groups):
        seen = set()
        for e in results["episodes"]:
            if (e["condition"], e.get("scenario", "single")) != (cond, scen) \
                    or e["modality"] in seen:
                continue
            seen.add(e["modality"])
            tr = np.array([np.nan if v is None else v for v in e.get(key, [])], float)
            ax.plot(np.arange(tr.size), tr, lw=1, label=f"{e['modality']} (seed {e['seed']})")
        title = cond if scen == "single" and results["task"] == "nav" else f"{cond}, {scen}"
        ax.set_title(f"{title}: {what}", fontsize=9)
        ax.set_xlabel("control tick")
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_latency(results: dict, path: Path) -> None:
    """Histogram of per-call inference latency per modality."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    fig, ax = plt.subplots(figsize=(6, 3.2))
    by_mod: dict[str, list] = {}
    for e in results["episodes"]:
        by_mod.setdefault(e["modality"], []).extend(e.get("inference_ms") or [])
    for mod, vals in by_mod.items():
        if vals:
            v = np.asarray(vals)
            ax.hist(v, bins=40, alpha=0.6,
                    label=f"{mod}: p50 {np.median(v):.2f} ms, p99 {np.percentile(v, 99):.2f}")
    ax.set_xlabel("inference latency per call (ms)")
    if by_mod and any(by_mod.values()):     # the expert and baseline rows infer nothing
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
