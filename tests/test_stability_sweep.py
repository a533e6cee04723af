"""The issue's stiff and extreme cases (QUICK grid of sebvs.numerics.stability): each must be
stable or detected; a case that blows up silently fails the suite."""
import pytest

from sebvs.numerics import stability as st
from sebvs.numerics.sweep import classify_exception


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
    assert {"nav_servo", "nav_contact", "belt", "arm"} <= set(result["by_kind"])
    # the stiff settings must really blow up somewhere, or the grid proves nothing
    assert counts["detected"] > 0 and counts["stable"] > 0


def test_arm_plausibility_passes_the_physical_and_flags_the_impossible():
    """The independent test must itself be right about the arm scene's physics: a cube
    resting on the belt or lying on the floor past the belt's end is physical; a cube
    wholly inside the frame, one ending with its centre in the belt, one above its drop
    point, one faster than belt and fall can make it, or the tcp off HOME is not."""
    import mujoco
    import numpy as np
    from sebvs.sim.arm_model import BELT_TOP
    from sebvs.numerics.arm_cases import arm_case
    model, data, _, _, plausible = arm_case({"timestep": 0.002, "integrator": "discrete"})
    scene = plausible.scene
    adr, half = scene.cube_qadr[0], scene.halves[0]
    dof = model.jnt_dofadr[model.body_jntadr[scene.cube_body[0]]]

    def put(x, y, z):           # cube 0, upright, at rest
        data.qpos[adr:adr + 7] = [x, y, z, 1, 0, 0, 0]
        data.qvel[dof:dof + 6] = 0
        mujoco.mj_forward(model, data)

    assert plausible(model, data, end=True) is None
    put(0.45, 1.3, -0.75 + half)                        # rode off the end to the floor
    assert plausible(model, data, end=True) is None
    put(0.45, 0.0, -0.3)
    assert "wholly inside" in plausible(model, data)
    put(0.45, 0.0, BELT_TOP - 0.3 * half)               # part of it still out
    assert plausible(model, data) is None
    assert "sunk" in plausible(model, data, end=True)
    put(0.45, 0.0, 0.5)
    assert "rose" in plausible(model, data)
    put(0.45, 0.0, BELT_TOP + half)
    data.qvel[dof] = 10.0                                # a 2 mm drop gives 3.9 m/s at most
    assert "speed" in plausible(model, data)
    data.qvel[dof] = 0.0
    data.qvel[dof + 3] = 500.0                           # spinning, not moving
    assert "kinetic energy" in plausible(model, data)
    data.qvel[dof + 3] = 0.0
    data.qvel[model.jnt_dofadr[scene.joint_ids[0]]] = 3.0    # the arm swinging at HOME
    assert "arm kinetic energy" in plausible(model, data)
    data.qvel[:] = 0.0
    data.qpos[scene.arm_qadr[0]] += 0.2                  # shoulder turned: tcp ~9 cm away
    mujoco.mj_forward(model, data)
    assert "from HOME" in plausible(model, data)
    data.qpos[adr + 2] = np.nan
    assert plausible(model, data) == "non-finite state"


def test_classification_of_exceptions():
    assert classify_exception(ValueError("dt must be > 0"))[0] == "detected"
    assert classify_exception(ValueError(""))[0] == "undetected"
    assert classify_exception(ZeroDivisionError("x"))[0] == "undetected"


def test_event_sanity_check_on_hand_made_streams():
    import numpy as np
    from sebvs.numerics import dvs_cases
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
