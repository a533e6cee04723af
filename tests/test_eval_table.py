"""`sebvs eval table` (sebvs/eval/table.py): training seeds of two modalities on the same episodes, per cell."""
import json

import pytest

from tests.eval_readers import reader


def results(a_wins: dict[str, list], b_wins: dict[str, list], seed: int = 7) -> dict:
    """An arm evaluation: per cell, rgb+event's and rgb's grasp outcome per episode (None:
    nothing graspable)."""
    eps = []
    for modality, cells in (("rgb+event", a_wins), ("rgb", b_wins)):
        for cell, outcomes in cells.items():
            cond, scen = cell.split("/")
            eps += [{"modality": modality, "condition": cond, "scenario": scen, "seed": 100 + k,
                     "metrics": {"grasp_success": o}} for k, o in enumerate(outcomes)]
    return {"task": "arm", "seed": seed, "episodes": eps}


def test_a_reading_needs_the_mean_and_every_run(tmp_path):
    one = [True] * 10
    runs = {
        # fast: A ahead by 30 and 20; nominal: +40 in one run, -10 in the other
        "s0": results({"fast/multi": one, "nominal/multi": one},
                      {"fast/multi": [True] * 7 + [False] * 3,
                       "nominal/multi": [True] * 6 + [False] * 4}),
        "s1": results({"fast/multi": one, "nominal/multi": [True] * 8 + [False] * 2},
                      {"fast/multi": [True] * 8 + [False] * 2,
                       "nominal/multi": [True] * 9 + [False]}),
    }
    with reader("table") as tool:
        table = tool.seed_table(runs, "rgb+event", "rgb", min_diff=10)
        md = tool.markdown(table)
    fast, nominal = table["cells"]["fast/multi"], table["cells"]["nominal/multi"]
    assert table["metric"] == "grasp_success"
    assert fast["per_run"]["s0"]["diff"] == pytest.approx(0.3)
    assert fast["mean_diff"] == pytest.approx(0.25) and fast["ahead"] == 2
    assert fast["reading"] == "rgb+event helps"
    # the episodes averaged over the runs: B missed episodes 7 (once), 8 and 9 (twice)
    assert (fast["episodes"]["wins"], fast["episodes"]["losses"]) == (3, 0)
    assert nominal["mean_diff"] == pytest.approx(0.15) and nominal["behind"] == 1
    assert nominal["reading"] == "no clear difference"     # the mean alone is not enough
    assert "| fast/multi | +30.0 | +20.0 | 100.0 | 75.0 | +25.0 | 2 / 0 |" in md
    with reader("table") as tool:
        loose = tool.seed_table(runs, "rgb+event", "rgb", min_diff=10, min_ahead=1)
    assert loose["cells"]["nominal/multi"]["reading"] == "rgb+event helps"


def test_ungraspable_episodes_are_left_out_and_bad_runs_refused(tmp_path):
    runs = {"s0": results({"moving/single": [True, None, True]},
                          {"moving/single": [False, None, True]}),
            "s1": results({"moving/single": [True, None, False]},
                          {"moving/single": [True, None, False]})}
    with reader("table") as tool:
        cell = tool.seed_table(runs, "rgb+event", "rgb")["cells"]["moving/single"]
        assert cell["per_run"]["s0"]["n"] == 2 and cell["episodes"]["n"] == 2
        assert cell["mean_diff"] == pytest.approx(0.25)
        # a cell one run has no graspable episode in is named, not dropped unseen
        gap = {"s0": runs["s0"], "s1": results({"moving/single": [True, None, False],
                                               "fast/multi": [None]},
                                              {"moving/single": [True, None, False],
                                               "fast/multi": [None]})}
        table = tool.seed_table(gap, "rgb+event", "rgb")
        assert list(table["cells"]) == ["moving/single"]
        assert table["left_out"] == ["fast/multi"]
        assert "Not scored by every run: fast/multi" in tool.markdown(table)
        with pytest.raises(ValueError, match="run 's1' differs in seed"):
            tool.seed_table({"s0": runs["s0"], "s1": {**runs["s1"], "seed": 8}}, "rgb+event", "rgb")
        with pytest.raises(ValueError, match="run 's0' holds no 'event' episodes"):
            tool.seed_table(runs, "event", "rgb")
        with pytest.raises(ValueError, match="at least two runs"):
            tool.seed_table({"s0": runs["s0"]}, "rgb+event", "rgb")
        # the command line: NAME=DIR pairs, a clear refusal of a directory without results
        for name, res in runs.items():
            (tmp_path / name).mkdir()
            (tmp_path / name / "results.json").write_text(json.dumps(res))
        out = tmp_path / "t.json"
        assert tool.main([f"s0={tmp_path / 's0'}", f"s1={tmp_path / 's1'}", "--a", "rgb+event",
                          "--b", "rgb", "--json", str(out), "--plot",
                          str(tmp_path / "seeds.png")]) == 0
        assert json.loads(out.read_text())["runs"] == ["s0", "s1"]
        assert (tmp_path / "seeds.png").stat().st_size > 5000
        assert tool.main([f"s0={tmp_path / 's0'}", f"s1={tmp_path / 'nope'}", "--a", "rgb+event",
                          "--b", "rgb"]) == 2


