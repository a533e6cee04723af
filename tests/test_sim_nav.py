"""The navigation scene: config, drive kinematics, scripted target, truth vs rendering."""
import math

import numpy as np
import pytest

from sebvs.sim import make_scene  # sets MUJOCO_GL before mujoco
from sebvs.sim.render import FrameRenderer
from sebvs.sim.trajectories import TrajectoryConfig, WaypointTrajectory

import mujoco  # noqa: E402


def build(**config):
    scene = make_scene("nav", **config)
    model = scene.compile()
    data = mujoco.MjData(model)
    scene.reset(model, data, np.random.default_rng(0))
    return scene, model, data


def front_rgb(size: int, **config) -> np.ndarray:
    """The front camera's first frame of a freshly reset scene."""
    scene, model, data = build(**config)
    scene.kinematics(model, data)
    with FrameRenderer(model, size, size) as r:
        r.update(data, "front")
        return r.rgb()


def drive(scene, model, data, command, seconds):
    scene.apply_command(model, data, np.asarray(command, float))
    for _ in range(round(seconds / model.opt.timestep)):
        scene.scripted(model, data)
        mujoco.mj_step(model, data)


# ---------------------------------------------------------------- config and model
def test_unknown_and_bad_config_keys_are_named():
    with pytest.raises(ValueError, match="'colour'"):
        make_scene("nav", colour="red")
    with pytest.raises(ValueError, match="variant"):
        make_scene("nav", variant="moon")
    with pytest.raises(ValueError, match="width"):
        make_scene("nav", width=0)
    with pytest.raises(ValueError, match="integrator"):
        make_scene("nav", integrator="leapfrog")
    with pytest.raises(ValueError, match="unknown scene"):
        make_scene("boat")


def test_mjcf_is_deterministic_and_fast_to_render():
    a, b = make_scene("nav", variant="outdoor"), make_scene("nav", variant="outdoor")
    assert a.mjcf() == b.mjcf()
    xml = a.mjcf()
    assert 'offsamples="0"' in xml and 'shadowsize="0"' in xml
    assert 'castshadow="true"' not in xml
    assert 'castshadow="true"' in make_scene("nav", shadows=True).mjcf()
    for variant in ("indoor", "outdoor"):
        model = make_scene("nav", variant=variant).compile()
        assert {model.camera(i).name for i in range(model.ncam)} == {"front", "overview"}


def test_floor_and_target_colour_keys():
    """The default scene is the one every dataset was recorded in (its MJCF must not move);
    plain swaps the checker for its mean grey; target_rgb colours the cube."""
    default = make_scene("nav").mjcf()
    assert make_scene("nav", floor="checker", target_rgb=[0.9, 0.15, 0.1]).mjcf() == default
    assert 'builtin="checker" rgb1="0.55 0.55 0.5" rgb2="0.3 0.3 0.32"' in default
    assert 'rgba="0.9 0.15 0.1 1"' in default
    plain = make_scene("nav", floor="plain", target_rgb=(1, 0.5, 0.45)).mjcf()
    assert 'builtin="flat" rgb1="0.425 0.425 0.41" rgb2="0.425 0.425 0.41"' in plain
    assert 'rgba="1 0.5 0.45 1"' in plain
    for bad in ([1, 0, 0, 1], [1.5, 0, 0], "red", [True, 0, 0]):
        with pytest.raises(ValueError, match="target_rgb"):
            make_scene("nav", target_rgb=bad)
    with pytest.raises(ValueError, match="floor"):
        make_scene("nav", floor="carpet")


def test_plain_floor_has_no_checker_edges():
    edges = {}
    for floor in ("checker", "plain"):
        rows = front_rgb(64, floor=floor)[40:].astype(float).mean(axis=2)   # below the horizon
        edges[floor] = np.abs(np.diff(rows, axis=1)).mean()   # the light falls off smoothly
    assert edges["plain"] < 0.6 * edges["checker"], edges


def test_integrator_and_timestep_applied():
    _, model, _ = build(integrator="rk4", timestep=0.004)
    assert model.opt.integrator == mujoco.mjtIntegrator.mjINT_RK4
    assert model.opt.timestep == 0.004
    assert model.opt.enableflags & mujoco.mjtEnableBit.mjENBL_ENERGY


