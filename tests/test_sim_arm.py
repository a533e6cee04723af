"""The manipulation scene: UR5 kinematics, HOME, the wrist camera's truth, the workspace and
leftmost rules, the conveyor, commands, the grasp at the end of an episode, and the stiff
and extreme cases under every integrator."""
import math

import numpy as np
import pytest

from sebvs.sim import make_scene  # sets MUJOCO_GL before mujoco
from sebvs.sim.arm import CLEARANCE, HOME_POSE, Y_LIMIT
from sebvs.sim.arm_model import BELT_TOP, JOINTS, STROKE, dh_forward
from sebvs.sim.ik import mat_to_rpy, rpy_to_mat
from sebvs.sim.render import FrameRenderer
from sebvs.sim.scene import INTEGRATORS
from sebvs.sim.stability import StabilityMonitor

import mujoco  # noqa: E402


def build(seed=0, **config):
    scene = make_scene("arm", **config)
    model = scene.compile()
    data = mujoco.MjData(model)
    scene.reset(model, data, np.random.default_rng(seed))
    return scene, model, data


def settle(scene, model, data, seconds=0.3):
    for _ in range(round(seconds / model.opt.timestep)):
        scene.scripted(model, data)
        mujoco.mj_step(model, data)


def place(scene, model, data, i, x, y, yaw=0.0):
    """Put cube i on the belt at (x, y) by hand."""
    adr = scene.cube_qadr[i]
    data.qpos[adr:adr + 7] = [x, y, BELT_TOP + scene.halves[i], math.cos(yaw / 2), 0, 0,
                              math.sin(yaw / 2)]
    data.qvel[model.jnt_dofadr[model.body_jntadr[scene.cube_body[i]]]:][:6] = 0
    mujoco.mj_forward(model, data)


# ---------------------------------------------------------------- config and kinematics
def test_bad_config_is_named():
    for kw, key in (({"conveyor": "fast"}, "conveyor"), ({"objects": 0}, "objects"),
                    ({"cube_half": [0.03, 0.02]}, "cube_half"), ({"belt_speed": -1}, "belt_speed"),
                    ({"cube_half": [0.02, 0.04]}, "stroke"), ({"grasp_at_end": 1}, "grasp_at_end"),
                    ({"tint": 1}, "'tint'")):
        with pytest.raises(ValueError, match=key):
            make_scene("arm", **kw)


def test_forward_kinematics_are_the_ur5_dh_parameters():
    scene, model, data = build()
    flange = model.body("gripper").id
    rng = np.random.default_rng(1)
    for _ in range(20):
        q = rng.uniform(-math.pi, math.pi, 6)
        data.qpos[scene.arm_qadr] = q
        mujoco.mj_kinematics(model, data)
        T = dh_forward(q)
        np.testing.assert_allclose(data.xpos[flange], T[:3, 3], atol=1e-9)
        np.testing.assert_allclose(data.xmat[flange].reshape(3, 3), T[:3, :3], atol=1e-9)


def test_rpy_round_trip():
    for r, p, y in ((math.pi, 0.0, 0.3), (0.2, -0.4, 1.2), (-2.0, 1.0, -3.0)):
        np.testing.assert_allclose(rpy_to_mat(*mat_to_rpy(rpy_to_mat(r, p, y))),
                                   rpy_to_mat(r, p, y), atol=1e-12)


@pytest.mark.parametrize("integrator", ["implicitfast", "discrete"])
def test_arm_holds_home_under_gravity(integrator):
    scene, model, data = build(integrator=integrator, timestep=0.001)
    settle(scene, model, data, 2.0)
    np.testing.assert_allclose(data.site_xpos[scene.tcp], HOME_POSE[:3], atol=1e-3)
    R = data.site_xmat[scene.tcp].reshape(3, 3)
    np.testing.assert_allclose(R, rpy_to_mat(*HOME_POSE[3:]), atol=1e-3)
    assert R[2, 2] < -0.999                           # the tool points down


def test_gripper_stroke_is_85_mm():
    scene, model, data = build()
    left, right = model.geom("pad_l").id, model.geom("pad_r").id

    def gap():      # between the pads' inner faces
        mujoco.mj_forward(model, data)
        return np.linalg.norm(data.geom_xpos[left] - data.geom_xpos[right]) \
            - 2 * model.geom_size[left][1]

    assert abs(gap() - STROKE) < 1e-6
    data.qpos[scene.finger_qadr] = STROKE / 2
    assert abs(gap()) < 1e-6


