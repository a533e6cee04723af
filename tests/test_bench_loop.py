"""tools/bench/bench_loop.py measures what ships (issue 64, item 6): the shipped topologies'
sensor pair by default, run as shipped, every row of its output naming its sensor; the
8-bit pair one option away. The topologies themselves are stood in for here: each part's
function is replaced by one that records what it was asked to run."""
import json
import sys

import pytest

from sebvs.sensor_pairs import topology_overrides
from tests.tools_loader import tool_module


def run_bench(monkeypatch, tmp_path, *argv) -> tuple[dict, dict]:
    """bench_loop's main with its parts stood in for: (its JSON, what each part got)."""
    asked = {"loop": [], "pipeline": [], "record": []}
    out = tmp_path / "loop.json"
    with tool_module("bench/bench_loop") as bench:
        def loop(seconds, warmup_s, extra=()):
            asked["loop"].append(list(extra))
            return {"chain": "sim > camera > policy > sim", "paths": {}, "chain_p50_ms": 5.0,
                    "chain_p99_ms": 9.0, "compute_p50_ms": 4.0, "chain_over_compute": 1.2,
                    "deadline": {"misses": 0}, "all": {"late_in_warmup": 0},
                    "sim_deadlines": None, "per_hop": [], "components": {}}

        def pipeline(seconds, dvs_hz, sensor="ideal8"):
            asked["pipeline"].append(sensor)
            return {"sensor": sensor, "real_time_factor": 3.0}

        def record(episodes, seconds, dvs_hz, sets=(), sensor=None):
            asked["record"].append(sensor)
            return {"sensor": bench.sensor_of(sets, sensor, bench.ROOT / "topologies"
                                              / "nav_record.toml"), "real_time_factor": 1.0}

        monkeypatch.setattr(bench, "bench_closed_loop", loop)
        monkeypatch.setattr(bench, "bench_pipeline", pipeline)
        monkeypatch.setattr(bench, "bench_record", record)
        monkeypatch.setattr(sys, "argv", ["bench_loop.py", "--quick", "--json", str(out),
                                          *argv])
        assert bench.main() == 0
    return json.loads(out.read_text()), asked


def rows_without_sensor(report: dict) -> list[str]:
    """The rows (each part's summary and each of its repeats) that name no sensor."""
    missing = []
    for key, part in report.items():
        if key.startswith("loop_") or key in ("pipeline", "record"):
            for i, row in enumerate([part, *part["repeats"]]):
                if "sensor" not in row:
                    missing.append(f"{key}[{i}]")
    return missing


def test_the_shipped_pair_runs_by_default_as_shipped(monkeypatch, tmp_path, capsys):
    report, asked = run_bench(monkeypatch, tmp_path)
    assert report["config"]["sensor"] == "physical"
    # the topology as it ships: no sensor override, only each variant's own settings
    for sets in asked["loop"]:
        assert topology_overrides("physical") not in sets
        assert not any(isinstance(s, dict) for s in sets), sets
    assert asked["pipeline"] == ["physical"] and asked["record"] == [None]
    assert {k for k in report if k.startswith("loop_")} == {"loop_plain", "loop_realtime",
                                                            "loop_shipped"}
    assert rows_without_sensor(report) == []
    assert {report[k]["sensor"] for k in ("loop_shipped", "pipeline", "record")} == \
        {"physical"}
    assert all(t["sensor"] == "physical" for t in report["targets"].values())


def test_the_ideal8_row_is_one_option_away(monkeypatch, tmp_path, capsys):
    report, asked = run_bench(monkeypatch, tmp_path, "--sensor", "ideal8", "--variant",
                              "shipped", "--loop-only")
    assert report["config"]["sensor"] == "ideal8"
    assert asked["loop"] == [[topology_overrides("ideal8")]]      # only the shipped variant
    assert asked["pipeline"] == asked["record"] == []             # --loop-only
    assert list(k for k in report if k.startswith("loop_")) == ["loop_shipped"]
    assert report["loop_shipped"]["sensor"] == "ideal8"
    assert report["loop_shipped"]["repeats"][0]["sensor"] == "ideal8"
    assert rows_without_sensor(report) == []


def test_a_sensor_set_by_hand_is_the_one_named(monkeypatch, tmp_path, capsys):
    report, _ = run_bench(monkeypatch, tmp_path, "--set", 'camera.sensor="ideal8"',
                          "--variant", "shipped")
    assert report["config"]["sensor"] == "ideal8"
    assert report["loop_shipped"]["sensor"] == report["record"]["sensor"] == "ideal8"


def test_an_unknown_variant_is_refused_in_one_line(monkeypatch, tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        run_bench(monkeypatch, tmp_path, "--variant", "fastest")
    assert exc.value.code == 2
    assert "invalid choice: 'fastest'" in capsys.readouterr().err
