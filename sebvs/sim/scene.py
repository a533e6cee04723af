"""The `Scene` interface every MuJoCo task implements (nav, arm).

A scene is pure library code: it builds an MJCF model from its config, resets episodes from
a seeded generator, applies commands and scripted motion, and reports privileged truth. It
never touches sockets or processes: the sim and camera actors wire it to the runtime.

Split of roles across processes:
  sim actor     compile() -> reset() -> loop { scripted(); mj_step } with apply_command()
                at control ticks, truth()/done() to end episodes, state() on the wire.
  camera actor  compile() its own model from the same config, then set_state() +
                Scene.kinematics() (not mj_kinematics alone: cameras would be stale)
                and render `cameras`.

Config is deterministic: mjcf() depends on the config only, never on the episode seed, so
the camera's model is identical to the sim's.
"""
from __future__ import annotations

from abc import ABC, abstractmethod
import math
from typing import TYPE_CHECKING, Any, ClassVar

import mujoco
import numpy as np

if TYPE_CHECKING:
    from .light import Photometry

# Integrator names accepted in config -> MuJoCo enum (mujoco.mjtIntegrator).
INTEGRATORS: dict[str, int] = {
    "euler": mujoco.mjtIntegrator.mjINT_EULER,
    "rk4": mujoco.mjtIntegrator.mjINT_RK4,
    "implicit": mujoco.mjtIntegrator.mjINT_IMPLICIT,
    "implicitfast": mujoco.mjtIntegrator.mjINT_IMPLICITFAST,
}
if hasattr(mujoco.mjtIntegrator, "mjINT_DISCRETE"):   # MuJoCo >= 3.13
    INTEGRATORS["discrete"] = mujoco.mjtIntegrator.mjINT_DISCRETE

# Keys every scene accepts (physics settings the sim actor may pass through).
COMMON_KEYS = frozenset({"integrator", "timestep", "shadows"})

# The render-speed settings every scene's MJCF carries: no MSAA, no shadow map.
FAST_VISUAL = '<visual><quality offsamples="0" shadowsize="0"/></visual>'

# Relative light levels (key light diffuse, headlight ambient) of the ideal 8-bit render:
# nominal (and flicker) lights, and the dim ones of the "low", "dusk" and "hdr" scenes.
NOMINAL_LEVELS = (0.7, 0.3)
DIM_LEVELS = (0.12, 0.04)
DIM_LIGHTING = ("low", "dusk", "hdr")
# The material of the HDR condition's self-luminous surface (a window, a lamp panel).
HDR_LAMP = "hdr_lamp"
# The light keys every scene with a `lighting` config key accepts, and their defaults
# (None: the scene's own, Scene.default_lux / default_hdr_lux).
LIGHT_DEFAULTS = {"illuminance_lux": None, "dusk_lux": 3.0, "hdr_lux": None,
                  "lamp_cd_m2": 1e4, "flicker_depth": 0.35}