# ---------------------------------------------------------------- truth and the task's rules
def test_truth_matches_the_wrist_image_and_the_expert_pose_rule():
    scene, model, data = build(objects=1)
    place(scene, model, data, 0, 0.47, 0.05, yaw=0.3)
    settle(scene, model, data)
    t = scene.truth(model, data)
    c = t["cubes"][0]
    assert t["target"] == 0 and t["mode"] == "grasp" and c["visible"]
    x, y, z = c["pos"]
    assert abs(t["expert_pose"][2] - (z + c["half"] + CLEARANCE)) < 1e-9
    assert t["expert_pose"][3:5] == [math.pi, 0.0]
    assert abs(c["yaw"] - 0.3) < 0.01
    with FrameRenderer(model, 160, 160) as r:
        r.update(data, "wrist")
        seg = r.segmentation()
    ys, xs = np.nonzero((seg[..., 0] == scene.cube_geom[0]) & (seg[..., 1] == mujoco.mjtObj.mjOBJ_GEOM))
    assert len(xs) > 30
    # the projected centre lies within the cube's silhouette, near its middle
    assert abs(xs.mean() + 0.5 - c["uv"][0]) < 2.5 and abs(ys.mean() + 0.5 - c["uv"][1]) < 2.5


def test_home_image_axes_right_is_world_y_up_is_toward_the_robot():
    scene, model, data = build(objects=2)
    place(scene, model, data, 0, 0.45, -0.1)
    place(scene, model, data, 1, 0.55, 0.2)
    t = scene.truth(model, data)
    (u0, v0), (u1, v1) = t["cubes"][0]["uv"], t["cubes"][1]["uv"]
    assert u1 > u0 and v1 > v0                          # +y is right, +x is down
    assert t["target"] == 0                             # leftmost = smallest y = smallest u


def test_beyond_the_workspace_limit_is_home():
    scene, model, data = build(objects=1)
    place(scene, model, data, 0, 0.45, Y_LIMIT + 0.03)
    t = scene.truth(model, data)
    assert t["cubes"][0]["visible"]
    assert t["mode"] == "home_workspace" and t["expert_pose"] == list(HOME_POSE)
    place(scene, model, data, 0, 0.45, -0.7)            # out of view
    t = scene.truth(model, data)
    assert not t["cubes"][0]["visible"] and t["mode"] == "home_none"


def test_cluttered_episodes_are_seeded_apart_and_coloured():
    a, ma, da = build(seed=3, objects=4)
    b, mb, db = build(seed=3, objects=4)
    np.testing.assert_array_equal(da.qpos, db.qpos)
    pos = da.xpos[a.cube_body]
    d = np.linalg.norm(pos[:, None, :2] - pos[None, :, :2], axis=2) + np.eye(4)
    assert d.min() > 2 * 0.0225 * 1.5
    colours = {tuple(ma.geom_rgba[g, :3]) for g in a.cube_geom}
    assert len(colours) == 4
    c, mc, dc = build(seed=4, objects=4)
    assert not np.array_equal(da.qpos, dc.qpos)


# ---------------------------------------------------------------- the conveyor
def test_moving_belt_carries_cubes_at_its_speed_and_static_does_not():
    scene, model, data = build(conveyor="moving", belt_speed=0.1, objects=1)
    place(scene, model, data, 0, 0.45, -0.2)
    settle(scene, model, data, 0.5)                     # start-up and settle
    y0 = data.xpos[scene.cube_body[0], 1]
    settle(scene, model, data, 1.0)
    assert abs(data.xpos[scene.cube_body[0], 1] - y0 - 0.1) < 0.005
    scene, model, data = build(conveyor="static", objects=1)
    y0 = data.xpos[scene.cube_body[0], 1]
    settle(scene, model, data, 1.0)
    assert abs(data.xpos[scene.cube_body[0], 1] - y0) < 1e-3


# ---------------------------------------------------------------- commands and the grasp
def test_commands_are_validated_clipped_and_wrapped():
    scene, model, data = build()
    np.testing.assert_array_equal(scene.idle_command(), HOME_POSE)
    for bad in (np.zeros(5), np.array([0.4, 0, 0.2, np.nan, 0, 0])):
        with pytest.raises(ValueError):
            scene.apply_command(model, data, bad)
    scene.apply_command(model, data, np.array([5.0, -5.0, 0.2, 3 * math.pi, 0.0, -0.5]))
    p = scene.command_pose
    assert p[0] == 0.9 and p[1] == -0.9
    assert abs(p[3] - math.pi) < 1e-9 and p[5] == -0.5
    np.testing.assert_array_equal(data.ctrl[scene.arm_act], scene.home_q)   # not executed


def test_finish_grasps_the_last_command():
    scene, model, data = build(objects=1, timestep=0.001)
    settle(scene, model, data)
    t = scene.truth(model, data)
    scene.apply_command(model, data, np.array(t["expert_pose"]))
    out = scene.finish(model, data)
    assert out["outcome"] == "lifted_and_held", out
    assert out["grasp"]["lift_m"] > 0.05


