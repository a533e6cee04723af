"""Both sensors on one scene's physical light: what the camera actor runs for sensor
"physical".

    rig = SensorRig(colour_renderer, scene.photometry(), preset("mv_global_shutter"),
                    frame_rate_hz=10.0)
    rig.new_episode(seed)
    lum = rig.luminance(data, "front", light_scale)           # the event sensor's light
    rig.ahead(history, pose, data, "front", t_next_end)        # as states arrive (optional)
    frame = rig.frame(history, pose, data, "front", t_end)    # the frame camera's image

The event sensor reads the radiance render's luminance (cd/m^2, float32, >= 100 dB in one
image) at every luma sample. The frame camera integrates sub-frames over its exposure
(one per `subframe_s`, at most `max_subframes`) at poses interpolated from the sim's
states, each linear RGB = luminance x the surface's unshaded colour over its luminance;
its exposure ends readout_s before the tick that gets it (or earlier: the caller says
where). `ahead` renders the next frame's sub-frames as the states that fix their poses
arrive, and `ahead_shared` exposes a frame on the light samples once they reach its end:
the same frame bit for bit as `frame` / `frame_shared` at the tick, which then return it
(sebvs.sensors.camera's frame_ready "ahead" makes every frame so, before its tick).
docs/sensors.md, section 3.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import mujoco
import numpy as np

from ..sim.poses import StateHistory
from ..sim.radiance import REC709, RadianceRenderer
from ..sim.render import FrameRenderer
from .framecam import Frame, FrameCamera, FrameCameraParams, subframe_times
from .light_samples import LightSamples
from ..sim.light import Photometry

# below this unshaded luminance a surface's colour is unknown: taken as grey
_CHROMA_FLOOR = 2.0 / 255.0


def chroma(albedo: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 unshaded colour -> (H, W, 3) float32 per-channel factors whose
    Rec. 709 luminance is 1 (grey where the surface is too dark to tell)."""
    a = albedo.astype(np.float32) * np.float32(1.0 / 255.0)
    y = a @ REC709.astype(np.float32)
    dark = y < _CHROMA_FLOOR
    c = a / np.where(dark, 1.0, y)[..., None]
    c[dark] = 1.0
    return c


@dataclass
class _Exposure:
    """One frame's exposure as its sub-frames come in."""
    t_end: float
    exposure_s: float
    times: np.ndarray               # (n,) the sub-frames' times
    stack: np.ndarray | None        # (n, H, W, 3) float32 linear RGB, None once exposed
    rendered: np.ndarray            # (n,) bool
    frame: Frame | None = None
    mean_luminance: np.ndarray | None = None


