"""sebvs demo's closing table, from the tracker's episode lines of either task."""
from sebvs.demo import _format_metrics


def _arm_line(episode, outcome, pos_mm):
    return {"episode": episode, "seed": 7, "reason": "time_limit", "ticks": 21,
            "metrics": {"scenario": "single", "n": 21, "position_error_mm": pos_mm,
                        "position_error_std_mm": 1.25, "yaw_error_deg": 23.6, "accuracy": 0.5,
                        "outcome": outcome, "grasp_success": outcome == "lifted_and_held"},
            "trace_error_mm": [pos_mm] * 21, "inference_ms": []}


def test_the_arm_trackers_episodes_make_a_table_of_their_own():
    # the arm tracker scores whole episodes and writes no per-modality split: the demo
    # ended in a KeyError on it after the whole run had been shown
    text = _format_metrics([_arm_line(0, "lifted_and_held", 6.7), _arm_line(1, "dropped", 41.0)])
    lines = text.splitlines()
    assert lines[0].startswith("tracking (Table 5")
    assert "6.7 ± 1.2" in lines[2] and lines[2].endswith("lifted_and_held")
    assert "41.0" in lines[3] and "50.0" in lines[3] and lines[3].endswith("dropped")


def test_an_arm_episode_without_a_scored_tick_is_said_so():
    line = {"episode": 3, "reason": "source_done", "ticks": 0, "metrics": {}}
    assert "no scored tick (source_done)" in _format_metrics([line])


def test_nav_episodes_are_split_by_the_modality_that_acted():
    m = {"frames": 5, "centroid_error_px": 12.0, "centroid_error_std_px": 2.0,
         "bbox_width_px": 16.5, "success": 1.0, "visible": 0.8}
    line = {"episode": 0, "ticks": 10, "metrics": m, "by_modality": {"rgb+event": m, "event": m}}
    lines = _format_metrics([line]).splitlines()
    assert lines[0].startswith("tracking (Table 4")
    assert [ln.split()[1] for ln in lines[2:]] == ["rgb+event", "event"]
    assert "100.0" in lines[2] and "80.0" in lines[2]


def test_no_finished_episode():
    assert _format_metrics([]) == "tracking: no finished episode"
