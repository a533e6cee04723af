"""research/ideal8/arm_aims.py: the last pose of an arm episode classed against every led cube."""
import json

import pytest

from research.tests.study_loader import study_module

# three cubes 100 mm apart along the belt (y); the target is cube 0; the reference
# leads every cube by +10 mm in y
CUBES = [[400.0, 0.0, 1], [400.0, 100.0, 1], [400.0, 200.0, 1]]
REFERENCE = [0.4, 0.010, 0.15, 3.14159, 0.0, 0.0]


def _episode(pred_xy_mm, grasped=True, modality="event", mode="grasp"):
    pred = [pred_xy_mm[0] / 1e3, pred_xy_mm[1] / 1e3, 0.15, 3.14159, 0.0, 0.0]
    return {"modality": modality, "condition": "moving", "scenario": "multi", "seed": 1,
            "metrics": {"pred": [pred, pred], "expert": [REFERENCE, REFERENCE],
                        "modes": ["grasp", mode], "target": [0, 0],
                        "cubes_mm": [CUBES, CUBES], "grasp_success": grasped}}


def test_each_class_by_the_nearest_led_cube():
    with study_module("ideal8/arm_aims") as tool:
        aim = lambda xy: tool.classify(_episode(xy)["metrics"], 20.0)["class"]  # noqa: E731
        assert aim((405.0, 15.0)) == "on target"        # 7 mm from the led target
        assert aim((400.0, 45.0)) == "off target"       # 35 mm downstream, still nearest it
        assert aim((400.0, 105.0)) == "other cube"      # the next cube, led: 5 mm
        assert aim((400.0, 75.0)) == "between"          # nearer the next cube, 35 mm off
        offset = tool.classify(_episode((400.0, 45.0))["metrics"], 20.0)["offset_mm"]
        assert offset == [0.0, 35.0]


def test_home_ticks_and_unrecorded_episodes_are_left_out(tmp_path):
    with study_module("ideal8/arm_aims") as tool:
        home = _episode((400.0, 10.0), mode="home_workspace")
        assert tool.classify(home["metrics"], 20.0) is None
        old = _episode((400.0, 10.0))
        del old["metrics"]["cubes_mm"]
        with pytest.raises(ValueError, match="predates"):
            tool.summarise({"task": "arm", "episodes": [old]}, 20.0)
        with pytest.raises(ValueError, match="not an arm"):
            tool.summarise({"task": "nav", "episodes": []}, 20.0)


def test_table_counts_grasps_and_the_median_miss_offset(tmp_path, capsys):
    episodes = [_episode((400.0, 12.0)), _episode((400.0, 45.0), grasped=False),
                _episode((400.0, 55.0), grasped=False),
                _episode((400.0, 12.0), modality="rgb", grasped=False)]
    path = tmp_path / "results.json"
    path.write_text(json.dumps({"task": "arm", "episodes": episodes}))
    with study_module("ideal8/arm_aims") as tool:
        assert tool.main([str(path), "--json", str(tmp_path / "aims.json")]) == 0
        cells = json.loads((tmp_path / "aims.json").read_text())["cells"]
        event = cells["event/moving/multi"]
        assert event["on target"] == {"episodes": 1, "grasped": 1}
        assert event["off target"] == {"episodes": 2, "grasped": 0}
        assert event["misses"] == 2 and event["miss_offset_mm"] == [0.0, 40.0]
        assert cells["rgb/moving/multi"]["miss_offset_mm"] == [0.0, 2.0]
        assert "| event/moving/multi | 1 (1) | 2 (0) | 0 (0) | 0 (0) | +0.0, +40.0 |" \
            in capsys.readouterr().out
        with pytest.raises(SystemExit) as exit_:
            tool.main([str(path), "--radius-mm", "0"])
        assert exit_.value.code == 2 and "--radius-mm must be > 0" in capsys.readouterr().err
