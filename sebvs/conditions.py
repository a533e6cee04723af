"""The tasks' conditions and scenarios as data, and what a run of one sets in a topology.

    from sebvs.conditions import TASKS
    nav = TASKS["nav"]
    nav.condition("flicker_100").overrides()
    # {"sim": {"config": {"lighting": "flicker", "flicker_hz": 100.0}, "render_hz": 1000.0},
    #  "camera": {"dvs_hz": 1000.0, "sensor": "physical"}}
    nav.scenario("outdoor").overrides()      # {"sim": {"config": {"variant": "outdoor"}}}
    nav.names("ideal8")                      # the 8-bit benchmark's six

What `sebvs eval` evaluates under (sebvs/eval/plan.py), what `sebvs record --condition`
records under (sebvs/data/record.py) and what the Gymnasium environments run
(sebvs/envs/erp.py) is declared here once: per task, its conditions (the sensor pair, the
light, the motion, the blur, the rates a condition needs), its scenarios (nav's two scene
variants, the arm's one or three cubes) and its topologies. Each gives its topology
overrides as a nested mapping (sebvs/runtime/overrides.py). The conditions table of
docs/sim.md is `conditions_table()` (``python -m sebvs.conditions`` prints it;
tests/test_conditions.py holds the page to it).

The rest of the module is what the evaluator and the environments both derive from a
condition: the control rate as a variable (`control_rate_overrides`) and the event frames a
checkpoint was trained on (`event_frame_overrides`).
"""
from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path

from sebvs.runtime.overrides import lookup, merge
from sebvs.sensor_pairs import camera_override, check_sensor, emulator_override
from sebvs.shipped import shipped_dir

ROOT = Path(__file__).resolve().parents[1]
# the checkout's topologies/, or a wheel's copy of them (sebvs/shipped.py)
TOPOLOGIES = shipped_dir("topologies")
# mains lamps flicker at twice the supply frequency; rendered at 100 Hz a 100 Hz flicker
# aliases to a constant level and 120 Hz to a 20 Hz beat, so those conditions render at 1 kHz
MAINS_RENDER_HZ = 1000.0


@dataclass(frozen=True)
class Condition:
    """One condition of a task: what its runs set beyond the topology as written (None: the
    topology's own setting). The scene keys are the sim's config (sebvs/sim/nav.py and
    arm.py); `render_hz` is the render rate and the camera's luma rate it needs."""
    name: str
    sensor: str                        # the sensor pair: "physical" | "ideal8"
    lighting: str | None = None        # the scene's lights: "low", "flicker", "hdr", "dusk"
    flicker_hz: float | None = None    # with lighting "flicker"
    target_speed: str | None = None    # nav: the target's "slow" | "nominal" | "fast"
    conveyor: str | None = None        # arm: "static" | "moving"
    belt_speed: float | None = None    # arm: m/s, when moving
    rgb_blur: int | None = None        # renders averaged into each RGB frame
    render_hz: float | None = None     # sim.render_hz = camera.dvs_hz
    # further per-actor overrides, merged last (none of the shipped conditions has any)
    extra: Mapping = field(default_factory=dict, hash=False)
    note: str = ""                     # one line for the docs' table

    # the sim config keys, in the order a condition sets them
    SCENE_KEYS = ("lighting", "flicker_hz", "target_speed", "conveyor", "belt_speed",
                  "rgb_blur")

    def scene_config(self) -> dict:
        """The sim config keys the condition sets."""
        return {k: getattr(self, k) for k in self.SCENE_KEYS if getattr(self, k) is not None}

    def overrides(self) -> dict:
        """Its topology overrides: the scene's config, the rates, the camera's sensor (so
        that a condition runs the same whatever the topology's default sensor), then
        `extra`."""
        layers = []
        config = self.scene_config()
        if config:
            layers.append({"sim": {"config": config}})
        if self.render_hz is not None:
            layers.append({"sim": {"render_hz": float(self.render_hz)},
                           "camera": {"dvs_hz": float(self.render_hz)}})
        return merge(*layers, camera_override(self.sensor), self.extra)

    def event_sensor_overrides(self) -> dict:
        """The event sensor the condition asks for: under the physical pair the emulator's
        "physical" preset (the sensor's own physics on linear light, slow and noisy at
        dusk), under the 8-bit benchmark's the paper's."""
        return emulator_override(self.sensor)


