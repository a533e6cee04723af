"""tools/bench/bench_sim.py on the physical pair (issue 64, item 6): the compute ceiling of
the shipped sensors through the camera's own code, side by side with the measured
recording rate and their ratio in one JSON, and every row naming its sensor. The recording
(a `sebvs record` subprocess) is stood in for where only the report's shape is tested."""
import json
import sys

import pytest

from tests.tools_loader import tool_module


def test_the_shipped_topologies_name_their_pair():
    with tool_module("bench/bench_sim") as bench:
        topologies = bench.ROOT / "topologies"
        assert bench.shipped_sensor(topologies / "nav_policy.toml") == "physical"
        assert bench.shipped_sensor(topologies / "nav_record.toml") == "physical"
        # nav_expert names none: the camera actor's default
        assert bench.shipped_sensor(topologies / "nav_expert.toml") == "ideal8"
        record = topologies / "nav_record.toml"
        assert bench.sensor_of([], None, record) == "physical"
        assert bench.sensor_of(['camera.sensor = "ideal8"'], None, record) == "ideal8"
        assert bench.sensor_of([], "ideal8", record) == "ideal8"


def test_the_physical_ceiling_runs_the_recordings_camera_and_inverts_its_cpu():
    with tool_module("bench/bench_sim") as bench:
        row = bench.bench_ceiling_physical(0.2, 200.0, 64, rgb_size=64, repeats=1)
    assert row["sensor"] == "physical"
    assert row["frames_per_run"] == {"luma": 40, "rgb": 2, "ideal": 2}
    stages = row["cpu_s_per_sim_s"]
    assert set(stages) == {"physics", "luma_render", "ideal_render", "frame_camera",
                           "emulator"}
    assert all(v > 0 for v in stages.values()), stages
    total = row["cpu_s_per_sim_s_total"]
    assert total == pytest.approx(sum(stages.values()), abs=1e-3)
    assert row["ceiling_x_on_2_cores"] == pytest.approx(2.0 / total, rel=0.01)
    assert row["events_per_run"][0] > 0


def test_ceiling_and_recording_side_by_side_in_one_json(monkeypatch, tmp_path, capsys):
    out = tmp_path / "sim.json"
    recorded = []
    with tool_module("bench/bench_sim") as bench:
        def record(episodes, seconds, dvs_hz=200.0, placement=None, sets=(), sensor=None):
            recorded.append((list(sets), sensor, dvs_hz))
            return {"sensor": sensor, "real_time_factor": 0.8}

        def ceiling(seconds, dvs_hz=200.0, luma_size=160, **k):
            return bench._ceiling_row("stand-in", k.get("sensor", "x"), [
                {"physics": 0.1, "luma_render": 0.3, "events": 1, "frames": {}}],
                ("physics", "luma_render"), seconds, 1)

        monkeypatch.setattr(bench, "bench_record", record)
        monkeypatch.setattr(bench, "bench_ceiling_physical",
                            lambda *a, **k: ceiling(*a, sensor="physical", **k))
        monkeypatch.setattr(bench, "bench_ceiling",
                            lambda *a, **k: {**ceiling(*a, **k), "sensor": "ideal8",
                                             "ceiling_x_on_2_cores": 8.0})
        monkeypatch.setattr(sys, "argv", ["bench_sim.py", "--ceiling-vs-record", "--quick",
                                          "--json", str(out)])
        assert bench.main() == 0
    row = json.loads(out.read_text())["ceiling_vs_record"]
    assert recorded == [(["sim.randomise={}"], "physical", 200.0)]
    assert row["sensor"] == row["ceiling"]["sensor"] == "physical"
    assert row["ceiling_ideal8"]["sensor"] == "ideal8"
    assert row["ceiling_x_on_2_cores"] == 5.0 and row["record_x_real_time"] == 0.8
    assert row["record_over_ceiling"] == pytest.approx(0.8 / 5.0)
    assert row["record_over_ideal8_ceiling"] == pytest.approx(0.8 / 8.0)
    assert "0.16 of it" in capsys.readouterr().out


def test_the_sensor_comparison_records_each_pair_it_names(monkeypatch):
    """nav_record ships the physical pair: the ideal8 run must ask for its own."""
    asked = []
    with tool_module("bench/bench_sim") as bench:
        monkeypatch.setattr(bench, "bench_record", lambda episodes, seconds, sets=(),
                            sensor=None: asked.append(sensor) or {"real_time_factor": 1.0})
        row = bench.bench_sensors(1, 1.0)
    assert asked == ["ideal8", "physical"] and row["physical_over_ideal8"] == 1.0


def test_frame_ready_measures_the_moved_exposure_against_the_noise():
    """(Where the tick's work went is tests/test_tick_path.py's: counted renders, not time.)"""
    with tool_module("bench/bench_sim") as bench:
        row = bench.bench_frame_ready(seconds=0.6, size=48)
    assert row["ticks"] == 6                     # 7 ticks, the first left out
    assert row["readout_ms"] == {"ahead": 10.0, "tick": 5.0}
    assert 0 < row["moved_dn_median"] < row["noise_dn_median"]
    assert row["counts"]["exposure_end_moved"] == row["counts"]["frames_ahead"] == 6
    for key in ("tick_ms_p50", "period_cpu_ms"):
        assert set(row[key]) == {"ahead", "tick"} and min(row[key].values()) > 0


def test_help_names_the_new_modes(capsys, monkeypatch):
    monkeypatch.setattr(sys, "argv", ["bench_sim.py", "--help"])
    with tool_module("bench/bench_sim") as bench, pytest.raises(SystemExit):
        bench.main()
    text = capsys.readouterr().out
    assert "--ceiling-vs-record" in text and "--frame-ready-only" in text
