"""What `sebvs eval` runs: the plan (`EvalPlan`), its runs (`Run`) and each run's overrides.

    plan = EvalPlan(task="nav", modalities=["rgb", "event"], conditions=["hdr"],
                    episodes=10, out=Path("out/eval"))
    plan.validate()
    for run in plan.runs():              # expert, no_action, rgb, event per condition/scenario
        topology, overrides = plan.overrides(run)   # a file and a nested mapping
        load_topology(topology, overrides)

For each condition, scenario and modality (plus the expert as the reference row and the
no-action baseline, actors/baseline.py, as the floor) one run of the policy topology plays
N seeded episodes: the same topology seed gives every modality, the expert and the
baseline the same episode seeds and so the same target trajectories. The topology seed
is the first of a split's range (sebvs/data/splits.py: dev by default, test held out from
every recording) or an explicit one ("custom"). The conditions and scenarios are
sebvs/conditions.py's; the runner (sebvs/eval/run.py) plays the runs.

Videos (`video`): the overrides add a video writer (actors/video.py) to the run, writing
<out>/videos/<condition>[__<scenario>]__<modality>__ep<k>.mp4 for the first `video_episodes`
episodes, with the event frames wired to it for the modalities that use them, and the sim
lingers past the writer's wait for an episode's trailing frames. Without `video` no such
actor starts and nothing else changes.

The event sensor: an event row runs the emulator preset its condition asks for (the
sensor pair's), at the preset version its checkpoint's config names ("emulator":
{"preset_version"}; absent: 1, the version every checkpoint before it was trained on),
set as the nested `emulator.overrides.preset_version` so the topology's other emulator
overrides stay; a user's override that contradicts it is refused. `event_sensors()` says
what the runs used, for results.json and the report's header.
"""
from __future__ import annotations

import json
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

from ..conditions import (TASKS, checkpoint_event_frames, control_rate_overrides,
                          event_frame_overrides, task)
from ..data.splits import DEFAULT_EVAL_SPLIT, EVAL_SPLITS, SPLITS, SeedRange
from ..policy.checkpoint import checkpoint_paths, read_config
from ..policy.inputs import CONTROL_MODALITIES, MODALITY_INPUTS
from ..policy.inputs import MODALITIES as PAPER_MODALITIES
from ..runtime.overrides import Overrides, as_mapping, layers, lookup, merge, replace
from ..runtime.topology import check_seed

# the learned rows: the paper's three, and the rgb+diff control when asked for by name
MODALITIES = PAPER_MODALITIES + CONTROL_MODALITIES
BASELINE = "no_action"
VIDEO_FINALIZE_S = 1.0         # the video writer's wait for an episode's trailing frames
VIDEO_DRAIN_MARGIN_S = 0.5     # the sim's linger beyond that wait
SHARED_SIM_KEYS = ("integrator", "physics_hz", "timestep", "control_hz", "render_hz",
                   "episode_s")
# the emulator preset version a checkpoint config that names none was trained on
DEFAULT_PRESET_VERSION = 1


def condition_sensor(task_name: str, condition: str) -> str:
    """The sensor pair a condition is defined for: "physical" or "ideal8"."""
    return task(task_name).condition(condition).sensor


