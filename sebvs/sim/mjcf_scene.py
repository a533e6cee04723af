"""Your own MJCF as a scene: any MuJoCo model in a topology (`scene = "mjcf"`).

    [actors.sim]
    run = "actors.sim:Sim"
    scene = "mjcf"
    config = { path = "robot.xml", camera = "wrist", width = 96, height = 96 }

The sim, camera, emulator, accumulator, recorder and viewer actors run on it as on the
project's own scenes. The camera compiles its own copy from the same config, as it does
for nav and arm; both keep the project's render-speed settings (no MSAA, no shadow map:
sebvs.sim.scene.FAST_VISUAL) unless `shadows = true`. docs/own_robot.md.

Config keys (defaults):
  path              the MJCF file (required): relative to the working directory, or to
                    `package`'s folder
  package           "" or an installed package that ships the file, e.g. "gymnasium"
                    for its stock models under envs/mujoco/assets/
  camera            the camera to render: a camera of the model, "" its first; with
                    camera_pose the name of the camera added ("" = "sebvs_view")
  camera_pose       None (or {}), or { pos = [x, y, z], lookat = [x, y, z], up = [0, 0,
                    1], fovy = 45.0 }: a fixed camera added to the world, for models
                    that have none (Gymnasium's reacher and pusher) or a view of your own
  keyframe          "" or a keyframe of the model that every episode starts from
  width, height     image size, px (160 x 160)
  illuminance_lux   the light on a white surface facing the key light (lux), or None
  luminance_cd_m2   or that surface's luminance (cd/m^2; = lux / pi), or None; neither:
                    400 lux (office light, sebvs/sim/model_scene.py DEFAULT_LUX). The
                    model's own lights set the relative levels either way
  script            "sine": with no actor commanding the actuators, each follows a
                    sinusoid inside its ctrlrange; "hold": they hold the idle command
  script_amplitude  the sinusoid's amplitude, a fraction of each half range (0.5)
  script_hz         [lo, hi]: each actuator's frequency drawn from it per episode
                    ([0.2, 1.0]; the phases too, from the episode's seed)
  rgb_blur          sub-frames averaged per ideal RGB frame (0)
plus the scenes' common keys (integrator and timestep come from the sim's parameters).

Commands: a vector of model.nu values, one per actuator in the model's order, each
clipped to its actuator's ctrlrange where the actuator is ctrllimited; another length or
a NaN/inf is refused (the sim keeps its last good command and counts the rejection).
The idle command is 0 clipped into each range.
"""
from __future__ import annotations

import copy
import math

import mujoco
import numpy as np

from .mjcf_source import WHERE, CameraPose, add_camera, compile_spec, find_mjcf, load_spec
from .model_scene import (DEFAULT_LUX, UnknownCamera, camera_names, check_size,
                          default_photometry, kinematics_with_tendons, prepare_render,
                          render_level)
from .scene import Scene

SCRIPTS = ("sine", "hold")
ADDED_CAMERA = "sebvs_view"