class Scene(ABC):
    """One task's MuJoCo world.

    Class attributes:
      task         "nav" | "arm"
      command_dim  length of the command vector apply_command() takes
      command_name the array name a command travels under ("action" for nav [v, w],
                   "pose" for the arm's pre-grasp pose)
      cameras      camera names present in the MJCF
      defaults     config key -> default value (subclasses extend; unknown keys are errors)

    Config (constructor keywords): scene settings from the topology, e.g. variant, conditions,
    plus the COMMON_KEYS: integrator ("euler" | "implicitfast" | "rk4" | "discrete" |
    "implicit"), timestep (s, > 0), shadows (bool, default False).
    """

    task: ClassVar[str]
    command_dim: ClassVar[int]
    command_name: ClassVar[str] = "action"
    cameras: ClassVar[tuple[str, ...]]
    defaults: ClassVar[dict[str, Any]] = {"integrator": None, "timestep": None,
                                          "shadows": False}

    def __init__(self, **config: Any) -> None:
        allowed = set(self.defaults)
        for key in config:
            if key not in allowed:
                raise ValueError(f"{self.task} scene: unknown config key {key!r} "
                                 f"(known: {', '.join(sorted(allowed))})")
        self.config: dict[str, Any] = {**self.defaults, **config}
        integ = self.config["integrator"]
        if integ is not None and integ not in INTEGRATORS:
            raise ValueError(f"{self.task} scene: integrator {integ!r} is not one of "
                             f"{sorted(INTEGRATORS)}")
        ts = self.config["timestep"]
        if ts is not None and not (isinstance(ts, (int, float)) and 0 < ts <= 0.1):
            raise ValueError(f"{self.task} scene: timestep {ts!r} must be in (0, 0.1] s")
        self.validate()

    def validate(self) -> None:
        """Check scene-specific config values; raise ValueError naming the bad key."""

    # -- model ---------------------------------------------------------------------------
    @abstractmethod
    def mjcf(self) -> str:
        """Full MJCF xml, a function of the config only (never of an episode seed)."""

    def compile(self) -> mujoco.MjModel:
        """The model from mjcf(), with the config's integrator and timestep applied."""
        model = mujoco.MjModel.from_xml_string(self.mjcf())
        self.configure(model)
        return model

    def configure(self, model: mujoco.MjModel) -> None:
        """Apply integrator/timestep from config to an existing model (also for tests)."""
        if self.config["integrator"] is not None:
            model.opt.integrator = INTEGRATORS[self.config["integrator"]]
        if self.config["timestep"] is not None:
            model.opt.timestep = float(self.config["timestep"])
        # Energy is needed by the stability checks (sebvs.sim.stability).
        model.opt.enableflags |= mujoco.mjtEnableBit.mjENBL_ENERGY

    def image_shape(self) -> tuple[int, int]:
        """(height, width) in px of the images the camera renders for this scene: config
        keys height/width (default 160 x 160). The camera actor and truth() use it."""
        return int(self.config.get("height", 160)), int(self.config.get("width", 160))

    def rgb_blur(self) -> int:
        """Sub-frames averaged per RGB frame (config key rgb_blur; 0/1 = no blur)."""
        return int(self.config.get("rgb_blur", 0) or 0)

    def light_xml(self) -> str:
        """`castshadow` attribute value for lights: shadows only when the config asks."""
        return "true" if self.config["shadows"] else "false"

    def light_levels(self) -> tuple[float, float]:
        """(key light diffuse, headlight ambient) for the config's lighting: "low", "dusk"
        and "hdr" are dim scenes (the event camera's case), not black ones; their physical
        light is photometry()'s."""
        return DIM_LEVELS if self.config.get("lighting") in DIM_LIGHTING else NOMINAL_LEVELS

    def mjcf_head(self, name: str) -> str:
        """The opening every scene's MJCF shares, up to <asset>: compiler, option, the fast
        render settings, an offscreen buffer for the configured image size, the headlight.
        With config contact_timeconst > 0 every geom's contact gets that solref time
        constant and MuJoCo's refsafe clamp (>= 2 timesteps) is off, so a stiff contact
        is really that stiff (the stiff cases)."""
        h, w = self.image_shape()
        tc = float(self.config.get("contact_timeconst", 0.0) or 0.0)
        flag = '<flag refsafe="disable"/>' if tc > 0 else ""
        solref = f'solref="{tc} 1"' if tc > 0 else ""
        amb = self.light_levels()[1]
        return f"""<mujoco model="{name}">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="0.002" integrator="implicitfast">{flag}</option>
  {FAST_VISUAL}
  <default><geom {solref}/></default>
  <visual>
    <global offwidth="{max(w, 640)}" offheight="{max(h, 640)}"/>
    <headlight ambient="{amb} {amb} {amb}" diffuse="0 0 0" specular="0 0 0"/>
  </visual>"""

    # -- episode -------------------------------------------------------------------------
    @abstractmethod
    def reset(self, model: mujoco.MjModel, data: mujoco.MjData,
              rng: np.random.Generator) -> None:
        """Start a new episode: mj_resetData, randomise from `rng`, mj_forward."""

    def idle_command(self) -> np.ndarray:
        """The command in force before any arrives (float64 (command_dim,)): stand still."""
        return np.zeros(self.command_dim)

    def clip_command(self, command: np.ndarray) -> np.ndarray:
        """The command as this scene executes it (a finite (command_dim,) float64): inside
        its limits. What the sim reports as its command in force (stats, the env's
        info["command"]); apply_command executes the same."""
        return np.asarray(command, dtype=np.float64)

    @abstractmethod
    def apply_command(self, model: mujoco.MjModel, data: mujoco.MjData,
                      command: np.ndarray) -> None:
        """Set data.ctrl (or mocap) from `command` (shape (command_dim,)).

        Raises ValueError on a wrong shape or NaN/inf (the caller keeps its last good
        command); clips to [-1, 1] or to physical limits.
        """

    def scripted(self, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        """Called before every mj_step: moving targets, light flicker, ..."""

    @abstractmethod
    def truth(self, model: mujoco.MjModel, data: mujoco.MjData) -> dict:
        """Privileged ground truth, msgpack-able (lists, floats, ints, bools, str)."""

    def limits(self) -> "Limits":
        """What counts as physical here, for sebvs.sim.stability (override per scene)."""
        from .stability import Limits
        return Limits()

    def done(self, model: mujoco.MjModel, data: mujoco.MjData) -> str | None:
        """A reason string when the episode ends by success/failure, else None."""
        return None

    def finish(self, model: mujoco.MjModel, data: mujoco.MjData, monitor=None) -> dict:
        """After an episode's last tick (not after a divergence or a stop): what the task
        does with the last command, e.g. the arm grasps its last pose. msgpack-able outcome
        for the episode's end message; steps `data` (checked by `monitor`, if given)."""
        return {}

    # -- lighting conditions ----------------------------------------------------------------
    # Scenes with config keys `lighting` ("nominal" | "low" | "flicker" | "dusk" | "hdr"),
    # `flicker_hz` and LIGHT_DEFAULTS' keys share the flicker and the photometry. The
    # flicker scales every light's diffuse by 1 - d + d sin(2 pi f t + phase) (d =
    # flicker_depth, f = flicker_hz), sent to the camera as state `light` since it changes
    # the model, not qpos.
    def validate_light(self) -> None:
        """Check LIGHT_DEFAULTS' keys (called by the scenes' validate()); ValueError
        naming the key."""
        c = self.config

        def number(key: str, lo: float, hi: float, lo_open: bool = True,
                   none: bool = False) -> None:
            v = c[key]
            if v is None and none:
                return
            ok = not isinstance(v, bool) and isinstance(v, (int, float)) and math.isfinite(v) \
                and (lo < v if lo_open else lo <= v) and v <= hi
            if not ok:
                what = f"({lo:g}, {hi:g}]" if lo_open else f"[{lo:g}, {hi:g}]"
                raise ValueError(f"{self.task} scene: {key} must be a number in {what}"
                                 f"{' or None' if none else ''}, got {v!r}")

        number("illuminance_lux", 0.0, 1e6, none=True)
        number("dusk_lux", 0.0, 1e6)
        number("hdr_lux", 0.0, 1e6, none=True)
        number("lamp_cd_m2", 0.0, 1e9)
        # the light never goes negative: its minimum is 1 - 2d
        number("flicker_depth", 0.0, 0.5)

    def default_lux(self) -> float:
        """The nominal illuminance (lux) when the config's illuminance_lux is None."""
        return 400.0

    def default_hdr_lux(self) -> float:
        """The shade's illuminance (lux) in the "hdr" lighting when hdr_lux is None."""
        return 30.0

    def has_lamp(self) -> bool:
        """Whether the "hdr" lighting adds a self-luminous HDR_LAMP surface to the model."""
        return True

    def sky_cd_m2(self, illuminance_lux: float) -> float | None:
        """Luminance (cd/m^2) of a skybox texel of value 1 under the scene's illuminance,
        or None where no sky is in view."""
        return None

    def photometry(self) -> "Photometry":
        """The physical scale of this config's light (sebvs.sim.light.Photometry).

        illuminance: illuminance_lux (or the scene's default) for "nominal" and
        "flicker"; for "low" the same light scaled as the dim render levels scale it
        (sum(DIM_LEVELS) / sum(NOMINAL_LEVELS) = 0.16: a dim indoor scene); dusk_lux for
        "dusk"; hdr_lux (or the scene's default) for "hdr", the shade the target is in.
        render_level is the key + ambient of the levels in force. In "hdr" the emitter
        (material HDR_LAMP, where the scene has one) has luminance lamp_cd_m2; a scene
        with a sky says what a sky texel of 1 is. flicker: (flicker_hz, flicker_depth)
        under "flicker", else None; the illuminance is then the lights' at scale 1 (as
        compiled). The render already carries the flicker (state `light` scales the
        lights' diffuse, not the headlight's ambient): a white surface renders at
        key * scale + ambient.
        """
        from .light import Photometry
        c = self.config
        lighting = c.get("lighting", "nominal")
        nominal = float(c["illuminance_lux"]) if c.get("illuminance_lux") is not None \
            else self.default_lux()
        levels = self.light_levels()
        if lighting == "low":
            lux = nominal * sum(DIM_LEVELS) / sum(NOMINAL_LEVELS)
        elif lighting == "dusk":
            lux = float(c["dusk_lux"])
        elif lighting == "hdr":
            lux = float(c["hdr_lux"]) if c.get("hdr_lux") is not None \
                else self.default_hdr_lux()
        else:
            lux = nominal
        emissive = {HDR_LAMP: float(c["lamp_cd_m2"])} \
            if lighting == "hdr" and self.has_lamp() else {}
        flicker = (float(c["flicker_hz"]), float(c["flicker_depth"])) \
            if lighting == "flicker" else None
        return Photometry(illuminance_lux=lux, render_level=sum(levels), emissive=emissive,
                          sky_cd_m2=self.sky_cd_m2(lux), flicker=flicker)

    def reset_lights(self, model: mujoco.MjModel, rng: np.random.Generator) -> None:
        """Episode start: full intensity, the flicker's phase drawn from `rng`."""
        self.flicker_phase = float(rng.uniform(0, 2 * math.pi))
        self.set_light_scale(model, 1.0)

    def flicker_scale(self, t: float) -> float:
        """The lights' scale at sim time t (s) under "flicker": 1 - d + d sin(2 pi f t +
        phase) (d = flicker_depth, default 0.35: 0.65 + 0.35 sin, 30-100 %)."""
        d = float(self.config.get("flicker_depth", 0.35))
        return (1 - d) + d * math.sin(
            2 * math.pi * self.config["flicker_hz"] * t + self.flicker_phase)

    def flicker(self, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        """From scripted(): modulate the lights when the config's lighting is "flicker".

        The modulation is sampled twice: by the sim's physics step (set every step, 1 kHz
        by default) and by the camera, which sees the lights as they were at each render
        (the sim's render_hz). Mains flicker (100 / 120 Hz: twice the supply frequency)
        needs render rates >= 1 kHz (sim.render_hz, camera.dvs_hz); at 100 Hz a 100 Hz
        flicker aliases to a constant level, 120 Hz to a slow 20 Hz beat.
        """
        if self.config.get("lighting") != "flicker":
            return
        self.set_light_scale(model, self.flicker_scale(data.time))

    def set_light_scale(self, model: mujoco.MjModel, scale: float) -> None:
        """Every light's diffuse at `scale` x the compiled one (taken at the first call)."""
        if not hasattr(self, "base_diffuse"):
            self.base_diffuse = model.light_diffuse.copy()     # (nlight, 3)
        self.light_scale = scale
        model.light_diffuse[:] = self.base_diffuse * scale

    # -- state on the wire ----------------------------------------------------------------
    def state(self, data: mujoco.MjData) -> dict[str, np.ndarray]:
        """What the camera needs to pose its own model: copies of qpos, mocap_pos,
        mocap_quat (float64; shapes (nq,), (nmocap, 3), (nmocap, 4)) and, in scenes with a
        lighting condition, `light` (float64 (1,): the flicker's diffuse scale)."""
        s = {"qpos": data.qpos.copy(), "mocap_pos": data.mocap_pos.copy(),
             "mocap_quat": data.mocap_quat.copy()}
        if "lighting" in self.defaults:
            s["light"] = np.array([getattr(self, "light_scale", 1.0)], dtype=np.float64)
        return s

    @staticmethod
    def kinematics(model: mujoco.MjModel, data: mujoco.MjData) -> None:
        """Positions of bodies, geoms, cameras and lights for the current qpos/mocap.

        mj_kinematics alone leaves cam_xpos/light_xpos stale (mj_camlight computes them):
        renderers and image projections must call this (or mj_forward) instead.
        """
        mujoco.mj_kinematics(model, data)
        mujoco.mj_comPos(model, data)       # subtree com, for tracking camera/light modes
        mujoco.mj_camlight(model, data)

    def set_state(self, model: mujoco.MjModel, data: mujoco.MjData,
                  state: dict[str, np.ndarray]) -> None:
        """Inverse of state(); the caller then runs Scene.kinematics (or mj_forward)."""
        data.qpos[:] = state["qpos"]
        if model.nmocap:
            data.mocap_pos[:] = state["mocap_pos"]
            data.mocap_quat[:] = state["mocap_quat"]
        if "light" in state:
            self.set_light_scale(model, float(state["light"][0]))
