"""The navigation scene (paper's ERPNav): a four-wheel differential-drive robot with a
forward camera tracks a cube that moves on seeded scripted trajectories.

Robot drive (a deliberate modelling choice; DESIGN.md section 5). Wheel-velocity
actuators on four contact wheels make a skid-steer robot scrub in turns (a commanded 1
rad/s gave 0.5-0.66 rad/s) and a stiff wheel servo can launch it. The paper's controller
commands the unicycle model (eq. 2: x' = v cos th, y' = v sin th, th' = w), so the base is
a planar body (slide x, slide y, hinge yaw) driven by three velocity servos acting in the
body frame through a site transmission:
  forward  force  = kv_v (v_cmd - v_fwd),    |force|  <= mu m g   (traction limit)
  yaw      torque = kv_w (w_cmd - w),        |torque| <= max_torque
  lateral  force  = kv_l (0 - v_lat),        |force|  <= mu m g   (tyre side grip)
This is the wheels' effect on the chassis (tracking with a first-order lag, bounded by
friction), without modelling rolling contacts: turns realise the commanded rate, and the
robot can still skid sideways if a turn asks for more than the grip. The four wheels are
visual geoms. The chassis collides with the room's walls.

Commands: [v, w] in [-1, 1] (clipped) scaled to v_max (m/s) and w_max (rad/s).

Camera "front" on the chassis looks along the robot's +x; the image is width x height px
with vertical field of view fovy (deg). Ground truth projects the cube's 8 corners with
these intrinsics (pinhole, focal f = height / (2 tan(fovy/2)) px, row 0 at the top).
"""
from __future__ import annotations

import math

import mujoco
import numpy as np

from .scene import HDR_LAMP, LIGHT_DEFAULTS, Scene
from .stability import Limits
from .trajectories import SPEEDS, TrajectoryConfig, WaypointTrajectory

VARIANTS = ("indoor", "outdoor")
LIGHTING = ("nominal", "low", "flicker", "dusk", "hdr")
# Nominal illuminance (lux) per variant (public orders of magnitude: an office, an
# overcast day) and the shade's under the "hdr" lighting (sebvs/sim/light.py).
NOMINAL_LUX = {"indoor": 400.0, "outdoor": 1e4}
HDR_LUX = {"indoor": 30.0, "outdoor": 50.0}
# The indoor HDR windows: a band on all four walls from sill to head height (m), so one
# is in view whichever way the robot faces.
WINDOW_Z = (0.3, 1.9)

MASS = 10.0            # chassis, kg
ROBOT_MASS = MASS + 4 * 0.5 + 0.1   # chassis, four wheels, mast (as in the MJCF), kg
ROBOT_INERTIA_Z = 0.52 # kg m^2, bounds the robot's largest principal moment (tested)
HALF = (0.25, 0.20, 0.06)   # chassis half sizes, m
CUBE = 0.1             # target half side, m
CHECKER = ((0.55, 0.55, 0.5), (0.3, 0.3, 0.32))   # the indoor floor's two greys
FLOORS = ("checker", "plain")
MU = 0.8               # tyre-ground friction, for the traction limits
G = 9.81


