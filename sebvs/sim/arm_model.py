"""The ERPArm scene's MuJoCo model as MJCF text: the UR5 from its DH parameters, the gripper
with its wrist camera, the conveyor and the cubes. What happens on the built model (reset,
commands, truth, the grasp) is sebvs/sim/arm.py's.

Arm. The UR5's kinematics are its published Denavit-Hartenberg parameters (DH below: d, a,
alpha per joint); body i of the MJCF is DH frame i, so the model's forward kinematics are
exactly the UR5's (tested against the DH product). Links are primitives (capsules and
cylinders on the DH lines) with the UR5's link masses; they are visual only (no
collisions), so an arm motion never snags on itself. Joints are position servos with
gravity compensation and the UR5's torque limits.

Gripper. Modelled on the Robotiq 2F-85: two parallel pads on slide joints, 85 mm stroke
(each pad travels 42.5 mm), position actuators whose force is capped (`grip_force`).
The end-effector site `tcp` sits between the pad centres; its z axis points out of the
tool, its y axis along the closing direction. The wrist camera `wrist` is on the gripper
housing, beside the tool axis, looking along it: at HOME (tool pointing down, yaw 0) image
right is world +y and image up is world -x (toward the robot).

HDR lamp. Under lighting "hdr" (only) a self-luminous panel (material "hdr_lamp", white in
the 8-bit render, luminance lamp_cd_m2 in the scene's photometry) lies beside the belt's
near side, between the pedestal and the belt (LAMP_X, LAMP_Y): a lamp panel or a sunlit
window's reflection, in the wrist camera's view at HOME (the top ~20 % of the image) and
never in front of a cube.

Conveyor. A static box geom whose surface moves at `belt_speed` m/s along +y
(MuJoCo's geom surfacevel: friction carries whatever lies on it). `conveyor` "static"
stops it, "moving" runs it during the episode, starting from rest at BELT_ACCEL (a belt
that jumped to 3 m/s would tip every cube over). When the episode ends the belt stops (a
stop-and-pick cell) before the last commanded pose is grasped. surfacevel moves contacts,
not pixels: what the camera sees of the belt is a textured skin on a mocap body that
travels with the surface and jumps back by one texture period (invisibly, the texture
repeats), so a running belt fires events as a real one does.
"""
from __future__ import annotations

import math

import numpy as np

from .scene import HDR_LAMP

# UR5 Denavit-Hartenberg parameters (Universal Robots' published values): per joint
# (d m, a m, alpha rad); frame i = frame i-1 * Rz(theta_i) Tz(d_i) Tx(a_i) Rx(alpha_i).
DH = ((0.089159, 0.0, math.pi / 2),
      (0.0, -0.425, 0.0),
      (0.0, -0.39225, 0.0),
      (0.10915, 0.0, math.pi / 2),
      (0.09465, 0.0, -math.pi / 2),
      (0.0823, 0.0, 0.0))
LINK_MASS = (3.7, 8.393, 2.275, 1.219, 1.219, 0.1879)   # kg, UR5 links 1-6
TORQUE = (150.0, 150.0, 150.0, 28.0, 28.0, 28.0)        # N m, UR5 joint limits
JOINTS = ("shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3")

STROKE = 0.085          # m, gripper opening (2F-85)
PAD = (0.02, 0.004, 0.016)    # pad half sizes, m (x across the finger, y closing, z along tool)
TCP = 0.16              # m, flange to the pads' centre along the tool axis

# The belt runs along world +y in front of the robot; its top surface is z = BELT_TOP.
BELT_X = 0.45           # belt centre line, m
BELT_HALF_W = 0.16      # half width (x), m
BELT_Y = (-0.75, 0.95)  # extent along y, m
BELT_TOP = 0.0
CONVEYOR_SOLIDS = ("belt", "belt_frame", "rail_l", "rail_r")   # static boxes nothing enters
SKIN_PERIOD = 0.1       # m, the belt texture's period along y (the skin's wrap-around;
                        # a uniform texture repeats texrepeat times per 2 m: measured)

