"""An event camera (and its frame camera) on any MuJoCo model's camera: the library API.

    import mujoco, sebvs
    cam = sebvs.EventCamera(model, camera="wrist", width=128, height=128, preset="physical")
    for k in range(100):
        mujoco.mj_step(model, data)
        events = cam.step(data)                 # the events since the previous sample
        if k % 10 == 9:
            image = cam.frame(data)             # the modelled frame camera's image
    cam.reset(seed=1)                           # the simulation restarted
    cam.close()

It runs the project's own sensor code, not a copy of it: the camera core that the camera
actor and the Gymnasium envs run (sebvs.sensors.camera.CameraCore, with the physical
pair's sensor rig and light samples, sebvs.sensors.rig and light_samples), the event
chain's emulator stream (sebvs.dvs.stream.SensorStream over sebvs.dvs.emulator with a
sebvs.dvs.params preset), and the EMVA 1288 frame camera (sebvs.sensors.framecam). The
model is rendered from the camera's own copy (sebvs/sim/model_scene.py), posed from each
sample's qpos, mocap_pos and mocap_quat. docs/own_robot.md.

Events: a structured array of EVENT_DTYPE, the x, y, t, p fields Tonic and evlib read,
time-sorted:
    x, y   uint16 pixel column and row, (0, 0) the top-left pixel of the image as
           rendered, x < width and y < height (times the emulator's downsample, 1 here
           unless `emulator` sets it)
    t      int64 nanoseconds on the clock of the `t` given (s): data.time unless told
    p      int8 polarity, +1 ON (the log brightness rose by a threshold), -1 OFF
Tonic's own convention (t in microseconds, p in {0, 1}) is one call away:
sebvs.dvs.tonic_layout.to_tonic(events).
"""
from __future__ import annotations

import logging
import math
import os
import sys
from dataclasses import dataclass, field, replace

os.environ.setdefault("MUJOCO_GL", "egl")   # before mujoco is first imported (sebvs.sim)

import mujoco  # noqa: E402
import numpy as np  # noqa: E402

from .dvs.emulator import EVENT_DTYPE, empty_events  # noqa: E402
from .dvs.params import EmulatorParams, preset as emulator_preset  # noqa: E402
from .dvs.stream import SensorStream  # noqa: E402
from .sim.model_scene import (DEFAULT_LUX, ModelScene, UnknownCamera,  # noqa: E402
                          check_size, default_photometry, resolve_camera)
from .sensor_pairs import check_sensor  # noqa: E402
from .sim.light import Photometry  # noqa: E402

LOG = logging.getLogger("sebvs.event_camera")
WHERE = "event camera"
FRAME_META = ("exposure_s", "gain_db", "t_exposure_end", "saturated")

__all__ = ["EVENT_DTYPE", "EventCamera", "UnknownCamera"]


@dataclass(frozen=True)
class CoreSettings:
    """The camera actor's parameters that sebvs.sensors.camera.CameraCore reads, as an
    EventCamera sets them: one luma sample per call (dvs_hz 0), a frame on each frame()
    (rgb_hz 0: the samples flagged as control ticks)."""
    camera: object
    sensor: str
    frame_camera: str = "mv_global_shutter"
    frame_overrides: dict = field(default_factory=dict)
    rgb_hz: float = 0.0
    dvs_hz: float = 0.0
    luma_scale: float = 1.0
    subframe_s: float = 0.004
    max_subframes: int = 8
    frame_light: str = "shared"
    radiance_ratio: float = 16.0
    luma_sampling: str = "fixed"


def check_gl() -> None:
    """Raise RuntimeError in one line when mujoco was imported before MUJOCO_GL was set and
    chose GLFW with no display to open (it picks its GL backend once, at import)."""
    from mujoco import gl_context
    ctx = getattr(gl_context, "GLContext", None)
    if ctx is not None and getattr(ctx, "__module__", "") == "mujoco.glfw" \
            and sys.platform.startswith("linux") \
            and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        raise RuntimeError(f"{WHERE}: mujoco was imported before MUJOCO_GL was set and chose "
                           "GLFW, which needs a display: set MUJOCO_GL=egl (or osmesa) in the "
                           "environment, or import sebvs.envs / sebvs.event_camera before "
                           "gymnasium makes a MuJoCo env")


def _seed(seed, what: str) -> int:
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"{WHERE}: {what} must be a non-negative integer, got {seed!r}")
    return int(seed)


def _join(packets: list) -> np.ndarray:
    packets = [p for p in packets if p.size]
    if not packets:
        return empty_events()
    return packets[0] if len(packets) == 1 else np.concatenate(packets)


