"""An event camera and a frame camera on any MuJoCo-based Gymnasium env.

    import gymnasium as gym
    from sebvs.envs import EventCameraWrapper
    env = EventCameraWrapper(gym.make("Pusher-v5"), width=64, height=64,
                             obs=("events", "rgb"))
    obs, info = env.reset(seed=0)     # obs["state"]: Pusher's own; "events", "rgb": added
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())

After each env step the wrapper reads env.unwrapped.model and .data and runs the library
API, sebvs.EventCamera (the project's camera core, emulator and frame camera), on the
step's states: luma samples at `dvs_hz` across the step, then the frame camera's image at
the step's end, its exposure integrated from those samples.

The states between two steps. The wrapper never steps MuJoCo itself (the env's physics
stays the env's). Where the env steps through Gymnasium's MujocoEnv.do_simulation(ctrl,
frame_skip) (every stock MuJoCo env does), `substeps=True` (the default) hooks it: the
hook calls the env's own do_simulation one frame at a time, frame_skip times, and keeps
the state after each, so the samples see every physics step as it was; the trajectory is
the same bit for bit (MuJoCo's nstep loop is the same mj_step, and the forces recomputed
after each frame are outputs, recomputed after the last one as before). Between those
states, and between whole steps where there is no hook (substeps=False, or an env
without do_simulation), each sample's pose is interpolated as the camera actor
interpolates the sim's states (sebvs.sim.poses: joints along their own geometry, mocap
bodies linearly). The hook is taken out again on close().

Observation (a Dict; static spaces): the env's own observation under `state_key` (the
keys of a Dict observation as they are), and
    events  the event frame of the step's window (the env's dt), at the image size:
            "counts" uint8 (2, H, W) ON then OFF counts clipped at `clip`;
            "histogram" uint8 (2 * bins, H, W); "voxel" float32 (bins, H, W);
            "time_surface" uint8 (2, H, W), 0..255, tau the env's dt (sebvs.dvs.accumulator)
    rgb     the frame camera's image, uint8 (H, W, 3)
and, with raw_events=True, info["raw_events"]: an EventPacket of the step's events
(EVENT_DTYPE x, y, t ns, p +-1; an object, so vector envs can batch it).

Seeds: reset(seed=s) seeds the sensors' fixed pattern and noise with s too (stream 0);
reset() without a seed plays the next stream of the last seed (the wrapper's `seed` at
first). render() is the env's own.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass

os.environ.setdefault("MUJOCO_GL", "egl")   # before mujoco is first imported

import gymnasium  # noqa: E402
import numpy as np  # noqa: E402
from gymnasium import spaces  # noqa: E402

OBS = ("events", "rgb")
WHERE = "EventCameraWrapper"


@dataclass(frozen=True)
class EventPacket:
    """One step's raw events: EVENT_DTYPE (N,), time-sorted, t in ns in (t_start_s,
    t_end_s] of the env's data.time."""
    events: np.ndarray
    t_start_s: float
    t_end_s: float

    def __len__(self) -> int:
        return int(self.events.size)


def env_view(base, model, data):
    """The view env.render() draws, for camera=None: the env's camera where its renderer
    names one, else (Gymnasium's MujocoRenderer without one) a free camera set up as it
    sets its own: looking at the median geom position, at the model's extent, then its
    default_camera_config. None where the env has no Gymnasium renderer: the model's
    first camera."""
    import mujoco
    renderer = getattr(base, "mujoco_renderer", None)
    if renderer is None:
        return None
    cam_id = getattr(renderer, "camera_id", None)
    if cam_id is not None and int(cam_id) >= 0:
        return int(cam_id)
    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_FREE
    cam.fixedcamid = -1
    cam.lookat[:] = np.median(data.geom_xpos, axis=0) if model.ngeom else 0.0
    cam.distance = model.stat.extent
    for key, value in (getattr(renderer, "default_cam_config", None) or {}).items():
        if isinstance(value, np.ndarray):
            getattr(cam, key)[:] = value
        else:
            setattr(cam, key, value)
    cam.type = mujoco.mjtCamera.mjCAMERA_FREE     # as its render() sets it for id -1
    return cam


