"""The conditions and scenarios as data (sebvs/conditions.py): the docs' tables are the
module's, every reader runs the same overrides, and `sebvs record --condition` records one."""
import json
import re
from argparse import Namespace
from pathlib import Path

import pytest

from sebvs.conditions import TASKS, conditions_table, scenarios_table
from sebvs.runtime.overrides import leaves, lookup
from sebvs.runtime.topology import load_topology

ROOT = Path(__file__).resolve().parents[1]
SIM_MD = ROOT / "docs" / "sim.md"
BEGIN, END = "<!-- conditions: generated from sebvs/conditions.py -->", \
    "<!-- end of the generated conditions -->"


def test_the_docs_tables_are_the_modules():
    text = SIM_MD.read_text()
    assert BEGIN in text and END in text, f"{SIM_MD}: the generated block's markers"
    block = text.split(BEGIN, 1)[1].split(END, 1)[0].strip()
    assert block == f"{conditions_table()}\n\n{scenarios_table()}", (
        f"{SIM_MD}'s conditions tables differ from sebvs/conditions.py: paste the output "
        f"of `python -m sebvs.conditions` between its markers")
    # the physical units' table below it names the same conditions, in the same order
    named = re.findall(r"^\| (nav|arm) \| (\w+)(?: \(physical\))? \| \d", text, re.M)
    assert named == [(t, c) for t in TASKS for c in TASKS[t].conditions]


def test_a_condition_is_its_fields():
    nav = TASKS["nav"]
    assert nav.condition("flicker_100").overrides() == {
        "sim": {"config": {"lighting": "flicker", "flicker_hz": 100.0}, "render_hz": 1000.0},
        "camera": {"dvs_hz": 1000.0, "sensor": "physical"}}
    assert nav.condition("nominal").overrides() == {"camera": {"sensor": "ideal8"}}
    assert nav.condition("nominal").event_sensor_overrides() == {"emulator": {"preset": "paper"}}
    assert TASKS["arm"].condition("dusk_moving").scene_config() == {
        "lighting": "dusk", "conveyor": "moving", "belt_speed": 0.08}
    assert TASKS["arm"].scenario("multi").overrides() == {"sim": {"config": {"objects": 3}}}
    assert [t.default_scenario for t in TASKS.values()] == ["indoor", "single"]
    with pytest.raises(ValueError, match=r"unknown condition 'dawn' for task nav \(one of "
                                         r"nominal, fast, "):
        nav.condition("dawn")
    with pytest.raises(ValueError, match="unknown scenario 'multi' for task nav"):
        nav.scenario("multi")
    hdr = nav.condition("hdr")
    with pytest.raises(Exception):
        hdr.lighting = "dusk"           # frozen: one registry, read by every reader


def test_the_evaluation_and_the_environment_run_the_same_condition(tmp_path):
    """env_settings and `sebvs eval`'s event row of a condition load the same sim, camera
    and emulator parameters (the environment's seeds and rates are the evaluation's)."""
    from sebvs.envs.erp import env_settings
    from sebvs.eval.plan import EvalPlan, Run
    for task, condition, scenario in (("nav", "flicker_100", "outdoor"),
                                      ("arm", "fast_hdr", "multi"), ("nav", "blur", "indoor")):
        plan = EvalPlan(task=task, modalities=["rgb+event"], conditions=[condition],
                        scenarios=[scenario], episodes=1, out=tmp_path,
                        checkpoints=str(tmp_path / "none"), control_hz=20.0)
        topo = load_topology(*plan.overrides(Run(condition, scenario, "rgb+event")))
        env = env_settings(task, condition, scenario, control_hz=20.0)["topology"]
        for actor in ("camera", "emulator", "accumulator"):
            assert env.actors[actor].params == topo.actors[actor].params, (task, actor)
        sim, env_sim = topo.actors["sim"].params, env.actors["sim"].params
        for key in ("config", "render_hz", "control_hz", "physics_hz", "scene"):
            assert env_sim.get(key) == sim.get(key), (task, key)