def uses_events(modality: str) -> bool:
    """Whether a row's policy reads event frames (its run keeps the event chain)."""
    return "events" in MODALITY_INPUTS.get(modality, ())


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
    # overrides for every run: a mapping, or layers (mappings, or --set lines as typed:
    # results.json keeps what was given)
    extra: Overrides = field(default_factory=list)
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

    @property
    def extra_overrides(self) -> dict:
        """`extra` as one mapping."""
        return as_mapping(self.extra)

    def extra_given(self) -> list | dict:
        """`extra` as given, for results.json: the --set lines as typed, or the mapping."""
        return dict(self.extra) if isinstance(self.extra, Mapping) else list(self.extra)

    def validate(self) -> None:
        if self.task not in TASKS:
            raise ValueError(f"unknown task {self.task!r} (one of {', '.join(TASKS)})")
        spec = TASKS[self.task]
        unknown = [m for m in self.modalities if m not in MODALITIES]
        if unknown:
            raise ValueError(f"unknown modality {unknown[0]!r} (one of {', '.join(MODALITIES)})")
        for kind, given, known in (("condition", self.conditions, spec.conditions),
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
        for keys, how in fixed.items():
            where = _setting(self.extra, keys)
            if where is not None:
                raise ValueError(f"{where}: the evaluation sets {'.'.join(keys)} itself "
                                 f"(use {how})")
        self._check_preset_versions()
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

    def _check_preset_versions(self) -> None:
        """A user's emulator preset version against the one an event row's checkpoint was
        trained on: refused where they differ, as the row would measure another sensor."""
        keys = ("emulator", "overrides", "preset_version")
        where = _setting(self.extra, keys)
        if where is None:
            return
        given = lookup(self.extra_overrides, *keys)
        for m in self.modalities:
            version = self.checkpoint_preset_version(m) if uses_events(m) else None
            if version is not None and given != version:
                _, config = checkpoint_paths(self.checkpoints, self.task, m)
                raise ValueError(f"{where}: {config} was trained on the emulator's "
                                 f"preset_version {version}, the version its event row "
                                 f"runs; evaluate a checkpoint trained on {given!r} instead")

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

    def video_overrides(self, run: Run) -> dict:
        if not self.video:
            return {}
        # one frame per control tick: at the control rate the video plays in sim time
        hz = lookup(self.extra_overrides, "sim", "control_hz",
                    default=self.policy_sim().get("control_hz"))
        inputs = {"rgb": {"from": "camera/rgb", "queue": 256}, "episode": "sim/episode"}
        if uses_events(run.modality):
            inputs["events"] = {"from": "accumulator/frames", "queue": 256}
        video = {"run": "actors.video:VideoWriter", "inputs": inputs,
                 "directory": str(self.out / "videos"), "prefix": run.key,
                 "episodes": min(self.video_episodes, self.episodes), "label": run.modality}
        if isinstance(hz, (int, float)) and hz > 0:
            video["fps"] = float(hz)
        # The run stops when the sim's linger ends, dropping what is still queued on the
        # writer's inputs; the writer waits VIDEO_FINALIZE_S for an episode's trailing
        # frames, so the sim lingers longer than that (a --set sim.linger_s still wins)
        video["finalize_after_s"] = VIDEO_FINALIZE_S
        return {"video": video, "sim": {"linger_s": VIDEO_FINALIZE_S + VIDEO_DRAIN_MARGIN_S}}

    def rate_overrides(self, run: Run) -> dict:
        """The control rate as a variable (sebvs.conditions.control_rate_overrides): the
        sim's ticks, the tracker's, the event frames' window (one tick; overrides() puts
        a checkpoint's own after it), a render rate that is a whole multiple of the control
        rate and a physics rate that is a whole multiple of that."""
        if self.control_hz is None:
            return {}
        return control_rate_overrides(self.policy_sim(),
                                      task(self.task).condition(run.condition),
                                      self.control_hz, uses_events(run.modality))

    def shared_sim(self) -> dict:
        """The policy topology's physics and rates, imposed on the expert's run.

        The expert row is a reference only if the robot, the clock and the camera's
        sampling (which sets the blur exposure) are the same as the policies'.
        """
        sim = self.policy_sim()
        return {"sim": {k: sim[k] for k in SHARED_SIM_KEYS if k in sim}}

    def policy_sim(self) -> dict:
        """The policy topology's [actors.sim] table, as written in its file."""
        return tomllib.loads(self.policy_topology.read_text())["actors"]["sim"]

    def overrides(self, run: Run) -> tuple[Path, dict]:
        """The topology file of a run and its overrides, in the order they apply: the
        run's own (seed, clock, episodes, where its tracker writes), the condition and the
        scenario (and the video writer), the row's (the expert's shared physics, the
        baseline, the policy), the control rate, the event frames and sensor, `extra`,
        and last the preset version an event row's checkpoint was trained on."""
        spec = task(self.task)
        condition = spec.condition(run.condition)
        run_sets = {"topology": {"seed": self.seed, "clock": self.clock},
                    "sim": {"episodes": self.episodes},
                    "tracker": {"path": str(self.episode_file(run)),
                                "label": replace({"condition": run.condition,
                                                  "modality": run.modality,
                                                  "topology_seed": self.seed})}}
        scene = merge(condition.overrides(), spec.scenario(run.scenario).overrides(),
                      self.video_overrides(run))
        rate, extra = self.rate_overrides(run), self.extra_overrides
        if run.modality == "expert":
            # the policies' rates first: a condition that sets its own (the mains flicker's
            # render_hz) sets them for the expert too
            return self.expert_topology, merge(run_sets, self.shared_sim(), scene, rate,
                                               extra)
        if run.modality == BASELINE:
            # the policy topology with the baseline answering each tick instead: the policy,
            # emulator and accumulator then feed nobody and are pruned
            baseline = {"baseline": {"run": "actors.baseline:NoAction", "task": self.task,
                                     "inputs": {"rgb": {"from": "camera/rgb", "queue": 64}}},
                        "sim": {"inputs": {"action": "baseline/action"}},
                        "tracker": {"inputs": {"action": replace(
                            {"from": "baseline/action", "queue": 256})}}}
            return self.policy_topology, merge(run_sets, scene, baseline, rate, extra)
        policy = {"policy": {"modality": run.modality, "directory": self.checkpoints,
                             "modalities": [run.modality]}}
        events, version = {}, {}
        if not uses_events(run.modality):   # no events wired: the event chain is pruned
            policy["policy"]["inputs"] = replace({"rgb": "camera/rgb"})
        else:   # after the rate's: a window the checkpoint learned from wins over one tick
            events = merge(self.event_frame_overrides(run.modality),
                           condition.event_sensor_overrides())
            trained = self.checkpoint_preset_version(run.modality)
            if trained is not None:     # nested: the topology's other emulator overrides stay
                version = {"emulator": {"overrides": {"preset_version": trained}}}
        return self.policy_topology, merge(run_sets, scene, policy, rate, events, extra,
                                           version)

    def checkpoint_config(self, modality: str) -> dict | None:
        """The config beside a modality's checkpoint, or None where it cannot be read (the
        policy actor then names what is wrong with the checkpoint)."""
        pt, _ = checkpoint_paths(self.checkpoints, self.task, modality)
        try:
            return read_config(pt)
        except (OSError, ValueError):
            return None

    def checkpoint_preset_version(self, modality: str) -> int | None:
        """The emulator preset version the checkpoint's training data was recorded with
        (its config's "emulator"; absent: 1), or None where the config cannot be read."""
        config = self.checkpoint_config(modality)
        if config is None:
            return None
        emulator = config.get("emulator")
        return (emulator if isinstance(emulator, dict) else {}).get(
            "preset_version", DEFAULT_PRESET_VERSION)

    def event_frames(self, modality: str) -> dict | None:
        """The checkpoint config's "event_frames" (how its training data's event frames
        were made), or None where it has none or cannot be read."""
        config = self.checkpoint_config(modality)
        return None if config is None else checkpoint_event_frames(config)

    def event_frame_notes(self) -> list[str]:
        """One line per event modality whose checkpoint exists but does not say how its
        event frames were made (trained before checkpoints kept it): its events then
        come from the topology as written, which may be another sensor than it learned
        from (the nav topologies' went from 80 to 160 px on 2026-11-25)."""
        notes = []
        for m in self.modalities:
            _, config = checkpoint_paths(self.checkpoints, self.task, m)
            if uses_events(m) and config.exists() and self.event_frames(m) is None:
                notes.append(f"{config} does not say which event frames it was trained on; "
                             f"they are made as {self.policy_topology.name} says (to match "
                             f"an older checkpoint: --set camera.luma_scale=0.5 for the "
                             f"80 px sensor)")
        return notes

    def event_frame_overrides(self, modality: str) -> dict:
        """The camera and accumulator made to give the event frames the checkpoint was
        trained on (sebvs.conditions.event_frame_overrides). A checkpoint without them gets
        the topology as written; a --set of the user's comes later and wins."""
        frames = self.event_frames(modality)
        if frames is None:
            return {}
        return event_frame_overrides(frames, self.policy_sim().get("config", {}))

    def event_sensors(self) -> list[dict]:
        """The event sensors the event rows ran, as their topologies say after every
        override: [{"preset", "preset_version", "conditions"}], one per distinct sensor
        ([] when no row reads events)."""
        from ..dvs.params import preset
        from ..runtime.topology import load_topology
        found: dict[tuple, list[str]] = {}
        for run in self.runs():
            if not uses_events(run.modality):
                continue
            topo = load_topology(*self.overrides(run))
            emulator = next((a for a in topo.active.values()
                             if a.run.endswith(":Emulator")), None)
            if emulator is None:
                continue
            name = emulator.params.get("preset", "paper")
            try:
                version = preset(name, **emulator.params.get("overrides", {})).preset_version
            except (TypeError, ValueError):     # refused by the emulator too, with its message
                version = None
            conditions = found.setdefault((name, version), [])
            if run.condition not in conditions:
                conditions.append(run.condition)
        return [{"preset": name, "preset_version": version, "conditions": conditions}
                for (name, version), conditions in found.items()]


def _setting(overrides: Overrides, keys: tuple) -> str | None:
    """Where an `extra` sets a key path, for a message: "--set LINE" (the last line that
    sets it) or "override a.b.c=value"; None where it is not set."""
    where = None
    for mapping, line in layers(overrides):
        value = lookup(mapping, *keys)
        if value is not None:
            where = f"--set {line}" if line is not None else \
                f"override {'.'.join(keys)}={json.dumps(value)}"
    return where
