import numpy as np
import pytest

from sebvs.metrics import nav_episode_metrics
from sebvs.eval.report import aggregate_nav, plot_success, render_report


def nav_episode(mod, seed, success_frames, cond="nominal"):
    visible = [True] * 10
    centroids = [[80, 80]] * success_frames + [[80, 150]] * (10 - success_frames)
    m = nav_episode_metrics(centroids, [20] * 10, visible, (160, 160), 10.0).as_dict()
    return {"modality": mod, "condition": cond, "seed": seed, "metrics": m}


def test_aggregate_nav_pools_frames_exactly():
    eps = [nav_episode("rgb", 0, 10), nav_episode("rgb", 1, 5)]
    a = aggregate_nav(eps)
    errors = np.array([0.0] * 10 + [0.0] * 5 + [70.0] * 5)
    assert a["centroid_error_px"] == pytest.approx(errors.mean())
    assert a["centroid_error_std_px"] == pytest.approx(errors.std())
    assert a["success"] == pytest.approx(15 / 20)
    assert a["success_ci95"][0] < 0.75 < a["success_ci95"][1]


def test_aggregate_nav_episode_success_and_strict_rate():
    # 10 of 10 frames at the centre: success, strict and episode success all 1; 5 of 10:
    # the episode fails, the frames at 70 px are outside both radii
    a = aggregate_nav([nav_episode("rgb", 0, 10), nav_episode("rgb", 1, 5)])
    assert a["strict_success"] == pytest.approx(15 / 20)
    assert a["episode_success"] == 0.5
    lo, hi = a["episode_success_ci95"]
    assert lo < 0.5 < hi


def test_nav_report_has_the_baseline_row_and_new_columns():
    eps = [nav_episode(m, s, k) for s in range(3)
           for m, k in (("expert", 10), ("no_action", 2), ("rgb", 9))]
    text = render_report({"task": "nav", "episodes": eps})
    tables = text.split("## Condition: nominal")[1]     # below the summary
    rows = [line for line in tables.splitlines() if line.startswith("| ")]
    assert "Strict (% within 50 px)" in rows[0] and "Episode success" in rows[0]
    names = [r.split("|")[1].strip() for r in rows[1:]]
    assert names == ["Expert (reference)", "No action (baseline)", "RGB-only"]
    assert "| No action (baseline) | 3 |" in text and "| 20.0 [" in text
    # the summary above the tables: a row per condition, a cell per model (paper rate /
    # strict / episodes with >= 90 % of frames within the radius)
    assert "| condition | Expert (reference) | No action (baseline) | RGB-only |" in text
    assert "| nominal | 100.0 / 100.0 / 3 of 3 | 20.0 / 20.0 / 0 of 3 | " \
           "90.0 / 90.0 / 3 of 3 |" in text


def test_report_reads_results_written_before_the_new_rates():
    ep = nav_episode("rgb", 0, 10)
    for key in ("strict_success", "episode_success"):
        del ep["metrics"][key]
    old_rgbe = nav_episode("rgb+event", 0, 10)
    for key in ("strict_success", "episode_success"):
        del old_rgbe["metrics"][key]
    text = render_report({"task": "nav", "episodes": [ep, old_rgbe]})
    assert "| RGB-only | 1 |" in text and "| - | - [-, -] |" in text
    assert "(strict rate," not in text and "nan" not in text   # nothing to pair on
    assert "| nominal | 100.0 / - / - | 100.0 / - / - |" in text


def test_nav_report_renders_tables_and_paired_comparison(tmp_path):
    eps = []
    for seed in range(6):
        eps += [nav_episode("expert", seed, 10), nav_episode("rgb", seed, 4),
                nav_episode("rgb+event", seed, 9), nav_episode("rgb+event", seed, 8, "fast")]
    results = {"task": "nav", "clock": "lockstep", "episodes": eps}
    text = render_report(results)
    assert "## Condition: nominal" in text and "## Condition: fast" in text
    assert "| Expert (reference) | 6 |" in text
    assert "| RGB+Event vs RGB-only | 6 | +50.0 |" in text
    assert "6/0/0" in text
    # the strict rate's own paired table: frames at 0 px are within 50 px, at 70 px not
    strict = text.split("(strict rate,")[1]
    assert "| RGB+Event vs RGB-only | 6 | +50.0 |" in strict
    plot_success(results, tmp_path / "s.png")
    assert (tmp_path / "s.png").stat().st_size > 5000