# ---------------------------------------------------------------- drive
def test_forward_command_drives_along_heading():
    scene, model, data = build()
    drive(scene, model, data, [1.0, 0.0], 1.0)
    x, y, yaw = scene.robot_pose(data)
    assert 1.2 < x < 1.5 and abs(y) < 1e-6 and abs(yaw) < 1e-6   # v_max 1.5 m/s, 50 ms lag
    drive(scene, model, data, [-0.5, 0.0], 2.0)
    assert scene.robot_pose(data)[0] < x - 1.0                   # reverse


def test_turn_sign_and_rate_follow_unicycle_model():
    scene, model, data = build()
    drive(scene, model, data, [0.0, 0.5], 1.0)                   # +w turns left (CCW)
    x, y, yaw = scene.robot_pose(data)
    assert yaw > 0.8 and abs(x) < 1e-3 and abs(y) < 1e-3
    w_rate = data.qvel[model.jnt_dofadr[model.joint("yaw").id]]
    assert w_rate == pytest.approx(0.5 * scene.config["w_max"], rel=0.02)  # no skid scrub
    # Driving forward while turning: velocity follows the heading (no side slip)
    drive(scene, model, data, [0.6, 0.3], 2.0)
    _, _, yaw = scene.robot_pose(data)
    vx, vy = data.qvel[0], data.qvel[1]
    assert math.hypot(vx, vy) == pytest.approx(0.6 * scene.config["v_max"], rel=0.03)
    assert math.atan2(vy, vx) == pytest.approx(math.atan2(math.sin(yaw), math.cos(yaw)),
                                               abs=0.05)


def test_commands_are_clipped_and_non_finite_rejected():
    scene, model, data = build()
    scene.apply_command(model, data, np.array([1e6, -1e6]))
    assert data.ctrl[0] == scene.config["v_max"] and data.ctrl[1] == -scene.config["w_max"]
    before = data.ctrl.copy()
    for bad in ([np.nan, 0.0], [0.0, np.inf]):
        with pytest.raises(ValueError, match="finite"):
            scene.apply_command(model, data, np.array(bad))
    with pytest.raises(ValueError, match="shape"):
        scene.apply_command(model, data, np.zeros(3))
    np.testing.assert_array_equal(data.ctrl, before)


def test_walls_stop_the_robot():
    scene, model, data = build(arena=3.0)
    drive(scene, model, data, [1.0, 0.0], 5.0)
    assert 2.0 < scene.robot_pose(data)[0] < 3.0                 # wall at x = 3


# ---------------------------------------------------------------- target
def _path(seed, speed="nominal", seconds=20.0):
    scene, model, data = build(target_speed=speed)
    scene.reset(model, data, np.random.default_rng(seed))
    mid = scene.target_mocap
    out = []
    for _ in range(round(seconds / model.opt.timestep)):
        scene.scripted(model, data)
        out.append(data.mocap_pos[mid].copy())
    return np.array(out)


def test_target_trajectory_is_seeded_and_reproducible():
    a, b, c = _path(3, seconds=5), _path(3, seconds=5), _path(4, seconds=5)
    np.testing.assert_array_equal(a, b)
    assert np.abs(a - c).max() > 0.1


def test_target_speeds_stops_and_bounds():
    dt = 0.002
    speeds = {}
    for cond in ("slow", "nominal", "fast"):
        p = _path(1, cond, seconds=20)
        v = np.linalg.norm(np.diff(p[:, :2], axis=0), axis=1) / dt
        speeds[cond] = np.median(v[v > 1e-6])
        assert (v < 1e-9).mean() > 0.0 or cond == "slow"    # some stops (seed-dependent)
        assert np.abs(p[:, :2]).max() <= 5.0 + 1e-9          # arena 6 m, 1 m margin
        assert np.allclose(p[:, 2], 0.1)
    assert speeds["slow"] < speeds["nominal"] < speeds["fast"]
    assert 0.15 < speeds["slow"] < 0.35 and 0.7 < speeds["fast"] < 1.4


