"""The manipulation scene (paper's ERPArm): a UR5 with a two-finger gripper and a wrist
camera above a conveyor belt that carries one cube or several.

The model (the UR5 from its DH parameters, gripper, wrist camera, conveyor, cubes) is
built by sebvs/sim/arm_model.py; this module is what happens on it. The belt's surface
moves at `belt_speed` m/s along +y: `conveyor` "static" stops it, "moving" runs it during
the episode, starting from rest at BELT_ACCEL (a belt that jumped to 3 m/s would tip every
cube over). When the episode ends the belt stops (a stop-and-pick cell) before the last
commanded pose is grasped. The belt's textured skin travels with the surface and jumps back
by one texture period, so a running belt fires events as a real one does.

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

from . import arm_model
from .arm_model import (BELT_HALF_W, BELT_TOP, BELT_X, BELT_Y, CONVEYOR_SOLIDS, CUBE_MASS,
                        JOINTS, SKIN_PERIOD, STROKE, TCP)
from .ik import dls_ik, rpy_to_mat
from .scene import LIGHT_DEFAULTS, Scene
from .stability import Limits

# The conveyor's start-up acceleration: below g * (side / height), no cube tips.
BELT_ACCEL = 0.5 * 9.81  # m/s^2

# The task's constants (the arm expert reads them from this module).
Y_LIMIT = 0.449                         # paper: objects beyond this world y are out of reach
HOME_POSE = (0.50, 0.10, 0.42, math.pi, 0.0, 0.0)   # tcp pose looking down at the belt
LEFTMOST = "world_y"                    # smallest world y = leftmost in the HOME image
CLEARANCE = 0.10                        # pre-grasp height above the cube top, m (expert's)
# A cube's faces repeat every quarter turn, so the pose's yaw leaves the gripper a choice
# of two face pairs: finish() closes on the pair facing along world x, across the belt,
# where the wrist view places cubes best (the belt's long axis, y, has ~2x the error).
GRASP_YAW_OFFSET = math.pi / 2

PALETTE = ((0.9, 0.15, 0.1), (0.1, 0.7, 0.2), (0.15, 0.3, 0.9), (0.95, 0.8, 0.1),
           (0.8, 0.2, 0.8), (0.1, 0.75, 0.8), (0.95, 0.5, 0.1))
CONVEYOR = ("static", "moving")
LIGHTING = ("nominal", "low", "flicker", "dusk", "hdr")
NOMINAL_LUX = 500.0                     # a workshop
HDR_LUX = 30.0                          # the belt in the shade of the HDR condition


class ArmScene(Scene):
    """UR5 + gripper + wrist camera + conveyor with cubes. Config keys (defaults):

    conveyor      "static" | "moving" (belt surface at belt_speed along +y)
    belt_speed    float m/s (0.08) when moving
    objects       int cubes on the belt (1; more = cluttered), 1..6
    cube_half     [min, max] half side, m ([0.0225, 0.03]: 45-60 mm cubes)
    min_gap       float m between cube centres beyond their sizes (0.03)
    spawn_y       [min, max] world y of cube centres at reset ([-0.3, 0.5]; moving: the
                  episode carries them on)
    lighting      "nominal" | "low" | "flicker" (flicker_hz, as the nav scene) | "dusk" |
                  "hdr" (see Light below)
    flicker_hz    float (10.0)
    flicker_depth float in (0, 0.5] (0.35), as the nav scene
    illuminance_lux  float or None: the nominal light (None: 500 lux, a workshop)
    dusk_lux      float (3.0): the light under "dusk"
    hdr_lux       float or None: the belt's light under "hdr" (None: 30 lux, in the shade)
    lamp_cd_m2    float in (0, 1e9] (1e4): the HDR lamp panel's luminance, cd/m^2
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

    Light (photometry(), sebvs/sim/light.py): "nominal" and "flicker" at
    illuminance_lux, "low" those lights dimmed as the render dims them (x 0.16), "dusk" at
    dusk_lux; "hdr" is a backlit cell: the belt and cubes in the shade at hdr_lux and a
    lamp beside the belt, a self-luminous panel (material "hdr_lamp", lamp_cd_m2: a lamp,
    or a sunlit window's reflection) between the pedestal and the belt's near rail that
    fills ~20 % of the HOME wrist image (its top), below the cubes' level, never over one
    (arm_model.LAMP_X, LAMP_Y). No sky.
    """

    task = "arm"
    command_dim = 6
    command_name = "pose"
    cameras = ("wrist", "overview")
    defaults = {**Scene.defaults, "conveyor": "static", "belt_speed": 0.08, "objects": 1,
                "cube_half": [0.0225, 0.03], "min_gap": 0.03, "spawn_y": [-0.3, 0.5],
                "lighting": "nominal", "flicker_hz": 10.0, "rgb_blur": 0, "width": 160,
                "height": 160, "fovy": 75.0, "servo_gain": 1.0, "grip_force": 40.0,
                "grasp_at_end": True, "drop_height": 0.002, "contact_timeconst": 0.0,
                **LIGHT_DEFAULTS}

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
        self.validate_light()

    def default_lux(self) -> float:
        return NOMINAL_LUX

    def default_hdr_lux(self) -> float:
        return HDR_LUX

    def mjcf(self) -> str:
        return arm_model.mjcf(self.mjcf_head("sebvs_arm"), self.config,
                              self.light_levels()[0], self.light_xml())

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
        self.command_pose = self.clip_command(cmd)

    def clip_command(self, command: np.ndarray) -> np.ndarray:
        """The pose with its position clipped into the arm's reach box and its angles
        wrapped to (-pi, pi]."""
        pose = np.array(command, dtype=np.float64)
        pose[:3] = np.clip(pose[:3], (-0.9, -0.9, -0.2), (0.9, 0.9, 0.9))
        pose[3:] = -((-pose[3:] + math.pi) % (2 * math.pi) - math.pi)
        return pose

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
