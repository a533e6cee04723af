"""A time surface: how recently each sensor pixel fired, per polarity, as a uint8 frame.

    surface = TimeSurface(sensor=(160, 160), tau_s=0.1)
    surface.add(events)                  # EVENT_DTYPE packets, as they arrive
    frame = surface.frame(t_end_ns)      # uint8 [2, H, W]: ON plane, OFF plane
    surface.clear()                      # a new episode: nothing has fired yet

    value = round(255 * exp(-(t_end - t_last) / tau))

t_last is the newest event of that polarity at that pixel; a pixel that never fired is 0,
and so is one that fired so long ago that the value rounds to 0 (about 6.2 tau). Unlike a
window's counts the memory reaches beyond any window: a target that stops moving stays
visible for a few tau. The accumulator's `time_surface` representation
(sebvs/dvs/accumulator.py) is this, mapped onto the output grid.
"""
from __future__ import annotations

import numpy as np

from .emulator import EVENT_DTYPE

# the last time of a pixel that has not fired: far enough back that exp() gives 0, near
# enough that t_end - NEVER cannot overflow int64 (for |t_end| < 2**62 ns, 146 years)
NEVER = -(2 ** 62)


class TimeSurface:
    """Per sensor pixel and polarity, the newest event's time (int64 ns), and the frame
    of exponentially decayed ages it gives at a time.

    Keeps the newest time only: a frame asked for a time before a pixel's newest event
    shows that pixel as 0 (its newer event does not count, and its older ones were
    overwritten). The sensor chain asks for frames at or after every event added, where
    this never happens; `hidden_frames` counts the frames where it did.

    Parameters:
        sensor: the sensor's (width, height) in px; events off it are ignored.
        tau_s: the decay constant tau, s (> 0).
    """

    def __init__(self, sensor: tuple[int, int], tau_s: float):
        if not tau_s > 0:
            raise ValueError(f"time surface: tau_s must be positive, got {tau_s}")
        self.width, self.height = (int(v) for v in sensor)
        self.plane = self.width * self.height
        self.tau_ns = float(tau_s) * 1e9
        # ON plane, OFF plane, and one spare slot that takes the ignored events
        self.last = np.full(2 * self.plane + 1, NEVER, np.int64)
        self.newest_t = NEVER
        self.hidden_frames = 0

    def clear(self) -> None:
        """Forget every event (a new episode)."""
        self.last.fill(NEVER)
        self.newest_t = NEVER

    def add(self, events: np.ndarray) -> None:
        """Take in one packet.

        Parameters:
            events: EVENT_DTYPE [N], in any order; events off the sensor or of polarity
                0 are ignored.
        """
        if events.dtype != EVENT_DTYPE:
            raise ValueError(f"time surface: events dtype {events.dtype} is not {EVENT_DTYPE}")
        if not events.size:
            return
        x, y, p, t = events["x"], events["y"], events["p"], events["t"]
        row = y.astype(np.int64) * self.width
        index = row + x
        index[p < 0] += self.plane
        index[(x >= self.width) | (row >= self.plane) | (p == 0)] = 2 * self.plane
        # maximum, not assignment: numpy does not promise which of repeated indices wins,
        # and a late packet must not move a pixel's time back. The times contiguous:
        # ufunc.at on the strided field took 20x as long (42 against 2 us per 1,000 events)
        np.maximum.at(self.last, index, np.ascontiguousarray(t))
        self.newest_t = max(self.newest_t, int(t.max()))

    def frame(self, t_end_ns: int) -> np.ndarray:
        """The time surface at ``t_end_ns``.

        Parameters:
            t_end_ns: the frame's time, int ns.

        Returns:
            uint8 [2, H, W] (ON, OFF) at the sensor's resolution, C-contiguous:
            255 * exp(-(t_end - t_last) / tau), rounded half up (computed in float32),
            0 where the pixel never fired or its newest event is after ``t_end_ns``.
        """
        age = np.subtract(int(t_end_ns), self.last[:-1]).astype(np.float32)
        age *= np.float32(-1.0 / self.tau_ns)
        ahead = None
        if self.newest_t > t_end_ns:
            # a negative age is an event this frame must not see (and would overflow exp)
            ahead = self.last[:-1] > t_end_ns
            np.minimum(age, 0.0, out=age)
        np.exp(age, out=age)
        age *= np.float32(255.0)
        age += np.float32(0.5)
        values = age.astype(np.uint8)
        if ahead is not None and ahead.any():
            values[ahead] = 0
            self.hidden_frames += 1
        return values.reshape(2, self.height, self.width)