class EventCameraWrapper(gymnasium.Wrapper, gymnasium.utils.RecordConstructorArgs):
    """Adds the event camera's observations to a MuJoCo-based env (module docstring).

    Parameters:
        env: the env; env.unwrapped must have `model` (mujoco.MjModel) and `data`.
        camera: a camera name or id, a mujoco.MjvCamera, or None: the view env.render()
            draws (env_view). UnknownCamera in one line for a camera the model lacks.
        obs: the keys to add, some of "events", "rgb".
        width, height: the image (None: the env's render size, else 160).
        preset, sensor, light, frame_camera, frame_overrides, emulator, fast_render: as
            sebvs.EventCamera takes them (preset "physical" by default, its noise in
            docs/dvs.md; "paper" has none).
        dvs_hz: luma samples per second of env time (the event sensor's sampling).
        substeps: hook the env's do_simulation where it has one (module docstring);
            False: interpolate between whole steps only.
        representation, bins, clip: the event frame (sebvs.dvs.accumulator).
        raw_events: also put the step's events in info["raw_events"] (EventPacket).
        state_key: the env's own observation's key (a Box or other non-Dict space).
        seed: the sensors' seed until a reset names one.
    """

    def __init__(self, env: gymnasium.Env, camera=None, obs=OBS, *,
                 width: int | None = None, height: int | None = None,
                 preset: str = "physical", sensor: str | None = None, light=None,
                 dvs_hz: float = 100.0, substeps: bool = True,
                 representation: str = "counts", bins: int = 5, clip: int = 255,
                 raw_events: bool = False, state_key: str = "state", seed: int = 0,
                 frame_camera: str = "mv_global_shutter", frame_overrides: dict | None = None,
                 emulator: dict | None = None, fast_render: bool = True) -> None:
        gymnasium.utils.RecordConstructorArgs.__init__(
            self, camera=camera, obs=obs, width=width, height=height, preset=preset,
            sensor=sensor, light=light, dvs_hz=dvs_hz, substeps=substeps,
            representation=representation, bins=bins, clip=clip, raw_events=raw_events,
            state_key=state_key, seed=seed, frame_camera=frame_camera,
            frame_overrides=frame_overrides, emulator=emulator, fast_render=fast_render)
        gymnasium.Wrapper.__init__(self, env)
        import mujoco
        from sebvs.dvs.accumulator import REPRESENTATIONS
        from sebvs.dvs.stream import FrameStream
        from sebvs.event_camera import EventCamera
        base = env.unwrapped
        model, data = getattr(base, "model", None), getattr(base, "data", None)
        if not isinstance(model, mujoco.MjModel) or not isinstance(data, mujoco.MjData):
            raise TypeError(f"{WHERE}: {type(base).__name__} has no MuJoCo model and data "
                            "(env.unwrapped.model, .data): wrap a MuJoCo-based env")
        obs = tuple(obs)
        if not obs or len(set(obs)) != len(obs) or any(k not in OBS for k in obs):
            raise ValueError(f"{WHERE}: obs must name some of {', '.join(OBS)} once each, "
                             f"got {obs!r}")
        if representation not in REPRESENTATIONS:
            raise ValueError(f"{WHERE}: representation must be one of "
                             f"{', '.join(REPRESENTATIONS)}, got {representation!r}")
        if isinstance(dvs_hz, bool) or not isinstance(dvs_hz, (int, float)) \
                or not 0 < dvs_hz <= 1e5:
            raise ValueError(f"{WHERE}: dvs_hz must be in (0, 100000], got {dvs_hz!r}")
        self.base, self.obs_keys = base, obs
        self.dvs_hz, self.raw_events, self.state_key = float(dvs_hz), bool(raw_events), \
            state_key
        width = width or _int_or(getattr(base, "width", None), 160)
        height = height or _int_or(getattr(base, "height", None), 160)
        # the env's free view takes its target from the posed scene: set at the first reset
        self._auto_view = camera is None
        view = env_view(base, model, data) if camera is None else camera
        self.step_s = _positive_or(getattr(base, "dt", None), None)
        self.camera = EventCamera(
            model, view, width, height, preset, light, sensor=sensor,
            frame_hz=1.0 / self.step_s if self.step_s else 30.0, frame_camera=frame_camera,
            frame_overrides=frame_overrides, emulator=emulator, seed=seed,
            fast_render=fast_render)
        self.frames = FrameStream(representation, self.step_s or 0.1, bins, clip,
                                  width, height)
        eh, ew = self.camera.event_shape
        self.geometry = {"event_sensor": [ew, eh], "frame": [width, height]}
        self.observation_space = self._spaces(env.observation_space, representation, bins,
                                              clip, height, width)
        self._substates: list[tuple[float, dict]] = []
        self._hooked = bool(substeps) and callable(getattr(base, "do_simulation", None)) \
            and hasattr(base, "frame_skip")
        if self._hooked:
            self._hook()
        self._streams = 0          # the event frames' stream (one per reset)
        self._started = False
        self._t: float | None = None
        self._state: dict | None = None

    # ------------------------------------------------------------------ set-up
    def _spaces(self, inner, representation, bins, clip, h, w) -> spaces.Dict:
        parts = dict(inner.spaces) if isinstance(inner, spaces.Dict) else \
            {self.state_key: inner}
        taken = [k for k in self.obs_keys if k in parts]
        if taken:
            raise ValueError(f"{WHERE}: the env's observation already has the key "
                             f"{taken[0]!r}; pass state_key= or fewer obs")
        if "events" in self.obs_keys:
            if representation == "voxel":
                big = float(np.finfo(np.float32).max)    # signed sums: unbounded
                parts["events"] = spaces.Box(-big, big, (bins, h, w), np.float32)
            else:
                planes = 2 if representation in ("counts", "time_surface") else 2 * bins
                high = 255 if representation == "time_surface" else clip   # not clipped
                parts["events"] = spaces.Box(0, high, (planes, h, w), np.uint8)
        if "rgb" in self.obs_keys:
            parts["rgb"] = spaces.Box(0, 255, (h, w, 3), np.uint8)
        return spaces.Dict(parts)

    def _hook(self) -> None:
        """Step the env's frames one at a time through its own do_simulation, keeping
        each frame's state (module docstring)."""
        from sebvs.sim.model_scene import ModelScene
        base = self.base
        original = base.do_simulation
        kept = self._substates

        def do_simulation(ctrl, n_frames):
            for _ in range(int(n_frames)):
                original(ctrl, 1)
                kept.append((float(base.data.time), ModelScene.state(base.data)))

        base.do_simulation = do_simulation

    def _unhook(self) -> None:
        if self._hooked and "do_simulation" in vars(self.base):
            del self.base.do_simulation
        self._hooked = False

    # ------------------------------------------------------------------ gymnasium
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        self._substates.clear()
        inner, info = self.env.reset(seed=seed, options=options)
        data = self.base.data
        if self._auto_view and not self._started:
            view = self.camera.scene.view
            if hasattr(view, "lookat") and self.base.model.ngeom:
                view.lookat[:] = np.median(data.geom_xpos, axis=0)
        self.camera.reset(seed if seed is not None or self._started else self.camera.seed)
        self._started = True
        self._streams += 1
        self._t, self._state = None, None
        events, image = self._sample_end(float(data.time))
        return self._observation(inner, events, image), self._info(info, events)

    def step(self, action):
        self._substates.clear()
        inner, reward, terminated, truncated, info = self.env.step(action)
        t1 = float(self.base.data.time)
        if self._t is None or t1 < self._t:
            # the env restarted its simulation inside a step: a new stream from here
            self.camera.reset()
            self._streams += 1
            self._t = None
            events, image = self._sample_end(t1)
        else:
            events = self._sample_between(t1)
            more, image = self._sample_end(t1)
            events = np.concatenate([events, more]) if more.size else events
        return (self._observation(inner, events, image), reward, terminated, truncated,
                self._info(info, events))

    def _sample_between(self, t1: float) -> np.ndarray:
        """The luma samples at the dvs_hz grid strictly between the previous step's end
        and `t1`, each at its state (a hooked frame's, or interpolated)."""
        from sebvs.dvs.emulator import empty_events
        from sebvs.sim.poses import StateHistory
        t0, hz = self._t, self.dvs_hz
        k = math.floor(t0 * hz + 1e-9) + 1
        if k / hz >= t1 - 1e-12:
            return empty_events()
        history = StateHistory(keep_s=math.inf)
        history.add(t0, self._state)
        for t, state in self._substates:
            if t0 < t < t1:
                history.add(t, state)
        history.add(t1, self.camera.scene.state(self.base.data))
        packets = []
        while (ts := k / hz) < t1 - 1e-12:
            packets.append(self.camera.sample(history.at(self.base.model, ts), ts)[0])
            k += 1
        packets = [p for p in packets if p.size]
        if not packets:
            return empty_events()
        return packets[0] if len(packets) == 1 else np.concatenate(packets)

    def _sample_end(self, t: float):
        """The sample at the step's end: its luma and, if wanted, the frame."""
        state = self.camera.scene.state(self.base.data)
        t_next = t + self.step_s if self.step_s else None
        events, image = self.camera.sample(state, t, frame="rgb" in self.obs_keys,
                                           t_next=t_next)
        self._t, self._state = t, state
        return events, image

    def _observation(self, inner, events: np.ndarray, image) -> dict:
        out = dict(inner) if isinstance(inner, dict) else {self.state_key: inner}
        if "events" in self.obs_keys:
            self.frames.add(events, self._streams, self.geometry)
            # a copy: the observation is the caller's to keep
            out["events"] = np.array(self.frames.frame(self._t))
        if "rgb" in self.obs_keys:
            out["rgb"] = image
        return out

    def _info(self, info: dict, events: np.ndarray) -> dict:
        if not self.raw_events:
            return info
        t1 = self._t
        t0 = t1 - self.step_s if self.step_s else t1
        return {**info, "raw_events": EventPacket(events, t0, t1)}

    def close(self) -> None:
        self._unhook()
        self.camera.close()
        super().close()


def _int_or(value, default: int) -> int:
    return int(value) if isinstance(value, (int, np.integer)) and value > 0 else default


def _positive_or(value, default):
    return float(value) if isinstance(value, (int, float, np.floating)) and value > 0 \
        else default