@pytest.mark.parametrize("command,outcome", [
    ("home", "home_missed"), ("offset", "not_grasped")])
def test_finish_reports_wrong_commands(command, outcome):
    scene, model, data = build(objects=1, timestep=0.001)
    settle(scene, model, data)
    pose = np.array(scene.truth(model, data)["expert_pose"])
    if command == "home":
        pose = np.array(HOME_POSE)
    else:
        pose[0] += 0.07                                 # 7 cm beside the cube
    scene.apply_command(model, data, pose)
    assert scene.finish(model, data)["outcome"] == outcome


def test_finish_on_home_when_nothing_is_graspable():
    scene, model, data = build(objects=1)
    place(scene, model, data, 0, 0.45, Y_LIMIT + 0.05)
    scene.apply_command(model, data, np.array(HOME_POSE))
    assert scene.finish(model, data)["outcome"] == "home_correct"
    scene.apply_command(model, data, np.array([0.45, 0.5, 0.2, math.pi, 0, 0]))
    assert scene.finish(model, data)["outcome"] == "grasp_unwanted"
    assert make_scene("arm", grasp_at_end=False).finish(model, data) == {}


def test_state_round_trip_renders_the_same_wrist_image():
    scene, model, data = build(objects=3, lighting="flicker", conveyor="moving")
    settle(scene, model, data, 0.37)
    other = make_scene("arm", objects=3, lighting="flicker", conveyor="moving")
    m2 = other.compile()
    d2 = mujoco.MjData(m2)
    # the cubes' sizes and colours are drawn per episode: they travel in the state
    assert not np.array_equal(m2.geom_size, model.geom_size)
    other.set_state(m2, d2, scene.state(data))
    other.kinematics(m2, d2)
    np.testing.assert_array_equal(m2.geom_size, model.geom_size)
    scene.kinematics(model, data)
    with FrameRenderer(model, 96, 96) as r1, FrameRenderer(m2, 96, 96) as r2:
        r1.update(data, "wrist")
        r2.update(d2, "wrist")
        np.testing.assert_array_equal(r1.rgb(), r2.rgb())


# ---------------------------------------------------------------- stiff and extreme cases
STIFF = {
    "stiff joint servo": {"servo_gain": 1e4},
    "timestep 0.01": {"timestep": 0.01},
    # solref time constant 0.002 s, below 2 x the timestep, refsafe off
    "stiff contact": {"contact_timeconst": 0.002, "timestep": 0.002},
    "stiff contact at 0.01": {"contact_timeconst": 0.002, "timestep": 0.01},
    "conveyor 3 m/s": {"conveyor": "moving", "belt_speed": 3.0},
    "dropped from 2 m": {"drop_height": 2.0},
}


@pytest.mark.parametrize("integrator", sorted(INTEGRATORS))
@pytest.mark.parametrize("case", sorted(STIFF))
def test_stiff_cases_stay_stable_or_are_detected(integrator, case):
    config = {"timestep": 0.001, "objects": 3, **STIFF[case], "integrator": integrator}
    scene, model, data = build(**config)
    mon = StabilityMonitor(model, scene.limits())
    mon.reset(data)
    why = None
    for _ in range(round(2.0 / model.opt.timestep)):
        scene.scripted(model, data)
        mujoco.mj_step(model, data)
        why = mon.check(model, data)
        if why:
            break
    if why is not None:
        assert why.startswith("diverged:")
        return
    # stable: a physical state, the arm still at HOME, every cube on the belt or the floor
    assert np.isfinite(data.qpos).all() and np.isfinite(data.qvel).all()
    np.testing.assert_allclose(data.site_xpos[scene.tcp], HOME_POSE[:3], atol=5e-3)
    z = data.xpos[scene.cube_body, 2]
    assert (z < 2.5).all() and (z > -0.75).all()
    on_belt = z > BELT_TOP
    assert (z[on_belt] < BELT_TOP + 0.06).all() or STIFF[case].get("drop_height")


@pytest.mark.parametrize("integrator", sorted(INTEGRATORS))
def test_nan_command_rejected_and_last_good_kept(integrator):
    scene, model, data = build(integrator=integrator)
    good = np.array([0.45, 0.0, 0.2, math.pi, 0.0, 0.1])
    scene.apply_command(model, data, good)
    with pytest.raises(ValueError):
        scene.apply_command(model, data, np.array([np.inf, 0, 0.2, math.pi, 0, 0]))
    np.testing.assert_allclose(scene.command_pose, good)


