"""The camera actor's rendering without its messaging: the sim's states in, the frames that
are due out.

    cam = CameraCore(params, wanted={"rgb", "luma"}, seed=camera_seed)
    for output, arrays, meta in cam.sample(state, state_meta, alloc):
        ...              # each as it is made; alloc(output, {name: (shape, dtype)})
    cam.close()

actors/camera.py wires this to the runtime (a state message in, an emit per output), and
sebvs.envs calls it in process (the Gymnasium environments): one code path, so the frames
are the same bit for bit; actors/camera.py says the outputs and the two sensors ("ideal8",
"physical"). `params` has the camera actor's Params fields (luma_sampling "fixed" where
it has none); `alloc` gives the arrays a frame is rendered into (the actor's shared-memory
slots, or plain arrays). With luma_sampling "adaptive" (sebvs/dvs/adaptive.py) a state
can also bring luma samples from between the previous state and itself: each with its
own meta t_ep (earlier than the state's), control False, before the state's own luma.
On the physical sensor with frame_ready "ahead" (what "auto", the default, is on the
realtime clock; FRAME_READY) the frame of a
control tick is made while an earlier state is handled (its call yields nothing more for
it) and the tick's call only yields it: iterate every state's outputs to the end.
"""
from __future__ import annotations

import collections
import logging
import math
from typing import Callable, Iterator

import numpy as np

from sebvs.dvs.adaptive import LumaSampler, SamplerParams, log_luminance
from sebvs.sim import make_scene  # sets MUJOCO_GL before mujoco is imported
from sebvs.sim.poses import StateHistory, interpolate_state
from sebvs.sim.render import FrameRenderer

import mujoco  # noqa: E402

OUTPUTS = ("rgb", "luma", "depth", "seg", "ideal")
# when the physical frame camera makes the frame a control tick gets (Camera.Params.frame_ready)
# ("auto": "ahead" where the clock is realtime, which is where it buys latency; "tick" in
# lockstep, where the states come back to back and it buys nothing, so that lockstep runs
# keep the frames the shipped checkpoints were trained and evaluated on)
FRAME_READY = ("auto", "ahead", "tick")
Alloc = Callable[[str, dict], dict]


def plain_alloc(output: str, specs: dict) -> dict:
    """An `alloc` of new arrays."""
    return {name: np.empty(shape, dtype) for name, (shape, dtype) in specs.items()}


class Rate:
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


