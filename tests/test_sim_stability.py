"""Divergence detection, and the issue's stiff and extreme cases for the nav robot under
every integrator: the sim stays stable or the monitor names the divergence; nothing hangs."""
import numpy as np
import pytest

from sebvs.sim import make_scene
from sebvs.sim.scene import INTEGRATORS
from sebvs.sim.stability import Limits, StabilityMonitor

import mujoco  # noqa: E402


def setup(**config):
    scene = make_scene("nav", **config)
    model = scene.compile()
    data = mujoco.MjData(model)
    scene.reset(model, data, np.random.default_rng(0))
    mon = StabilityMonitor(model, scene.limits())
    mon.reset(data)
    return scene, model, data, mon


def run(scene, model, data, mon, seconds, commands=None):
    """Step with the monitor; returns (reason or None, steps). Bounded: cannot hang."""
    n = round(seconds / model.opt.timestep)
    for i in range(n):
        if commands is not None and i % 25 == 0:
            scene.apply_command(model, data, commands(i))
        scene.scripted(model, data)
        mujoco.mj_step(model, data)
        why = mon.check(model, data)
        if why:
            return why, i + 1
    return None, n


# ---------------------------------------------------------------- the monitor itself
def test_monitor_passes_a_normal_episode():
    scene, model, data, mon = setup()
    why, _ = run(scene, model, data, mon, 3.0, lambda i: np.array([0.8, 0.5]))
    assert why is None


@pytest.mark.parametrize("poke,expect", [
    (lambda m, d: d.qvel.__setitem__(0, 40.0), "speed"),
    (lambda m, d: d.qvel.__setitem__(2, 80.0), "angular speed"),
    (lambda m, d: d.qpos.__setitem__(1, np.nan), "non-finite"),
    (lambda m, d: d.mocap_pos.__setitem__((0, 0), 1e3), "left the world bounds"),
    (lambda m, d: d.warning[mujoco.mjtWarning.mjWARN_BADQACC].__setattr__("number", 1),
     "BADQACC"),
])
def test_monitor_names_each_kind_of_divergence(poke, expect):
    scene, model, data, mon = setup()
    assert mon.check(model, data) is None
    poke(model, data)
    mujoco.mj_forward(model, data)
    why = mon.check(model, data)
    assert why is not None and why.startswith("diverged:") and expect in why, why


def test_monitor_detects_an_energy_jump():
    scene, model, data, mon = setup()
    mujoco.mj_forward(model, data)
    assert mon.check(model, data) is None            # sets the energy reference
    data.qvel[0] = 4.0                               # below the speed limit, +80 J
    mujoco.mj_forward(model, data)
    why = mon.check(model, data)
    assert why is not None and "energy jumped" in why