def test_arm_report_renders():
    eps = []
    for seed in range(4):
        for mod, off in (("rgb", 0.08), ("rgb+event", 0.01)):
            eps.append({"modality": mod, "condition": "nominal", "seed": seed,
                        "inference_ms": [3.0, 4.0],
                        "metrics": {"scenario": "single", "pred": [[off, 0, 0.2, 0, 0, 0]] * 2,
                                    "expert": [[0, 0, 0.2, 0, 0, 0]] * 2,
                                    "grasp_success": mod == "rgb+event",
                                    "end_decision_correct": seed != 0}})
    text = render_report({"task": "arm", "episodes": eps})
    assert "## Condition: nominal, single-object" in text
    # 4 episodes, 8 predictions; grasp success; end decision 3 of 4
    assert "| RGB+Event | 4 | 8 | 10.0 ± 0.0 | 100.0 | 3.50 / 4.00 | 100.0 [51.0, 100.0] | 75.0 |" \
        in text, text
    assert "| RGB-only | 4 | 8 | 80.0 ± 0.0 | 0.0 |" in text
    assert "RGB+Event vs RGB-only | 4 | +100.0" in text


def test_arm_success_plot_with_certain_outcomes(tmp_path):
    """All grasps succeed or all fail: the Wilson bound may miss 0 or 1 by a rounding
    error, which once made matplotlib refuse a negative error bar."""
    eps = [{"modality": mod, "condition": "nominal", "scenario": scen, "seed": seed,
            "inference_ms": [1.0],
            "metrics": {"scenario": scen, "pred": [[0, 0, 0.2, 0, 0, 0]],
                        "expert": [[0, 0, 0.2, 0, 0, 0]], "grasp_success": mod == "expert",
                        "end_decision_correct": True}}
           for seed in range(14) for mod in ("expert", "rgb") for scen in ("single",)]
    # the Wilson upper bound of 14 successes in 14 is 1 - 1e-16
    from sebvs.metrics import wilson_interval
    assert wilson_interval(14, 14)[1] < 1.0
    plot_success({"task": "arm", "episodes": eps}, tmp_path / "s.png")
    assert (tmp_path / "s.png").stat().st_size > 5000


def test_nav_report_breaks_down_per_scene_variant(tmp_path):
    """The same seeds in both variants: one table each, never pooled, and the paired
    comparison pairs within a variant (pooled, the seeds would collide)."""
    eps = []
    for scen, good in (("indoor", 10), ("outdoor", 3)):
        for seed in range(4):
            for mod, k in (("no_action", 2), ("rgb", good), ("rgb+event", 10)):
                eps.append({**nav_episode(mod, seed, k), "scenario": scen})
    text = render_report({"task": "nav", "split": "test", "episodes": eps})
    indoor, outdoor = text.split("## Condition: nominal, outdoor")
    assert "## Condition: nominal, indoor" in indoor
    assert "| RGB-only | 4 | 0.0 ± 0.0 |" in indoor and "| RGB-only | 4 |" in outdoor
    assert "| RGB+Event vs RGB-only | 4 | +0.0 |" in indoor
    assert "| RGB+Event vs RGB-only | 4 | +70.0 |" in outdoor
    assert "| No action (baseline) | 4 |" in indoor and "| No action (baseline) | 4 |" in outdoor
    plot_success({"task": "nav", "episodes": eps}, tmp_path / "s.png")
    assert (tmp_path / "s.png").stat().st_size > 5000


def test_report_flags_a_custom_seed_in_the_train_range():
    eps = [nav_episode("rgb", 0, 10)]
    note = "lies in the train range"
    assert note in render_report({"task": "nav", "split": "custom", "seed": 3, "episodes": eps})
    for split, seed in (("custom", 2000), ("dev", 1000), ("custom", 150_000)):
        assert note not in render_report({"task": "nav", "split": split, "seed": seed,
                                          "episodes": eps})


def test_unknown_task_is_an_error():
    with pytest.raises(ValueError, match="unknown task"):
        render_report({"task": "fly", "episodes": []})


def test_paired_difference_that_sums_to_zero_reads_plus_zero():
    # per-seed differences 0, +0.1 and -0.1 sum to -9e-18 in floating point: the table
    # must say +0.0, as the study reports do, not a signed -0.0
    eps = []
    for seed, (mine, other) in enumerate(((0, 0), (3, 2), (1, 2))):
        eps += [nav_episode("rgb+event", seed, mine), nav_episode("rgb", seed, other)]
    text = render_report({"task": "nav", "episodes": eps})
    assert "| RGB+Event vs RGB-only | 3 | +0.0 | [-10.0, +10.0] | 1/1/1 |" in text, text
    assert "-0.0" not in text