CUBE_MASS = 0.1         # kg, every cube (a 5 cm wooden block)

# The HDR condition's emitter (lighting "hdr" only): a self-luminous panel lying beside the
# belt's near side, between the robot's pedestal (radius 0.08 m) and the near rail (x 0.27),
# facing up, 1 cm below the belt top: a lamp panel, or a sunlit window's reflection in a
# glossy bench. In the HOME wrist image it is the top ~20 % (image up is world -x), and it
# stays in view as the wrist descends to a pre-grasp pose over the belt; it lies below and
# beside the belt, so it never covers a cube. (x0, x1), (y0, y1): world extents, m.
LAMP_X = (0.09, 0.265)
LAMP_Y = (-0.6, 0.8)
LAMP_Z = BELT_TOP - 0.01


def dh_forward(q) -> np.ndarray:
    """4x4 base -> flange transform of the UR5 for joint angles q (6,), from DH alone."""
    T = np.eye(4)
    for (d, a, alpha), th in zip(DH, q):
        ct, st, ca, sa = math.cos(th), math.sin(th), math.cos(alpha), math.sin(alpha)
        T = T @ np.array([[ct, -st * ca, st * sa, a * ct],
                          [st, ct * ca, -ct * sa, a * st],
                          [0.0, sa, ca, d],
                          [0.0, 0.0, 0.0, 1.0]])
    return T


# Arm links are visual: they never collide (only the gripper touches the world).
VISUAL = 'contype="0" conaffinity="0"'


def _finger(side: str, sign: int, travel: float, pad: str) -> str:
    """One gripper finger on the +y (sign 1) or -y side: a slide joint closing toward the
    tool axis by up to `travel` m, a visual finger and the colliding pad `pad_<side>`."""
    return f"""<body name="finger_{side}" pos="0 {sign * (travel + PAD[1])} {TCP}" gravcomp="1">
            <joint name="finger_{side}" type="slide" axis="0 {-sign} 0" range="0 {travel}"
                   damping="20"/>
            <geom type="box" size="0.008 0.005 0.05" pos="0 {sign * 0.003} -0.045" mass="0.05"
                  material="gripper" contype="0" conaffinity="0"/>
            <geom name="pad_{side}" type="box" size="{pad}" mass="0.02"
                  friction="1.5 0.02 0.001" material="pad"/>
          </body>"""


def _quat_rx(alpha: float) -> str:
    return f"{math.cos(alpha / 2):.12g} {math.sin(alpha / 2):.12g} 0 0"


def grip_gains(grip_force: float) -> tuple[float, float]:
    """(kp, force cap) of each pad's position actuator: full force 2 cm short of the target."""
    return grip_force / 0.02, grip_force