class NavScene(Scene):
    """Four-wheel diff-drive robot + moving cube. Config keys (defaults):

    variant       "indoor" (walled room, checker floor) | "outdoor" (ground, sky, sun)
    floor         "checker" | "plain": the indoor floor's texture; plain is the checker's two
                  greys replaced by their mean, its sparse light marks kept (the outdoor
                  ground has no checker and ignores it)
    target_rgb    [r, g, b] in [0, 1], the cube's colour ([0.9, 0.15, 0.1]); the expert's
                  colour detector looks for red, so keep the hue red
    target_speed  "slow" | "nominal" | "fast"  (0.25 / 0.5 / 1.0 m/s nominal)
    lighting      "nominal" | "low" | "flicker" (light intensity modulated at flicker_hz)
                  | "dusk" | "hdr" (see Light below)
    flicker_hz    float, 10.0
    flicker_depth float in (0, 0.5] (0.35): the lights at 1 - d + d sin(2 pi f t + phase)
    illuminance_lux  float or None: the nominal light (None: indoor 400 lux, an office;
                  outdoor 1e4, an overcast day)
    dusk_lux      float (3.0): the light under "dusk"
    hdr_lux       float or None: the shade's light under "hdr" (None: indoor 30, outdoor 50)
    lamp_cd_m2    float in (0, 1e9] (1e4): the HDR emitter's luminance, cd/m^2 (a window
                  onto a bright overcast sky)
    rgb_blur      int sub-frames averaged per RGB frame (0 or 1: no blur); the camera uses it
    width, height int image size, px (160 x 160)
    fovy          float, degrees (70)
    v_max, w_max  float m/s (1.5), rad/s (2.0): command scale
    servo_gain    float multiplier on the drive servos' gains (1.0; large = stiff servo)
    arena         float half size of the room / target area, m (6.0)
    contact_timeconst  float s (0.0 = MuJoCo's default 0.02): contact solref time constant;
                  set, MuJoCo's refsafe clamp (>= 2 timesteps) is disabled too, so stiff
                  contacts (the issue's stiff case) are really that stiff
    plus integrator, timestep, shadows (Scene).

    Light (photometry(), sebvs/sim/light.py). The render's lights are relative; the
    config says what they are in physical units: "nominal" and "flicker" at
    illuminance_lux, "low" the same lights dimmed as the render dims them (x 0.16),
    "dusk" at dusk_lux, "hdr" a backlit scene. The outdoor sky is always in view: a
    uniform overcast sky of luminance L gives E = pi L, so a sky texel of 1 is
    illuminance / pi, as bright as a white lit surface; under "hdr" the sky is the bright
    emitter (lamp_cd_m2) and the ground and target are in the shade (hdr_lux). Indoors
    "hdr" adds windows: a band of self-luminous panels (material "hdr_lamp", luminance
    lamp_cd_m2, white in the 8-bit render) on all four walls from a 0.3 m sill to 1.9 m,
    glazing onto an overcast sky; from the robot's start pose they fill ~21 % of the front
    image, behind and above the target (tests/test_sim_light.py), while the room is at
    hdr_lux.
    """

    task = "nav"
    command_dim = 2
    cameras = ("front", "overview")
    defaults = {**Scene.defaults, "variant": "indoor", "floor": "checker",
                "target_rgb": (0.9, 0.15, 0.1), "target_speed": "nominal",
                "lighting": "nominal", "flicker_hz": 10.0, "rgb_blur": 0, "width": 160,
                "height": 160, "fovy": 70.0, "v_max": 1.5, "w_max": 2.0, "servo_gain": 1.0,
                "arena": 6.0, "contact_timeconst": 0.0, **LIGHT_DEFAULTS}

    def validate(self) -> None:
        c = self.config
        choices = {"variant": VARIANTS, "floor": FLOORS, "target_speed": tuple(SPEEDS),
                   "lighting": LIGHTING}
        for key, allowed in choices.items():
            if c[key] not in allowed:
                raise ValueError(f"nav scene: {key} {c[key]!r} is not one of {allowed}")
        positive = {"flicker_hz": float, "width": int, "height": int, "fovy": float,
                    "v_max": float, "w_max": float, "servo_gain": float, "arena": float}
        for key, tp in positive.items():
            v = c[key]
            ok = isinstance(v, int) if tp is int else isinstance(v, (int, float))
            if isinstance(v, bool) or not ok or not v > 0:
                raise ValueError(f"nav scene: {key} must be a positive {tp.__name__}, got {v!r}")
        if not (isinstance(c["rgb_blur"], int) and 0 <= c["rgb_blur"] <= 64):
            raise ValueError(f"nav scene: rgb_blur must be an int in [0, 64], got {c['rgb_blur']!r}")
        if not 1 <= c["fovy"] < 180:
            raise ValueError(f"nav scene: fovy {c['fovy']!r} must be in [1, 180) degrees")
        tc = c["contact_timeconst"]
        if isinstance(tc, bool) or not isinstance(tc, (int, float)) or tc < 0:
            raise ValueError(f"nav scene: contact_timeconst must be >= 0, got {tc!r}")
        if c["arena"] < 2.0:
            raise ValueError("nav scene: arena must be >= 2 m")
        rgb = c["target_rgb"]
        if not (isinstance(rgb, (list, tuple)) and len(rgb) == 3 and all(
                isinstance(x, (int, float)) and not isinstance(x, bool) and 0 <= x <= 1
                for x in rgb)):
            raise ValueError(f"nav scene: target_rgb must be three numbers in [0, 1], "
                             f"got {rgb!r}")
        self.validate_light()

    # ------------------------------------------------------------------ light
    def default_lux(self) -> float:
        return NOMINAL_LUX[self.config["variant"]]

    def default_hdr_lux(self) -> float:
        return HDR_LUX[self.config["variant"]]

    def has_lamp(self) -> bool:
        """Indoors the HDR emitter is the windows; outdoors it is the sky."""
        return self.config["variant"] == "indoor"

    def sky_cd_m2(self, illuminance_lux: float) -> float | None:
        if self.config["variant"] != "outdoor":
            return None
        if self.config["lighting"] == "hdr":
            return float(self.config["lamp_cd_m2"])
        return illuminance_lux / math.pi

    def windows_xml(self) -> str:
        """The HDR condition's windows (indoor, lighting "hdr"; else nothing): one panel 1 cm
        in front of each wall's inner face, 30 cm short of each corner, no collisions."""
        if self.config["lighting"] != "hdr":
            return ""
        a = float(self.config["arena"])
        z0, z1 = WINDOW_Z
        zc, hz = (z0 + z1) / 2, (z1 - z0) / 2
        d = a - 0.05 - 0.011            # wall inner face at a - 0.05; panels 1 cm thick
        half = a - 0.3
        panels = (("n", 0, d, half, 0.005), ("s", 0, -d, half, 0.005),
                  ("e", d, 0, 0.005, half), ("w", -d, 0, 0.005, half))
        return "".join(
            f'\n    <geom name="window_{n}" type="box" pos="{x:g} {y:g} {zc:g}" '
            f'size="{sx:g} {sy:g} {hz:g}" material="{HDR_LAMP}" contype="0" conaffinity="0"/>'
            for n, x, y, sx, sy in panels)

    # ------------------------------------------------------------------ model
    def mjcf(self) -> str:
        c = self.config
        shadow = self.light_xml()
        a = float(c["arena"])
        key = self.light_levels()[0]
        gain = c["servo_gain"]
        kv_v = gain * MASS / 0.05            # forward servo: 50 ms time constant
        kv_w = gain * 0.5 / 0.05             # yaw: ~0.5 kg m^2 about z (chassis + wheels)
        kv_l = gain * MASS / 0.02            # lateral grip: stiffer
        traction = MU * MASS * G
        torque = traction * HALF[1]          # what the wheels' traction can apply about z
        vmax, wmax = float(c["v_max"]), float(c["w_max"])
        if c["variant"] == "indoor":
            wall_h = 2.0
            walls = "\n".join(
                f'<geom name="wall_{n}" type="box" pos="{x} {y} {wall_h / 2}" '
                f'size="{sx} {sy} {wall_h / 2}" material="wall"/>'
                for n, x, y, sx, sy in (("n", 0, a, a, 0.05), ("s", 0, -a, a, 0.05),
                                        ("e", a, 0, 0.05, a), ("w", -a, 0, 0.05, a)))
            world = f"""
    <geom name="floor" type="plane" size="{a} {a} 1" material="floor"/>
    {walls}
    <geom name="ceiling" type="box" pos="0 0 {wall_h}" size="{a} {a} 0.02" material="wall"
          contype="0" conaffinity="0"/>
    <light name="key" pos="0 0 {wall_h - 0.1}" dir="0 0 -1" directional="false" diffuse="{key} {key} {key}"
           specular="0.1 0.1 0.1" attenuation="1 0 0" castshadow="{shadow}"/>
    <light name="fill" pos="{a / 2} {-a / 2} 3" dir="-0.3 0.3 -1" diffuse="{key / 2} {key / 2} {key / 2}"
           specular="0 0 0" castshadow="false"/>{self.windows_xml()}"""
            # plain: one grey, the checker's mean, so only the marks and the target move
            light, dark = CHECKER
            mean = tuple((a + b) / 2 for a, b in zip(light, dark))
            rgb1, rgb2 = (light, dark) if c["floor"] == "checker" else (mean, mean)
            floor_builtin = "checker" if c["floor"] == "checker" else "flat"
            floor_rgb1, floor_rgb2 = (" ".join(f"{x:g}" for x in v) for v in (rgb1, rgb2))
            assets = f"""
    <texture name="floor" type="2d" builtin="{floor_builtin}" rgb1="{floor_rgb1}" rgb2="{floor_rgb2}"
             width="256" height="256" mark="random" random="0.02" markrgb="0.8 0.8 0.8"/>
    <material name="floor" texture="floor" texrepeat="12 12"/>
    <texture name="wall" type="2d" builtin="gradient" rgb1="0.75 0.72 0.65" rgb2="0.45 0.45 0.5"
             width="64" height="64"/>
    <material name="wall" texture="wall" texrepeat="4 1"/>"""
            if c["lighting"] == "hdr":
                assets += f"""
    <material name="{HDR_LAMP}" rgba="0.95 0.97 1 1" emission="1" specular="0"/>"""
        else:
            world = f"""
    <geom name="floor" type="plane" size="{4 * a} {4 * a} 4" material="ground"/>
    <light name="key" pos="0 0 20" dir="-0.4 0.3 -1" directional="true" diffuse="{key} {key} {key * 0.92}"
           specular="0.2 0.2 0.2" castshadow="{shadow}"/>
    <light name="fill" pos="0 0 20" dir="0.3 -0.2 -1" directional="true" diffuse="{key / 3} {key / 3} {key / 3}"
           specular="0 0 0" castshadow="false"/>"""
            assets = """
    <texture name="sky" type="skybox" builtin="gradient" rgb1="0.45 0.62 0.85" rgb2="0.9 0.93 1.0"
             width="256" height="256"/>
    <texture name="ground" type="2d" builtin="flat" rgb1="0.32 0.42 0.22" rgb2="0.25 0.33 0.18"
             width="256" height="256" mark="random" random="0.15" markrgb="0.45 0.4 0.3"/>
    <material name="ground" texture="ground" texrepeat="30 30"/>"""
        wheels = "\n".join(
            f'<geom name="wheel_{i}" type="cylinder" size="0.07 0.03" pos="{x} {y} -0.03" '
            f'euler="1.5708 0 0" rgba="0.08 0.08 0.08 1" contype="0" conaffinity="0" mass="0.5"/>'
            for i, (x, y) in enumerate(((0.17, 0.23), (0.17, -0.23), (-0.17, 0.23),
                                        (-0.17, -0.23))))
        target_rgba = " ".join(f"{float(x):g}" for x in c["target_rgb"]) + " 1"
        return f"""{self.mjcf_head(f"sebvs_nav_{c['variant']}")}
  <asset>{assets}
  </asset>
  <worldbody>{world}
    <body name="robot" pos="0 0 0.1">
      <joint name="x" type="slide" axis="1 0 0"/>
      <joint name="y" type="slide" axis="0 1 0"/>
      <joint name="yaw" type="hinge" axis="0 0 1"/>
      <geom name="chassis" type="box" size="{HALF[0]} {HALF[1]} {HALF[2]}" pos="0 0 0.02"
            mass="{MASS}" rgba="0.2 0.35 0.7 1"/>
      <geom name="mast" type="box" size="0.03 0.03 0.05" pos="0.2 0 0.12" mass="0.1"
            rgba="0.15 0.15 0.15 1" contype="0" conaffinity="0"/>
      {wheels}
      <site name="base" pos="0 0 0"/>
      <camera name="front" pos="0.24 0 0.18" xyaxes="0 -1 0 0 0 1" fovy="{float(c['fovy'])}"/>
    </body>
    <body name="target" mocap="true" pos="2.5 0 {CUBE}">
      <geom name="target" type="box" size="{CUBE} {CUBE} {CUBE}" rgba="{target_rgba}"
            contype="0" conaffinity="0"/>
    </body>
    <camera name="overview" pos="0 {-a * 1.1} {a}" xyaxes="1 0 0 0 0.7 0.7" fovy="60"/>
  </worldbody>
  <actuator>
    <velocity name="v" site="base" gear="1 0 0 0 0 0" kv="{kv_v}" ctrlrange="{-vmax} {vmax}"
              forcerange="{-traction} {traction}"/>
    <velocity name="w" site="base" gear="0 0 0 0 0 1" kv="{kv_w}" ctrlrange="{-wmax} {wmax}"
              forcerange="{-torque} {torque}"/>
    <velocity name="lateral" site="base" gear="0 1 0 0 0 0" kv="{kv_l}" ctrlrange="0 0"
              forcerange="{-traction} {traction}"/>
  </actuator>
</mujoco>
"""

    def compile(self) -> mujoco.MjModel:
        model = super().compile()
        # map.znear is relative to the model's extent (~24 m here): 0.02 would clip the
        # floor within 0.5 m of the camera. Ask for 3 cm in absolute terms.
        model.vis.map.znear = 0.03 / model.stat.extent
        self._ids(model)
        return model

    def _ids(self, model: mujoco.MjModel) -> None:
        self.target_mocap = int(model.body_mocapid[model.body("target").id])
        self.cam_front = model.camera("front").id
        self.qadr = [int(model.jnt_qposadr[model.joint(n).id]) for n in ("x", "y", "yaw")]

    def limits(self) -> Limits:
        a = float(self.config["arena"])
        return Limits(bounds=(-4 * a, 4 * a, -4 * a, 4 * a, -1.0, 5.0),
                      max_speed=3 * float(self.config["v_max"]) + 1.0,
                      max_angular=3 * float(self.config["w_max"]) + 1.0,
                      # kinetic energy at top speed is ~ 0.5*10*1.5^2 = 11 J
                      max_energy_jump=50.0,
                      # what the drive can give (top speed and turn rate at once), x1.5
                      max_kinetic=1.5 * 0.5 * (ROBOT_MASS * float(self.config["v_max"]) ** 2
                                               + ROBOT_INERTIA_Z
                                               * float(self.config["w_max"]) ** 2))

    # ------------------------------------------------------------------ episode
    def reset(self, model, data, rng: np.random.Generator) -> None:
        if not hasattr(self, "target_mocap"):
            self._ids(model)
        mujoco.mj_resetData(model, data)
        a = float(self.config["arena"])
        inner = a - 1.0                          # keep the target off the walls
        # Target starts 2-3.5 m ahead within +-20 deg, so the episode begins in view.
        r, b = rng.uniform(2.0, 3.5), rng.uniform(-0.35, 0.35)
        start = np.array([r * math.cos(b), r * math.sin(b)])
        cfg = TrajectoryConfig(speed=SPEEDS[self.config["target_speed"]],
                               bounds=(-inner, inner, -inner, inner))
        self.trajectory = WaypointTrajectory(start, rng.uniform(-math.pi, math.pi), cfg,
                                             np.random.default_rng(rng.integers(2 ** 63)))
        data.mocap_pos[self.target_mocap] = [start[0], start[1], CUBE]
        data.mocap_quat[self.target_mocap] = [1, 0, 0, 0]
        self.reset_lights(model, rng)
        data.ctrl[:] = 0.0
        mujoco.mj_forward(model, data)

    def clip_command(self, command: np.ndarray) -> np.ndarray:
        """[v, w] clipped to [-1, 1], the fractions of v_max and w_max the wheels take."""
        return np.clip(np.asarray(command, dtype=np.float64), -1.0, 1.0)

    def apply_command(self, model, data, command: np.ndarray) -> None:
        cmd = np.asarray(command, dtype=np.float64)
        if cmd.shape != (2,):
            raise ValueError(f"nav command must have shape (2,), got {cmd.shape}")
        if not np.isfinite(cmd).all():
            raise ValueError(f"nav command is not finite: {cmd.tolist()}")
        v, w = self.clip_command(cmd)
        data.ctrl[0] = v * float(self.config["v_max"])
        data.ctrl[1] = w * float(self.config["w_max"])
        data.ctrl[2] = 0.0

    def scripted(self, model, data) -> None:
        xy = self.trajectory.step(model.opt.timestep)
        data.mocap_pos[self.target_mocap, :2] = xy
        self.flicker(model, data)

    # ------------------------------------------------------------------ truth
    def robot_pose(self, data) -> tuple[float, float, float]:
        """(x m, y m, yaw rad) of the robot base."""
        q = data.qpos
        return float(q[self.qadr[0]]), float(q[self.qadr[1]]), float(q[self.qadr[2]])

    def project(self, model, data, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pinhole projection into the front camera (needs kinematics of this state).

        points (N, 3) world m -> (uv (N, 2) px, column/row from the top-left corner,
        depth (N,) m along the view axis; <= 0 is behind the camera).
        """
        w, h = int(self.config["width"]), int(self.config["height"])
        f = 0.5 * h / math.tan(math.radians(model.cam_fovy[self.cam_front]) / 2)
        R = data.cam_xmat[self.cam_front].reshape(3, 3)   # columns: camera x, y, z in world
        pc = (points - data.cam_xpos[self.cam_front]) @ R   # (N, 3) in the camera frame
        depth = -pc[:, 2]                                   # MuJoCo cameras look along -z
        safe = np.where(depth > 1e-6, depth, 1e-6)
        uv = np.stack([w / 2 + f * pc[:, 0] / safe, h / 2 - f * pc[:, 1] / safe], axis=1)
        return uv, depth

    def truth(self, model, data) -> dict:
        """Target centroid/bbox in the front image and both poses (see module docstring).

        Keys: robot [x, y, yaw], target [x, y, z], centroid [u, v] px (projected cube
        centre), bbox [u0, v0, u1, v1] px clipped to the image, visible (bool: centre in
        front and the box overlaps the image), distance m, image [width, height].
        Kinematics are recomputed for the current qpos/mocap (mj_step leaves them one step
        behind), so the truth matches what the camera renders from state().
        """
        self.kinematics(model, data)
        w, h = int(self.config["width"]), int(self.config["height"])
        c = data.mocap_pos[self.target_mocap].copy()
        corners = c + CUBE * np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1)
                                       for sz in (-1, 1)], dtype=np.float64)
        uv, depth = self.project(model, data, np.vstack([c[None], corners]))
        centre, cuv, cdepth = uv[0], uv[1:], depth[1:]
        in_front = bool(depth[0] > 0 and (cdepth > 0).all())
        u0, v0 = cuv.min(axis=0)
        u1, v1 = cuv.max(axis=0)
        overlaps = in_front and u1 > 0 and v1 > 0 and u0 < w and v0 < h
        bbox = [float(np.clip(u0, 0, w)), float(np.clip(v0, 0, h)),
                float(np.clip(u1, 0, w)), float(np.clip(v1, 0, h))] if overlaps else \
            [0.0, 0.0, 0.0, 0.0]
        rx, ry, ryaw = self.robot_pose(data)
        return {"robot": [rx, ry, ryaw], "target": c.tolist(),
                "centroid": [float(centre[0]), float(centre[1])] if in_front else [-1.0, -1.0],
                "bbox": bbox, "visible": bool(overlaps),
                "distance": float(np.hypot(c[0] - rx, c[1] - ry)), "image": [w, h]}
