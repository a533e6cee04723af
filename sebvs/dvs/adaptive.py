"""When to render the next luma frame for the event emulator: adaptive sampling (ESIM's rule).

The emulator places each threshold crossing on the straight line between two consecutive
samples of a pixel's log brightness (sebvs/dvs/emulator.py). That line is a good stand-in
for the true brightness only while a pixel changes by less than its contrast threshold C
between samples; a fixed clock either wastes renders on a still scene or under-samples a
fast one. So, as ESIM does (Rebecq et al. 2018), take the next sample when the brightness
could have changed by a fraction lambda of C:

    rate  = max over pixels |L_k - L_(k-1)| / (t_k - t_(k-1))     log units per second,
                                                                   from the last two samples
            but at least half the previous sample's rate
    dt    = lambda * C / rate, clamped to [1 / ceiling_hz, 1 / floor_hz]
    next  = t_k + dt

L is the lin-log brightness the emulator works in (`linlog` of 8-bit luma). The rate is
the last interval's largest per-pixel change, so the next interval's largest change stays
near lambda * C while the motion changes slowly against the sampling (the scenes' drives and
targets accelerate over tens of ms, samples come every 1-20 ms). A still scene asks for the
floor rate.

Why the rate may fall by at most half per sample: MuJoCo's renders here are not
antialiased, so a pixel an edge crosses changes in one step, not along a ramp. Over a short
interval that no edge crossed, the largest change is a rounding step or nothing, and a rate
read from it alone sends the next sample to the floor; the interval after that one holds
many steps and sends the next to the ceiling, and so on (on the arm's moving belt, with an
allowance for one-DN rounding: 74 samples a second and a median event-time error of 4.4 ms
against 1 kHz; docs/dvs.md, "Adaptive sampling"). Halving at most per sample lets the
rate come down to the floor within a few tens of ms of the motion stopping (about six
samples from the ceiling).

A caller that samples only at fixed candidate times (the sim's states, every
1 / render_hz) asks `due(t, period)`: whether the candidate at t is the last one before the
next sample time, so the bound holds on the candidates' grid. One that can render between
candidates (the camera, at poses interpolated between the sim's states) asks
`pending_before(t)` for the sample times before the next candidate and renders each.
Samples taken for another reason (the control ticks, which always get one) are observed
like the others.

    sampler = LumaSampler(SamplerParams(fraction=0.35, threshold=0.3, floor_hz=20,
                                        ceiling_hz=500))
    for t, state in states:                        # every 1 ms, say
        if control or sampler.due(t, 0.001):
            luma = render(state)
            sampler.observe(t, luma)               # uint8 (H, W), or float log brightness
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from .emulator import LINLOG, LINLOG_BREAK

# a candidate within this of the next sample time counts as at it (float episode times)
_TIME_TOLERANCE_S = 1e-9


@dataclass(frozen=True)
class SamplerParams:
    """The adaptive sampler's options (the camera actor's luma_* parameters)."""
    fraction: float = 0.35       # lambda: the largest per-pixel change aimed at, as a
                                 # fraction of the contrast threshold
    threshold: float = 0.3       # C, log units: the emulator's contrast threshold (its
                                 # pos_thres / neg_thres; the smaller if they differ)
    floor_hz: float = 20.0       # at least this many samples per second (a still scene)
    ceiling_hz: float = 500.0    # at most this many (a fast one)

    def validate(self) -> "SamplerParams":
        for name, v in asdict(self).items():
            if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v):
                raise ValueError(f"luma sampler: {name} must be a finite number, got {v!r}")
        if not 0 < self.fraction <= 10:
            raise ValueError(f"luma sampler: fraction must be in (0, 10], got {self.fraction}")
        if self.threshold <= 0:
            raise ValueError(f"luma sampler: threshold must be positive, got {self.threshold}")
        if not 0 < self.floor_hz <= self.ceiling_hz:
            raise ValueError(f"luma sampler: need 0 < floor_hz <= ceiling_hz, got "
                             f"{self.floor_hz} and {self.ceiling_hz}")
        return self

    @property
    def bound(self) -> float:
        """lambda * C: the per-pixel log change one interval should stay below."""
        return self.fraction * self.threshold


def sample_interval(log_rate: float, params: SamplerParams) -> float:
    """Seconds from a sample to the next for a largest brightness change rate `log_rate`
    (log units per second): bound / rate, clamped to [1 / ceiling_hz, 1 / floor_hz]; a
    rate of 0 (a still scene) gives the floor's interval."""
    shortest, longest = 1.0 / params.ceiling_hz, 1.0 / params.floor_hz
    if not log_rate > 0:
        return longest
    return min(max(params.bound / log_rate, shortest), longest)