class MjcfScene(Scene):
    """A user's MJCF model (module docstring). `command_dim` (model.nu) and `cameras`
    (the camera to render first, then the model's others) are known once the config's
    file has compiled, in the constructor."""

    task = "mjcf"
    command_name = "action"
    defaults = {**Scene.defaults, "path": "", "package": "", "camera": "",
                "camera_pose": None, "keyframe": "", "width": 160, "height": 160,
                "illuminance_lux": None, "luminance_cd_m2": None, "script": "sine",
                "script_amplitude": 0.5, "script_hz": [0.2, 1.0], "rgb_blur": 0}

    def validate(self) -> None:
        c = self.config
        self.file = find_mjcf(c["path"], c["package"])
        spec = load_spec(self.file)
        view = self._add_view(spec)
        model = compile_spec(spec, self.file)
        self.view = self._pick_camera(model, view)
        # an unnamed camera goes by its id, as the renderers take it
        names = [k if n.startswith("#") else n for k, n in enumerate(camera_names(model))]
        self.cameras = (self.view, *[n for n in names if n != self.view])
        self._check_size()
        self._check_light(model)
        self._check_script()
        self.keyframe_id = self._keyframe(model)
        self.source_model = model
        self.command_dim = int(model.nu)
        lo, hi = self.ctrl_bounds(model)
        self.lo, self.hi = lo, hi
        # the script of the episode (reset draws it): frequency and phase per actuator
        self.script_f = np.zeros(model.nu)
        self.script_phase = np.zeros(model.nu)

    # -- config checks -------------------------------------------------------------------
    def _add_view(self, spec: mujoco.MjSpec) -> str | None:
        """Add the camera_pose's camera (its name), or None when there is no pose."""
        c = self.config
        if c["camera_pose"] is None or c["camera_pose"] == {}:
            return None                 # {}: none (TOML has no null; --set 'key={}')
        pose = CameraPose.parse(c["camera_pose"])
        name = c["camera"] or ADDED_CAMERA
        if not isinstance(name, str):
            raise ValueError(f"{WHERE}: config key 'camera' must be a name, got {name!r}")
        if any(cam.name == name for cam in spec.cameras):
            raise ValueError(f"{WHERE}: {self.file} already has a camera named {name!r}: "
                             f"drop camera_pose to render it, or name the added one "
                             f"otherwise (config key 'camera')")
        add_camera(spec, name, pose)
        return name

    def _pick_camera(self, model: mujoco.MjModel, added: str | None):
        if added is not None:
            return added
        name = self.config["camera"]
        names = camera_names(model)
        have = ", ".join(repr(n) for n in names) if names else "none"
        pose_hint = ("add one with camera_pose = { pos = [x, y, z], lookat = [x, y, z] } "
                     "(config key)")
        if not isinstance(name, str):
            raise UnknownCamera(f"{WHERE}: config key 'camera' must be a camera's name, got "
                                f"{name!r}")
        if not names:
            raise UnknownCamera(f"{WHERE}: {self.file} has no camera: {pose_hint}")
        if not name:
            return names[0] if not names[0].startswith("#") else 0
        if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, name) < 0:
            raise UnknownCamera(f"{WHERE}: {self.file} has no camera named {name!r} (its "
                                f"cameras: {have}; or {pose_hint})")
        return name

    def _check_size(self) -> None:
        check_size(self.config["width"], self.config["height"], WHERE)
        blur = self.config["rgb_blur"]
        if isinstance(blur, bool) or not isinstance(blur, int) or not 0 <= blur <= 64:
            raise ValueError(f"{WHERE}: rgb_blur must be an integer in 0..64, got {blur!r}")

    def _check_light(self, model: mujoco.MjModel) -> None:
        c = self.config
        given = [k for k in ("illuminance_lux", "luminance_cd_m2") if c[k] is not None]
        if len(given) > 1:
            raise ValueError(f"{WHERE}: set illuminance_lux or luminance_cd_m2, not both")
        for key in given:
            v = c[key]
            if isinstance(v, bool) or not isinstance(v, (int, float)) \
                    or not 0 < v <= 1e9 or not math.isfinite(v):
                raise ValueError(f"{WHERE}: {key} must be a positive number, got {v!r}")
        if not render_level(model) > 0:
            raise ValueError(f"{WHERE}: nothing lights {self.file} (no active light and the "
                             f"headlight off): add a <light> to it")

    def _check_script(self) -> None:
        c = self.config
        if c["script"] not in SCRIPTS:
            raise ValueError(f"{WHERE}: script must be one of {', '.join(SCRIPTS)}, got "
                             f"{c['script']!r}")
        a = c["script_amplitude"]
        if isinstance(a, bool) or not isinstance(a, (int, float)) or not 0 <= a <= 1:
            raise ValueError(f"{WHERE}: script_amplitude must be in [0, 1] (a fraction of "
                             f"each ctrlrange's half width), got {a!r}")
        hz = c["script_hz"]
        ok = isinstance(hz, (list, tuple)) and len(hz) == 2 and all(
            not isinstance(v, bool) and isinstance(v, (int, float)) for v in hz) \
            and 0 < hz[0] <= hz[1] <= 100
        if not ok:
            raise ValueError(f"{WHERE}: script_hz must be [lo, hi] with 0 < lo <= hi <= 100 "
                             f"Hz, got {hz!r}")

    def _keyframe(self, model: mujoco.MjModel) -> int | None:
        key = self.config["keyframe"]
        if key in ("", None):
            return None
        k = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_KEY, key) \
            if isinstance(key, str) else -1
        if k < 0:
            have = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_KEY, i) or f"#{i}"
                    for i in range(model.nkey)]
            raise ValueError(f"{WHERE}: {self.file} has no keyframe {key!r} (its keyframes: "
                             f"{', '.join(have) or 'none'})")
        return k

    @staticmethod
    def ctrl_bounds(model: mujoco.MjModel) -> tuple[np.ndarray, np.ndarray]:
        """Each actuator's ctrlrange, float64 (nu,) each; (-inf, inf) where it is not
        ctrllimited."""
        limited = np.asarray(model.actuator_ctrllimited, bool)
        rng = np.asarray(model.actuator_ctrlrange, np.float64).reshape(-1, 2)
        lo = np.where(limited, rng[:, 0], -np.inf)
        hi = np.where(limited, rng[:, 1], np.inf)
        return lo, hi

    # -- model ---------------------------------------------------------------------------
    def mjcf(self) -> str:
        """The file's own text (its includes are resolved when it is compiled)."""
        return self.file.read_text()

    def compile(self) -> mujoco.MjModel:
        """A fresh copy of the compiled model with the config's integrator and timestep,
        the render-speed settings and an offscreen buffer at least the image's size."""
        model = copy.deepcopy(self.source_model)
        self.configure(model)
        h, w = self.image_shape()
        prepare_render(model, w, h, shadows=bool(self.config["shadows"]))
        return model

    def photometry(self):
        """The model's MJCF lights scaled to the config's light (module docstring)."""
        c = self.config
        if c["illuminance_lux"] is not None:
            lux = float(c["illuminance_lux"])
        elif c["luminance_cd_m2"] is not None:
            lux = math.pi * float(c["luminance_cd_m2"])    # a white Lambertian surface
        else:
            lux = DEFAULT_LUX
        return default_photometry(self.source_model, lux)

    # -- episode -------------------------------------------------------------------------
    def reset(self, model, data, rng: np.random.Generator) -> None:
        """The model's initial state (or the config's keyframe), and the episode's script
        drawn from `rng`."""
        if self.keyframe_id is None:
            mujoco.mj_resetData(model, data)
        else:
            mujoco.mj_resetDataKeyframe(model, data, self.keyframe_id)
        lo, hi = self.config["script_hz"]
        self.script_f = rng.uniform(float(lo), float(hi), model.nu)
        self.script_phase = rng.uniform(0.0, 2 * math.pi, model.nu)
        mujoco.mj_forward(model, data)

    def idle_command(self) -> np.ndarray:
        return np.clip(np.zeros(self.command_dim), self.lo, self.hi)

    def clip_command(self, command: np.ndarray) -> np.ndarray:
        """Each value inside its actuator's ctrlrange (where ctrllimited)."""
        return np.clip(np.asarray(command, dtype=np.float64), self.lo, self.hi)

    def apply_command(self, model, data, command: np.ndarray) -> None:
        cmd = np.asarray(command, dtype=np.float64)
        if cmd.shape != (self.command_dim,):
            raise ValueError(f"mjcf command must have shape ({self.command_dim},) (one per "
                             f"actuator), got {cmd.shape}")
        if not np.isfinite(cmd).all():
            raise ValueError(f"mjcf command is not finite: {cmd.tolist()}")
        data.ctrl[:] = self.clip_command(cmd)

    def scripted_command(self, model, data) -> np.ndarray:
        """The script's command at the state's time, float64 (nu,): each actuator's
        sinusoid about the middle of its ctrlrange ([-1, 1] for one not ctrllimited), or
        the idle command under script "hold"."""
        if self.config["script"] == "hold":
            return self.idle_command()
        lo = np.where(np.isfinite(self.lo), self.lo, -1.0)
        hi = np.where(np.isfinite(self.hi), self.hi, 1.0)
        mid, half = (lo + hi) / 2, (hi - lo) / 2
        a = float(self.config["script_amplitude"])
        wave = np.sin(2 * math.pi * self.script_f * float(data.time) + self.script_phase)
        return self.clip_command(mid + a * half * wave)

    def truth(self, model, data) -> dict:
        """No task, so no privileged target: the image size only (as the other scenes give
        it, for the viewer's overlays)."""
        return {"image": [int(self.config["width"]), int(self.config["height"])]}

    def proprio_reader(self, model):
        """qpos then qvel of every joint (sebvs/sim/proprio.py)."""
        from .proprio import ProprioReader
        names, lo, hi = joint_components(model)

        def read(data) -> np.ndarray:
            return np.concatenate([data.qpos, data.qvel]).astype(np.float64)

        return ProprioReader(tuple(names), lo, hi, read)

    kinematics = staticmethod(kinematics_with_tendons)


