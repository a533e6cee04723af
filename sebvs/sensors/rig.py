"""Both sensors on one scene's physical light: what the camera actor runs for sensor
"physical".

    rig = SensorRig(colour_renderer, scene.photometry(), preset("mv_global_shutter"),
                    frame_rate_hz=10.0)
    rig.new_episode(seed)
    lum = rig.luminance(data, "front", light_scale)           # the event sensor's light
    frame = rig.frame(history, pose, data, "front", t_end)    # the frame camera's image

The event sensor reads the scene's luminance (cd/m^2, float32) at every luma sample: one
render of the radiance renderer (sebvs.sim.radiance, >= 100 dB in one image).

The frame camera integrates its exposure: for an exposure T ending at t_end it renders
sub-frames at `subframe_times` (one per `subframe_s` of exposure, at most
`max_subframes`), at poses interpolated from the sim's states (sebvs.sim.poses). Each
sub-frame is linear RGB = luminance x chroma, chroma = the unshaded surface colour
(FrameRenderer.albedo) over its luminance, exact for white light; the camera model
(sebvs.sensors.framecam) turns their mean into electrons, noise, DN and an 8-bit image,
and runs its auto exposure. The frame a control tick gets is the one whose readout has
finished by then: its exposure ends readout_s earlier, so a frame camera's latency is in
the image even on the lockstep clock.
"""
from __future__ import annotations

from dataclasses import replace

import cv2
import mujoco
import numpy as np

from ..sim.poses import StateHistory
from ..sim.radiance import REC709, RadianceRenderer
from ..sim.render import FrameRenderer
from .framecam import Frame, FrameCamera, FrameCameraParams, subframe_times
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
        self.subframes_rendered = 0

    def set_scene(self, model: mujoco.MjModel, photometry: Photometry) -> None:
        """A new model (the colour renderer already switched to it)."""
        self.radiance.set_model(model, photometry)

    def new_episode(self, seed: int) -> None:
        """A fresh camera: its fixed pattern and its auto exposure from the start."""
        self.camera = FrameCamera(self.params, (self.height, self.width), seed)

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
        """
        if self.camera is None:
            raise RuntimeError("sensor rig: new_episode() before the first frame")
        times = subframe_times(t_end, exposure_s or self.camera.exposure_s, self.subframe_s,
                               self.max_subframes)
        stack = np.empty((times.size, self.height, self.width, 3), np.float32)
        for i, t in enumerate(times):
            state = history.at(self.colour.model, t)
            pose(state)
            self.colour.update(data, camera)
            self.colour.albedo(self._albedo)
            lum = self.luminance(data, camera, light_scale_of(state))
            np.multiply(chroma(self._albedo), lum[..., None], out=stack[i])
        self.subframes_rendered += times.size
        # the exposure's mean, taken once: what the camera integrates (expose() of one
        # frame means it as it would the stack) and what the caller scores against
        mean = stack.mean(axis=0, dtype=np.float64)
        self.mean_luminance = (mean @ REC709).astype(np.float32)
        return self.camera.expose(mean, t_end, exposure_s)

    def close(self) -> None:
        self.radiance.close()
