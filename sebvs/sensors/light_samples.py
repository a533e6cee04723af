"""The scene's light at recent sample times, and its mean over any exposure.

    light = LightSamples(keep_s=0.2)
    light.add(0.000, lum0)                  # (H, W) cd/m^2, in time order
    light.add(0.005, lum1)
    mean = light.mean(0.001, 0.004)         # the exposure's mean luminance (H, W) float32

One stream of light samples serves both sensors (issue 64): the event sensor reads each
sample as it is rendered, and the frame camera's exposure [t0, t1] integrates the same
samples instead of rendering sub-frames of its own. Between two samples the light is taken
to change linearly, so the integral is exact for that interpolation at both ends of the
exposure, wherever they fall: a sample at t_k contributes to the segments on either side,
each weighted by the length of its overlap with the exposure and by where in the segment
that overlap sits. Before the first sample and after the last the light is held.
"""
from __future__ import annotations

import bisect

import numpy as np


class LightSamples:
    """Recent (t, luminance) samples of one episode, oldest first."""

    def __init__(self, keep_s: float) -> None:
        if not keep_s > 0:
            raise ValueError(f"light samples: keep_s must be > 0, got {keep_s!r}")
        self.keep_s = float(keep_s)
        self.times: list[float] = []
        self.images: list[np.ndarray] = []

    def clear(self) -> None:
        self.times.clear()
        self.images.clear()

    def add(self, t: float, luminance: np.ndarray) -> None:
        """Keep a copy of the luminance at time ``t`` (s; a time already kept is replaced,
        an earlier one is inserted in order, a much later stream's start clears the rest).

        Parameters:
            t: the sample's time.
            luminance: (H, W) float luminance in cd/m^2 (copied: it may be a reused slot).
        """
        t = float(t)
        i = bisect.bisect_left(self.times, t)
        if i < len(self.times) and self.times[i] == t:
            np.copyto(self.images[i], luminance)
            return
        self.times.insert(i, t)
        self.images.insert(i, np.array(luminance, np.float32))
        cut = bisect.bisect_left(self.times, self.times[-1] - self.keep_s)
        if cut > 1:                     # one sample older than the window stays
            del self.times[:cut - 1], self.images[:cut - 1]

    def inside(self, t0: float, t1: float) -> int:
        """How many samples lie strictly inside (t0, t1)."""
        return bisect.bisect_left(self.times, t1) - bisect.bisect_right(self.times, t0)

    def reaches(self, t: float) -> bool:
        """Whether a sample at or after ``t`` is kept: the light up to ``t`` is known."""
        return bool(self.times) and self.times[-1] >= t

    def weights(self, t0: float, t1: float) -> list[tuple[int, float]]:
        """(sample index, weight) of the exposure's mean over [t0, t1]; weights sum to 1.

        Parameters:
            t0, t1: the exposure's start and end (s), t1 > t0.

        Returns:
            Each sample's share of the integral of the piecewise-linear light over the
            exposure, divided by its length.
        """
        if not self.times:
            raise LookupError("light samples: none kept yet")
        if not t1 > t0:
            raise ValueError(f"light samples: an exposure ends after it starts, got "
                             f"[{t0!r}, {t1!r}]")
        times, span = self.times, t1 - t0
        w: dict[int, float] = {}

        def put(i: int, value: float) -> None:
            if value:
                w[i] = w.get(i, 0.0) + value

        # held before the first sample and after the last
        put(0, max(0.0, min(t1, times[0]) - t0))
        put(len(times) - 1, max(0.0, t1 - max(t0, times[-1])))
        lo = max(bisect.bisect_right(times, t0) - 1, 0)
        hi = min(bisect.bisect_left(times, t1), len(times) - 1)
        for k in range(lo, hi):
            a, b = max(t0, times[k]), min(t1, times[k + 1])
            if b <= a:
                continue
            # the linear light's integral over [a, b] is its value at the midpoint times
            # the length: split between the segment's two samples by where that lies
            m = (0.5 * (a + b) - times[k]) / (times[k + 1] - times[k])
            put(k, (b - a) * (1.0 - m))
            put(k + 1, (b - a) * m)
        return [(i, v / span) for i, v in sorted(w.items())]

    def mean(self, t0: float, t1: float) -> np.ndarray:
        """The mean luminance over [t0, t1], (H, W) float32 (module docstring)."""
        out = np.zeros(self.images[0].shape if self.images else (0, 0), np.float64)
        for i, weight in self.weights(t0, t1):
            out += weight * self.images[i]
        return out.astype(np.float32)