@dataclass(frozen=True)
class Scenario:
    """One scene of a task: nav's variant (indoor, outdoor) or the arm's cube count."""
    name: str
    variant: str | None = None         # nav
    objects: int | None = None         # arm
    note: str = ""

    def overrides(self) -> dict:
        config = {k: getattr(self, k) for k in ("variant", "objects")
                  if getattr(self, k) is not None}
        return {"sim": {"config": config}}


@dataclass(frozen=True)
class Task:
    """A task's conditions (the 8-bit benchmark's first, then the physical pair's), its
    scenarios (the first is the default) and its topologies."""
    name: str
    condition_list: tuple[Condition, ...]
    scenario_list: tuple[Scenario, ...]
    policy_topology: Path
    expert_topology: Path
    record_topology: Path

    @property
    def conditions(self) -> dict[str, Condition]:
        """Every condition a run may name, by name."""
        return {c.name: c for c in self.condition_list}

    @property
    def scenarios(self) -> dict[str, Scenario]:
        return {s.name: s for s in self.scenario_list}

    @property
    def default_scenario(self) -> str:
        return self.scenario_list[0].name

    def names(self, sensor: str) -> list[str]:
        """The conditions of one sensor pair, in order."""
        check_sensor(sensor)
        return [c.name for c in self.condition_list if c.sensor == sensor]

    def condition(self, name: str) -> Condition:
        """The condition called `name`; ValueError (one line, the known ones listed)."""
        return self._named(self.conditions, "condition", name)

    def scenario(self, name: str) -> Scenario:
        """The scenario called `name`; ValueError (one line, the known ones listed)."""
        return self._named(self.scenarios, "scenario", name)

    def _named(self, table: dict, kind: str, name: str):
        found = table.get(name)
        if found is None:
            raise ValueError(f"unknown {kind} {name!r} for task {self.name} "
                             f"(one of {', '.join(table)})")
        return found

    def policy_sim(self) -> dict:
        """The policy topology's [actors.sim] table, as written in its file."""
        return tomllib.loads(self.policy_topology.read_text())["actors"]["sim"]


def _pair(sensor: str, *conditions: Condition) -> tuple[Condition, ...]:
    return tuple(c for c in conditions if c.sensor == sensor)


IDEAL8, PHYSICAL = "ideal8", "physical"
# The 8-bit benchmark's conditions (the paper's, and docs/results_history.md): light in the
# render's 8-bit terms, for the ideal 8-bit sensor pair. The physical conditions: light,
# flicker and motion as physical quantities (the scenes' photometry(), sebvs/sim/light.py;
# docs/sim.md, "Conditions in physical terms"), for cameras that model a sensor on physical
# light: the default sensor pair's (`--conditions all` with `--sensor physical`).
NAV = Task(
    "nav",
    (Condition("nominal", IDEAL8, note="the paper's nominal scene"),
     Condition("fast", IDEAL8, target_speed="fast", note="the target at 1 m/s"),
     Condition("low_light", IDEAL8, lighting="low", note="the lights dimmed to ~1/6"),
     Condition("flicker", IDEAL8, lighting="flicker", note="the lights flicker (10 Hz)"),
     Condition("blur", IDEAL8, rgb_blur=8, note="an 80 ms RGB exposure"),
     # the hardest pairing for a frame camera: fast motion under a flickering light
     Condition("fast_flicker", IDEAL8, target_speed="fast", lighting="flicker",
               note="fast motion under a flickering light"),
     Condition("nominal_physical", PHYSICAL,
               note="the office: 400 lux indoors, an overcast day outdoors"),
     Condition("hdr", PHYSICAL, lighting="hdr",
               note="backlit: windows (indoor) or the sky (outdoor), target in shade"),
     Condition("dusk", PHYSICAL, lighting="dusk", note="3 lux"),
     Condition("dusk_fast", PHYSICAL, lighting="dusk", target_speed="fast",
               note="3 lux, the target at 1 m/s"),
     Condition("flicker_100", PHYSICAL, lighting="flicker", flicker_hz=100.0,
               render_hz=MAINS_RENDER_HZ, note="50 Hz mains"),
     Condition("flicker_120", PHYSICAL, lighting="flicker", flicker_hz=120.0,
               render_hz=MAINS_RENDER_HZ, note="60 Hz mains"),
     Condition("fast_hdr", PHYSICAL, lighting="hdr", target_speed="fast",
               note="backlit, the target at 1 m/s")),
    # the shipped checkpoints were trained indoors only: outdoor asks whether a policy
    # transfers
    (Scenario("indoor", variant="indoor", note="the room"),
     Scenario("outdoor", variant="outdoor", note="open ground under the sky and sun")),
    TOPOLOGIES / "nav_policy.toml", TOPOLOGIES / "nav_expert.toml",
    TOPOLOGIES / "nav_record.toml")
