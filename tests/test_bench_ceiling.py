"""tools/bench/bench_sim.py's compute ceiling: the frames it renders are the ones the rates ask
for, every stage is timed, and the ceiling is the CPU per simulated second inverted."""
import sys

import pytest

from tests.tools_loader import tool_module


@pytest.mark.parametrize("dvs_hz, luma_size", [(200.0, 80), (100.0, 160)])
def test_ceiling_renders_the_rates_frames_and_inverts_their_cpu(dvs_hz, luma_size):
    with tool_module("bench/bench_sim") as bench:
        row = bench.bench_ceiling(0.2, dvs_hz, luma_size, rgb_hz=10.0, rgb_size=160, repeats=1)
    assert row["frames_per_run"] == {"luma": round(0.2 * dvs_hz), "rgb": 2}
    stages = row["cpu_s_per_sim_s"]
    assert set(stages) == {"physics", "luma_render", "emulator", "rgb_render"}
    assert all(v > 0 for v in stages.values()), stages
    total = row["cpu_s_per_sim_s_total"]
    assert total == pytest.approx(sum(stages.values()), abs=1e-3)
    assert row["ceiling_x_on_2_cores"] == pytest.approx(2.0 / total, rel=0.01)
    assert row["ceiling_x_on_1_core"] == pytest.approx(1.0 / total, rel=0.01)
    assert row["events_per_run"][0] > 0        # the robot turns: the emulator saw motion


def test_bench_sim_help_names_the_ceiling(capsys, monkeypatch):
    monkeypatch.setattr(sys, "argv", ["bench_sim.py", "--help"])
    with tool_module("bench/bench_sim") as bench, pytest.raises(SystemExit):
        bench.main()
    assert "--ceiling-only" in capsys.readouterr().out