def test_a_run_may_join_directories_that_each_hold_some_modalities(tmp_path):
    """NAME=DIR given twice: a seed whose control was evaluated after, into its own
    directory."""
    def only(res, modality):
        return {**res, "episodes": [e for e in res["episodes"] if e["modality"] == modality]}
    runs = {"s0": results({"fast/multi": [True, True]}, {"fast/multi": [False, True]}),
            "s1": results({"fast/multi": [True, False]}, {"fast/multi": [False, False]})}
    for name, res in runs.items():
        for modality in ("rgb+event", "rgb"):
            d = tmp_path / f"{name}-{modality}"
            d.mkdir()
            (d / "results.json").write_text(json.dumps(only(res, modality)))
    out = tmp_path / "t.json"
    spec = [f"{n}={tmp_path / (n + '-' + m)}" for n in runs for m in ("rgb+event", "rgb")]
    with reader("table") as tool:
        assert tool.main([*spec, "--a", "rgb+event", "--b", "rgb", "--json", str(out)]) == 0
        joined = json.loads(out.read_text())["cells"]["fast/multi"]
        assert joined == tool.seed_table(runs, "rgb+event", "rgb")["cells"]["fast/multi"]
        parts = [("x", runs["s0"]), ("y", only(runs["s0"], "rgb"))]
        with pytest.raises(ValueError, match="x and y both hold 'rgb' episodes of fast/multi"):
            tool.merge_runs(parts)
        with pytest.raises(ValueError, match="y differs from x in seed"):
            tool.merge_runs([("x", only(runs["s0"], "rgb")),
                             ("y", {**only(runs["s0"], "rgb+event"), "seed": 9})])


def test_a_tag_compares_one_modality_under_two_settings(tmp_path, capsys):
    """NAME@TAG=DIR: the same modality from two directories (two sensors), paired by seed."""
    def rgb_only(wins):
        return results({}, {"fast/multi": wins})
    dirs = {"s0": ([True, True, True], [True, False, False]),
            "s1": ([True, True, False], [False, True, False])}
    spec = []
    for name, (sharp, blunt) in dirs.items():
        for tag, wins in (("fr", sharp), ("", blunt)):
            d = tmp_path / f"{name}{tag}"
            d.mkdir()
            (d / "results.json").write_text(json.dumps(rgb_only(wins)))
            spec.append(f"{name}{'@' + tag if tag else ''}={d}")
    out = tmp_path / "t.json"
    with reader("table") as tool:
        assert tool.main([*spec, "--a", "rgb@fr", "--b", "rgb", "--json", str(out)]) == 0
        capsys.readouterr()
        assert tool.main([f"s0@={tmp_path / 's0'}", "--a", "rgb", "--b", "rgb"]) == 2
        assert "a run is NAME=DIR or NAME@TAG=DIR, got 's0@=" in capsys.readouterr().err
        # the files a reader writes are its own: an existing one needs --force
        assert tool.main([*spec, "--a", "rgb@fr", "--b", "rgb", "--json", str(out)]) == 2
        assert "t.json: exists; give --force to replace it" in capsys.readouterr().err
        assert tool.main([*spec, "--a", "rgb@fr", "--b", "rgb", "--json", str(out),
                          "--force"]) == 0
        assert tool.tagged(rgb_only([True]), "")["episodes"][0]["modality"] == "rgb"
    cell = json.loads(out.read_text())["cells"]["fast/multi"]
    assert cell["per_run"]["s0"]["diff"] == pytest.approx(2 / 3)
    assert cell["per_run"]["s1"]["diff"] == pytest.approx(1 / 3)
    assert cell["reading"] == "rgb@fr helps"


def test_a_mean_that_sums_to_zero_prints_plus_zero():
    """Seeds at -5, +5 and 0 points average to -1e-17 in floating point; the printed table
    says +0.0 there, as the study's report does (research/ideal8/studyio.py points)."""
    cell = {"per_run": {"s0": {"diff": -0.05}, "s1": {"diff": 0.05}, "s2": {"diff": 0.0}},
            "mean_a": 0.9, "mean_b": 0.9, "mean_diff": -1e-17, "ahead": 1, "behind": 1,
            "episodes": {"ci95": [-0.05, 0.05], "p_sign": 1.0}, "reading": "no clear difference"}
    table = {"a": "rgb+event", "b": "rgb+diff", "runs": ["s0", "s1", "s2"], "metric": "m",
             "rule": {"min_diff_points": 10, "min_ahead": 3}, "cells": {"x/y": cell},
             "left_out": []}
    with reader("table") as tool:
        row = tool.markdown(table).splitlines()[-1]
    assert row == ("| x/y | -5.0 | +5.0 | +0.0 | 90.0 | 90.0 | +0.0 | 1 / 1 | [-5.0, +5.0], 1 "
                   "| no clear difference |")
