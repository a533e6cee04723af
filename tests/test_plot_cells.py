"""tools/eval/plot_cells.py: one modality's rate per cell across evaluations, beside no action."""
import json
from pathlib import Path

import pytest

from tests.tools_loader import tool_module


def _results(path: Path, event_rates: dict, baseline: float | None) -> Path:
    episodes = []
    for (cond, scen), rates in event_rates.items():
        for seed, rate in enumerate(rates):
            m = {"success": rate, "strict_success": rate / 2, "episode_success": float(rate > .9)}
            episodes.append({"modality": "event", "condition": cond, "scenario": scen,
                             "seed": seed, "metrics": m})
            if baseline is not None:
                episodes.append({"modality": "no_action", "condition": cond, "scenario": scen,
                                 "seed": seed, "metrics": {"success": baseline,
                                                           "strict_success": 0.0,
                                                           "episode_success": 0.0}})
    path.mkdir()
    (path / "results.json").write_text(json.dumps({"task": "nav", "seed": 7,
                                                   "episodes": episodes}))
    return path


def test_cell_rates_pair_each_cell_with_its_no_action_mean(tmp_path):
    with tool_module("eval/plot_cells") as tool:
        path = _results(tmp_path / "a", {("nominal", "indoor"): [0.2, 0.4],
                                         ("fast", "outdoor"): [1.0]}, baseline=0.3)
        cells = tool.cell_rates(tool.read_results(path), "event", "success")
        assert list(cells) == ["fast/outdoor", "nominal/indoor"]
        assert cells["nominal/indoor"] == {"episodes": [0.2, 0.4], "no_action": 0.3}
        strict = tool.cell_rates(tool.read_results(path), "event", "strict_success")
        assert strict["nominal/indoor"]["episodes"] == [0.1, 0.2]


def test_main_draws_and_writes_every_evaluation(tmp_path, capsys):
    with tool_module("eval/plot_cells") as tool:
        a = _results(tmp_path / "a", {("nominal", "indoor"): [0.2, 0.4]}, baseline=0.3)
        b = _results(tmp_path / "b", {("nominal", "indoor"): [0.9, 0.7]}, baseline=None)
        out, js = tmp_path / "cells.png", tmp_path / "cells.json"
        assert tool.main([str(a), str(b), "--labels", "checker,plain", "--modality", "event",
                          "--out", str(out), "--json", str(js)]) == 0
        assert out.stat().st_size > 1000
        cells = json.loads(js.read_text())["cells"]
        assert cells["checker"]["nominal/indoor"] == {"mean": pytest.approx(0.3), "episodes": 2,
                                                      "no_action": 0.3}
        assert cells["plain"]["nominal/indoor"]["no_action"] is None
        assert "80.0 % over   2 episodes (no action -)" in capsys.readouterr().out


def test_main_names_what_is_wrong(tmp_path, capsys):
    with tool_module("eval/plot_cells") as tool:
        a = _results(tmp_path / "a", {("nominal", "indoor"): [0.2]}, baseline=None)
        with pytest.raises(SystemExit):
            tool.main([str(a), "--labels", "x,y", "--modality", "event", "--out",
                       str(tmp_path / "f.png")])
        assert "--labels names 2 evaluations, 1 given" in capsys.readouterr().err
        with pytest.raises(SystemExit):
            tool.main([str(a), "--modality", "rgb", "--out", str(tmp_path / "f.png")])
        assert "no 'rgb' episodes" in capsys.readouterr().err
        with pytest.raises(SystemExit):
            tool.main([str(tmp_path / "missing"), "--modality", "event", "--out",
                       str(tmp_path / "f.png")])
        assert "no such file" in capsys.readouterr().err


def test_arm_grasp_success_skips_home_episodes_and_takes_a_modality_per_evaluation(
        tmp_path, capsys):
    with tool_module("eval/plot_cells") as tool:
        def arm(name, modality, grasps):
            eps = [{"modality": modality, "condition": "fast", "scenario": "single",
                    "seed": i, "metrics": {"grasp_success": g}} for i, g in enumerate(grasps)]
            eps += [{"modality": "no_action", "condition": "fast", "scenario": "single",
                     "seed": i, "metrics": {"grasp_success": None if g is None else False}}
                    for i, g in enumerate(grasps)]
            path = tmp_path / name
            path.mkdir()
            (path / "results.json").write_text(json.dumps({"task": "arm", "seed": 3,
                                                           "episodes": eps}))
            return path
        a = arm("a", "rgb+event", [True, None, True, False])
        b = arm("b", "expert", [True, None, True, True])
        js = tmp_path / "cells.json"
        assert tool.main([str(a), str(b), "--modality", "rgb+event,expert", "--out",
                          str(tmp_path / "f.png"), "--json", str(js)]) == 0
        got = json.loads(js.read_text())
        assert got["metric"] == "grasp_success"
        assert got["cells"]["a"]["fast/single"] == {"mean": pytest.approx(2 / 3),
                                                    "episodes": 3, "no_action": 0.0}
        assert got["cells"]["b"]["fast/single"]["mean"] == 1.0
        with pytest.raises(SystemExit):
            tool.main([str(a), str(b), "--modality", "rgb,event,expert", "--out",
                       str(tmp_path / "g.png")])
        assert "--modality names 3 modalities for 2 evaluations" in capsys.readouterr().err