def arm_xml(grip_force: float, fovy: float) -> str:
    """The UR5's links on their DH lines, then the gripper with its wrist camera."""
    radius = (0.06, 0.055, 0.045, 0.04, 0.04, 0.035)
    bodies, close = [], []
    pos, quat = "0 0 0", "1 0 0 0"
    for i, ((d, a, alpha), m, name) in enumerate(zip(DH, LINK_MASS, JOINTS)):
        r = radius[i]
        # The link from this joint's frame to the next one: along z by d, then x by a.
        geoms = [f'<geom type="cylinder" size="{r} {r * 1.1}" mass="{m * 0.4}" '
                 f'material="joint" {VISUAL}/>']
        if d:
            geoms.append(f'<geom type="capsule" fromto="0 0 0 0 0 {d}" size="{r * 0.8}" '
                         f'mass="{m * 0.3}" material="link" {VISUAL}/>')
        if a:
            geoms.append(f'<geom type="capsule" fromto="0 0 {d} {a} 0 {d}" '
                         f'size="{r * 0.8}" mass="{m * 0.3}" material="link" {VISUAL}/>')
        if not (d and a):
            geoms.append(f'<geom type="sphere" size="{r * 0.5}" mass="{m * 0.3}" '
                         f'material="link" {VISUAL}/>')
        bodies.append(f'<body name="link{i + 1}" pos="{pos}" quat="{quat}" gravcomp="1">'
                      f'<joint name="{name}" axis="0 0 1" range="-6.2832 6.2832" '
                      f'damping="{60 if i < 3 else 6}" armature="0.1"/>'
                      + "".join(geoms))
        close.append("</body>")
        pos, quat = f"{a} 0 {d}", _quat_rx(alpha)
    h = STROKE / 2
    pad = " ".join(str(v) for v in PAD)
    gripper = f"""<body name="gripper" pos="{pos}" quat="{quat}" gravcomp="1">
          <geom type="cylinder" size="0.04 0.012" pos="0 0 0.012" mass="0.2" material="joint"/>
          <geom name="housing" type="box" size="0.03 0.055 0.035" pos="0 0 0.06" mass="0.6"
                material="gripper"/>
          <site name="tcp" pos="0 0 {TCP}" group="4"/>
          <camera name="wrist" pos="-0.075 0 0.03" xyaxes="0 -1 0 -1 0 0"
                  fovy="{float(fovy)}"/>
          {_finger("l", 1, h, pad)}
          {_finger("r", -1, h, pad)}
        </body>"""
    return "".join(bodies) + gripper + "".join(reversed(close))


def lamp_xml(c: dict) -> tuple[str, str]:
    """(asset, geom) of the HDR lamp panel: both empty unless c["lighting"] is "hdr"."""
    if c.get("lighting") != "hdr":
        return "", ""
    (x0, x1), (y0, y1) = LAMP_X, LAMP_Y
    return (f'\n    <material name="{HDR_LAMP}" rgba="0.95 0.97 1 1" emission="1" specular="0"/>',
            f'\n    <geom name="hdr_lamp" type="box" pos="{(x0 + x1) / 2:g} {(y0 + y1) / 2:g} '
            f'{LAMP_Z - 0.002:g}" size="{(x1 - x0) / 2:g} {(y1 - y0) / 2:g} 0.002" '
            f'material="{HDR_LAMP}" contype="0" conaffinity="0"/>')


