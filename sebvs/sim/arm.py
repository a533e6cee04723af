"""The manipulation scene (paper's ERPArm): a UR5 with a two-finger gripper and a wrist
camera above a conveyor belt that carries one cube or several.

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

Conveyor. A static box geom whose surface moves at `belt_speed` m/s along +y
(MuJoCo's geom surfacevel: friction carries whatever lies on it). `conveyor` "static"
stops it, "moving" runs it during the episode, starting from rest at BELT_ACCEL (a belt
that jumped to 3 m/s would tip every cube over). When the episode ends the belt stops (a
stop-and-pick cell) before the last commanded pose is grasped. surfacevel moves contacts,
not pixels: what the camera sees of the belt is a textured skin on a mocap body that
travels with the surface and jumps back by one texture period (invisibly, the texture
repeats), so a running belt fires events as a real one does.

Task. The arm holds the HOME pose and looks down at the belt; the command is a pre-grasp
pose [x, y, z, roll, pitch, yaw] (m, rad, world frame), stored, not executed, while the
episode runs (the paper's one-shot pose prediction from the wrist view). With
`grasp_at_end` the scene's finish() runs the grasp executor on the last command and reports
the outcome. The workspace rule: an object beyond y > 0.449 m is out of reach and the
right command is HOME_POSE.

Objects. `objects` cubes (1: single; more: cluttered), each with a seeded colour from a
palette of saturated hues, half size in `cube_half`, yaw, and position on the belt, kept
`min_gap` apart. The target is the leftmost visible cube: the smallest image u at HOME,
which is the smallest world y (LEFTMOST below, read by the arm expert).
"""
from __future__ import annotations

import math

import mujoco
import numpy as np

from .ik import dls_ik, mat_to_rpy, rpy_to_mat
from .scene import Scene
from .stability import Limits

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
BELT_ACCEL = 0.5 * 9.81  # m/s^2 at start-up: below g * (side / height), no cube tips
CONVEYOR_SOLIDS = ("belt", "belt_frame", "rail_l", "rail_r")   # static boxes nothing enters
SKIN_PERIOD = 0.1       # m, the belt texture's period along y (the skin's wrap-around;
                        # a uniform texture repeats texrepeat times per 2 m: measured)

# The task's constants (the arm expert reads them from this module).
Y_LIMIT = 0.449                         # paper: objects beyond this world y are out of reach
HOME_POSE = (0.50, 0.10, 0.42, math.pi, 0.0, 0.0)   # tcp pose looking down at the belt
LEFTMOST = "world_y"                    # smallest world y = leftmost in the HOME image
CLEARANCE = 0.10                        # pre-grasp height above the cube top, m (expert's)
CUBE_MASS = 0.1                         # kg, every cube (a 5 cm wooden block)
# A cube's faces repeat every quarter turn, so the pose's yaw leaves the gripper a choice
# of two face pairs: finish() closes on the pair facing along world x, across the belt,
# where the wrist view places cubes best (the belt's long axis, y, has ~2x the error).
GRASP_YAW_OFFSET = math.pi / 2

PALETTE = ((0.9, 0.15, 0.1), (0.1, 0.7, 0.2), (0.15, 0.3, 0.9), (0.95, 0.8, 0.1),
           (0.8, 0.2, 0.8), (0.1, 0.75, 0.8), (0.95, 0.5, 0.1))
CONVEYOR = ("static", "moving")
LIGHTING = ("nominal", "low", "flicker")


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