class SensorRig:
    """The frame camera and the event sensor's light for one scene and camera size."""

    def __init__(self, colour: FrameRenderer, photometry: Photometry,
                 params: FrameCameraParams, frame_rate_hz: float, subframe_s: float = 0.004,
                 max_subframes: int = 8, ratio: float = 16.0) -> None:
        if not subframe_s > 0 or max_subframes < 1:
            raise ValueError(f"sensor rig: subframe_s must be > 0 and max_subframes >= 1, "
                             f"got {subframe_s!r}, {max_subframes!r}")
        self.colour = colour
        self.height, self.width = colour.height, colour.width
        # a camera running slower than its sensor's top rate may expose for longer
        self.params = replace(params, frame_rate_hz=min(params.frame_rate_hz,
                                                        float(frame_rate_hz))).validate()
        self.subframe_s, self.max_subframes = float(subframe_s), int(max_subframes)
        self.radiance = RadianceRenderer(colour.model, photometry, self.height, self.width,
                                         ratio)
        self._albedo = np.empty((self.height, self.width, 3), np.uint8)
        self.camera: FrameCamera | None = None
        self._pending: _Exposure | None = None     # the next frame's, rendered ahead
        self.subframes_rendered = 0
        self.subframes_ahead = 0        # of those, rendered before their frame's tick
        self.subframes_discarded = 0    # rendered ahead for a frame that came otherwise
        # the event sensor's light samples, which a shared-light frame integrates
        # (frame_shared); the longest exposure, the readout and a margin behind the newest
        self.light = LightSamples(self.params.exposure_max_s + self.params.readout_s + 0.05)
        self.light_extra = 0            # light samples rendered for the frame camera alone
        self.frames_ahead = 0           # frames exposed before their tick (either light)

    def set_scene(self, model: mujoco.MjModel, photometry: Photometry) -> None:
        """A new model (the colour renderer already switched to it)."""
        self.radiance.set_model(model, photometry)

    def new_episode(self, seed: int) -> None:
        """A fresh camera: its fixed pattern and its auto exposure from the start."""
        self.camera = FrameCamera(self.params, (self.height, self.width), seed)
        self._drop_pending()
        self.light.clear()

    @property
    def readout_s(self) -> float:
        return self.params.readout_s

    def luminance(self, data: mujoco.MjData, camera: str | int, light_scale: float,
                  out: np.ndarray | None = None) -> np.ndarray:
        """The posed scene's luminance (H, W) float32 cd/m^2."""
        self.radiance.update(data, camera, light_scale)
        return self.radiance.luminance(out)

    @staticmethod
    def luminance_at(lum: np.ndarray, out: np.ndarray) -> np.ndarray:
        """`lum` resized by area to `out`'s size (the event sensor's own resolution)."""
        cv2.resize(lum, (out.shape[1], out.shape[0]), dst=out, interpolation=cv2.INTER_AREA)
        return out

    def frame(self, history: StateHistory, pose, data: mujoco.MjData, camera: str | int,
              t_end: float, light_scale_of, exposure_s: float | None = None) -> Frame:
        """The frame whose exposure ends at `t_end`, auto-exposed unless `exposure_s` is
        given (then at 0 dB, the auto exposure left alone).

        pose(state)          writes a state into `data` and updates its kinematics
        light_scale_of(state) the scene's light scale in that state
        The caller re-poses `data` for its own renders afterwards. `mean_luminance` keeps
        the exposure's mean luminance (H, W) (what the frame's pixels integrated).
        Sub-frames `ahead()` rendered for this `t_end` are used, not rendered again.
        """
        if self.camera is None:
            raise RuntimeError("sensor rig: new_episode() before the first frame")
        if exposure_s is not None:        # a manual exposure: not the one rendered ahead
            self._drop_pending()
        ex, self._pending = self._pending_for(t_end), None
        if ex is None:
            ex = self._exposure(t_end, exposure_s or self.camera.exposure_s)
        else:
            self.subframes_ahead += int(ex.rendered.sum())
            self.frames_ahead += ex.frame is not None
        if ex.frame is None:
            self._render(ex, np.flatnonzero(~ex.rendered), history, pose, data, camera,
                         light_scale_of)
            self._expose(ex, exposure_s)
        self.mean_luminance = ex.mean_luminance
        return ex.frame

    def ahead(self, history: StateHistory, pose, data: mujoco.MjData, camera: str | int,
              t_end: float, light_scale_of) -> int:
        """Render now the sub-frames of the auto-exposed frame ending at `t_end` whose
        poses `history` already fixes: those before its newest state (states only come
        later, so the two a sub-frame is interpolated between cannot change). Once every
        sub-frame is in, the frame is exposed too. `frame()` for the same `t_end` then
        renders only the rest, with the same result bit for bit; a frame for another
        `t_end` or exposure drops them (counted in `subframes_discarded`). Returns how
        many sub-frames this call rendered. Poses `data` as frame() does."""
        if self.camera is None or not history.times:
            return 0
        ex = self._pending_for(t_end)
        if ex is None:
            ex = self._pending = self._exposure(t_end, self.camera.exposure_s)
        if ex.frame is not None:
            return 0
        todo = np.flatnonzero(~ex.rendered & (ex.times < history.times[-1]))
        self._render(ex, todo, history, pose, data, camera, light_scale_of)
        if ex.rendered.all():
            self._expose(ex, None)
        return int(todo.size)

    def _pending_for(self, t_end: float) -> "_Exposure | None":
        """The exposure ahead if it is the one a frame ending at `t_end` would take now
        (once it is exposed, the auto exposure has moved on: its end alone says); any
        other is dropped (counted) and None returned."""
        ex = self._pending
        if ex is not None and not (ex.t_end == t_end and (
                ex.frame is not None or ex.exposure_s == self.camera.exposure_s)):
            self._drop_pending()
        return self._pending

    def _drop_pending(self) -> None:
        if self._pending is not None:
            self.subframes_discarded += int(self._pending.rendered.sum())
        self._pending = None

    def _exposure(self, t_end: float, exposure_s: float) -> "_Exposure":
        times = subframe_times(t_end, exposure_s, self.subframe_s, self.max_subframes)
        return _Exposure(t_end, exposure_s, times,
                         np.empty((times.size, self.height, self.width, 3), np.float32),
                         np.zeros(times.size, bool))

    def _render(self, ex: "_Exposure", which: np.ndarray, history: StateHistory, pose,
                data: mujoco.MjData, camera: str | int, light_scale_of) -> None:
        for i in which:
            state = history.at(self.colour.model, ex.times[i])
            pose(state)
            self.colour.update(data, camera)
            self.colour.albedo(self._albedo)
            lum = self.luminance(data, camera, light_scale_of(state))
            np.multiply(chroma(self._albedo), lum[..., None], out=ex.stack[i])
            ex.rendered[i] = True
        self.subframes_rendered += len(which)

    def _expose(self, ex: "_Exposure", exposure_s: float | None) -> None:
        # the exposure's mean, taken once: what the camera integrates (expose() of one
        # frame means it as it would the stack) and what the caller scores against
        mean = ex.stack.mean(axis=0, dtype=np.float64)
        ex.mean_luminance = (mean @ REC709).astype(np.float32)
        ex.frame = self.camera.expose(mean, ex.t_end, exposure_s)
        ex.stack = None                 # the frame holds what is needed from here

    # ---------------------------------------- the frame camera on the shared light samples
    def add_light(self, t: float, luminance: np.ndarray) -> None:
        """A light sample the event sensor read: (H, W) cd/m^2 at the rig's full size."""
        self.light.add(t, luminance)

    def frame_shared(self, history: StateHistory, pose, data: mujoco.MjData,
                     camera: str | int, t_end: float, light_scale_of,
                     exposure_s: float | None = None) -> Frame:
        """The auto-exposed frame ending at `t_end`, integrated from the light samples
        (`add_light`, sebvs.sensors.light_samples) instead of sub-frames of its own: the
        luminance's exact mean over the exposure for light linear between samples, and
        the surfaces' colour once, at the exposure's middle. An exposure with no sample
        inside gets one rendered at its middle. A frame `ahead_shared` exposed for this
        `t_end` is returned as it is. `exposure_s` as in frame(): manual, at 0 dB."""
        if self.camera is None:
            raise RuntimeError("sensor rig: new_episode() before the first frame")
        if exposure_s is not None:
            self._drop_pending()
        ex, self._pending = self._pending_for(t_end), None
        if ex is None or ex.frame is None:
            ex = self._expose_shared(history, pose, data, camera, t_end, light_scale_of,
                                     exposure_s)
        else:
            self.frames_ahead += 1
        self.mean_luminance = ex.mean_luminance
        return ex.frame

    def ahead_shared(self, history: StateHistory, pose, data: mujoco.MjData,
                     camera: str | int, t_end: float, light_scale_of) -> bool:
        """Expose now the frame ending at `t_end` if the light samples reach its end, so
        that its tick only reads it out; True when it was. Poses `data`."""
        if self.camera is None or not self.light.reaches(t_end):
            return False
        ex = self._pending_for(t_end)
        if ex is not None and ex.frame is not None:
            return False
        self._pending = self._expose_shared(history, pose, data, camera, t_end,
                                            light_scale_of)
        return True

    def _expose_shared(self, history: StateHistory, pose, data: mujoco.MjData,
                       camera: str | int, t_end: float, light_scale_of,
                       manual_s: float | None = None) -> _Exposure:
        exposure_s = self.camera.exposure_s if manual_s is None else manual_s
        t0, t_mid = t_end - exposure_s, t_end - 0.5 * exposure_s
        state = history.at(self.colour.model, t_mid)
        pose(state)
        if not self.light.inside(t0, t_end):
            # shorter than the samples' spacing: its own sample, or a blend of two poses
            self.add_light(t_mid, self.luminance(data, camera, light_scale_of(state)))
            self.light_extra += 1
        self.colour.update(data, camera)
        self.colour.albedo(self._albedo)
        mean = self.light.mean(t0, t_end)
        ex = _Exposure(t_end, exposure_s, np.array([t_mid]), None, np.ones(1, bool))
        ex.mean_luminance = mean
        ex.frame = self.camera.expose(chroma(self._albedo) * mean[..., None], t_end,
                                      manual_s)
        return ex

    def close(self) -> None:
        self.radiance.close()