def test_monitor_on_a_free_body_model():
    xml = """<mujoco><option timestep="0.002"><flag energy="enable"/></option><worldbody>
      <geom type="plane" size="5 5 .1"/>
      <body name="box" pos="0 0 2"><freejoint/><geom type="box" size=".1 .1 .1"/></body>
      </worldbody></mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    mon = StabilityMonitor(model, Limits(bounds=(-5, 5, -5, 5, -1, 5), max_speed=10))
    mon.reset(data)
    assert mon.linear.tolist() == [True] * 3 + [False] * 3
    for _ in range(1000):                            # a 2 m drop, landing: fine
        mujoco.mj_step(model, data)
        assert mon.check(model, data) is None
    data.qvel[3] = 500.0                             # spinning beyond the limit
    assert "angular speed" in mon.check(model, data)


# ---------------------------------------------------------------- the stiff cases
CASES = {
    "stiff wheel servo": ({"servo_gain": 1e4}, lambda i: np.array([1.0, 1.0])),
    "timestep 0.01": ({"timestep": 0.01}, lambda i: np.array([1.0, -1.0])),
    "stiff servo at 0.01": ({"servo_gain": 1e3, "timestep": 0.01},
                            lambda i: np.array([1.0, (-1.0) ** (i // 25)])),
    "commands +-1e6": ({}, lambda i: np.array([1e6, -1e6]) * (-1) ** (i // 25)),
    "into the wall at 0.01": ({"timestep": 0.01, "arena": 3.0}, lambda i: np.array([1.0, 0.0])),
    # solref time constant 0.002 s < 2 x timestep 0.002, refsafe off
    "stiff wall contact": ({"contact_timeconst": 0.002, "arena": 3.0},
                           lambda i: np.array([1.0, 0.3 * (-1) ** (i // 50)])),
    "stiff wall contact at 0.01": ({"contact_timeconst": 0.002, "arena": 3.0, "timestep": 0.01},
                                   lambda i: np.array([1.0, 0.3 * (-1) ** (i // 50)])),
}


@pytest.mark.parametrize("integrator", sorted(INTEGRATORS))
@pytest.mark.parametrize("case", sorted(CASES))
def test_stiff_cases_stay_stable_or_are_detected(integrator, case):
    config, commands = CASES[case]
    scene, model, data, mon = setup(integrator=integrator, **config)
    why, steps = run(scene, model, data, mon, 3.0, commands)
    if why is None:
        assert np.isfinite(data.qpos).all() and np.isfinite(data.qvel).all()
        x, y, _ = scene.robot_pose(data)
        a = scene.config["arena"]
        assert abs(x) < a and abs(y) < a              # inside the walls
        speed = np.hypot(data.qvel[0], data.qvel[1])
        assert speed <= scene.config["v_max"] * 1.2
    else:
        assert why.startswith("diverged:")


@pytest.mark.parametrize("integrator", sorted(INTEGRATORS))
def test_nan_command_rejected_and_last_good_kept(integrator):
    scene, model, data, mon = setup(integrator=integrator)
    scene.apply_command(model, data, np.array([0.5, 0.2]))
    good = data.ctrl.copy()
    for bad in (np.array([np.nan, 0.0]), np.array([0.0, -np.inf])):
        with pytest.raises(ValueError):
            scene.apply_command(model, data, bad)
        np.testing.assert_array_equal(data.ctrl, good)
    why, _ = run(scene, model, data, mon, 0.5)
    assert why is None and np.isfinite(data.qpos).all()


def test_stiff_contact_diverges_except_under_discrete():
    """DESIGN.md 5 on this robot: a wall contact with time constant 0.002 s at timestep
    0.01 (refsafe off) blows up under euler and implicitfast, and the monitor says so; the
    discrete integrator stays stable (MuJoCo 4.0)."""
    config, commands = CASES["stiff wall contact at 0.01"]
    for integrator, diverges in (("euler", True), ("implicitfast", True), ("discrete", False)):
        scene, model, data, mon = setup(integrator=integrator, **config)
        why, _ = run(scene, model, data, mon, 3.0, commands)
        assert (why is not None) == diverges, (integrator, why)
        if diverges:
            assert "speed" in why


def test_kinetic_ceiling_matches_the_robot_and_catches_a_slow_pump():
    import mujoco
    import numpy as np
    from sebvs.sim import make_scene
    from sebvs.sim.nav import ROBOT_INERTIA_Z, ROBOT_MASS
    from sebvs.sim.stability import StabilityMonitor
    scene = make_scene("nav")
    model = scene.compile()
    robot = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "robot")
    assert model.body_subtreemass[robot] == np.float64(ROBOT_MASS)
    assert model.body_inertia[robot].max() <= ROBOT_INERTIA_Z
    data = mujoco.MjData(model)
    scene.reset(model, data, np.random.default_rng(0))
    mon = StabilityMonitor(model, scene.limits())
    mujoco.mj_forward(model, data)
    assert mon.check(model, data) is None
    # under the speed limit (5.5 m/s) but far above what the drive can give
    data.qvel[:2] = [3.5, 3.5]
    mujoco.mj_forward(model, data)
    mujoco.mj_energyVel(model, data)
    reason = StabilityMonitor(model, scene.limits()).check(model, data)
    assert reason and "kinetic energy" in reason