def test_record_refuses_an_unknown_condition_naming_the_known_ones(tmp_path, capsys):
    from sebvs.cli import main
    code = main(["record", "topologies/nav_record.toml", "--episodes", "1", "--out",
                 str(tmp_path / "ds"), "--condition", "dawn"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1
    assert "unknown condition 'dawn' for task nav (one of nominal, fast" in err
    assert "fast_hdr)" in err
    assert main(["record", "topologies/arm_record.toml", "--episodes", "1", "--out",
                 str(tmp_path / "ds"), "--condition", "hdr", "--scenario", "outdoor"]) == 2
    assert "unknown scenario 'outdoor' for task arm (one of single, multi)" in \
        capsys.readouterr().err
    assert main(["record", "topologies/arm_record.toml", "--episodes", "1", "--out",
                 str(tmp_path / "ds"), "--scenario", "multi"]) == 2
    assert "--scenario needs --condition" in capsys.readouterr().err
    assert main(["record", "topologies/arm_record.toml", "--episodes", "1", "--out",
                 str(tmp_path / "ds"), "--condition", "hdr", "--sensor", "ideal8"]) == 2
    assert "condition 'hdr' is the physical sensor pair's" in capsys.readouterr().err
    assert not (tmp_path / "ds").exists()


def test_a_condition_replaces_the_recordings_randomised_mix():
    from sebvs.data.record import requested_overrides
    args = Namespace(topology=str(ROOT / "topologies" / "nav_record.toml"), sensor=None,
                     condition="flicker_120", scenario="outdoor",
                     set=["sim.episode_s=2.0"])
    given = requested_overrides(args)
    assert given[-1] == "sim.episode_s=2.0"         # the user's line last, as typed
    json.dumps(given)                               # the episodes' provenance: plain JSON
    topo = load_topology(args.topology, given)
    sim = topo.actors["sim"].params
    assert sim["randomise"] == {}
    assert {k: sim["config"][k] for k in ("lighting", "flicker_hz", "variant")} == {
        "lighting": "flicker", "flicker_hz": 120.0, "variant": "outdoor"}
    assert sim["render_hz"] == topo.actors["camera"].params["dvs_hz"] == 1000.0
    assert topo.actors["emulator"].params["preset"] == "physical"
    # the topology's emulator pin stays: the condition sets the preset, not its overrides
    assert topo.actors["emulator"].params["overrides"] == {"downsample": 1.0,
                                                           "preset_version": 1}


def test_sebvs_record_condition_records_that_condition(tmp_path):
    """One short episode under a named condition and scenario: its scene is the
    condition's, and the episode's topology attribute says what was asked for."""
    from sebvs.cli import main
    from sebvs.data.episode import open_episode
    from sebvs.data.index import DatasetIndex
    out = tmp_path / "ds"
    assert main(["record", "topologies/arm_record.toml", "--episodes", "1", "--out", str(out),
                 "--runs-dir", str(tmp_path / "runs"), "--quiet", "--condition",
                 "fast_physical", "--scenario", "multi", "--set", "sim.episode_s=0.5"]) == 0
    with open_episode(DatasetIndex(out).episode_paths()[0]) as ep:
        stored, named = ep.attrs["topology"], ep.attrs.get("condition")
    assert named == "fast_physical"     # what `sebvs data` groups its episodes by
    sim = stored["content"]["actors"]["sim"]
    assert sim["randomise"] == {} and sim["episode_s"] == 0.5
    assert {k: sim["config"][k] for k in ("conveyor", "belt_speed", "objects")} == {
        "conveyor": "moving", "belt_speed": 0.25, "objects": 3}
    assert stored["overrides"][-1] == "sim.episode_s=0.5"
    assert lookup(stored["overrides"][0], "camera", "sensor") == "physical"


def test_every_condition_sets_only_keys_its_scene_and_topologies_know():
    for task in TASKS.values():
        for condition in task.conditions.values():
            for topology in (task.policy_topology, task.expert_topology, task.record_topology):
                load_topology(topology, [condition.overrides()])     # the sim accepts it
            for path, _ in leaves(condition.overrides()):
                assert path[0] in ("sim", "camera"), (task.name, condition.name, path)
