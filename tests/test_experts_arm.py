"""The arm expert's geometry on a small MuJoCo scene of its own (a cube on a table under a
downward camera): object position and yaw from rgb + depth + intrinsics, pre-grasp pose,
HOME beyond the workspace and with nothing in view, leftmost of several cubes."""
import math

import numpy as np
import pytest

from sebvs.sim import render  # noqa: F401  (sets MUJOCO_GL before mujoco is imported)
from sebvs.sim.render import FrameRenderer

import mujoco  # noqa: E402

from sebvs.experts.arm import (ArmExpertConfig, CameraPose, fold_yaw,  # noqa: E402
                               pregrasp_from_images)
from sebvs.experts.detector import ColorDetector  # noqa: E402

H = W = 160
HALF = 0.025


def scene(cubes, cam_pos=(0.3, 0.1, 0.55), xyaxes="1 0 0 0 1 0"):
    bodies = "\n".join(
        f'<body pos="{x} {y} {HALF}" euler="0 0 {yaw}"><geom type="box" size="{HALF} {HALF} {HALF}" '
        f'rgba="0.9 0.15 0.1 1"/></body>' for x, y, yaw in cubes)
    xml = f"""<mujoco><compiler angle="radian"/><visual><quality offsamples="0" shadowsize="0"/></visual>
    <worldbody><light pos="0 0 2" dir="0 0 -1" castshadow="false"/>
    <geom type="plane" size="2 2 0.1" rgba="0.5 0.5 0.5 1"/>{bodies}
    <camera name="wrist" pos="{' '.join(map(str, cam_pos))}" xyaxes="{xyaxes}" fovy="60"/>
    </worldbody></mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    with FrameRenderer(model, H, W) as r:
        r.update(data, "wrist")
        rgb, depth = r.rgb(), r.depth()
    cid = model.camera("wrist").id
    cam = CameraPose(pos=data.cam_xpos[cid].copy(), mat=data.cam_xmat[cid].reshape(3, 3).copy(),
                     fovy=float(model.cam_fovy[cid]), width=W, height=H)
    return rgb, depth, cam


def test_projection_round_trip():
    _, _, cam = scene([(0.3, 0.1, 0.0)], cam_pos=(0.2, 0.0, 0.5), xyaxes="1 0 0 0 0.8 0.6")
    pts = np.array([[0.3, 0.1, 0.0], [0.1, -0.05, 0.05]])
    uv = cam.project(pts)
    d = -((pts - cam.pos) @ cam.mat)[:, 2]
    np.testing.assert_allclose(cam.backproject(uv[:, 0], uv[:, 1], d), pts, atol=1e-9)


@pytest.mark.parametrize("x,y,yaw,cam_pos,xyaxes", [
    (0.30, 0.10, 0.3, (0.3, 0.1, 0.55), "1 0 0 0 1 0"),      # straight down, centred
    (0.36, 0.05, -0.6, (0.3, 0.1, 0.55), "1 0 0 0 1 0"),     # off centre
    (0.30, 0.20, 1.2, (0.3, 0.0, 0.5), "1 0 0 0 0.94 0.34"),  # slanted view (side faces seen)
])
def test_pregrasp_pose_from_rgb_and_depth(x, y, yaw, cam_pos, xyaxes):
    rgb, depth, cam = scene([(x, y, yaw)], cam_pos, xyaxes)
    cfg = ArmExpertConfig(clearance=0.1)
    pose, det, mode = pregrasp_from_images(rgb, depth, cam, ColorDetector(), cfg)
    assert mode == "grasp" and det is not None and pose.dtype == np.float32
    # top-face centre within 3 mm in xy, 2 mm in height; yaw within 3 deg (mod 90)
    assert np.hypot(pose[0] - x, pose[1] - y) < 0.003, pose
    assert abs(pose[2] - (2 * HALF + 0.1)) < 0.002, pose
    assert abs(fold_yaw(pose[5] - yaw)) < math.radians(3.0), (pose[5], yaw)
    assert pose[3] == pytest.approx(math.pi) and pose[4] == 0.0


def test_home_beyond_the_workspace_and_with_nothing_seen():
    cfg = ArmExpertConfig()
    rgb, depth, cam = scene([(0.3, 0.47, 0.0)], cam_pos=(0.3, 0.47, 0.5))
    pose, det, mode = pregrasp_from_images(rgb, depth, cam, ColorDetector(), cfg)
    assert mode == "home_workspace" and det is not None
    np.testing.assert_allclose(pose, np.array(cfg.home, np.float32))
    rgb, depth, cam = scene([(0.3, 0.1, 0.0)], cam_pos=(1.5, 1.5, 0.5))   # looks elsewhere
    pose, det, mode = pregrasp_from_images(rgb, depth, cam, ColorDetector(), cfg)
    assert mode == "home_none" and det is None
    np.testing.assert_allclose(pose, np.array(cfg.home, np.float32))


def test_leftmost_of_several_cubes():
    cubes = [(0.36, 0.12, 0.2), (0.24, 0.08, -0.3), (0.31, 0.02, 0.5)]
    rgb, depth, cam = scene(cubes)
    pose, _, mode = pregrasp_from_images(rgb, depth, cam, ColorDetector(), ArmExpertConfig())
    assert mode == "grasp" and abs(pose[0] - 0.24) < 0.003       # image u grows with world x here
    pose, _, _ = pregrasp_from_images(rgb, depth, cam, ColorDetector(),
                                      ArmExpertConfig(leftmost="-world_y"))
    assert abs(pose[1] - 0.12) < 0.003


def test_target_lead_aims_where_a_steadily_moving_target_will_be():
    from sebvs.experts.arm import TargetLead
    lead = TargetLead(lead_s=0.1)
    assert np.allclose(lead.update(0.0, [0.5, 0.0]), 0.0)        # one sighting: no velocity
    for k in range(1, 4):
        off = lead.update(0.1 * k, [0.5, 0.025 * k])              # 25 cm/s along +y
        assert np.allclose(off, [0.0, 0.025]), off
    # another cube becomes the target 8 cm behind: a 0.8 m/s jump keeps the belt's velocity
    assert np.allclose(lead.update(0.4, [0.5, 0.075 - 0.08]), [0.0, 0.025])
    assert np.allclose(lead.update(0.5, [0.5, 0.075 - 0.08 + 0.025]), [0.0, 0.025])
    # no target: no offset, and the next sighting is not paired with a stale position
    assert np.allclose(lead.update(0.6, None), 0.0)
    assert np.allclose(lead.update(0.7, [0.3, 0.3]), [0.0, 0.025])
    lead.reset()
    assert np.allclose(lead.update(0.8, [0.3, 0.4]), 0.0)
    assert np.allclose(TargetLead(0.0).update(1.0, [1, 1]), 0.0)
    for bad in (-0.1, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="lead_s"):
            TargetLead(bad)
    with pytest.raises(ValueError, match="max_speed"):
        TargetLead(0.1, max_speed=0.0)


def test_target_lead_is_not_moved_by_the_pose_it_shifts():
    """The expert passes a view of its pose and then shifts that pose by the lead
    (actors/expert.py): the sighting kept for the next velocity must be the unshifted one.
    Keeping the view made the velocity alternate between the belt's and zero, so the
    lead reached every other tick only."""
    from sebvs.experts.arm import TargetLead
    lead = TargetLead(lead_s=0.1)
    for k in range(6):
        pose = np.array([0.5, -0.1 + 0.025 * k, 0.1, np.pi, 0.0, 0.0])
        pose[:2] += lead.update(0.1 * k, pose[:2])
        assert np.allclose(pose[:2], [0.5, -0.1 + 0.025 * k + (0.025 if k else 0.0)]), k


def test_leading_poses_score_against_the_next_ticks_cube():
    """The arm tracker's reference (sebvs.experts.arm.leading_poses): on a belt at 15 cm/s
    with a 0.1 s lead at 10 Hz, each grasp pose after the first lands where the cube is at
    the next tick; home ticks keep their pose and restart the velocity estimate."""
    from sebvs.experts.arm import leading_poses
    from sebvs.sim.arm import HOME_POSE
    times = 0.1 * np.arange(6)
    cube_y = -0.1 + 0.15 * times
    poses = [[0.5, y, 0.1, np.pi, 0.0, 0.2] for y in cube_y]
    modes = ["grasp"] * 6
    poses[3], modes[3] = list(HOME_POSE), "home_none"       # the cube lost for one tick
    led = leading_poses(poses, modes, times, 0.1)
    assert led.shape == (6, 6)
    assert np.allclose(led[0], poses[0])                     # one sighting: no velocity yet
    for k in (1, 2, 5):
        assert np.allclose(led[k, :2], [0.5, cube_y[k] + 0.015]), k
        assert np.allclose(led[k, 2:], poses[k][2:])
    assert np.allclose(led[3], HOME_POSE)
    # after the gap the belt's velocity is kept (as the expert keeps it)
    assert np.allclose(led[4, :2], [0.5, cube_y[4] + 0.015])
    assert np.array_equal(leading_poses(poses, modes, times, 0.0), np.array(poses))
    with pytest.raises(ValueError, match="6 poses, 5 modes, 6 times"):
        leading_poses(poses, modes[:5], times, 0.1)


def test_the_arm_tracker_leads_as_the_expert_that_made_the_labels():
    """The lead the arm recording's expert aims with is the one the evaluation scores with."""
    import tomllib
    from pathlib import Path
    top = Path(__file__).resolve().parents[1] / "topologies"

    def actor(name, key):
        return tomllib.loads((top / name).read_text())["actors"][key]
    recorded = actor("arm_record.toml", "expert")["lead_s"]
    assert recorded > 0
    assert actor("arm_policy.toml", "tracker")["lead_s"] == recorded
    assert actor("arm_expert.toml", "tracker")["lead_s"] == recorded
    assert actor("arm_expert.toml", "expert")["lead_s"] == recorded
