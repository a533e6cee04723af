"""The event sensor of `sebvs eval`'s event rows: the preset version its checkpoint was
trained on (the nested override, the topology's other emulator overrides kept), a user's
contradicting override refused, and what ran named in results.json and the report."""
import json
from pathlib import Path

import pytest

from sebvs.cli import main
from sebvs.eval.plan import EvalPlan, Run
from sebvs.eval.report import render_report
from sebvs.runtime.overrides import lookup
from sebvs.runtime.topology import load_topology

ROOT = Path(__file__).resolve().parents[1]


def checkpoints(tmp_path, emulator=None, modality="event") -> Path:
    ck = tmp_path / "ck"
    ck.mkdir(exist_ok=True)
    cfg = {"task": "nav", "modality": modality}
    if emulator is not None:
        cfg["emulator"] = emulator
    (ck / f"nav-{modality}.json").write_text(json.dumps(cfg))
    return ck


def plan_of(tmp_path, ck, extra=(), modalities=("rgb", "event")) -> EvalPlan:
    return EvalPlan(task="nav", modalities=list(modalities),
                    conditions=["nominal_physical", "hdr"], scenarios=["indoor"], episodes=1,
                    out=tmp_path / "out", checkpoints=str(ck), extra=list(extra))


def test_an_event_row_runs_the_version_its_checkpoint_was_trained_on(tmp_path):
    ck = checkpoints(tmp_path, {"preset": "physical", "preset_version": 2})
    plan = plan_of(tmp_path, ck)
    plan.validate()
    _, sets = plan.overrides(Run("hdr", "indoor", "event"))
    assert lookup(sets, "emulator", "overrides") == {"preset_version": 2}     # nested
    topo = load_topology(*plan.overrides(Run("hdr", "indoor", "event")))
    assert topo.actors["emulator"].params["overrides"] == {"downsample": 1.0,
                                                           "preset_version": 2}
    # the RGB row runs no event sensor at all
    _, sets = plan.overrides(Run("hdr", "indoor", "rgb"))
    assert lookup(sets, "emulator") is None
    assert plan.event_sensors() == [{"preset": "physical", "preset_version": 2,
                                     "conditions": ["nominal_physical", "hdr"]}]
    # a user's --set that replaces the whole table still runs the checkpoint's version
    plan = plan_of(tmp_path, ck, ["emulator.overrides={downsample=1.0}"])
    plan.validate()
    topo = load_topology(*plan.overrides(Run("hdr", "indoor", "event")))
    assert topo.actors["emulator"].params["overrides"] == {"downsample": 1.0,
                                                           "preset_version": 2}


def test_a_checkpoint_naming_no_version_runs_version_1_as_the_shipped_topologies_pin(tmp_path):
    ck = checkpoints(tmp_path)
    plan = plan_of(tmp_path, ck)
    _, sets = plan.overrides(Run("hdr", "indoor", "event"))
    assert lookup(sets, "emulator", "overrides", "preset_version") == 1
    pinned = load_topology(ROOT / "topologies" / "nav_policy.toml")
    topo = load_topology(*plan.overrides(Run("hdr", "indoor", "event")))
    assert topo.actors["emulator"].params == pinned.actors["emulator"].params
    # no readable config: the topology as written (the policy actor names the problem)
    plan = plan_of(tmp_path, tmp_path / "nothing-here")
    _, sets = plan.overrides(Run("hdr", "indoor", "event"))
    assert lookup(sets, "emulator", "overrides") is None


def test_a_user_override_that_contradicts_the_checkpoint_is_refused(tmp_path):
    ck = checkpoints(tmp_path, {"preset": "physical", "preset_version": 2})
    with pytest.raises(ValueError) as err:
        plan_of(tmp_path, ck, ["emulator.overrides.preset_version=1"]).validate()
    msg = str(err.value)
    assert msg.startswith("--set emulator.overrides.preset_version=1: ")
    assert str(ck / "nav-event.json") in msg and "preset_version 2" in msg
    assert len(msg.splitlines()) == 1
    with pytest.raises(ValueError, match=r"^override emulator.overrides.preset_version=1: "):
        plan_of(tmp_path, ck, [{"emulator": {"overrides": {"preset_version": 1}}}]).validate()
    # agreeing, or with no event row, it stands
    plan_of(tmp_path, ck, ["emulator.overrides.preset_version=2"]).validate()
    plan_of(tmp_path, ck, ["emulator.overrides.preset_version=1"],
            modalities=["rgb"]).validate()


def test_sebvs_eval_refuses_a_contradicting_version_in_one_line(tmp_path, capsys):
    # the shipped checkpoints name no version: they were trained on version 1
    code = main(["eval", "--task", "nav", "--modalities", "event", "--episodes", "1",
                 "--out", str(tmp_path / "eval"), "--set",
                 "emulator.overrides.preset_version=2"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1
    assert err.startswith("sebvs eval: --set emulator.overrides.preset_version=2: ")
    assert "nav-event.json" in err and not (tmp_path / "eval").exists()


def test_the_report_names_the_event_sensor_in_its_header():
    results = {"task": "nav", "clock": "lockstep", "split": "dev", "seed": 1000,
               "event_sensor": [{"preset": "physical", "preset_version": 1,
                                 "conditions": ["hdr"]}], "episodes": [], "runs": []}
    report = render_report(results)
    header = report.split("\n\n")[:3]
    assert "event sensor: emulator preset physical, version 1" in header
    assert "event_sensor" not in report           # not also among the generic fields
    two = {**results, "event_sensor": [{"preset": "physical", "preset_version": 1,
                                        "conditions": ["hdr"]},
                                       {"preset": "paper", "preset_version": 1,
                                        "conditions": ["nominal"]}]}
    assert ("event sensor: emulator preset physical, version 1 (hdr); preset paper, "
            "version 1 (nominal)") in render_report(two)
    # results written before the field: nothing said
    assert "event sensor" not in render_report({k: v for k, v in results.items()
                                                if k != "event_sensor"})