ARM = Task(
    "arm",
    (Condition("nominal", IDEAL8, note="static conveyor"),
     Condition("moving", IDEAL8, conveyor="moving", note="the belt at 8 cm/s"),
     Condition("fast", IDEAL8, conveyor="moving", belt_speed=0.25,
               note="the belt at 25 cm/s"),
     Condition("low_light", IDEAL8, lighting="low", note="the lights dimmed to ~1/6"),
     Condition("flicker", IDEAL8, lighting="flicker", note="the lights flicker (10 Hz)"),
     Condition("blur", IDEAL8, conveyor="moving", rgb_blur=8,
               note="an 80 ms RGB exposure of the moving belt"),
     Condition("nominal_physical", PHYSICAL, note="500 lux, static"),
     Condition("fast_physical", PHYSICAL, conveyor="moving", belt_speed=0.25,
               note="the belt at 25 cm/s"),
     Condition("hdr", PHYSICAL, lighting="hdr", note="a lamp beside the belt"),
     Condition("dusk_moving", PHYSICAL, lighting="dusk", conveyor="moving", belt_speed=0.08,
               note="3 lux, the belt at 8 cm/s"),
     Condition("fast_hdr", PHYSICAL, lighting="hdr", conveyor="moving", belt_speed=0.25,
               note="the lamp, the belt at 25 cm/s")),
    # the arm's single- and multi-object (cluttered) scenes
    (Scenario("single", objects=1, note="one cube"),
     Scenario("multi", objects=3, note="three cubes (clutter)")),
    TOPOLOGIES / "arm_policy.toml", TOPOLOGIES / "arm_expert.toml",
    TOPOLOGIES / "arm_record.toml")
TASKS: dict[str, Task] = {"nav": NAV, "arm": ARM}


def task(name: str) -> Task:
    """The task called `name`; ValueError (one line) for another."""
    if name not in TASKS:
        raise ValueError(f"unknown task {name!r} (one of {', '.join(TASKS)})")
    return TASKS[name]


# ------------------------------------------------------- what a run of a condition derives
def control_rate_overrides(sim: Mapping, condition: Condition, control_hz: float,
                           events: bool) -> dict:
    """The control rate as a variable (`sebvs eval --control-hz`, the environments'
    control_hz): the sim's ticks, the tracker's, a render rate that is a whole multiple of
    the control rate (at least the one the topology or the condition asks for) and a
    physics rate that is a whole multiple of that (at least the topology's); with `events`,
    the event frames' window (one tick).

    Parameters:
        sim: the topology's [actors.sim] table as written (its rates).
        condition: the run's condition (its render rate, where it needs one).
        control_hz: ticks per second.
        events: whether the run's event frames follow the tick.

    Returns:
        The overrides.
    """
    hz = float(control_hz)
    render = float(lookup(condition.overrides(), "sim", "render_hz",
                          default=sim.get("render_hz", hz)))
    render = hz * max(1, math.ceil(render / hz - 1e-9))
    physics = 1.0 / sim["timestep"] if sim.get("timestep") else \
        float(sim.get("physics_hz", 1000.0))
    physics = render * max(1, math.ceil(physics / render - 1e-9))
    step = {"timestep": 1.0 / physics} if sim.get("timestep") else {"physics_hz": physics}
    sets = {"sim": {"control_hz": hz, "render_hz": render, **step},
            "camera": {"dvs_hz": render}, "tracker": {"control_hz": hz}}
    if events:
        sets["accumulator"] = {"window_s": 1.0 / hz}
    return sets


