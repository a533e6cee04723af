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
H, W = scene.image_shape() (the scene config's height/width). Frames are rendered straight into the
runtime's shared-memory slots (self.reserve).
"""
from __future__ import annotations

import collections
import math
from dataclasses import dataclass
from typing import Annotated

import numpy as np

from sebvs.runtime import Actor, Message, Range
from sebvs.sim import make_scene  # sets MUJOCO_GL before mujoco is imported
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
    outputs = ("rgb", "luma", "depth", "seg")

    @dataclass
    class Params:
        camera: str = ""           # camera name in the MJCF; "" = the scene's first
        rgb_hz: Annotated[float, Range(ge=0, le=100_000)] = 0.0   # 0: one per control tick
        dvs_hz: Annotated[float, Range(ge=0, le=100_000)] = 0.0   # 0: every state sample
        luma_scale: Annotated[float, Range(gt=0, le=1)] = 1.0
                                   # render luma at this fraction of H, W (own renderer):
                                   # 0.5 is the emulator's downsample done by the GPU
                                   # path, ~2.6x cheaper per frame at 160 -> 80 px

    async def setup(self) -> None:
        self.key = None            # (scene name, config) of the compiled model
        self.renderer: FrameRenderer | None = None
        self.luma_renderer: FrameRenderer | None = None
        if not 0 < self.params.luma_scale <= 1:
            raise ValueError(f"camera: luma_scale must be in (0, 1], got {self.params.luma_scale}")
        self.episode = None
        self.last_t: float | None = None
        self.warned_rate = False
        self.counts = {"rgb": 0, "luma": 0, "depth": 0, "seg": 0, "no_model": 0}
        self.wanted = {o for o in self.outputs if o in self.consumed}
        self.log.info("camera: rendering %s", sorted(self.wanted) or "nothing")

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
        self.log.info("camera: compiled %s %s, %dx%d, camera %s, blur %d", scene_name, config,
                      self.w, self.h, cam, self.blur)

    def _pose(self, state: dict) -> None:
        self.scene.set_state(self.model, self.data, state)
        self.scene.kinematics(self.model, self.data)

    async def on_state(self, msg: Message) -> None:
        meta = msg.meta
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
        if self.blur > 1 and "rgb" in self.wanted:
            self._remember(msg.arrays)
        if not (want_luma or want_rgb or (rgb_due and self.wanted & {"depth", "seg"})):
            return
        self._pose(msg.arrays)
        r = self.renderer
        r.update(self.data, self.cam)     # the scene of every size (luma_renderer's too)
        out_meta = {"episode": ep, "control": control, "t_ep": t_ep}
        sharp = None          # an unblurred RGB render of this sample, if made
        if want_rgb:
            out = self.reserve("rgb", {"rgb": ((self.h, self.w, 3), np.uint8)})
            if self.blur > 1:
                # the history ends with this sample, so its pose is the one left in
                # self.data and in the scene for the luma, depth and seg renders below
                r.rgb_blurred(self.data, self.cam, self.history, out["rgb"], self._pose)
            else:
                sharp = r.rgb(out["rgb"])
            await self.emit("rgb", out, parent=msg,
                            meta={**out_meta, "truth": meta.get("truth")})
            self.counts["rgb"] += 1
        if want_luma:
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
        if self.renderer is not None:
            self.renderer.close()           # and its view, the luma renderer
        self.renderer = self.luma_renderer = None

    async def teardown(self) -> None:
        self._close()

    def stats(self) -> dict:
        return dict(self.counts)