# qpos / qvel components per joint type (mjtJoint: free, ball, slide, hinge)
QPOS_PARTS = {0: ("x", "y", "z", "qw", "qx", "qy", "qz"), 1: ("qw", "qx", "qy", "qz"),
              2: ("",), 3: ("",)}
QVEL_PARTS = {0: ("vx", "vy", "vz", "wx", "wy", "wz"), 1: ("wx", "wy", "wz"), 2: ("",),
              3: ("",)}


def joint_components(model: mujoco.MjModel) -> tuple[list[str], np.ndarray, np.ndarray]:
    """Names and bounds of qpos then qvel, joint by joint.

    Parameters:
        model: the model.
    Returns:
        names ("qpos.<joint>[.<part>]", then "qvel.<joint>[.<part>]"; an unnamed joint is
        "joint<k>"), lo, hi float64 (nq + nv,): a limited hinge or slide joint's range
        widened by 0.1 (a joint limit is soft), else -inf / inf.
    """
    names_q, names_v = [None] * model.nq, [None] * model.nv
    lo = np.full(model.nq + model.nv, -np.inf)
    hi = np.full(model.nq + model.nv, np.inf)
    for j in range(model.njnt):
        name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, j) or f"joint{j}"
        kind = int(model.jnt_type[j])
        qadr, dadr = int(model.jnt_qposadr[j]), int(model.jnt_dofadr[j])
        for i, part in enumerate(QPOS_PARTS[kind]):
            names_q[qadr + i] = f"qpos.{name}" + (f".{part}" if part else "")
        for i, part in enumerate(QVEL_PARTS[kind]):
            names_v[dadr + i] = f"qvel.{name}" + (f".{part}" if part else "")
        if kind in (2, 3) and model.jnt_limited[j]:
            lo[qadr], hi[qadr] = model.jnt_range[j, 0] - 0.1, model.jnt_range[j, 1] + 0.1
    return [*names_q, *names_v], lo, hi