def checkpoint_event_frames(config: Mapping) -> dict | None:
    """A checkpoint config's "event_frames" (how its training data's event frames were
    made), or None where it names none a topology can make."""
    frames = config.get("event_frames")
    if not isinstance(frames, dict) or frames.get("representation") not in (
            "counts", "histogram", "time_surface"):
        return None
    return frames


def event_frame_overrides(frames: Mapping, sim_config: Mapping) -> dict:
    """The camera and accumulator made to give the event frames a checkpoint was trained
    on (representation, time bins, window, sensor size: its config's "event_frames").

    Parameters:
        frames: checkpoint_event_frames() of the config.
        sim_config: the topology's sim config (its image size).

    Returns:
        The overrides.
    """
    accumulator = {"representation": frames.get("representation"),
                   "bins": int(frames.get("bins") or 1)}
    if isinstance(frames.get("window_s"), (int, float)):
        accumulator["window_s"] = float(frames["window_s"])
    sets = {"accumulator": accumulator}
    sensor, output = frames.get("sensor"), frames.get("output")
    if sensor and output and list(output) == [sim_config.get("width"),
                                               sim_config.get("height")]:
        # the camera renders the emulator's luma at luma_scale x the RGB frame
        sets["camera"] = {"luma_scale": sensor[0] / output[0]}
    return sets


# ------------------------------------------------------------------------- the docs' table
def _cell(value) -> str:
    return "-" if value is None else str(value)


def conditions_table() -> str:
    """docs/sim.md's table of the conditions: what each sets beyond the topology."""
    extra = any(c.extra for t in TASKS.values() for c in t.condition_list)
    head = ["task", "condition", "sensor pair", "lighting", "flicker (Hz)", "motion",
            "RGB blur (renders)", "render = luma (Hz)", *(["further overrides"] if extra else []),
            "what it is"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for t in TASKS.values():
        for c in t.condition_list:
            motion = ", ".join(f"{k} {getattr(c, k)}" for k in ("target_speed", "conveyor",
                                                                "belt_speed")
                               if getattr(c, k) is not None)
            row = [t.name, c.name, c.sensor, _cell(c.lighting), _cell(c.flicker_hz),
                   motion or "-", _cell(c.rgb_blur), _cell(c.render_hz),
                   *([str(dict(c.extra)) if c.extra else "-"] if extra else []), c.note]
            lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines)


def scenarios_table() -> str:
    """docs/sim.md's table of the scenarios."""
    lines = ["| task | scenario | sim config | what it is |", "|---|---|---|---|"]
    for t in TASKS.values():
        for s in t.scenario_list:
            config = ", ".join(f"{k} = {v!r}".replace("'", '"')
                               for k, v in s.overrides()["sim"]["config"].items())
            default = " (default)" if s.name == t.default_scenario else ""
            lines.append(f"| {t.name} | {s.name}{default} | {config} | {s.note} |")
    return "\n".join(lines)


def _check_tasks() -> None:
    """Each task's names are unique and its conditions set only its scene's motion keys."""
    own = {"nav": {"target_speed"}, "arm": {"conveyor", "belt_speed"}}
    for t in TASKS.values():
        for kind, names in (("condition", [c.name for c in t.condition_list]),
                            ("scenario", [s.name for s in t.scenario_list])):
            if len(set(names)) != len(names):
                raise ValueError(f"sebvs.conditions: task {t.name} names a {kind} twice")
        motion = {f.name for f in fields(Condition)} & {"target_speed", "conveyor",
                                                         "belt_speed"}
        for c in t.condition_list:
            check_sensor(c.sensor)
            wrong = {k for k in motion - own[t.name] if getattr(c, k) is not None}
            if wrong:
                raise ValueError(f"sebvs.conditions: {t.name} condition {c.name!r} sets "
                                 f"{', '.join(sorted(wrong))}, another scene's key")


_check_tasks()

if __name__ == "__main__":
    print(conditions_table())
    print()
    print(scenarios_table())
