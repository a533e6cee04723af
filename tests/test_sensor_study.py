"""tools/studies/sensor_study.py builds the plan's steps (docs/study_sensors_plan.md) and
resumes where a stop left them."""
import json

import pytest

from tests.tools_loader import tool_module


def test_the_steps_are_the_plans():
    with tool_module("studies/sensor_study") as study:
        steps = study.plan_steps(study.ROOT / "out" / "x", 2, None)
        kinds = [s.kind for s in steps]
        assert [kinds.count(k) for k in ("record", "train", "eval", "read")] == [4, 36, 18, 4]
        record = " ".join(steps[0].argv)
        for part in ("topologies/nav_record.toml", "--episodes 120", "topology.seed=20",
                     'camera.sensor="physical"', 'emulator.preset="physical"',
                     "sim.episode_s=20.0"):
            assert part in record, part
        evals = [" ".join(s.argv) for s in steps if s.kind == "eval"]
        assert all("--split test" in e and "--episodes 20" in e for e in evals)
        assert sum("--seed 100100" in e for e in evals) == 12      # nav: 2 rates x 3 x 2
        assert all("--control-hz 30" in e for e in evals if "nav30" in e or "arm30" in e)
        # the expert and no-action rows once per task and rate: with training seed 0
        assert sum("--no-expert" not in e for e in evals) == 6
        reads = [" ".join(s.argv) for s in steps if s.kind == "read"]
        assert all("--a rgb+event --b rgb+diff --min-diff 10 --min-ahead 3" in r
                   for r in reads)
        assert "--metric strict_success" in reads[0]


def test_a_recording_resumes_with_the_episodes_missing(tmp_path, monkeypatch):
    with tool_module("studies/sensor_study") as study:
        monkeypatch.setattr(study, "dataset_dir", lambda task, rate: tmp_path / f"{task}{rate}")
        step = study.plan_steps(tmp_path, 2, {"nav10"})[0]
        assert not study.is_done(step)
        (tmp_path / "nav10").mkdir()
        index = tmp_path / "nav10" / "index.json"

        def holding(numbers):
            index.write_text(json.dumps(
                {"episodes": [{"file": f"episode_{k:04d}.h5"} for k in numbers]}))
        holding(range(30))                       # 0..29: extended by the 90 missing
        argv = study.command_of(step)
        assert argv[argv.index("--episodes") + 1] == "90"
        holding([*range(10), *range(60, 75)])    # an interrupted fan-out's gaps: refused
        with pytest.raises(study.GappedDataset, match="25 episodes with gaps \\(first "
                                                      "missing: 10\\).*resume at 75"):
            study.command_of(step)
        holding(range(120))
        assert study.is_done(step)
