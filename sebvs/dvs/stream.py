"""The event chain's per-sample logic without its messaging: the emulator and accumulator
actors (actors/emulator.py, actors/accumulator.py) and sebvs.envs run the same code.

    sensor = SensorStream(preset("paper", seed=emulator_seed, downsample=1.0))
    frames = FrameStream("counts", window_s=0.1, out_width=160, out_height=160)
    events = sensor.frame(luma, t_sim, episode, units)        # one luma sample
    frames.add(events, episode, sensor.geometry_meta(luma))
    if control:
        frame = frames.frame(t_sim)                            # the tick's event frame
"""
from __future__ import annotations

import numpy as np

from .accumulator import EventAccumulator, EventGeometry
from .emulator import EventEmulator
from .params import EmulatorParams


class SensorStream:
    """The emulator over a run's episodes: a new episode restarts the stream (the scene
    jumps, and a jump is not a brightness change the sensor would see), with the fixed
    pattern that episode draws from [seed, episode] alone (not from how many episodes
    this process played before: a fan-out worker that plays episodes [a, b) of a run
    draws what one process playing them all draws). Timestamps: t_sim s -> int ns."""

    def __init__(self, params: EmulatorParams) -> None:
        self.emulator = EventEmulator(params)
        self.episode = None

    def frame(self, frame: np.ndarray, t_sim: float | None, episode,
              units: str | None = None) -> np.ndarray:
        """One luma frame (uint8 DN, or float32 cd/m^2 with units "cd/m2") at t_sim (s)
        of `episode` -> the events since the previous frame. Raises ValueError (a bad
        frame or timestamp; the state stays), OverflowError (an infinite t_sim)."""
        if episode != self.episode:
            self.emulator.reset()
            if isinstance(episode, int) and episode >= 0:
                self.emulator.rng = np.random.default_rng([self.emulator.params.seed, episode])
            self.episode = episode
        # round() of an inf t_sim raises OverflowError, of NaN ValueError
        t_ns = round((t_sim or 0.0) * 1e9)
        if units == "cd/m2":
            return self.emulator.step_luminance(frame, t_ns)
        return self.emulator.step(frame, t_ns)

    def geometry_meta(self, frame: np.ndarray) -> dict:
        """What the emulator actor adds to its packets' meta: the emulated sensor's
        [w, h] and the input frame's [W, H]."""
        h, w = self.emulator.shape
        return {"event_sensor": [w, h], "frame": [frame.shape[1], frame.shape[0]]}


class FrameStream:
    """The accumulator over a run's event packets: built for the geometry the packets
    carry (rebuilt when it changes), cleared at a new episode, an event frame on demand."""

    def __init__(self, representation: str = "counts", window_s: float = 0.1, bins: int = 5,
                 clip: int = 255, out_width: int = 0, out_height: int = 0) -> None:
        self.representation, self.window_s, self.bins, self.clip = \
            representation, window_s, bins, clip
        self.out_width, self.out_height = out_width, out_height   # 0: the input frame's
        self.acc: EventAccumulator | None = None
        self.geometry_key = None       # (event_sensor, frame) the accumulator was built for
        self.episode = None

    def _accumulator(self, geometry: dict) -> EventAccumulator:
        # every packet carries the geometry; it changes only with the scene's image size
        key = (geometry["event_sensor"], geometry.get("frame"))
        if self.acc is not None and key == self.geometry_key:
            return self.acc
        out = (self.out_width or geometry["frame"][0], self.out_height or geometry["frame"][1])
        g = EventGeometry(tuple(geometry["event_sensor"]), out)
        if self.acc is None or self.acc.geometry != g:
            self.acc = EventAccumulator(g, self.representation, self.window_s, self.bins,
                                        self.clip)
        self.geometry_key = key
        return self.acc

    def add(self, events: np.ndarray, episode, geometry: dict) -> None:
        """One packet of `episode` (kept, not copied) with its geometry meta
        (event_sensor, frame)."""
        acc = self._accumulator(geometry)
        if episode != self.episode:
            acc.clear()
            self.episode = episode
        acc.add(events)

    def frame(self, t_sim: float | None) -> np.ndarray:
        """The event frame of the window ending at t_sim (s)."""
        return self.acc.frame(round((t_sim or 0.0) * 1e9))

    def frame_meta(self) -> dict:
        """The accumulator actor's meta of a frame: geometry, representation, bins,
        window."""
        acc = self.acc
        return {**acc.geometry.to_meta(), "representation": acc.representation,
                "bins": 1 if acc.representation in ("counts", "time_surface") else acc.bins,
                "window_s": self.window_s}