class EventCamera:
    """An event sensor, and the frame camera beside it, on one camera of a MuJoCo model.

    Parameters:
        model: the mujoco.MjModel (the camera renders its own copy, taken now).
        camera: a camera's name or id, a mujoco.MjvCamera (a free or tracking view), or
            None: the model's first camera. UnknownCamera (a ValueError), in one line
            naming the camera and the cameras the model has, when it is not there.
        width, height: the image in pixels; the events' array is the same size.
        preset: the emulator preset (sebvs.dvs.params.PRESETS): "physical" (default),
            "paper" (the paper's Table 2 v2e settings), "clean", "noisy"; its noise rates
            in docs/dvs.md, "Noise and preset versions". The preset's downsample is set to
            1 (the paper's halves the image) unless `emulator` says otherwise.
        light: the scene's light in physical units, for the physical sensor: a
            sebvs.sim.light.Photometry, a number (lux on a white surface facing the key
            light), or None: the model's MJCF lights scaled to DEFAULT_LUX (400 lux,
            office light; sebvs/sim/model_scene.py), which one logged line (INFO, logger
            "sebvs.event_camera") says.
        sensor: "physical" (both sensors on the scene's linear light, docs/sensors.md) or
            "ideal8" (both read one ideal 8-bit render); None: "physical" for the physical
            preset, else "ideal8" (the project's two sensor pairs).
        frame_hz: how often frame() will be called (caps the frame camera's exposure).
        frame_camera, frame_overrides: the frame camera's preset and changes to it
            (sebvs.sensors.framecam; physical sensor only).
        emulator: changes to the emulator preset's fields, e.g. {"downsample": 0.5}.
        seed: the fixed-pattern and noise seed of the first stream (reset(seed) sets
            another).
        fast_render: render without MSAA and shadow maps (sebvs/sim/model_scene.py).

    Samples must come in time order; reset() starts a new stream (the first sample after
    it initialises the sensor and gives no events). The GL context is made at the first
    sample, so an unused camera costs none (and forks cleanly).
    """

    def __init__(self, model: mujoco.MjModel, camera=None, width: int = 160,
                 height: int = 160, preset: str = "physical",
                 light: Photometry | float | None = None, *, sensor: str | None = None,
                 frame_hz: float = 30.0, frame_camera: str = "mv_global_shutter",
                 frame_overrides: dict | None = None, emulator: dict | None = None,
                 seed: int = 0, fast_render: bool = True,
                 log: logging.Logger | None = None) -> None:
        self.log = log or LOG
        self.seed = _seed(seed, "seed")
        self.preset = preset
        self.sensor = check_sensor("physical" if sensor is None and preset == "physical"
                                   else sensor or "ideal8")
        self.params: EmulatorParams = emulator_preset(
            preset, **{"downsample": 1.0, **(emulator or {}), "seed": self.seed})
        if isinstance(frame_hz, bool) or not isinstance(frame_hz, (int, float)) \
                or not 0 < frame_hz <= 1e5:
            raise ValueError(f"{WHERE}: frame_hz must be in (0, 100000], got {frame_hz!r}")
        self.frame_hz = float(frame_hz)
        frame_overrides = dict(frame_overrides or {})
        if self.sensor == "physical":
            from .sensors.framecam import preset as frame_preset
            frame_preset(frame_camera, **frame_overrides)       # bad names fail here
        if not isinstance(model, mujoco.MjModel):
            raise TypeError(f"{WHERE}: model must be a mujoco.MjModel, got "
                            f"{type(model).__name__}")
        resolve_camera(model, camera, WHERE)    # a bad camera or size fails before the
        check_size(width, height, WHERE)        # light is looked at (and said)
        self.photometry = self._light(model, light) if self.sensor == "physical" else None
        self.scene = ModelScene(model, camera, width, height, self.photometry, fast_render,
                                WHERE)
        self.settings = CoreSettings(camera=self.scene.view, sensor=self.sensor,
                                     frame_camera=frame_camera,
                                     frame_overrides=frame_overrides)
        ds = self.params.downsample
        self.event_shape = (max(1, round(self.scene.height * ds)),
                            max(1, round(self.scene.width * ds)))
        self._core = None
        self._pending: list[np.ndarray] = []
        self.luma: np.ndarray | None = None
        self.frame_meta: dict = {}
        self.episode = -1
        self.reset(self.seed)

    def _light(self, model, light) -> Photometry:
        if isinstance(light, Photometry):
            return light
        if light is None:
            photometry = default_photometry(model)
            self.log.info("%s: the model declares no photometry: default light, its MJCF "
                          "lights scaled so that a white surface facing the key light "
                          "receives %g lux (render level %.3g); pass light= to set it",
                          WHERE, DEFAULT_LUX, photometry.render_level)
            return photometry
        if isinstance(light, bool) or not isinstance(light, (int, float)) \
                or not 0 < light < math.inf:
            raise ValueError(f"{WHERE}: light must be a Photometry, a positive number of "
                             f"lux or None, got {light!r}")
        return default_photometry(model, float(light))

    @property
    def shape(self) -> tuple[int, int]:
        """(height, width) of the images."""
        return self.scene.image_shape()

    # ------------------------------------------------------------------ streams
    def reset(self, seed: int | None = None) -> None:
        """Start a new stream: the emulator forgets the light (the next sample initialises
        it and gives no events), the frame camera's auto exposure starts again. The
        fixed pattern and noise come from (seed, stream index): `seed` given, it is the
        seed from now on and the index restarts at 0; None, the index moves on by one.

        Parameters:
            seed: a non-negative integer, or None.
        """
        if seed is not None:
            self.seed = _seed(seed, "reset(seed=...)")
            self.episode = 0
        else:
            self.episode += 1
        self._stream = SensorStream(replace(self.params, seed=self.seed))
        if self._core is not None:
            self._core.seed = self.seed
            self._core.episode = None          # a new episode even at the same index
        self._pending = []
        self._last_t: float | None = None
        self.luma = None

    def _camera_core(self):
        if self._core is None:
            check_gl()
            from .sensors.camera import CameraCore
            core = CameraCore(self.settings, {"luma", "rgb"}, seed=self.seed, log=self.log)
            core.control_hz = self.frame_hz    # the frame camera's rate (before its rig)
            try:
                core.use_scene(self.scene, ("model", {"width": self.scene.width,
                                                      "height": self.scene.height}))
            except BaseException:
                core.close()
                raise
            self._core = core
        return self._core

    # ------------------------------------------------------------------ samples
    def sample(self, state: dict, t: float, frame: bool = False,
               t_next: float | None = None) -> tuple[np.ndarray, np.ndarray | None]:
        """One sample of the scene's state: its luma through the event sensor and, with
        `frame`, the frame camera's image (its exposure ends readout_s before `t`).

        Parameters:
            state: {"qpos": (nq,), "mocap_pos": (nmocap, 3), "mocap_quat": (nmocap, 4)}
                (ModelScene.state(data)).
            t: the sample's time, s, not before the previous sample's.
            frame: also return the frame camera's image.
            t_next: with `frame`, when the next frame is due (s): its exposure is then
                integrated as the samples before it arrive.
        Returns:
            (events since the previous sample, EVENT_DTYPE (N,) time-sorted, with those of
            a frame() since the last step(); the image (H, W, 3) uint8 or None).
        """
        if isinstance(t, bool) or not isinstance(t, (int, float, np.floating, np.integer)) \
                or not math.isfinite(t) or t < 0:
            raise ValueError(f"{WHERE}: t must be a finite time >= 0 s, got {t!r}")
        t = float(t)
        if self._last_t is not None and t < self._last_t:
            raise ValueError(f"{WHERE}: t = {t:g} s is before the previous sample's "
                             f"{self._last_t:g} s: call reset() when the simulation restarts")
        core = self._camera_core()
        meta = {"episode": self.episode, "t_ep": t, "control": bool(frame)}
        if frame and t_next is not None:
            meta["t_next_control"] = float(t_next)
        packets, self._pending = self._pending, []
        image = None
        for output, arrays, m in core.sample(state, meta):
            if output == "luma":
                self.luma = arrays["luma"]
                packets.append(self._stream.frame(arrays["luma"], m["t_ep"], self.episode,
                                                  m.get("units")))
            elif output == "rgb":
                image = arrays["rgb"]
                self.frame_meta = {k: m[k] for k in FRAME_META if k in m}
        self._last_t = t
        return _join(packets), image

    def _state(self, data: mujoco.MjData) -> dict:
        if not isinstance(data, mujoco.MjData):
            raise TypeError(f"{WHERE}: data must be a mujoco.MjData, got "
                            f"{type(data).__name__}")
        nq = self.scene.source.nq
        if data.qpos.shape != (nq,):
            raise ValueError(f"{WHERE}: data has {data.qpos.shape[0]} qpos, the camera's "
                             f"model {nq}: not data of this model")
        return ModelScene.state(data)

    def step(self, data: mujoco.MjData, t: float | None = None) -> np.ndarray:
        """One luma sample of `data` as posed now.

        Parameters:
            data: the simulation's mujoco.MjData (read, not changed).
            t: the sample's time, s (None: data.time).
        Returns:
            the events since the previous sample, EVENT_DTYPE (N,) (module docstring).
        """
        return self.sample(self._state(data), data.time if t is None else t)[0]

    def frame(self, data: mujoco.MjData, t: float | None = None,
              t_next: float | None = None) -> np.ndarray:
        """The frame camera's image at `t`: exposed up to readout_s before it from the
        light the event sensor read (the physical sensor; the ideal 8-bit render on
        "ideal8"). It is a luma sample too: its events come with the next step().

        Parameters:
            data: the simulation's mujoco.MjData.
            t: the frame's time, s (None: data.time).
            t_next: when the next frame is due, s (optional; sample()).
        Returns:
            (H, W, 3) uint8 RGB; frame_meta then holds its exposure_s, gain_db,
            t_exposure_end and saturated fraction (physical sensor).
        """
        events, image = self.sample(self._state(data), data.time if t is None else t,
                                    frame=True, t_next=t_next)
        if events.size:
            self._pending.append(events)
        return image

    def close(self) -> None:
        """Free the GL contexts (a later sample makes new ones)."""
        if self._core is not None:
            self._core.close()
            self._core = None

    def __enter__(self) -> "EventCamera":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
