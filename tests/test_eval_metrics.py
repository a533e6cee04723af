import math

import numpy as np
import pytest

from sebvs.metrics import (arm_metrics, nav_episode_metrics, paired_comparison,
                                success_radius, wilson_interval, yaw_error_deg)


def test_success_radius_scales_with_width():
    assert success_radius(640) == 200
    assert success_radius(160) == 50


def test_nav_metrics_hand_computed():
    # 160x160 image, centre (80, 80); radius 50 px
    centroids = [[80, 80], [110, 120], [80, 20], [0, 0]]   # errors 0, 50, 60, (invisible)
    widths = [10, 20, 30, 99]
    visible = [True, True, True, False]
    m = nav_episode_metrics(centroids, widths, visible, (160, 160), duration_s=12.5)
    assert m.frames == 4
    assert m.visible == 0.75
    assert m.centroid_error_px == pytest.approx((0 + 50 + 60) / 3)
    assert m.centroid_error_std_px == pytest.approx(np.std([0, 50, 60]))
    assert m.bbox_width_px == pytest.approx(20)
    assert m.success == 0.5            # 0 and 50 px are within 50 px; 60 and the invisible one not
    assert m.duration_s == 12.5


def test_strict_rate_and_episode_success_hand_computed():
    # 160x160: the paper's radius is 50 px, the strict one 12.5 px
    errors = [0, 10, 12.5, 13, 40, 50, 51, 60, 70, 80]
    centroids = [[80 + e, 80] for e in errors]
    m = nav_episode_metrics(centroids, [10] * 10, [True] * 10, (160, 160), 1.0)
    assert m.success == 0.6 and m.strict_success == 0.3
    assert m.episode_success == 0.0                       # 60 % < 90 %
    near = nav_episode_metrics([[80, 80]] * 9 + [[0, 0]], [10] * 10, [True] * 10,
                               (160, 160), 1.0)
    assert near.success == 0.9 and near.episode_success == 1.0   # exactly 90 % counts
    hidden = nav_episode_metrics([[80, 80]] * 10, [10] * 10, [True] * 8 + [False] * 2,
                                 (160, 160), 1.0)
    assert hidden.episode_success == 0.0                  # frames out of view are misses


def test_strict_rate_never_exceeds_the_paper_rate():
    rng = np.random.default_rng(0)
    for _ in range(50):
        n = int(rng.integers(1, 40))
        m = nav_episode_metrics(rng.uniform(0, 160, (n, 2)), np.ones(n),
                                rng.random(n) < 0.8, (160, 160), 1.0)
        assert m.strict_success <= m.success


def test_nav_metrics_never_visible():
    m = nav_episode_metrics([[1, 1]], [5], [False], (160, 160), 1.0)
    assert m.success == 0 and math.isnan(m.centroid_error_px)


def test_nav_metrics_reject_bad_input():
    with pytest.raises(ValueError, match="lengths differ"):
        nav_episode_metrics([[1, 1], [2, 2]], [5], [True], (160, 160), 1.0)
    with pytest.raises(ValueError, match="without frames"):
        nav_episode_metrics(np.zeros((0, 2)), [], [], (160, 160), 1.0)


def test_yaw_error_respects_cube_symmetry():
    assert yaw_error_deg(np.radians(95), np.radians(0)) == pytest.approx(5)
    assert yaw_error_deg(np.radians(-44), np.radians(44)) == pytest.approx(2)
    assert yaw_error_deg(np.radians(10), np.radians(0), symmetry_deg=360) == pytest.approx(10)


def test_arm_metrics_hand_computed():
    expert = np.zeros((3, 6))
    pred = np.array([[0.03, 0.04, 0, 0, 0, 0],                # 50 mm, 0 deg -> inside
                     [0.0, 0.0, 0.06, 0, 0, 0],               # 60 mm -> outside
                     [0.0, 0.01, 0, 0, 0, np.radians(20)]])   # 10 mm, 20 deg -> outside
    m = arm_metrics(pred, expert)
    assert m["position_error_mm"] == pytest.approx((50 + 60 + 10) / 3)
    assert m["accuracy"] == pytest.approx(1 / 3)
    assert m["yaw_error_deg"] == pytest.approx(20 / 3)


def test_wilson_interval_known_values():
    lo, hi = wilson_interval(8, 10)
    assert lo == pytest.approx(0.4902, abs=1e-3) and hi == pytest.approx(0.9433, abs=1e-3)
    lo, hi = wilson_interval(0, 10)
    assert lo == 0 and hi == pytest.approx(0.2775, abs=1e-3)
    assert all(math.isnan(v) for v in wilson_interval(0, 0))


def test_paired_comparison_sign_test():
    a = [1, 1, 1, 1, 1, 1, 0.5]
    b = [0, 0, 0, 0, 0, 0, 0.5]
    r = paired_comparison(a, b)
    assert (r["wins"], r["losses"], r["ties"]) == (6, 0, 1)
    assert r["p_sign"] == pytest.approx(2 / 64)      # two-sided exact: 2 * 0.5^6
    assert r["mean_diff"] == pytest.approx(6 / 7)
    assert r["ci95"][0] <= r["mean_diff"] <= r["ci95"][1]
    assert paired_comparison([1, 0], [0, 1])["p_sign"] == 1.0
    with pytest.raises(ValueError, match="same seeds"):
        paired_comparison([1, 2], [1])