def mjcf(head: str, c: dict, key: float, shadow: str) -> str:
    """The whole scene for config ``c`` (ArmScene's keys) under ``head`` (the scene's
    compiler, options and visuals), the key light at ``key`` with its shadow flag."""
    lamp_asset, lamp_geom = lamp_xml(c)
    gain = float(c["servo_gain"])
    arm = arm_xml(float(c["grip_force"]), float(c["fovy"]))
    kp = [gain * k for k in (2000, 2000, 1500, 300, 300, 100)]
    servos = "\n    ".join(
        f'<position name="{j}" joint="{j}" kp="{k:g}" ctrlrange="-6.2832 6.2832" '
        f'forcerange="{-t} {t}"/>' for j, k, t in zip(JOINTS, kp, TORQUE))
    gkp, gf = grip_gains(float(c["grip_force"]))
    # compiled at the largest size: reset() only shrinks a cube, and the collision
    # bounds MuJoCo derived at compile time (aabb, rbound) stay conservative
    big = float(c["cube_half"][1])
    cubes = "\n    ".join(
        f'<body name="cube{i}" pos="{BELT_X} {0.2 * i} 0.03"><freejoint name="cube{i}"/>'
        f'<geom name="cube{i}" type="box" size="{big} {big} {big}" mass="{CUBE_MASS}" '
        f'friction="1.2 0.02 0.001" rgba="0.9 0.15 0.1 1"/></body>'
        for i in range(int(c["objects"])))
    speed = float(c["belt_speed"]) if c["conveyor"] == "moving" else 0.0
    y0, y1 = BELT_Y
    belt_len, belt_mid = (y1 - y0) / 2, (y0 + y1) / 2
    return f"""{head}
  <asset>
    <texture name="floor" type="2d" builtin="checker" rgb1="0.5 0.5 0.48" rgb2="0.42 0.42 0.42"
             width="256" height="256"/>
    <material name="floor" texture="floor" texrepeat="8 8"/>
    <texture name="belt" type="2d" builtin="flat" rgb1="0.16 0.16 0.17" width="128" height="128"
             mark="random" random="0.08" markrgb="0.3 0.3 0.3"/>
    <material name="belt" texture="belt" texuniform="true"
              texrepeat="{2 / SKIN_PERIOD:g} {2 / SKIN_PERIOD:g}"/>
    <material name="link" rgba="0.75 0.77 0.8 1"/>
    <material name="joint" rgba="0.3 0.32 0.36 1"/>   <!-- unsaturated: the expert segments saturated cubes of any hue -->
    <material name="gripper" rgba="0.2 0.2 0.22 1"/>
    <material name="pad" rgba="0.1 0.1 0.1 1"/>
    <material name="frame" rgba="0.55 0.57 0.6 1"/>{lamp_asset}
  </asset>
  <worldbody>
    <geom name="floor" type="plane" pos="0 0 -0.75" size="3 3 0.1" material="floor"/>
    <light name="key" pos="0.4 0.1 1.6" dir="0 0 -1" directional="false"
           diffuse="{key} {key} {key}" specular="0.1 0.1 0.1" attenuation="1 0 0"
           castshadow="{shadow}"/>
    <light name="fill" pos="1.5 -1 2" dir="-0.5 0.3 -1" directional="true"
           diffuse="{key / 2} {key / 2} {key / 2}" specular="0 0 0" castshadow="false"/>
    <geom name="pedestal" type="cylinder" size="0.08 0.375" pos="0 0 -0.375" material="frame"/>
    <geom name="belt" type="box" size="{BELT_HALF_W} {belt_len} 0.02"
          pos="{BELT_X} {belt_mid} {BELT_TOP - 0.02}" friction="1 0.02 0.001"
          surfacevel="0 {speed:g} 0" group="3" rgba="0.16 0.16 0.17 1"/>
    <body name="belt_skin" mocap="true" pos="{BELT_X} {belt_mid} {BELT_TOP - 0.001}">
      <geom name="belt_skin" type="box" size="{BELT_HALF_W} {belt_len - SKIN_PERIOD} 0.001"
            material="belt" contype="0" conaffinity="0"/>
    </body>
    <geom name="belt_frame" type="box" size="{BELT_HALF_W + 0.02} {belt_len} 0.355"
          pos="{BELT_X} {belt_mid} {BELT_TOP - 0.395}" material="frame"/>
    <geom name="rail_l" type="box" size="0.01 {belt_len} 0.015"
          pos="{BELT_X - BELT_HALF_W - 0.01} {belt_mid} {BELT_TOP + 0.005}" material="frame"/>
    <geom name="rail_r" type="box" size="0.01 {belt_len} 0.015"
          pos="{BELT_X + BELT_HALF_W + 0.01} {belt_mid} {BELT_TOP + 0.005}" material="frame"/>{lamp_geom}
    <body name="base" pos="0 0 0">
      <geom type="cylinder" size="0.075 0.04" pos="0 0 0.04" material="joint" mass="4"/>
      {arm}
    </body>
    {cubes}
    <camera name="overview" pos="1.6 -1.2 1.1" xyaxes="0.6 0.8 0 -0.35 0.26 0.9" fovy="45"/>
  </worldbody>
  <actuator>
    {servos}
    <position name="finger_l" joint="finger_l" kp="{gkp:g}" ctrlrange="0 {STROKE / 2}"
              forcerange="{-gf} {gf}"/>
    <position name="finger_r" joint="finger_r" kp="{gkp:g}" ctrlrange="0 {STROKE / 2}"
              forcerange="{-gf} {gf}"/>
  </actuator>
</mujoco>
"""
