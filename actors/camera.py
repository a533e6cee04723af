"""The camera actor: renders the sim's state with its own copy of the scene's model.

Input  `state`  from the sim (use the default queue, not "latest", in lockstep: every
                sample is a frame). The episode's first sample carries meta scene + config;
                the camera compiles its model from them (one source of truth: the sim's
                params), and recompiles only when they change.
Outputs, each rendered only when some actor consumes it (self.consumed):
  rgb    {"rgb": (H, W, 3) uint8} at rgb_hz (0: one per control tick), motion-blurred over
         the scene's rgb_blur sub-frames when set. meta: episode, control, t_ep, truth.
  luma   {"luma": (h, w) uint8} (H, W times luma_scale) at dvs_hz (0: every state sample) and on every control
         sample, never blurred. meta:
         episode, control (True on the sample of a control tick), t_ep. tick = the sim's.
  depth  {"depth": (H, W) float32, m} and seg {"seg": (H, W, 2) int32 [id, mjtObj type]}
         at the RGB times.
  ideal  {"rgb": (H, W, 3) uint8}: the ideal 8-bit render at the RGB times, whatever the
         sensor: the experts' privileged view.

sensor "ideal8" (default, the benchmark the shipped checkpoints were trained on): rgb is
the ideal render (blurred over rgb_blur sub-frames when the scene sets it) and luma its
8-bit luma. sensor "physical" (sebvs.sensors.rig, docs/sensors.md): the scene's light in
cd/m^2 (Scene.photometry) rendered beyond 8 bits; rgb is a modelled frame camera's image
(EMVA 1288 terms: exposure and gain under auto exposure, shot, read and dark noise, full
well, ADC, tone curve, motion blur integrated from sub-frames over the exposure; its
exposure ends readout_s before the tick, meta exposure_s, gain_db, t_exposure_end), and
luma carries the scene's luminance {"luma": (h, w) float32 cd/m^2, meta units "cd/m2"},
which the emulator reads as linear light.
H, W = scene.image_shape() (the scene config's height/width). Frames are rendered straight into the
runtime's shared-memory slots (self.reserve). The rendering is sebvs.sensors.camera's
CameraCore, which sebvs.envs runs in process too.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Annotated, Literal

from sebvs.runtime import Actor, Message, Range
from sebvs.sensors.camera import OUTPUTS, CameraCore


class Camera(Actor):
    inputs = ("state",)
    outputs = OUTPUTS

    @dataclass
    class Params:
        camera: str = ""           # camera name in the MJCF; "" = the scene's first
        rgb_hz: Annotated[float, Range(ge=0, le=100_000)] = 0.0   # 0: one per control tick
        dvs_hz: Annotated[float, Range(ge=0, le=100_000)] = 0.0   # 0: every state sample
        luma_scale: Annotated[float, Range(gt=0, le=1)] = 1.0
                                   # render luma at this fraction of H, W (own renderer):
                                   # 0.5 is the emulator's downsample done by the GPU
                                   # path, ~2.6x cheaper per frame at 160 -> 80 px
        sensor: Literal["ideal8", "physical"] = "ideal8"
        frame_camera: str = "mv_global_shutter"   # sebvs.sensors.framecam preset
        frame_overrides: dict = field(default_factory=dict)   # e.g. { readout_s = 0.002 }
        subframe_s: Annotated[float, Range(gt=0, le=0.1)] = 0.004
                                   # one sub-frame render per this much exposure...
        max_subframes: Annotated[int, Range(ge=1, le=256)] = 8    # ...at most this many
                                   # (an edge moving more than its width in 1/8 of the
                                   # exposure then ghosts instead of smearing)
        radiance_ratio: Annotated[float, Range(gt=1, le=64)] = 16.0
                                   # exposure ratio between the radiance render's channels

    async def setup(self) -> None:
        wanted = {o for o in self.outputs if o in self.consumed}
        self.core = CameraCore(self.params, wanted, seed=self.seed, log=self.log)
        self.log.info("camera: rendering %s, sensor %s", sorted(wanted) or "nothing",
                      self.params.sensor)

    @property
    def counts(self) -> dict:
        return self.core.counts

    async def on_state(self, msg: Message) -> None:
        for output, arrays, meta in self.core.sample(msg.arrays, msg.meta, self.reserve):
            await self.emit(output, arrays, parent=msg, meta=meta)

    async def teardown(self) -> None:
        self.core.close()

    def stats(self) -> dict:
        return dict(self.counts)
