"""The issue's stiff and extreme cases (QUICK grid of sebvs.eval.stability): each must be
stable or detected; a case that blows up silently fails the suite."""
import pytest

from sebvs.eval import stability as st


@pytest.fixture(scope="module")
def result(tmp_path_factory):
    import os
    cwd = os.getcwd()
    os.chdir(tmp_path_factory.mktemp("sweep"))     # MuJoCo's warnings go to MUJOCO_LOG.TXT
    try:
        return st.sweep("quick")
    finally:
        os.chdir(cwd)


def test_quick_grid_has_no_silent_blow_up(result):
    # the stiff wall contact that pumps the nav robot slowly, under the speed and jump
    # limits, is caught by the kinetic-energy ceiling (sebvs.sim.stability.Limits)
    bad = [f"{r['name']}: {r['reason']}" for r in result["cases"]
           if r["class"] == "undetected"]
    assert not bad, "undetected divergence:\n" + "\n".join(bad)


def test_quick_grid_covers_every_kind_and_class_counts_add_up(result):
    counts = result["counts"]
    assert sum(counts.values()) == len(result["cases"])
    assert {"nav_servo", "nav_contact", "belt"} <= set(result["by_kind"])
    # the stiff settings must really blow up somewhere, or the grid proves nothing
    assert counts["detected"] > 0 and counts["stable"] > 0


def test_classification_of_exceptions():
    assert st.classify_exception(ValueError("dt must be > 0"))[0] == "detected"
    assert st.classify_exception(ValueError(""))[0] == "undetected"
    assert st.classify_exception(ZeroDivisionError("x"))[0] == "undetected"


def test_event_sanity_check_on_hand_made_streams():
    import numpy as np
    from sebvs.eval import dvs_cases
    frames = np.zeros((3, 4, 4), np.uint8)
    t_ns = np.array([0, 10, 20], np.int64)
    ok = (np.array([1, 5], np.int64), np.array([0, 3]), np.array([2, 1]), np.array([1, -1]))
    assert dvs_cases.check_events(ok, frames, t_ns) is None
    late = (np.array([1, 50], np.int64),) + ok[1:]
    assert "span" in dvs_cases.check_events(late, frames, t_ns)
    unsorted = (np.array([5, 1], np.int64),) + ok[1:]
    assert "sorted" in dvs_cases.check_events(unsorted, frames, t_ns)
    outside = ok[:1] + (np.array([0, 4]),) + ok[2:]
    assert "outside the image" in dvs_cases.check_events(outside, frames, t_ns)
    pol = ok[:3] + (np.array([1, 0]),)
    assert "polarity" in dvs_cases.check_events(pol, frames, t_ns)
