import csv
import json

from sebvs.numerics.work_precision import pareto_front, plot_study, write_csv, write_summary

POINTS = [
    {"method": "euler", "setting": 0.01, "error": 1.0, "seconds": 0.1},
    {"method": "euler", "setting": 0.001, "error": 0.1, "seconds": 1.0},
    {"method": "rk4", "setting": 0.01, "error": 0.05, "seconds": 0.4},     # beats euler 0.001
    {"method": "rk4", "setting": 0.001, "error": 0.001, "seconds": 4.0},
    {"method": "rk4", "setting": 0.1, "error": None, "seconds": 0.01, "diverged": True},
]


def test_pareto_front_drops_dominated_and_diverged():
    assert pareto_front(POINTS) == [0, 2, 3]


def test_outputs(tmp_path):
    write_csv(POINTS, tmp_path / "s.csv")
    rows = list(csv.DictReader(open(tmp_path / "s.csv")))
    assert len(rows) == 5 and rows[4]["diverged"] == "True"
    plot_study("physics", POINTS, tmp_path / "s.png", "position error [m]")
    assert (tmp_path / "s.png").stat().st_size > 10_000
    write_summary([{"name": "physics", "points": POINTS}], tmp_path / "summary.json")
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["studies"][0]["name"] == "physics"
    assert summary["studies"][0]["points"][2]["method"] == "rk4"
