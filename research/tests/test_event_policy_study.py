"""research/event_policies/study.py: steps 2-4 of docs/plan_event_policies.md as the
plan writes them, on the sensor study's driver."""
import pytest

from research.event_policies import study
from research.sensors import sensor_study as driver


@pytest.fixture(autouse=True)
def no_real_datasets(tmp_path, monkeypatch):
    monkeypatch.setenv("SEBVS_STUDY_DATASETS", str(tmp_path / "study-datasets"))


def steps_of(chosen, out, monkeypatch):
    monkeypatch.setattr(driver, "PLAN", study.event_policy_plan(chosen))
    return driver.plan_steps(out, 2, None)


def test_the_steps_are_the_plans(tmp_path, monkeypatch):
    steps = steps_of("R3", tmp_path, monkeypatch)
    kinds = [s.kind for s in steps]
    # nav and arm; 3 seeds of Event, RGB+Event, RGB+Diff and RGB's seed 0 per task; nav's
    # two evaluation groups and the arm's one per training seed; one reading per task
    assert [kinds.count(k) for k in ("record", "train", "eval", "read")] == [2, 20, 9, 2]
    nav, arm = (" ".join(s.argv) for s in steps if s.kind == "record")
    for part in ("topologies/nav_record.toml", "--episodes 120", "topology.seed=40",
                 "sim.episode_s=20.0", "--hard-share 0.5",
                 "--hard-conditions hdr,dusk_fast,flicker_120", "preset_version=2",
                 'accumulator.representation="time_surface"', "accumulator.window_s=0.3"):
        assert part in nav, part
    for part in ("topologies/arm_record.toml", "--episodes 1500", "topology.seed=42",
                 "--hard-conditions hdr,dusk_moving,fast_physical", "preset_version=2"):
        assert part in arm, part
    assert "time_surface" not in arm          # the arm trains R0's recipe: counts
    assert all(str(s.done).startswith(str(tmp_path / "study-datasets" / "evtest_"))
               for s in steps if s.kind == "record")
    trains = {(s.task, s.argv[s.argv.index("--modality") + 1],
               int(s.argv[s.argv.index("--seed") + 1])): " ".join(s.argv)
              for s in steps if s.kind == "train"}
    assert ("nav", "rgb", 0) in trains and ("nav", "rgb", 1) not in trains
    assert all("--memory gru" in a and "--aux-weight 0.5" in a
               for (task, _, _), a in trains.items() if task == "nav")
    assert all(("--modality-dropout 0.25" in a) == (m in ("rgb+event", "rgb+diff"))
               for (task, m, _), a in trains.items() if task == "nav")
    assert not any("--memory" in a or "--modality-dropout" in a
                   for (task, _, _), a in trains.items() if task == "arm")
    evals = [" ".join(s.argv) for s in steps if s.kind == "eval"]
    assert all("--split test" in e and "--episodes 20" in e for e in evals)
    assert sum("--seed 100500" in e for e in evals) == 6
    assert sum("--seed 100600" in e for e in evals) == 3
    assert all("--scenarios indoor " in e for e in evals if "flicker_120" in e)
    assert sum("--no-expert" not in e for e in evals) == 3     # seed 0's, per group
    reads = [" ".join(s.argv) for s in steps if s.kind == "read"]
    assert all("--a rgb+event --b rgb+diff --min-diff 10 --min-ahead 3" in r for r in reads)


def test_a_recipe_without_memory_adds_no_dropout(tmp_path, monkeypatch):
    steps = steps_of("R0", tmp_path, monkeypatch)
    assert not any("--modality-dropout" in " ".join(s.argv) or "time_surface" in
                   " ".join(s.argv) for s in steps)


def test_it_runs_only_a_recipe_step_1_chose_and_it_can_drive(monkeypatch, capsys):
    with pytest.raises(study.NotChosen, match="DAgger rounds"):
        study.event_policy_plan("R4")
    with pytest.raises(study.NotChosen, match="not a step-1 candidate"):
        study.event_policy_plan("R9")
    monkeypatch.setattr(study, "CHOSEN", None)
    assert study.main(["plan"]) == 2
    err = capsys.readouterr().err.strip()
    assert "has not chosen its recipe" in err and "\n" not in err


def test_the_chosen_recipe_is_step_1s(tmp_path):
    """CHOSEN stays unset until step 1's table is complete, and then says what it chose."""
    assert study.CHOSEN in (None, study.selection_chosen())
    table = tmp_path / "selection.json"
    table.write_text('{"chosen": "R3", "complete": false}')
    assert study.selection_chosen(table) is None
    table.write_text('{"chosen": "R3", "complete": true}')
    assert study.selection_chosen(table) == "R3"
