"""The grasp executor on a small gantry rig of its own (x, y, z slides + yaw, two-finger
slide gripper, a free cube on the floor): a hand-placed static cube is grasped and lifted,
an offset pose misses it with a reason, an unreachable pose fails in IK; and the arm
expert's pose from the rig's own camera, executed, lifts the cube."""
import math

import numpy as np
import pytest

from sebvs.sim import render  # noqa: F401  (sets MUJOCO_GL before mujoco is imported)
from sebvs.sim.render import FrameRenderer

import mujoco  # noqa: E402

from sebvs.experts.arm import ArmExpertConfig, CameraPose, pregrasp_from_images  # noqa: E402
from sebvs.experts.detector import ColorDetector  # noqa: E402
from sebvs.sim.grasp import (ArmHandles, GraspConfig, execute_grasp,  # noqa: E402
                                 rpy_to_mat)

HALF = 0.025
PAD = 'type="box" size="0.012 0.005 0.035" mass="0.05" friction="1.5 0.02 0.001" rgba="0.2 0.2 0.2 1"'
RIG = f"""<mujoco><compiler angle="radian"/>
<option timestep="0.002" integrator="implicitfast"/>
<visual><quality offsamples="0" shadowsize="0"/></visual>
<worldbody>
  <light pos="0 0 2" dir="0 0 -1" castshadow="false"/>
  <geom type="plane" size="1 1 0.1" rgba="0.5 0.5 0.5 1"/>
  <body name="cube" pos="{{x}} {{y}} {HALF}" euler="0 0 {{yaw}}"><freejoint/>
    <geom name="cube" type="box" size="{HALF} {HALF} {HALF}" mass="0.1"
          friction="1.5 0.02 0.001" rgba="0.9 0.15 0.1 1"/></body>
  <body name="carriage" pos="0 0 0.4" gravcomp="1">
    <joint name="x" type="slide" axis="1 0 0" range="-0.8 0.8" damping="60"/>
    <joint name="y" type="slide" axis="0 1 0" range="-0.8 0.8" damping="60"/>
    <joint name="z" type="slide" axis="0 0 1" range="-0.35 0.3" damping="60"/>
    <joint name="yaw" type="hinge" axis="0 0 1" damping="4"/>
    <geom type="box" size="0.03 0.07 0.01" mass="1" rgba="0.3 0.3 0.8 1"/>
    <site name="ee" pos="0 0 -0.1" euler="{math.pi} 0 0"/>
    <camera name="wrist" pos="0.06 0 -0.02" xyaxes="0 -1 0 1 0 0" fovy="70"/>
    <body name="left" pos="0 0.05 -0.07" gravcomp="1">
      <joint name="lf" type="slide" axis="0 1 0" range="-0.05 0.01" damping="5"/>
      <geom name="left_pad" {PAD}/></body>
    <body name="right" pos="0 -0.05 -0.07" gravcomp="1">
      <joint name="rf" type="slide" axis="0 -1 0" range="-0.05 0.01" damping="5"/>
      <geom name="right_pad" {PAD}/></body>
  </body>
</worldbody>
<actuator>
  <position name="ax" joint="x" kp="3000" ctrlrange="-0.8 0.8"/>
  <position name="ay" joint="y" kp="3000" ctrlrange="-0.8 0.8"/>
  <position name="az" joint="z" kp="3000" ctrlrange="-0.35 0.3"/>
  <position name="ayaw" joint="yaw" kp="200" ctrlrange="-4 4"/>
  <position name="gl" joint="lf" kp="300" ctrlrange="-0.05 0.01"/>
  <position name="gr" joint="rf" kp="300" ctrlrange="-0.05 0.01"/>
</actuator></mujoco>"""

HANDLES = ArmHandles(ee_site="ee", arm_joints=["x", "y", "z", "yaw"],
                     arm_actuators=["ax", "ay", "az", "ayaw"], gripper_actuators=["gl", "gr"],
                     gripper_open=[0.0, 0.0], gripper_closed=[-0.045, -0.045],
                     finger_geoms=("left_pad", "right_pad"), object_body="cube")


def rig(x=0.3, y=0.1, yaw=0.3):
    model = mujoco.MjModel.from_xml_string(RIG.format(x=x, y=y, yaw=yaw))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    for _ in range(100):                      # let the cube settle on the floor
        mujoco.mj_step(model, data)
    return model, data


def test_rpy_to_mat_is_a_rotation():
    R = rpy_to_mat(0.3, -0.2, 1.1)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(rpy_to_mat(math.pi, 0, 0) @ [0, 0, 1], [0, 0, -1], atol=1e-12)


def test_grasps_a_hand_placed_static_cube():
    model, data = rig(0.3, 0.1, 0.3)
    pose = [0.3, 0.1, 2 * HALF + 0.10, math.pi, 0.0, 0.3]
    res = execute_grasp(model, data, pose, HANDLES, GraspConfig())
    assert res.success, res.as_dict()
    assert res.lift_m > 0.05 and res.held_s >= 0.99
    assert res.phases["reach"]["ik_pos_m"] < 1e-3


@pytest.mark.parametrize("dx,dz", [(0.08, 0.0), (0.0, 0.08)])
def test_a_bad_pose_fails_with_a_reason(dx, dz):
    model, data = rig(0.3, 0.1, 0.0)        # beside the cube, or closing above it
    res = execute_grasp(model, data, [0.3 + dx, 0.1, 0.15 + dz, math.pi, 0.0, 0.0], HANDLES)
    assert not res.success
    assert res.reason == "not_grasped", res.as_dict()


def test_unreachable_pose_fails_in_ik():
    model, data = rig()
    res = execute_grasp(model, data, [2.0, 0.1, 0.15, math.pi, 0.0, 0.0], HANDLES)
    assert not res.success and res.reason.startswith("ik_failed: reach")
    res = execute_grasp(model, data, [0.3, 0.1, 0.15, np.nan, 0.0, 0.0], HANDLES)
    assert res.reason.startswith("bad_pose")


def test_expert_pose_from_the_wrist_camera_is_grasped():
    model, data = rig(0.32, 0.12, -0.5)
    # look from above the cube: move the carriage over it first
    data.qpos[model.jnt_qposadr[model.joint("x").id]] = 0.3
    data.qpos[model.jnt_qposadr[model.joint("y").id]] = 0.1
    data.ctrl[:4] = [0.3, 0.1, 0.0, 0.0]
    mujoco.mj_forward(model, data)
    cid = model.camera("wrist").id
    with FrameRenderer(model, 160, 160) as r:
        r.update(data, "wrist")
        rgb, depth = r.rgb(), r.depth()
    cam = CameraPose(pos=data.cam_xpos[cid].copy(), mat=data.cam_xmat[cid].reshape(3, 3).copy(),
                     fovy=float(model.cam_fovy[cid]), width=160, height=160)
    pose, det, mode = pregrasp_from_images(rgb, depth, cam, ColorDetector(), ArmExpertConfig())
    assert mode == "grasp", mode
    res = execute_grasp(model, data, pose, HANDLES)
    assert res.success, (pose, res.as_dict())