def test_trajectory_sudden_turns_snap_heading():
    cfg = TrajectoryConfig(p_sudden=1.0, p_stop=0.0, max_turn_rate=0.5)
    tr = WaypointTrajectory(np.zeros(2), 0.0, cfg, np.random.default_rng(0))
    headings = []
    for _ in range(20000):
        tr.step(0.002)
        headings.append(tr.heading)
    jumps = np.abs(np.diff(headings))
    assert jumps.max() > 0.3            # snaps, far beyond 0.5 rad/s * 2 ms
    assert tr.n_waypoints > 2


# ---------------------------------------------------------------- truth and rendering
@pytest.mark.parametrize("variant", ["indoor", "outdoor"])
def test_truth_bbox_matches_segmentation(variant):
    scene, model, data = build(variant=variant, width=160, height=120, fovy=80.0)
    gid = model.geom("target").id
    checked = 0
    with FrameRenderer(model, 120, 160) as r:
        seg = np.empty((120, 160, 2), np.int32)
        for seed in range(6):
            scene.reset(model, data, np.random.default_rng(seed))
            drive(scene, model, data, [0.2, 0.1 * (seed - 3)], 0.5)
            truth = scene.truth(model, data)       # also updates kinematics
            r.update(data, "front")
            r.segmentation(seg)
            mask = (seg[..., 0] == gid) & (seg[..., 1] == int(mujoco.mjtObj.mjOBJ_GEOM))
            if not truth["visible"]:
                assert mask.sum() == 0
                continue
            ys, xs = np.nonzero(mask)
            box = np.array([xs.min(), ys.min(), xs.max() + 1, ys.max() + 1], float)
            assert np.abs(box - np.array(truth["bbox"])).max() <= 2.0, (box, truth["bbox"])
            cu, cv = truth["centroid"]
            assert box[0] <= cu <= box[2] and box[1] <= cv <= box[3]
            checked += 1
    assert checked >= 3


def test_state_round_trip_renders_the_same_image_with_flicker_and_blur():
    scene, model, data = build(lighting="flicker", flicker_hz=7.0)
    drive(scene, model, data, [0.3, 0.2], 0.37)
    cam_scene = make_scene("nav", lighting="flicker", flicker_hz=7.0)
    cam_model = cam_scene.compile()
    cam_data = mujoco.MjData(cam_model)
    state = scene.state(data)
    assert set(state) >= {"qpos", "mocap_pos", "mocap_quat", "light"}
    assert 0.25 < state["light"][0] <= 1.0
    cam_scene.set_state(cam_model, cam_data, state)
    cam_scene.kinematics(cam_model, cam_data)
    scene.kinematics(model, data)
    with FrameRenderer(model, 64, 64) as ra, FrameRenderer(cam_model, 64, 64) as rb:
        ra.update(data, "front")
        rb.update(cam_data, "front")
        a, b = ra.rgb(), rb.rgb()
        np.testing.assert_array_equal(a, b)
        luma = rb.luma(src=b)
        assert luma.shape == (64, 64) and luma.dtype == np.uint8
        # flicker: a dimmer light gives a darker frame
        dim = dict(state, light=np.array([0.3]))
        cam_scene.set_state(cam_model, cam_data, dim)
        rb.update(cam_data, "front")
        assert rb.rgb().mean() < b.mean() - 3
        # blur: identical sub-frames give the sharp image; moving ones differ from it
        cam_scene.set_state(cam_model, cam_data, state)

        def pose(s):
            cam_scene.set_state(cam_model, cam_data, s)
            cam_scene.kinematics(cam_model, cam_data)

        out = np.empty((64, 64, 3), np.uint8)
        rb.rgb_blurred(cam_data, "front", [state] * 3, out, pose)
        assert np.abs(out.astype(int) - b).max() <= 1
        moved = dict(state, qpos=state["qpos"] + np.array([0.0, 0.0, 0.2]))
        rb.rgb_blurred(cam_data, "front", [state, moved], out, pose)
        assert np.abs(out.astype(int) - b).mean() > 1.0
        depth = rb.depth()
        assert depth.dtype == np.float32 and 0.01 < np.median(depth) < 50


def test_low_light_is_darker():
    means = {lighting: front_rgb(48, lighting=lighting).mean() for lighting in ("nominal", "low")}
    assert means["low"] < 0.5 * means["nominal"]