def test_monitor_names_a_cube_sunk_in_the_belt_and_a_hopping_cube():
    scene, model, data = build(objects=1)
    mon = StabilityMonitor(model, scene.limits())
    mon.reset(data)
    adr = scene.cube_qadr[0]
    data.qpos[adr + 2] = BELT_TOP - 0.015               # centre inside the belt, at rest
    why = None
    for _ in range(100):
        mujoco.mj_forward(model, data)
        data.time += model.opt.timestep
        why = why or mon.check(model, data)
    assert why and "sank into 'belt'" in why, why
    scene, model, data = build(objects=1)
    mon = StabilityMonitor(model, scene.limits())
    mon.reset(data)
    data.qpos[adr + 2] += 0.03                          # lifted 3 cm with nothing touching it
    mujoco.mj_forward(model, data)
    why = None
    for _ in range(20):         # the free-body checks run every few steps
        data.time += model.opt.timestep
        why = why or mon.check(model, data)
    assert why and "rose" in why and "'cube0'" in why, why


def test_a_cube_launched_by_the_gripper_may_fly_up_to_its_apex():
    """A touch by the robot resets the reference height to where the launch can take the
    cube (z + v_z^2 / 2g); above that apex, with nothing touching it, it is climbing."""
    scene, model, data = build(objects=1)
    mon = StabilityMonitor(model, scene.limits())
    mon.reset(data)
    watch = mon.bodies
    body, adr = scene.cube_body[0], scene.cube_qadr[0]
    dof = model.jnt_dofadr[model.body_jntadr[body]]
    pad = data.geom_xpos[model.geom("pad_l").id].copy()
    out = np.sign(pad[1] - data.site_xpos[scene.tcp][1])   # away from the other pad
    half = scene.halves[0]

    def at(z_offset, vz, touching):
        # outside the left pad (overlapping it by 1 mm when touching), moving up at vz
        gap = -0.001 if touching else 0.05
        data.qpos[adr:adr + 7] = [pad[0], pad[1] + out * (0.004 + half + gap),
                                  pad[2] + z_offset, 1, 0, 0, 0]
        data.qvel[:] = 0
        data.qvel[dof + 2] = vz
        mujoco.mj_forward(model, data)
        why = None
        for _ in range(watch.every):
            data.time += model.opt.timestep
            why = why or watch.check(data)
        return why

    assert at(0.0, 1.0, touching=True) is None          # launched: apex 5.1 cm up
    assert mon.bodies.z_ref[0] == pytest.approx(data.xpos[body, 2] + 1 / (2 * 9.81), abs=1e-3)
    assert at(0.045, 0.1, touching=False) is None       # below the apex: fine
    why = at(0.075, 0.0, touching=False)                # 2.4 cm above it: climbing
    assert why and "rose" in why, why


def test_joint_names_and_handles():
    scene, model, _ = build(objects=2)
    h = scene.grasp_handles(model, 1)
    assert h.arm_joints == list(JOINTS) and h.object_body == "cube1"
    for name in h.arm_actuators + h.gripper_actuators:
        model.actuator(name)


def test_cubes_rest_on_the_belt_at_their_drawn_size():
    """Sizes are drawn per episode after compiling: a cube must still rest on its face
    (compiled at the largest size, collision bounds stay valid) with a cube's inertia."""
    scene, model, data = build(seed=5, objects=4)
    settle(scene, model, data, 1.0)
    z = data.xpos[scene.cube_body, 2]
    np.testing.assert_allclose(z, BELT_TOP + scene.halves, atol=1e-3)
    for body, half in zip(scene.cube_body, scene.halves):
        np.testing.assert_allclose(model.body_inertia[body], 0.1 * (2 * half) ** 2 / 6)


def test_a_running_belt_moves_its_skin_and_the_texture_wraps_seamlessly():
    from sebvs.sim.arm_model import SKIN_PERIOD
    scene, model, data = build(conveyor="moving", belt_speed=0.1, objects=1)
    y0 = data.mocap_pos[scene.skin, 1]
    settle(scene, model, data, 0.5)
    from sebvs.sim.arm import BELT_ACCEL
    moved = (data.mocap_pos[scene.skin, 1] - y0) % SKIN_PERIOD
    dt = model.opt.timestep
    # the surface speed applied at each step, start-up ramp included
    travelled = sum(min(0.1, BELT_ACCEL * k * dt) * dt for k in range(round(0.5 / dt)))
    assert abs(moved - travelled % SKIN_PERIOD) < 1e-9
    with FrameRenderer(model, 96, 96) as r:
        images = []
        for shift in (0.0, SKIN_PERIOD, SKIN_PERIOD / 3):
            data.mocap_pos[scene.skin, 1] = y0 + shift
            mujoco.mj_forward(model, data)
            r.update(data, "wrist")
            images.append(r.rgb().astype(int))
    # one period: the same picture (but for rasterisation rounding, a few DN)
    assert np.abs(images[0] - images[1]).max() <= 3
    assert (np.abs(images[0] - images[2]).max(axis=2) > 2).sum() > 100   # else: it moved