def log_brightness(luma: np.ndarray) -> np.ndarray:
    """The emulator's lin-log brightness of 8-bit luma: float32, the shape of `luma`."""
    return LINLOG[luma]


def log_luminance(luminance: np.ndarray, dark_cd_m2: float = 0.1) -> np.ndarray:
    """Log brightness of linear luminance (cd/m^2, float (H, W)), float32: ln L above
    `dark_cd_m2` (the physical emulator preset's lin-log break), linear below it with the
    emulator's lin-log slope (ln 20 per break), so a dark pixel's noise does not read as
    huge log changes. Its differences are the emulator's, whatever its reference level."""
    lum = np.asarray(luminance, np.float32)
    dark = np.float32(dark_cd_m2)
    out = np.log(np.maximum(lum, dark))
    low = lum < dark
    out[low] = np.log(dark) + np.float32(np.log(LINLOG_BREAK)) * (lum[low] - dark) / dark
    return out


def largest_log_change(previous: np.ndarray, current: np.ndarray) -> float:
    """The largest per-pixel |current - previous| (0 for empty frames)."""
    return float(np.abs(current - previous).max()) if current.size else 0.0


# the most the rate estimate may fall from one sample to the next (module docstring)
RATE_FALL_PER_SAMPLE = 0.5


class LumaSampler:
    """Decides, candidate by candidate, when the next luma sample is due (module docstring).

    Times are seconds of one stream (the episode's); call `reset()` when it restarts.
    """

    def __init__(self, params: SamplerParams | None = None) -> None:
        self.params = (params or SamplerParams()).validate()
        self.reset()

    def reset(self) -> None:
        """A new stream: the next candidate is sampled, and the first interval after it is
        the ceiling's (no rate has been measured yet)."""
        self.t_last: float | None = None
        self.log_last: np.ndarray | None = None
        self.rate = math.inf            # log units per second; inf: unknown, sample soon
        self.next_t = -math.inf
        self.samples = 0

    def due(self, t: float, period: float = 0.0) -> bool:
        """Whether to sample the candidate at `t`, the next candidate coming `period` s
        later: yes when that one would be past the next sample time (so no interval
        outgrows the bound on the candidates' grid), or when t is already past it."""
        return t + period > self.next_t + _TIME_TOLERANCE_S

    def pending_before(self, t: float) -> float | None:
        """The next sample time if it comes before the candidate at `t`, else None. A caller
        that can render between candidates (at poses interpolated between two states)
        renders and observes it, then asks again:

            while (ts := sampler.pending_before(t)) is not None:
                sampler.observe(ts, render_at(ts))
        """
        if self.t_last is None or not self.next_t < t - _TIME_TOLERANCE_S:
            return None
        return self.next_t

    def observe(self, t: float, frame: np.ndarray) -> float:
        """A sample taken at `t`: 8-bit luma (uint8 (H, W)) or log brightness (float
        (H, W)). Updates the rate from the previous sample; returns the next sample time."""
        log = log_brightness(frame) if frame.dtype == np.uint8 else \
            np.asarray(frame, np.float32)
        if self.t_last is not None and t > self.t_last:
            measured = largest_log_change(self.log_last, log) / (t - self.t_last)
            # inf (nothing measured yet) falls to the measurement
            floor = self.rate * RATE_FALL_PER_SAMPLE if math.isfinite(self.rate) else 0.0
            self.rate = max(measured, floor)
        elif self.t_last is not None and t < self.t_last:
            self.rate = math.inf          # time went back: a new stream the caller missed
        self.t_last, self.log_last = t, log
        self.samples += 1
        self.next_t = t + sample_interval(self.rate, self.params)
        return self.next_t