class ArmScene(Scene):
    """UR5 + gripper + wrist camera + conveyor with cubes. Config keys (defaults):

    conveyor      "static" | "moving" (belt surface at belt_speed along +y)
    belt_speed    float m/s (0.08) when moving
    objects       int cubes on the belt (1; more = cluttered), 1..6
    cube_half     [min, max] half side, m ([0.0225, 0.03]: 45-60 mm cubes)
    min_gap       float m between cube centres beyond their sizes (0.03)
    spawn_y       [min, max] world y of cube centres at reset ([-0.3, 0.5]; moving: the
                  episode carries them on)
    lighting      "nominal" | "low" | "flicker" (flicker_hz, as the nav scene)
    flicker_hz    float (10.0)
    rgb_blur      int sub-frames averaged per RGB frame (0: none)
    width, height int wrist image, px (160 x 160)
    fovy          float deg (75)
    servo_gain    float multiplier on the arm's joint servo gains (1.0; large = stiff)
    grip_force    float N per pad (40)
    grasp_at_end  bool: finish() executes the last command as a grasp (True)
    drop_height   float m the cubes fall onto the belt at reset (0.002)
    contact_timeconst  float s (0 = MuJoCo's default): contact solref time constant, with
                  refsafe off (the stiff case), as the nav scene
    plus integrator, timestep, shadows (Scene).
    """

    task = "arm"
    command_dim = 6
    command_name = "pose"
    cameras = ("wrist", "overview")
    defaults = {**Scene.defaults, "conveyor": "static", "belt_speed": 0.08, "objects": 1,
                "cube_half": [0.0225, 0.03], "min_gap": 0.03, "spawn_y": [-0.3, 0.5],
                "lighting": "nominal", "flicker_hz": 10.0, "rgb_blur": 0, "width": 160,
                "height": 160, "fovy": 75.0, "servo_gain": 1.0, "grip_force": 40.0,
                "grasp_at_end": True, "drop_height": 0.002, "contact_timeconst": 0.0}

    def validate(self) -> None:
        c = self.config
        for key, allowed in (("conveyor", CONVEYOR), ("lighting", LIGHTING)):
            if c[key] not in allowed:
                raise ValueError(f"arm scene: {key} {c[key]!r} is not one of {allowed}")
        numbers = {"belt_speed": (0.0, 20.0), "flicker_hz": (1e-3, 1e4), "fovy": (1.0, 179.0),
                   "servo_gain": (1e-6, 1e9), "grip_force": (1e-3, 1e4),
                   "drop_height": (0.0, 10.0), "contact_timeconst": (0.0, 1.0),
                   "min_gap": (0.0, 0.5)}
        for key, (lo, hi) in numbers.items():
            v = c[key]
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not lo <= v <= hi:
                raise ValueError(f"arm scene: {key} must be a number in [{lo:g}, {hi:g}], "
                                 f"got {v!r}")
        for key, lo, hi in (("objects", 1, 6), ("width", 8, 4096), ("height", 8, 4096),
                            ("rgb_blur", 0, 64)):
            v = c[key]
            if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
                raise ValueError(f"arm scene: {key} must be an int in [{lo}, {hi}], got {v!r}")
        for key, lo, hi in (("cube_half", 0.01, 0.04), ("spawn_y", BELT_Y[0], BELT_Y[1])):
            v = c[key]
            if not (isinstance(v, (list, tuple)) and len(v) == 2
                    and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v)
                    and lo <= v[0] <= v[1] <= hi):
                raise ValueError(f"arm scene: {key} must be [min, max] within [{lo:g}, {hi:g}], "
                                 f"got {v!r}")
        if 2 * c["cube_half"][1] >= STROKE - 0.01:
            raise ValueError(f"arm scene: cube_half {c['cube_half'][1]} does not fit the "
                             f"gripper's {STROKE * 1000:.0f} mm stroke")
        if not isinstance(c["grasp_at_end"], bool):
            raise ValueError(f"arm scene: grasp_at_end must be true or false, "
                             f"got {c['grasp_at_end']!r}")

    # ------------------------------------------------------------------ model
    def _arm_xml(self) -> str:
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
        f = float(self.config["grip_force"])
        gripper = f"""<body name="gripper" pos="{pos}" quat="{quat}" gravcomp="1">
          <geom type="cylinder" size="0.04 0.012" pos="0 0 0.012" mass="0.2" material="joint"/>
          <geom name="housing" type="box" size="0.03 0.055 0.035" pos="0 0 0.06" mass="0.6"
                material="gripper"/>
          <site name="tcp" pos="0 0 {TCP}" group="4"/>
          <camera name="wrist" pos="-0.075 0 0.03" xyaxes="0 -1 0 -1 0 0"
                  fovy="{float(self.config['fovy'])}"/>
          {_finger("l", 1, h, pad)}
          {_finger("r", -1, h, pad)}
        </body>"""
        self._grip = (f / 0.02, f)      # kp: full force 2 cm short of the target
        return "".join(bodies) + gripper + "".join(reversed(close))

    def mjcf(self) -> str:
        c = self.config
        shadow = self.light_xml()
        key = self.light_levels()[0]
        gain = float(c["servo_gain"])
        arm = self._arm_xml()
        kp = [gain * k for k in (2000, 2000, 1500, 300, 300, 100)]
        servos = "\n    ".join(
            f'<position name="{j}" joint="{j}" kp="{k:g}" ctrlrange="-6.2832 6.2832" '
            f'forcerange="{-t} {t}"/>' for j, k, t in zip(JOINTS, kp, TORQUE))
        gkp, gf = self._grip
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
        return f"""{self.mjcf_head("sebvs_arm")}
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
    <material name="frame" rgba="0.55 0.57 0.6 1"/>
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
          pos="{BELT_X + BELT_HALF_W + 0.01} {belt_mid} {BELT_TOP + 0.005}" material="frame"/>
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

    def compile(self) -> mujoco.MjModel:
        model = super().compile()
        model.vis.map.znear = 0.01 / model.stat.extent      # 1 cm, absolute
        self._ids(model)
        self.home_q = self._home_joints(model)
        return model

    def _ids(self, model: mujoco.MjModel) -> None:
        self.joint_ids = np.array([model.joint(j).id for j in JOINTS])
        self.arm_qadr = model.jnt_qposadr[self.joint_ids]
        self.arm_act = np.array([model.actuator(j).id for j in JOINTS])
        self.grip_act = np.array([model.actuator(n).id for n in ("finger_l", "finger_r")])
        self.finger_qadr = np.array([model.jnt_qposadr[model.joint(n).id]
                                     for n in ("finger_l", "finger_r")])
        self.tcp = model.site("tcp").id
        self.cam_wrist = model.camera("wrist").id
        self.belt = model.geom("belt").id
        self.skin = int(model.body_mocapid[model.body("belt_skin").id])
        self.skin_y0 = float(model.body_pos[model.body("belt_skin").id][1])
        n = int(self.config["objects"])
        self.cube_body = np.array([model.body(f"cube{i}").id for i in range(n)])
        self.cube_geom = np.array([model.geom(f"cube{i}").id for i in range(n)])
        self.cube_qadr = np.array([model.jnt_qposadr[model.joint(f"cube{i}").id]
                                   for i in range(n)])
        self.belt_speed = float(model.geom_surfacevel[self.belt, 1])

    def _home_joints(self, model: mujoco.MjModel) -> np.ndarray:
        """Joint angles of HOME_POSE, elbow up, wrist down (deterministic: fixed start)."""
        data = mujoco.MjData(model)
        q0 = np.array([0.1, -1.3, 1.6, -1.87, -1.57, 0.0])
        pose = np.asarray(HOME_POSE)
        q, perr, rerr = dls_ik(model, data, self.tcp, self.joint_ids, pose[:3],
                               rpy_to_mat(*pose[3:]), q0, iters=1000)
        if perr > 1e-4 or rerr > 1e-3:
            raise RuntimeError(f"arm scene: HOME_POSE is not reachable (residual "
                               f"{perr * 1e3:.2f} mm, {math.degrees(rerr):.2f} deg)")
        return q

    def limits(self) -> Limits:
        speed = float(self.config["belt_speed"]) if self.config["conveyor"] == "moving" else 0.0
        fall = math.sqrt(2 * 9.81 * (float(self.config["drop_height"]) + 0.5))
        # cubes a fast belt throws off its end land and bounce metres away on the floor
        return Limits(bounds=(-5.0, 5.0, -5.0, 5.0, -0.8, 3.0 + self.config["drop_height"]),
                      # a cube carried by the belt, falling, or swung by the gripper
                      max_speed=2 * max(speed, fall, 2.0) + 1.0,
                      # UR5 joints turn at most ~3 rad/s; a 5 cm cube tumbling at 3 m/s
                      # spins at ~130 rad/s
                      max_angular=300.0,
                      max_energy_jump=20.0,
                      max_kinetic=30.0 + 0.1 * self.config["objects"] * (speed ** 2 + fall ** 2),
                      # a cube whose centre is inside the belt or its frame tunnelled
                      solid_boxes=CONVEYOR_SOLIDS,
                      free_bodies=tuple(f"cube{i}" for i in range(int(self.config["objects"]))),
                      # a cube on the belt climbs only by tipping onto an edge (a fast belt
                      # starting under it does that); more means a chattering contact
                      # makes it hop
                      passive_rise=(math.sqrt(2) - 1) * self.config["cube_half"][1] + 0.003)

    # ------------------------------------------------------------------ episode
    def reset(self, model, data, rng: np.random.Generator) -> None:
        if not hasattr(self, "tcp"):
            self._ids(model)
            self.home_q = self._home_joints(model)
        mujoco.mj_resetData(model, data)
        model.geom_surfacevel[self.belt, 1] = 0.0        # starts from rest (scripted)
        self.belt_travel = 0.0                           # m the surface moved (mod period)
        data.qpos[self.arm_qadr] = self.home_q
        data.ctrl[self.arm_act] = self.home_q
        data.ctrl[self.grip_act] = 0.0
        c = self.config
        lo, hi = c["cube_half"]
        y_lo, y_hi = c["spawn_y"]
        placed: list[tuple[float, float, float]] = []
        colours = rng.permutation(len(PALETTE))
        for i, (body, geom, adr) in enumerate(zip(self.cube_body, self.cube_geom,
                                                  self.cube_qadr)):
            half = float(rng.uniform(lo, hi))
            z = BELT_TOP + half + float(c["drop_height"])
            for _ in range(200):    # rejection sampling: keep cubes apart (and out of the
                x = float(rng.uniform(BELT_X - BELT_HALF_W + 0.05, BELT_X + BELT_HALF_W - 0.05))
                y = float(rng.uniform(y_lo, y_hi))       # gripper, when dropped from its height)
                if all(math.hypot(x - px, y - py) > 1.5 * (half + ph) + c["min_gap"]
                       for px, py, ph in placed) and not _in_gripper(x, y, z, half):
                    break
            else:
                raise RuntimeError(f"arm scene: could not place {len(self.cube_body)} cubes "
                                   f"{c['min_gap']} m apart within spawn_y {c['spawn_y']}")
            placed.append((x, y, half))
            yaw = float(rng.uniform(-math.pi / 4, math.pi / 4))
            model.geom_size[geom] = half
            model.body_inertia[body] = CUBE_MASS * (2 * half) ** 2 / 6   # a solid cube
            model.geom_rgba[geom, :3] = PALETTE[int(colours[i % len(PALETTE)])]
            data.qpos[adr:adr + 7] = [x, y, z, math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)]
        self.halves = np.array([p[2] for p in placed])
        self.colours = model.geom_rgba[self.cube_geom, :3].copy()
        self.reset_lights(model, rng)
        self.command_pose = np.asarray(HOME_POSE, dtype=np.float64)
        mujoco.mj_forward(model, data)

    def idle_command(self) -> np.ndarray:
        return np.asarray(HOME_POSE, dtype=np.float64)

    def apply_command(self, model, data, command: np.ndarray) -> None:
        """Store a pre-grasp pose (not executed until finish()). Position clipped into the
        arm's reach box, angles wrapped to (-pi, pi]."""
        cmd = np.asarray(command, dtype=np.float64)
        if cmd.shape != (6,):
            raise ValueError(f"arm command must be a pose of shape (6,), got {cmd.shape}")
        if not np.isfinite(cmd).all():
            raise ValueError(f"arm command is not finite: {cmd.tolist()}")
        pose = cmd.copy()
        pose[:3] = np.clip(pose[:3], (-0.9, -0.9, -0.2), (0.9, 0.9, 0.9))
        pose[3:] = -((-pose[3:] + math.pi) % (2 * math.pi) - math.pi)
        self.command_pose = pose

    def scripted(self, model, data) -> None:
        if self.belt_speed:
            v = min(self.belt_speed, BELT_ACCEL * data.time)
            model.geom_surfacevel[self.belt, 1] = v
            # the skin shows the surface's motion; one period back is the same picture
            self.belt_travel = (self.belt_travel + v * model.opt.timestep) % SKIN_PERIOD
            data.mocap_pos[self.skin, 1] = self.skin_y0 + self.belt_travel
        self.flicker(model, data)

    # ------------------------------------------------------------------ state
    def state(self, data) -> dict[str, np.ndarray]:
        """Scene.state() plus the episode's cube sizes and colours (`cube_half` (n,),
        `cube_rgb` (n, 3)): drawn at reset, they change the model, and the camera renders
        from its own copy of it."""
        s = super().state(data)
        s["cube_half"] = self.halves.copy()
        s["cube_rgb"] = self.colours.copy()
        return s

    def set_state(self, model, data, state) -> None:
        super().set_state(model, data, state)
        if "cube_half" in state:
            if not hasattr(self, "cube_geom"):
                self._ids(model)
            model.geom_size[self.cube_geom] = np.asarray(state["cube_half"])[:, None]
            model.geom_rgba[self.cube_geom, :3] = state["cube_rgb"]
            self.halves = np.array(state["cube_half"], dtype=np.float64)
            self.colours = np.array(state["cube_rgb"], dtype=np.float64)

    # ------------------------------------------------------------------ truth
    def cube_yaw(self, data, i: int) -> float:
        """Yaw (rad, folded into [-pi/4, pi/4)) of cube i's vertical faces: of whichever of
        its axes is most horizontal, so a cube that tipped onto another face still counts."""
        R = data.xmat[self.cube_body[i]].reshape(3, 3)
        up = int(np.argmax(np.abs(R[2])))
        side = (up + 1) % 3
        return fold_yaw(math.atan2(R[1, side], R[0, side]))

    def project(self, model, data, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pinhole projection into the wrist camera (needs kinematics of this state):
        points (N, 3) world m -> (uv (N, 2) px from the top-left corner, depth (N,) m along
        the view axis)."""
        h, w = self.image_shape()
        f = 0.5 * h / math.tan(math.radians(model.cam_fovy[self.cam_wrist]) / 2)
        R = data.cam_xmat[self.cam_wrist].reshape(3, 3)
        pc = (np.asarray(points, np.float64) - data.cam_xpos[self.cam_wrist]) @ R
        depth = -pc[:, 2]
        safe = np.where(depth > 1e-6, depth, 1e-6)
        return np.stack([w / 2 + f * pc[:, 0] / safe, h / 2 - f * pc[:, 1] / safe], 1), depth

    def truth(self, model, data) -> dict:
        """Privileged truth of the cubes and the pose the task asks for.

        Keys: cubes [{pos [x, y, z] m, yaw rad (folded), half m, rgb, uv [u, v] px in the
        wrist image, visible (centre in front of the camera and inside the image)}],
        target (index of the leftmost visible cube: smallest world y; -1 if none),
        expert_pose [x, y, z, roll, pitch, yaw]: the pre-grasp pose above the target's top
        face (CLEARANCE m), gripper down, or HOME_POSE when nothing is visible or the target
        lies beyond Y_LIMIT; mode "grasp" | "home_none" | "home_workspace";
        tcp [x, y, z] m; image [W, H].
        """
        self.kinematics(model, data)
        h, w = self.image_shape()
        pos = data.xpos[self.cube_body]
        uv, depth = self.project(model, data, pos)
        cubes = []
        for i in range(len(self.cube_body)):
            visible = bool(depth[i] > 0 and 0 <= uv[i, 0] < w and 0 <= uv[i, 1] < h)
            cubes.append({"pos": pos[i].tolist(), "yaw": self.cube_yaw(data, i),
                          "half": float(self.halves[i]),
                          "rgb": model.geom_rgba[self.cube_geom[i], :3].tolist(),
                          "uv": uv[i].tolist(), "visible": visible})
        seen = [i for i, c in enumerate(cubes) if c["visible"]]
        target = min(seen, key=lambda i: cubes[i]["pos"][1]) if seen else -1
        pose, mode = list(HOME_POSE), "home_none"
        if target >= 0:
            c = cubes[target]
            if c["pos"][1] > Y_LIMIT:
                mode = "home_workspace"
            else:
                x, y, z = c["pos"]
                pose, mode = [x, y, z + c["half"] + CLEARANCE, math.pi, 0.0, c["yaw"]], "grasp"
        return {"cubes": cubes, "target": target, "expert_pose": [float(v) for v in pose],
                "mode": mode, "tcp": data.site_xpos[self.tcp].tolist(), "image": [w, h]}

    # ------------------------------------------------------------------ grasp
    def grasp_handles(self, model, target: int = 0):
        """The names the grasp executor drives and checks (sebvs.sim.grasp.ArmHandles)."""
        from .grasp import ArmHandles
        h = STROKE / 2
        return ArmHandles(ee_site="tcp", arm_joints=list(JOINTS), arm_actuators=list(JOINTS),
                          gripper_actuators=["finger_l", "finger_r"], gripper_open=[0.0, 0.0],
                          gripper_closed=[h, h], finger_geoms=("pad_l", "pad_r"),
                          object_body=f"cube{target}")

    def is_home(self, pose) -> bool:
        """A command that means "do not grasp": within 5 cm and 0.2 rad of HOME_POSE."""
        pose, home = np.asarray(pose, np.float64), np.asarray(HOME_POSE)
        d_ang = np.abs((pose[3:] - home[3:] + math.pi) % (2 * math.pi) - math.pi)
        return bool(np.linalg.norm(pose[:3] - home[:3]) < 0.05 and d_ang.max() < 0.2)

    def finish(self, model, data, monitor=None) -> dict:
        """After the episode's last tick: stop the belt, then grasp with the last command.

        Returns {"truth_mode", "command", "outcome"} with outcome "home_correct" (HOME was
        right and commanded), "home_missed" (HOME commanded, a graspable cube was there),
        "grasp_unwanted" (a grasp commanded where the task says HOME; not executed),
        or "lifted_and_held" / a failure reason of the grasp executor (sebvs.sim.grasp),
        plus "grasp" (the executor's result dict) when it ran. {} when grasp_at_end is off.
        """
        if not self.config["grasp_at_end"]:
            return {}
        from .grasp import GraspConfig, execute_grasp
        model.geom_surfacevel[self.belt, 1] = 0.0
        truth = self.truth(model, data)
        pose = self.command_pose.copy()
        out = {"truth_mode": truth["mode"], "command": pose.tolist(),
               "target": truth["target"]}
        home = self.is_home(pose)
        if truth["mode"] != "grasp":
            out["outcome"] = "home_correct" if home else "grasp_unwanted"
            return out
        if home:
            out["outcome"] = "home_missed"
            return out
        pose[5] += GRASP_YAW_OFFSET
        res = execute_grasp(model, data, pose, self.grasp_handles(model, truth["target"]),
                            GraspConfig(clearance=CLEARANCE), monitor)
        out["outcome"] = res.reason
        out["grasp"] = res.as_dict()
        return out


def _in_gripper(x: float, y: float, z: float, half: float) -> bool:
    """Would a cube centred at (x, y, z) overlap the gripper at HOME (pads to flange)?"""
    hx, hy, hz = HOME_POSE[:3]
    return math.hypot(x - hx, y - hy) < 0.1 + half and hz - 0.03 - half < z < hz + TCP + half


def fold_yaw(yaw: float, symmetry: float = math.pi / 2) -> float:
    """Yaw folded into [-symmetry/2, symmetry/2) (a cube looks the same a quarter turn on).
    The one definition of the cube's yaw label: the scene's truth and the arm expert."""
    return float((yaw + symmetry / 2) % symmetry - symmetry / 2)
