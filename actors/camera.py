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
         luma_sampling "adaptive": at the times sebvs.dvs.adaptive asks for instead of
         dvs_hz, those between two states rendered at interpolated poses and sent with
         their own t_sim and t_ep and the earlier state's tick (docs/dvs.md)
  depth  {"depth": (H, W) float32, m} and seg {"seg": (H, W, 2) int32 [id, mjtObj type]}
         at the RGB times.
  ideal  {"rgb": (H, W, 3) uint8}: the ideal 8-bit render at the RGB times, whatever the
         sensor: the experts' privileged view.

sensor "ideal8" (the parameter's default; the shipped topologies set "physical", and
checkpoints/ideal8/ holds the policies trained on this one): rgb is the ideal render (blurred over rgb_blur sub-frames when the scene sets it) and luma its
8-bit luma. sensor "physical" (sebvs.sensors.rig, docs/sensors.md): the scene's light in
cd/m^2 (Scene.photometry) rendered beyond 8 bits; rgb is a modelled frame camera's image
(EMVA 1288 terms: exposure and gain under auto exposure, shot, read and dark noise, full
well, ADC, tone curve, motion blur integrated from sub-frames over the exposure; its
exposure ends readout_s before the tick, meta exposure_s, gain_db, t_exposure_end), and
luma carries the scene's luminance {"luma": (h, w) float32 cd/m^2, meta units "cd/m2"},
which the emulator reads as linear light. Each output is emitted as soon as it is made;
at a tick the physical frame comes last. frame_ready "auto" (the default) is "ahead" on the
realtime clock and "tick" in lockstep. "ahead": the frame a
tick gets is made in full (renders, integral, noise) on the states before it, and the tick
only publishes it; its exposure ends readout_s before the tick where a state comes between
that end and the tick, else at the last state before the tick (t_exposure_end says which;
docs/sensors.md, "When a frame is made"). frame_ready "tick": the exposure ends readout_s
before the tick wherever that falls, and the tick's own state closes it where the states
are sparser than readout_s (the frames before issue 64's item 2).
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
        # the frame camera's light: "shared", the event sensor's luma samples integrated
        # over each exposure (no sub-frames of its own; where no luma is consumed it falls
        # back to them), or "subframes", its own renders every subframe_s (before issue 64)
        frame_light: Literal["shared", "subframes"] = "shared"
        # when the physical frame a tick gets is made: "ahead", on the states before its
        # tick (which only publishes it), or "tick", exposed to readout_s before the tick
        # wherever that falls (the tick's own state may be needed: the path before)
        # ("auto", the default: "ahead" on the realtime clock, "tick" in lockstep)
        frame_ready: Literal["auto", "ahead", "tick"] = "auto"
        radiance_ratio: Annotated[float, Range(gt=1, le=64)] = 16.0
                                   # exposure ratio between the radiance render's channels
        # luma times: "fixed" at dvs_hz; "adaptive" when the brightness could have changed
        # by luma_fraction of luma_threshold (the emulator's contrast threshold), between
        # luma_floor_hz and luma_ceiling_hz, rendered between the sim's states at poses
        # interpolated to those times (sebvs/dvs/adaptive.py, docs/dvs.md); dvs_hz unused
        luma_sampling: Literal["fixed", "adaptive"] = "fixed"
        luma_fraction: Annotated[float, Range(gt=0, le=10)] = 0.35
        luma_threshold: Annotated[float, Range(gt=0, le=10)] = 0.3
        luma_floor_hz: Annotated[float, Range(gt=0, le=100_000)] = 20.0
        luma_ceiling_hz: Annotated[float, Range(gt=0, le=100_000)] = 500.0

    async def setup(self) -> None:
        wanted = {o for o in self.outputs if o in self.consumed}
        self.core = CameraCore(self.params, wanted, seed=self.seed, log=self.log,
                               clock=self.clock)
        self.tick = None           # the previous state's, for luma between two states
        self.log.info("camera: rendering %s, sensor %s", sorted(wanted) or "nothing",
                      self.params.sensor)

    @property
    def counts(self) -> dict:
        return self.core.counts

    async def on_state(self, msg: Message) -> None:
        t_ep = float(msg.meta.get("t_ep", 0.0))       # as the core reads it
        for output, arrays, meta in self.core.sample(msg.arrays, msg.meta, self.reserve):
            if meta.get("t_ep") == t_ep or msg.t_sim is None:
                await self.emit(output, arrays, parent=msg, meta=meta)
            else:     # adaptive luma between the previous state and this one: its own time
                await self.emit(output, arrays, parent=msg, meta=meta,
                                t_sim=msg.t_sim + (meta["t_ep"] - t_ep), tick=self.tick)
        self.tick = msg.tick

    async def teardown(self) -> None:
        self.core.close()

    def stats(self) -> dict:
        return dict(self.counts)
