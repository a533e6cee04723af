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
runtime's shared-memory slots (self.reserve).
"""
from __future__ import annotations

import collections
import math
from dataclasses import dataclass, field
from typing import Annotated, Literal

import numpy as np

from sebvs.runtime import Actor, Message, Range
from sebvs.sim import make_scene  # sets MUJOCO_GL before mujoco is imported
from sebvs.sim.poses import StateHistory
from sebvs.sim.render import FrameRenderer

import mujoco  # noqa: E402


class _Rate:
    """Decides which samples of a stream to keep for a target rate (by episode time)."""

    def __init__(self, hz: float) -> None:
        self.hz = hz
        self.last = -1

    def due(self, t_ep: float) -> bool:
        if self.hz <= 0:
            return True
        i = math.floor(t_ep * self.hz + 1e-6)
        if i != self.last:
            self.last = i
            return True
        return False


class Camera(Actor):
    inputs = ("state",)
    outputs = ("rgb", "luma", "depth", "seg", "ideal")

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
        self.key = None            # (scene name, config) of the compiled model
        self.renderer: FrameRenderer | None = None
        self.luma_renderer: FrameRenderer | None = None
        if not 0 < self.params.luma_scale <= 1:
            raise ValueError(f"camera: luma_scale must be in (0, 1], got {self.params.luma_scale}")
        self.episode = None
        self.last_t: float | None = None
        self.warned_rate = False
        self.counts = {"rgb": 0, "luma": 0, "depth": 0, "seg": 0, "ideal": 0,
                       "no_model": 0, "subframes": 0, "clipped_px": 0}
        self.wanted = {o for o in self.outputs if o in self.consumed}
        self.physical = self.params.sensor == "physical"
        self.rig = None
        self.control_hz = 10.0     # the sim's, from the episode's first state
        if self.physical:
            from sebvs.sensors.framecam import preset
            self.frame_params = preset(self.params.frame_camera,
                                       **self.params.frame_overrides)
            # exposure (<= 0.1 s) plus readout, and one state before them
            self.states = StateHistory(self.frame_params.exposure_max_s
                                       + self.frame_params.readout_s + 0.05)
        self.log.info("camera: rendering %s, sensor %s", sorted(self.wanted) or "nothing",
                      self.params.sensor)

    def _build_rig(self, frame_rate_hz: float) -> None:
        from sebvs.sensors.rig import SensorRig
        photometry = self.scene.photometry()
        if self.rig is not None and self.rig.colour is self.renderer and \
                self.rig.params.frame_rate_hz == min(self.frame_params.frame_rate_hz,
                                                     frame_rate_hz):
            self.rig.set_scene(self.model, photometry)
            return
        if self.rig is not None:
            self.rig.close()
        p = self.params
        self.rig = SensorRig(self.renderer, photometry, self.frame_params, frame_rate_hz,
                             p.subframe_s, p.max_subframes, p.radiance_ratio)
        self.log.info("camera: physical sensor, radiance range %.3g-%.3g cd/m^2 (%.0f dB), "
                      "frame camera %s at %g Hz", self.rig.radiance.floor_cd_m2,
                      self.rig.radiance.top_cd_m2, self.rig.radiance.dynamic_range_db,
                      p.frame_camera, self.rig.params.frame_rate_hz)

    def _build(self, scene_name: str, config: dict) -> None:
        self.scene = make_scene(scene_name, **config)
        self.model = self.scene.compile()
        self.data = mujoco.MjData(self.model)
        cam = self.params.camera or self.scene.cameras[0]
        if cam not in self.scene.cameras:
            raise ValueError(f"camera: {cam!r} is not one of {self.scene.cameras}")
        self.cam = cam
        self.h, self.w = self.scene.image_shape()
        self.blur = self.scene.rgb_blur()
        self.history: collections.deque = collections.deque(maxlen=max(1, self.blur))
        k = self.params.luma_scale
        self.lh, self.lw = max(1, round(self.h * k)), max(1, round(self.w * k))
        # a new scene every randomised episode: the renderer keeps its GL context, and
        # the luma renderer is a view of it (one context, one upload, one scene update)
        if self.renderer is not None and (self.renderer.height, self.renderer.width) == \
                (self.h, self.w):
            self.renderer.set_model(self.model)
        else:
            self._close()
            self.renderer = FrameRenderer(self.model, self.h, self.w)
        if (self.lh, self.lw) == (self.h, self.w):
            self.luma_renderer = None           # luma comes from the RGB render
        elif self.luma_renderer is None or (self.luma_renderer.height,
                                            self.luma_renderer.width) != (self.lh, self.lw):
            self.luma_renderer = self.renderer.view(self.lh, self.lw)
        self.key = (scene_name, config)
        if self.physical:
            self._build_rig(self.params.rgb_hz or float(self.control_hz))
        self.log.info("camera: compiled %s %s, %dx%d, camera %s, blur %d", scene_name, config,
                      self.w, self.h, cam, self.blur)

    def _pose(self, state: dict) -> None:
        self.scene.set_state(self.model, self.data, state)
        self.scene.kinematics(self.model, self.data)

    async def on_state(self, msg: Message) -> None:
        meta = msg.meta
        if "control_hz" in meta:
            self.control_hz = meta["control_hz"]
        if "config" in meta and (meta["scene"], meta["config"]) != self.key:
            self._build(meta["scene"], meta["config"])
        if self.renderer is None:
            self.counts["no_model"] += 1      # joined mid-episode: wait for the next start
            return
        ep, t_ep, control = meta.get("episode"), float(meta.get("t_ep", 0.0)), \
            bool(meta.get("control", False))
        if ep != self.episode:
            self.episode = ep
            self.rgb_rate, self.luma_rate = _Rate(self.params.rgb_hz), _Rate(self.params.dvs_hz)
            self.history.clear()
            self.last_t = None
            if self.physical:
                self.states.clear()
                self.rig.new_episode(self.seed * 1_000_003 + (ep if isinstance(ep, int) else 0))
        # Luma on every control sample too, whatever dvs_hz: the emulator's packets carry
        # that flag to the accumulator, which closes its windows on it.
        want_luma = "luma" in self.wanted and (self.luma_rate.due(t_ep) or control)
        if self.last_t is not None and self.params.dvs_hz > 0 and not self.warned_rate \
                and t_ep - self.last_t > 1.5 / self.params.dvs_hz:
            self.warned_rate = True
            self.log.warning("states arrive every %.4f s, slower than dvs_hz %g: raise the "
                             "sim's render_hz", t_ep - self.last_t, self.params.dvs_hz)
        self.last_t = t_ep
        rgb_due = control if self.params.rgb_hz <= 0 else self.rgb_rate.due(t_ep)
        want_rgb = "rgb" in self.wanted and rgb_due
        want_ideal = "ideal" in self.wanted and rgb_due
        if self.physical and "rgb" in self.wanted:
            self.states.add(t_ep, msg.arrays)
        # the blur history serves the ideal render (rgb too, on the 8-bit sensor; the
        # physical camera integrates its own sub-frames from self.states)
        if self.blur > 1 and self.wanted & ({"ideal"} if self.physical else {"rgb", "ideal"}):
            self._remember(msg.arrays)
        if not (want_luma or want_rgb or want_ideal
                or (rgb_due and self.wanted & {"depth", "seg"})):
            return
        out_meta = {"episode": ep, "control": control, "t_ep": t_ep}
        if want_rgb and self.physical:
            await self._emit_frame(msg, t_ep, {**out_meta, "truth": meta.get("truth")})
        self._pose(msg.arrays)
        r = self.renderer
        r.update(self.data, self.cam)     # the scene of every size (luma_renderer's too)
        sharp = None          # an unblurred RGB render of this sample, if made
        ideal_outputs = [o for o, due in (("rgb", want_rgb and not self.physical),
                                          ("ideal", want_ideal)) if due]
        if ideal_outputs:
            outs = {o: self.reserve(o, {"rgb": ((self.h, self.w, 3), np.uint8)})
                    for o in ideal_outputs}
            first = outs[ideal_outputs[0]]["rgb"]
            if self.blur > 1:
                # the history ends with this sample, so its pose is the one left in
                # self.data and in the scene for the luma, depth and seg renders below
                r.rgb_blurred(self.data, self.cam, self.history, first, self._pose)
            else:
                sharp = r.rgb(first)
            for o in ideal_outputs:
                if outs[o]["rgb"] is not first:
                    np.copyto(outs[o]["rgb"], first)
                await self.emit(o, outs[o], parent=msg,
                                meta={**out_meta, "truth": meta.get("truth")})
                self.counts[o] += 1
        if want_luma and self.physical:
            out = self.reserve("luma", {"luma": ((self.lh, self.lw), np.float32)})
            lum = self.rig.luminance(self.data, self.cam, self._light_scale(msg.arrays),
                                     None if self.luma_renderer is not None else out["luma"])
            if self.luma_renderer is not None:
                self.rig.luminance_at(lum, out["luma"])
            self.counts["clipped_px"] += self.rig.radiance.clipped
            await self.emit("luma", out, parent=msg, meta={**out_meta, "units": "cd/m2"})
            self.counts["luma"] += 1
        elif want_luma:
            out = self.reserve("luma", {"luma": ((self.lh, self.lw), np.uint8)})
            if self.luma_renderer is not None:
                self.luma_renderer.luma(out["luma"])
            else:
                r.luma(out["luma"], src=sharp)
            await self.emit("luma", out, parent=msg, meta=out_meta)
            self.counts["luma"] += 1
        if rgb_due and "depth" in self.wanted:
            out = self.reserve("depth", {"depth": ((self.h, self.w), np.float32)})
            r.depth(out["depth"])
            await self.emit("depth", out, parent=msg, meta=out_meta)
            self.counts["depth"] += 1
        if rgb_due and "seg" in self.wanted:
            out = self.reserve("seg", {"seg": ((self.h, self.w, 2), np.int32)})
            r.segmentation(out["seg"])
            await self.emit("seg", out, parent=msg, meta=out_meta)
            self.counts["seg"] += 1

    @staticmethod
    def _light_scale(state: dict) -> float:
        light = state.get("light")
        return 1.0 if light is None else float(light[0])

    async def _emit_frame(self, msg: Message, t_ep: float, meta: dict) -> None:
        """The modelled frame camera's image at this tick: exposed up to readout_s
        before it (sebvs.sensors.rig)."""
        t_end = t_ep - self.rig.readout_s
        out = self.reserve("rgb", {"rgb": ((self.h, self.w, 3), np.uint8)})
        frame = self.rig.frame(self.states, self._pose, self.data, self.cam, t_end,
                               self._light_scale)
        out["rgb"][...] = frame.image
        self.counts["subframes"] = self.rig.subframes_rendered
        await self.emit("rgb", out, parent=msg, meta={
            **meta, "exposure_s": frame.exposure_s, "gain_db": frame.gain_db,
            "t_exposure_end": frame.t_end_s, "saturated": frame.saturated_fraction})
        self.counts["rgb"] += 1

    def _remember(self, state: dict) -> None:
        """Keep a copy of this state for the blur (its arrays are views of the sender's ring
        slots, which it reuses); the copy the full history evicts is refilled, not freed."""
        if len(self.history) == self.history.maxlen:
            old = self.history.popleft()
            if old.keys() == state.keys() and all(
                    old[k].shape == a.shape and old[k].dtype == a.dtype
                    for k, a in state.items()):
                for k, a in state.items():
                    np.copyto(old[k], a)
                self.history.append(old)
                return
        self.history.append({k: np.array(a) for k, a in state.items()})

    def _close(self) -> None:
        if self.rig is not None:
            self.rig.close()
            self.rig = None
        if self.renderer is not None:
            self.renderer.close()           # and its view, the luma renderer
        self.renderer = self.luma_renderer = None

    async def teardown(self) -> None:
        self._close()

    def stats(self) -> dict:
        return dict(self.counts)