class CameraCore:
    """Renders a scene's states with its own copy of the scene's model."""

    def __init__(self, params, wanted, seed: int = 0,
                 log: logging.Logger | None = None, clock: str = "lockstep") -> None:
        self.params = params
        self.seed = seed
        self.log = log or logging.getLogger("sebvs.camera")
        self.key = None            # (scene name, config) of the compiled model
        self.renderer: FrameRenderer | None = None
        self.luma_renderer: FrameRenderer | None = None
        if not 0 < params.luma_scale <= 1:
            raise ValueError(f"camera: luma_scale must be in (0, 1], got {params.luma_scale}")
        self.episode = None
        self.last_t: float | None = None
        self.warned_rate = False
        self.counts = {"rgb": 0, "luma": 0, "depth": 0, "seg": 0, "ideal": 0,
                       "no_model": 0, "subframes": 0, "clipped_px": 0}
        self.wanted = set(wanted) & set(OUTPUTS)
        self.physical = params.sensor == "physical"
        self.rig = None
        self.control_hz = 10.0     # the sim's, from the episode's first state
        # luma_sampling "adaptive" (sebvs/dvs/adaptive.py): luma when the brightness could
        # have changed by a fraction of the emulator's threshold, rendered between the sim's
        # states at interpolated poses; the previous state (t_ep, copy) to interpolate from
        self.sampler: LumaSampler | None = None
        if getattr(params, "luma_sampling", "fixed") == "adaptive":
            self.sampler = LumaSampler(SamplerParams(
                fraction=params.luma_fraction, threshold=params.luma_threshold,
                floor_hz=params.luma_floor_hz, ceiling_hz=params.luma_ceiling_hz))
            self.counts["luma_between"] = 0
        self.previous: tuple[float, dict] | None = None
        # the frame camera integrates the event sensor's light samples ("shared") where
        # there are any, else sub-frames of its own ("subframes", the path before issue 64)
        frame_light = getattr(params, "frame_light", "shared")
        if frame_light not in ("shared", "subframes"):
            raise ValueError(f"camera: frame_light must be 'shared' or 'subframes', got "
                             f"{frame_light!r}")
        self.shared_light = self.physical and frame_light == "shared" and "luma" in self.wanted
        # "ahead": the frame a tick gets is made on the states before it, and the tick only
        # publishes it; "tick": its exposure ends readout_s before the tick wherever that
        # falls, and the tick's own state closes it where the states are sparser than that
        frame_ready = getattr(params, "frame_ready", "auto")
        if frame_ready not in FRAME_READY:
            raise ValueError(f"camera: frame_ready must be one of {', '.join(FRAME_READY)}, "
                             f"got {frame_ready!r}")
        self.frame_ahead = frame_ready == "ahead" or (frame_ready == "auto"
                                                      and clock == "realtime")
        self.state_dt: float | None = None      # the last two states' spacing
        if self.physical:
            from .framecam import preset
            self.frame_params = preset(params.frame_camera, **params.frame_overrides)
            # exposure (<= 0.1 s) plus readout, and one state before them
            self.states = StateHistory(self.frame_params.exposure_max_s
                                       + self.frame_params.readout_s + 0.05)
            # the next frame's exposure end, once a tick has said when the next tick
            # comes (frames on control ticks only): its sub-frames are rendered as the
            # states that fix their poses arrive, not all at that tick
            self.next_t_end: float | None = None
            self.next_tick: float | None = None     # that tick's t_ep
            # frame_ready "ahead": the end of the exposure already made for the next tick
            self.made_end: float | None = None
            self.counts.update(subframes_ahead=0, subframes_discarded=0,
                               bad_t_next_control=0, light_extra=0, frames_ahead=0,
                               exposure_end_moved=0)

    def _build_rig(self, frame_rate_hz: float) -> None:
        from .rig import SensorRig
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

    def build(self, scene_name: str, config: dict) -> None:
        """Compile the scene's model for `config` (kept for the next episodes)."""
        self.use_scene(make_scene(scene_name, **config), (scene_name, config))

    def use_scene(self, scene, key) -> None:
        """Render `scene` from now on: a Scene, or any object with its compile(), cameras,
        image_shape(), rgb_blur(), set_state(), kinematics() and photometry() (sebvs/
        model_scene.py: anyone's compiled model); `key` names it (a state's meta scene and
        config equal to it need no new build)."""
        scene_name, config = key
        self.scene = scene
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
            self.close()
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

    def pose(self, state: dict) -> None:
        self.scene.set_state(self.model, self.data, state)
        self.scene.kinematics(self.model, self.data)

    def sample(self, state: dict, meta: dict, alloc: Alloc = plain_alloc
               ) -> Iterator[tuple[str, dict, dict]]:
        """One state sample of the sim (its arrays and meta) -> (output, arrays, meta) of
        each frame due at it, yielded as soon as it is made (the camera actor emits each
        at once). The physical frame camera's image comes last: the event sensor's luma
        and the privileged renders are on their way while the exposure is integrated.
        Iterate to the end: the camera's state moves on as the outputs are made."""
        if not self._ready_for(meta):
            return
        ep, t_ep, control = meta.get("episode"), float(meta.get("t_ep", 0.0)), \
            bool(meta.get("control", False))
        p = self.params
        if ep != self.episode:
            self._new_episode(ep)
        want_luma, between = self._luma_due(state, ep, t_ep, control)
        self._check_state_rate(t_ep)
        rgb_due = control if p.rgb_hz <= 0 else self.rgb_rate.due(t_ep)
        want_rgb = "rgb" in self.wanted and rgb_due
        want_ideal = "ideal" in self.wanted and rgb_due
        self._keep_state(state, t_ep, want_rgb)
        made_end = self._ahead_end(t_ep, rgb_due)
        if not (want_luma or want_rgb or want_ideal or made_end is not None
                or (rgb_due and self.wanted & {"depth", "seg"})):
            yield from between
            return
        out_meta = {"episode": ep, "control": control, "t_ep": t_ep}
        if want_luma or want_ideal or (want_rgb and not self.physical) \
                or (rgb_due and self.wanted & {"depth", "seg"}):
            # the scene of every size (luma's too); the physical frame poses its own
            self.pose(state)
            self.renderer.update(self.data, self.cam)
        # an unblurred RGB render of this sample, if one was made
        sharp = yield from self._ideal_frames(want_rgb and not self.physical, want_ideal,
                                              out_meta, meta.get("truth"), alloc)
        yield from between              # luma in time order: those before this state first
        if want_luma:
            yield self._luma_frame(state, t_ep, out_meta, alloc, sharp)
        if rgb_due:
            yield from self._privileged_frames(out_meta, alloc)
        if made_end is not None:
            # the next tick's frame, made here in full (after the renders above: it
            # re-poses); the tick then only publishes it
            self._frame_ahead(state, t_ep, made_end)
        elif want_luma and self.shared_light and not want_rgb and self.next_t_end is not None \
                and not self.frame_ahead:
            # the exposure may have ended with this sample: expose it now, ahead of its
            # tick, which then only reads it out (after the renders above: it re-poses)
            self.rig.ahead_shared(self.states, self.pose, self.data, self.cam,
                                  self.next_t_end, self._light_scale)
            self._count_subframes()
        if want_rgb and self.physical:
            # last: its sub-frames re-pose the model, which the renders above read posed
            frame = self._frame(t_ep, {**out_meta, "truth": meta.get("truth")}, alloc)
            self.next_t_end = self._next_exposure_end(
                meta.get("t_next_control") if p.rgb_hz <= 0 else None, t_ep)
            yield frame

    def _ready_for(self, meta: dict) -> bool:
        """Take a state's control rate and scene (compiled anew when it changed); False,
        counted in no_model, while no scene is compiled (joined mid-episode: the next
        episode's start brings one)."""
        if "control_hz" in meta:
            self.control_hz = meta["control_hz"]
        if "config" in meta and (meta["scene"], meta["config"]) != self.key:
            self.build(meta["scene"], meta["config"])
        if self.renderer is None:
            self.counts["no_model"] += 1
            return False
        return True

    def _new_episode(self, ep) -> None:
        """Start episode ``ep``: fresh rates, blur history and samplers; the physical
        rig's noise seeded from the camera's seed and the episode number."""
        p = self.params
        self.episode = ep
        self.rgb_rate, self.luma_rate = Rate(p.rgb_hz), Rate(p.dvs_hz)
        self.history.clear()
        self.last_t = None
        self.previous = None
        if self.sampler is not None:
            self.sampler.reset()
        self.state_dt = None
        if self.physical:
            self.states.clear()
            self.next_t_end = self.next_tick = self.made_end = None
            self.rig.new_episode(self.seed * 1_000_003 + (ep if isinstance(ep, int) else 0))

    def _luma_due(self, state: dict, ep, t_ep: float, control: bool
                  ) -> tuple[bool, list[tuple[str, dict, dict]]]:
        """(whether this state's luma is due, the adaptive sampler's luma samples between
        the previous state and this one). Luma on every control sample too, whatever
        dvs_hz: the emulator's packets carry that flag to the accumulator, which closes
        its windows on it."""
        if "luma" not in self.wanted:
            return False, []
        if self.sampler is None:
            return self.luma_rate.due(t_ep) or control, []
        between = self._luma_between(state, ep, t_ep)
        self.previous = (t_ep, {k: np.array(a) for k, a in state.items()})
        return control or self.sampler.due(t_ep), between

    def _check_state_rate(self, t_ep: float) -> None:
        """Keep the states' spacing (state_dt); warn once when the states come slower than
        dvs_hz asks for."""
        p = self.params
        if self.last_t is not None and t_ep > self.last_t:
            self.state_dt = t_ep - self.last_t
        if self.last_t is not None and p.dvs_hz > 0 and not self.warned_rate \
                and t_ep - self.last_t > 1.5 / p.dvs_hz:
            self.warned_rate = True
            self.log.warning("states arrive every %.4f s, slower than dvs_hz %g: raise the "
                             "sim's render_hz", t_ep - self.last_t, p.dvs_hz)
        self.last_t = t_ep

    def _keep_state(self, state: dict, t_ep: float, want_rgb: bool) -> None:
        """Keep what later frames need of this state: the physical camera's state history
        (and the next frame's sub-frames that it fixes), and the blur history."""
        if self.physical and "rgb" in self.wanted:
            self.states.add(t_ep, state)
            if not want_rgb and self.next_t_end is not None and not self.shared_light \
                    and (not self.frame_ahead or self._state_reaches_end()):
                self.rig.ahead(self.states, self.pose, self.data, self.cam, self.next_t_end,
                               self._light_scale)
                self._count_subframes()
        # the blur history serves the ideal render (rgb too, on the 8-bit sensor; the
        # physical camera integrates its own sub-frames from self.states)
        if self.blur > 1 and self.wanted & ({"ideal"} if self.physical else {"rgb", "ideal"}):
            self._remember(state)

    def _ideal_frames(self, want_rgb: bool, want_ideal: bool, out_meta: dict, truth,
                      alloc: Alloc):
        """Yield the ideal render as each of the outputs that want it ("rgb" on the 8-bit
        sensor, "ideal"), blurred over the history where the scene blurs; returns the
        unblurred render it made, or None."""
        ideal_outputs = [o for o, due in (("rgb", want_rgb), ("ideal", want_ideal)) if due]
        if not ideal_outputs:
            return None
        sharp = None
        outs = {o: alloc(o, {"rgb": ((self.h, self.w, 3), np.uint8)}) for o in ideal_outputs}
        first = outs[ideal_outputs[0]]["rgb"]
        if self.blur > 1:
            # the history ends with this sample, so its pose is the one left in
            # self.data and in the scene for the luma, depth and seg renders below
            self.renderer.rgb_blurred(self.data, self.cam, self.history, first, self.pose)
        else:
            sharp = self.renderer.rgb(first)
        for o in ideal_outputs:
            if outs[o]["rgb"] is not first:
                np.copyto(outs[o]["rgb"], first)
            self.counts[o] += 1
            yield o, outs[o], {**out_meta, "truth": truth}
        return sharp

    def _luma_frame(self, state: dict, t_ep: float, out_meta: dict, alloc: Alloc,
                    sharp) -> tuple[str, dict, dict]:
        """This state's luma: the scene's luminance in cd/m^2 on the physical sensor, else
        8-bit luma (from ``sharp``, the RGB render, where it is at the luma's size)."""
        if self.physical:
            arrays = alloc("luma", {"luma": ((self.lh, self.lw), np.float32)})
            lum = self.rig.luminance(self.data, self.cam, self._light_scale(state),
                                     None if self.luma_renderer is not None else arrays["luma"])
            if self.luma_renderer is not None:
                self.rig.luminance_at(lum, arrays["luma"])
            if self.shared_light:
                self.rig.add_light(t_ep, lum)
            self.counts["clipped_px"] += self.rig.radiance.clipped
            self.counts["luma"] += 1
            if self.sampler is not None:
                self.sampler.observe(t_ep, log_luminance(arrays["luma"]))
            return "luma", arrays, {**out_meta, "units": "cd/m2"}
        arrays = alloc("luma", {"luma": ((self.lh, self.lw), np.uint8)})
        if self.luma_renderer is not None:
            self.luma_renderer.luma(arrays["luma"])
        else:
            self.renderer.luma(arrays["luma"], src=sharp)
        self.counts["luma"] += 1
        if self.sampler is not None:
            self.sampler.observe(t_ep, arrays["luma"])
        return "luma", arrays, out_meta

    def _privileged_frames(self, out_meta: dict, alloc: Alloc):
        """Yield the depth and segmentation renders that are wanted."""
        if "depth" in self.wanted:
            arrays = alloc("depth", {"depth": ((self.h, self.w), np.float32)})
            self.renderer.depth(arrays["depth"])
            self.counts["depth"] += 1
            yield "depth", arrays, out_meta
        if "seg" in self.wanted:
            arrays = alloc("seg", {"seg": ((self.h, self.w, 2), np.int32)})
            self.renderer.segmentation(arrays["seg"])
            self.counts["seg"] += 1
            yield "seg", arrays, out_meta

    def _luma_between(self, state: dict, ep, t_ep: float) -> list[tuple[str, dict, dict]]:
        """The luma samples the adaptive sampler asks for between the previous state and
        this one, each rendered at the pose interpolated to its time (sebvs.sim.poses) into
        a plain array (several per state: the output's one reserved slot cannot hold them);
        meta t_ep is the sample's own time, control False."""
        out: list[tuple[str, dict, dict]] = []
        if self.previous is None or not t_ep > self.previous[0]:
            return out
        t0, before = self.previous
        while (ts := self.sampler.pending_before(t_ep)) is not None:
            posed = interpolate_state(self.model, before, state, (ts - t0) / (t_ep - t0))
            self.pose(posed)
            self.renderer.update(self.data, self.cam)
            meta = {"episode": ep, "control": False, "t_ep": ts}
            if self.physical:
                luma = np.empty((self.lh, self.lw), np.float32)
                lum = self.rig.luminance(self.data, self.cam, self._light_scale(posed),
                                         None if self.luma_renderer is not None else luma)
                if self.luma_renderer is not None:
                    self.rig.luminance_at(lum, luma)
                if self.shared_light:
                    self.rig.add_light(ts, lum)
                self.counts["clipped_px"] += self.rig.radiance.clipped
                meta["units"] = "cd/m2"
                self.sampler.observe(ts, log_luminance(luma))
            else:
                luma = np.empty((self.lh, self.lw), np.uint8)
                (self.luma_renderer or self.renderer).luma(luma)
                self.sampler.observe(ts, luma)
            out.append(("luma", {"luma": luma}, meta))
            self.counts["luma"] += 1
            self.counts["luma_between"] += 1
        return out

    def _state_reaches_end(self) -> bool:
        """Whether a state comes at or after the next exposure's end and before its tick:
        the states' spacing is at most readout_s (a state lands on the tick)."""
        return self.state_dt is not None and self.state_dt <= self.rig.readout_s + 1e-9

    def _ahead_end(self, t_ep: float, rgb_due: bool) -> float | None:
        """frame_ready "ahead": where the exposure of the next tick's frame ends if it is
        made at this state, else None. It is made at the first state at or past its end
        (readout_s before the tick), or, where no state falls between that end and the
        tick (states sparser than readout_s), at the last state before the tick, where it
        ends instead: the readout latency then rounds up to the states' spacing. The last
        is the one whose successor, a spacing later, would be the tick."""
        if not (self.frame_ahead and self.physical and "rgb" in self.wanted) or rgb_due \
                or self.next_t_end is None or self.made_end is not None:
            return None
        if t_ep >= self.next_t_end:
            return self.next_t_end
        if self.state_dt is not None and t_ep + 1.5 * self.state_dt > self.next_tick:
            return t_ep
        return None

    def _frame_ahead(self, state: dict, t_ep: float, t_end: float) -> None:
        """Make the next tick's frame now, its exposure ending at `t_end` (<= t_ep): on the
        light samples (with one of its own at this state where no luma sample is here), or
        on its sub-frames, all of whose poses the states now fix."""
        rig = self.rig
        if self.shared_light:
            if not rig.light.reaches(t_end):
                self.pose(state)
                rig.add_light(t_ep, rig.luminance(self.data, self.cam, self._light_scale(state)))
                rig.light_extra += 1
            rig.ahead_shared(self.states, self.pose, self.data, self.cam, t_end,
                             self._light_scale)
        else:
            rig.ahead(self.states, self.pose, self.data, self.cam, t_end, self._light_scale)
        self.made_end = t_end
        if t_end != self.next_t_end:
            self.counts["exposure_end_moved"] += 1
        self._count_subframes()

    def _next_exposure_end(self, t_next, t_ep: float) -> float | None:
        """When the next frame's exposure ends, from a tick's t_next_control (kept in
        next_tick): None where the sim said nothing, or something other than a later finite
        time (counted in bad_t_next_control, logged once); that frame is then rendered at
        its tick."""
        self.next_tick = None
        if t_next is None:
            return None
        if isinstance(t_next, bool) or not isinstance(t_next, (int, float)) \
                or not math.isfinite(t_next) or not t_next > t_ep:
            if not self.counts["bad_t_next_control"]:
                self.log.warning("camera: t_next_control %r at t_ep %s is not a later time; "
                                 "frames are rendered at their ticks (bad_t_next_control "
                                 "counts these)", t_next, t_ep)
            self.counts["bad_t_next_control"] += 1
            return None
        self.next_tick = float(t_next)
        return self.next_tick - self.rig.readout_s

    @staticmethod
    def _light_scale(state: dict) -> float:
        light = state.get("light")
        return 1.0 if light is None else float(light[0])

    def _frame(self, t_ep: float, meta: dict, alloc: Alloc) -> tuple[str, dict, dict]:
        """The modelled frame camera's image at this tick: exposed up to readout_s
        before it (sebvs.sensors.rig), or the one made ahead for this tick."""
        if self.made_end is not None and t_ep == self.next_tick:
            t_end = self.made_end
        else:
            t_end = t_ep - self.rig.readout_s
        self.made_end = None
        arrays = alloc("rgb", {"rgb": ((self.h, self.w, 3), np.uint8)})
        make = self.rig.frame_shared if self.shared_light else self.rig.frame
        frame = make(self.states, self.pose, self.data, self.cam, t_end, self._light_scale)
        arrays["rgb"][...] = frame.image
        self._count_subframes()
        self.counts["rgb"] += 1
        return ("rgb", arrays, {
            **meta, "exposure_s": frame.exposure_s, "gain_db": frame.gain_db,
            "t_exposure_end": frame.t_end_s, "saturated": frame.saturated_fraction})

    def _count_subframes(self) -> None:
        rig = self.rig
        self.counts.update(subframes=rig.subframes_rendered,
                           subframes_ahead=rig.subframes_ahead,
                           subframes_discarded=rig.subframes_discarded,
                           light_extra=rig.light_extra, frames_ahead=rig.frames_ahead)

    def _remember(self, state: dict) -> None:
        """Keep a copy of this state for the blur (its arrays may be views of the sender's
        ring slots, which it reuses); the copy the full history evicts is refilled, not
        freed."""
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

    def close(self) -> None:
        if self.rig is not None:
            self.rig.close()
            self.rig = None
        if self.renderer is not None:
            self.renderer.close()           # and its view, the luma renderer
        self.renderer = self.luma_renderer = None
