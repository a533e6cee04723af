"""A non-learned event-cluster tracker: one target followed through event frames alone.

    tracker = EventTracker(EventTrackerConfig())
    det = tracker.step(events, dt)         # events [2K, H, W] counts (the accumulator's frame)
    det = tracker.step(events, dt, measure=False)    # predict only: the frame is not trusted
    tracker.shift(du)                      # the image moved by du px (the robot's own turn)
    det                                    # a Detection (centroid, bbox, ...) or None
    tracker.mode                           # "acquire" | "track" | "coast" | "lost"

Measurement, per frame: the counts of every polarity and time bin are summed into one map.
A frame whose share of active pixels exceeds `burst_active` is a burst (mains flicker, an
exposure jump: the whole image fires) and measures nothing. Otherwise every pixel gets a
centre-surround significance: how many Poisson standard deviations the counts of the
square window around it (half side `window` of the width) exceed what the densest of the
four strips of its surround (the ring out to `surround` times the window: above, below,
left, right) puts there. The background is local and the densest side's because the
sensor's noise is not uniform (a bright sky fires far more than a dark floor, measured in
the hdr cell) and a floor edge is a line, not a cluster: the strips along it hold it
too. The most significant pixel is taken over the whole image when no target is held, and
within `gate` of the prediction when one is (the gate grows by `gate_growth` widths per
second without a measurement); the window is moved to its counts' centroid
(mean shift, `shift_iterations`), and it is a target when it holds at least `min_events`
counts and `min_z` standard deviations more than its surround predicts (`acquire_z` to take
up a target while none is held: over a whole frame, noise alone reaches 4-5.4, measured in
the hdr cell's first frames).

Memory: an alpha-beta filter keeps the position and velocity (px/s) between measurements,
its velocity updated from the residual over the time since the last measurement (constant
velocity in between). Without a measurement it coasts on the prediction for at most
`coast_s`, then reports lost and forgets the target; a prediction that leaves the image is
lost at once. The Detection's width is the cluster's extent in u (sqrt(12) times the
standard deviation of the column sums above the frame's background in a window twice the
measurement window's, smoothed, clipped to [min_width, max_width] of the width); its
confidence is 1 on a measured frame and falls to 0 over the coast. Sizes are fractions of
the frame's width, so one configuration holds at any resolution.

What drives the robot from this tracker: sebvs/experts/event_agent.py.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from .detector import Detection


@dataclass
class EventTrackerConfig:
    """The tracker's settings (sizes as fractions of the event frame's width)."""
    burst_active: float = 0.3     # a frame with more active pixels than this is a burst
    window: float = 0.05          # half side of the measurement window (8 px at 160 px)
    surround: float = 3.0         # the background's window: this many times its side
    gate: float = 0.15            # search radius around the prediction while holding one
    gate_growth: float = 0.1      # ... growing by this many widths per second unmeasured
    min_events: float = 12.0      # counts in the window for a measurement, at least
    min_z: float = 4.0            # ... and this many Poisson standard deviations above the
                                  #     counts its surround's density puts there (holding one)
    acquire_z: float = 6.0        # ... to take up a target while none is held: the most
                                  #     significant of a whole frame's noise reaches 4-5.4
    shift_iterations: int = 3     # mean-shift steps of the window
    alpha: float = 0.7            # position gain of the alpha-beta filter
    beta: float = 0.2             # velocity gain
    max_speed: float = 1.0        # image widths per s: faster velocity estimates are clipped
    coast_s: float = 1.5          # predict this long without a measurement, then lost
    width_smoothing: float = 0.5  # weight of a new width measurement
    min_width: float = 0.03
    max_width: float = 0.4

    def __post_init__(self) -> None:
        for name in ("window", "gate", "max_width", "max_speed"):
            if not getattr(self, name) > 0:
                raise ValueError(f"event tracker: {name} must be > 0, got "
                                 f"{getattr(self, name)!r}")
        if not self.surround > 1:
            raise ValueError(f"event tracker: surround must be > 1, got {self.surround!r}")
        if not 0 < self.burst_active <= 1:
            raise ValueError(f"event tracker: burst_active must be in (0, 1], got "
                             f"{self.burst_active!r}")
        for name in ("alpha", "width_smoothing"):
            if not 0 < getattr(self, name) <= 1:
                raise ValueError(f"event tracker: {name} must be in (0, 1], got "
                                 f"{getattr(self, name)!r}")
        if not 0 <= self.beta <= 2:
            raise ValueError(f"event tracker: beta must be in [0, 2], got {self.beta!r}")
        for name in ("coast_s", "min_events", "min_z", "acquire_z", "shift_iterations",
                     "gate_growth", "min_width"):
            if getattr(self, name) < 0:
                raise ValueError(f"event tracker: {name} must be >= 0, got "
                                 f"{getattr(self, name)!r}")
        if not self.min_width <= self.max_width:
            raise ValueError("event tracker: min_width must not exceed max_width")


@dataclass
class Measurement:
    """One frame's cluster: centre (u, v) px, counts in its window, its width px, and its
    counts over those the frame's mean density puts in the window."""
    centre: tuple[float, float]
    counts: float
    width: float
    contrast: float


class EventTracker:
    """One target over an episode; `reset()` between episodes."""

    def __init__(self, config: EventTrackerConfig | None = None) -> None:
        self.cfg = config or EventTrackerConfig()
        self.image_size: tuple[int, int] | None = None     # (width, height), from the frames
        self.reset()

    def reset(self) -> None:
        self.pos: np.ndarray | None = None     # (u, v) px
        self.vel = np.zeros(2)                 # px / s
        self.width: float | None = None        # px
        self.coasted_s = 0.0                   # s since the last measurement
        self.mode = "acquire"
        self.last: Measurement | None = None   # the last frame's measurement, if any
        self.burst = False                     # whether the last frame was a burst
        self.active = 0.0                      # the last frame's share of active pixels
        self.counts = {"frames": 0, "measured": 0, "coasted": 0, "bursts": 0, "lost": 0}

    # ---------------------------------------------------------------- measurement
    def measure(self, events: np.ndarray) -> Measurement | None:
        """The frame's target cluster, or None (a burst, or no cluster that passes).

        Parameters:
            events: [2K, H, W] or [H, W] counts.

        Returns:
            The Measurement, or None; sets `burst` and `active` for the frame.
        """
        c = self.cfg
        counts = _count_map(events)
        h, w = counts.shape
        self.burst = False
        self.active = float(np.count_nonzero(counts)) / counts.size
        if not counts.any():
            return None
        if self.active > c.burst_active:
            self.burst = True
            return None
        half = max(1.0, c.window * w)
        z, inside, expected, density = _significance(counts, half, c.surround,
                                           float(counts.sum()) / counts.size)
        if self.pos is not None:
            r = (c.gate + c.gate_growth * self.coasted_s) * w
            u0, u1 = _span(self.pos[0], r, w)
            v0, v1 = _span(self.pos[1], r, h)
            if u1 <= u0 or v1 <= v0:
                return None
            region = z[v0:v1, u0:u1]
        else:
            u0, v0, region = 0, 0, z
        cy, cx = divmod(int(np.argmax(region)), region.shape[1])
        centre = np.array([u0 + cx + 0.5, v0 + cy + 0.5])
        for _ in range(c.shift_iterations):
            moved = _centroid(counts, centre, half)
            if moved is None:
                break
            centre = moved
        # the test at the pixel the window ended on
        y, x = min(h - 1, int(centre[1])), min(w - 1, int(centre[0]))
        need = c.min_z if self.pos is not None else c.acquire_z
        if inside[y, x] < c.min_events or z[y, x] < need:
            return None
        return Measurement((float(centre[0]), float(centre[1])), float(inside[y, x]),
                           _extent(counts, centre, 2 * half, float(density[y, x])),
                           float(inside[y, x] / max(expected[y, x], 1e-9)))

    # ---------------------------------------------------------------- the filter
    def step(self, events: np.ndarray, dt: float, measure: bool = True) -> Detection | None:
        """Advance one frame (`dt` s since the previous) and return the held target.

        Parameters:
            events: [2K, H, W] (or [H, W]) counts of the frame.
            dt: s since the previous frame (<= 0 or not finite: 0).
            measure: False: predict only (a frame the caller knows to be blind, as while
                the robot itself turns and the whole scene fires).

        Returns:
            The target's Detection, or None while none is held (not yet found, or lost).
        """
        c = self.cfg
        events = np.asarray(events)
        h, w = events.shape[-2:]
        self.image_size = (w, h)
        dt = float(dt) if dt and dt > 0 and math.isfinite(dt) else 0.0
        self.counts["frames"] += 1
        if self.pos is not None:
            self.pos = self.pos + self.vel * dt
            self.coasted_s += dt
        meas = self.measure(events) if measure else None
        if not measure:
            self.burst = False
        self.last = meas
        self.counts["bursts"] += int(self.burst)
        if meas is not None:
            self._update(np.array(meas.centre), meas.width, w)
        elif self.pos is not None:
            inside = 0 <= self.pos[0] < w and 0 <= self.pos[1] < h
            if self.coasted_s > c.coast_s or not inside:
                self.counts["lost"] += 1
                self.pos, self.vel, self.width = None, np.zeros(2), None
                self.coasted_s = 0.0
                self.mode = "lost"
                return None
            self.mode = "coast"
            self.counts["coasted"] += 1
        else:
            self.mode = "lost" if self.counts["lost"] else "acquire"
            return None
        return self.detection()

    def _update(self, z: np.ndarray, width: float, image_width: int) -> None:
        c = self.cfg
        if self.pos is None:
            self.pos, self.vel = z, np.zeros(2)
        else:
            r = z - self.pos
            self.pos = self.pos + c.alpha * r
            # the residual built up over the whole time since the last measurement
            if self.coasted_s > 0:
                self.vel = self.vel + c.beta * r / self.coasted_s
            limit = c.max_speed * image_width
            speed = float(np.hypot(*self.vel))
            if speed > limit:
                self.vel *= limit / speed
        width = float(np.clip(width, c.min_width * image_width, c.max_width * image_width))
        self.width = width if self.width is None else \
            (1 - c.width_smoothing) * self.width + c.width_smoothing * width
        self.coasted_s = 0.0
        self.mode = "track"
        self.counts["measured"] += 1

    def shift(self, du: float, dv: float = 0.0) -> None:
        """Move the held target by (du, dv) px: the image's own motion, known to the caller
        (a turn of the robot it commanded), which the constant-velocity memory cannot know."""
        if self.pos is not None:
            self.pos = self.pos + np.array([du, dv], np.float64)

    def detection(self) -> Detection | None:
        """The held target as a Detection (None when none is held)."""
        if self.pos is None or self.image_size is None:
            return None
        c = self.cfg
        w, _ = self.image_size
        width = self.width if self.width is not None else c.min_width * w
        side = max(1, int(round(width)))
        u, v = float(self.pos[0]), float(self.pos[1])
        if self.mode == "track":
            confidence = 1.0
        else:
            confidence = max(0.0, 1.0 - self.coasted_s / c.coast_s) if c.coast_s > 0 else 0.0
        area = int(round(self.last.counts)) if self.mode == "track" and self.last else 0
        return Detection(centroid=(u, v),
                         bbox=(int(math.floor(u - side / 2)), int(math.floor(v - side / 2)),
                               side, side),
                         area=area, confidence=float(confidence))


def _count_map(events: np.ndarray) -> np.ndarray:
    """float32 [H, W]: every plane's counts summed (ON and OFF, every time bin)."""
    events = np.asarray(events)
    if events.ndim == 2:
        return events.astype(np.float32)
    return events.astype(np.float32).sum(axis=0)


def _rect_sums(ii: np.ndarray, rows: tuple[int, int], cols: tuple[int, int]
               ) -> tuple[np.ndarray, np.ndarray]:
    """For every pixel (y, x): the sum over rows y + rows[0] .. y + rows[1] - 1 and columns
    x + cols[0] .. x + cols[1] - 1, clipped to the image, and that rectangle's area; `ii` is
    the image's integral (cv2.integral, [H + 1, W + 1])."""
    h, w = ii.shape[0] - 1, ii.shape[1] - 1
    ys, xs = np.arange(h)[:, None], np.arange(w)[None, :]
    y0, y1 = np.clip(ys + rows[0], 0, h), np.clip(ys + rows[1], 0, h)
    x0, x1 = np.clip(xs + cols[0], 0, w), np.clip(xs + cols[1], 0, w)
    return ii[y1, x1] - ii[y0, x1] - ii[y1, x0] + ii[y0, x0], (y1 - y0) * (x1 - x0)


def _significance(counts: np.ndarray, half: float, surround: float, floor: float
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per pixel: (z, the counts of the window around it, the counts the surround's density
    puts there, that density).

    The window is (2 a + 1) px square, a = round(half); its surround the ring out to
    round(surround * half), cut into four strips (above, below, left, right). The density
    is the densest strip's (at least `floor`): a cluster stands out against every side of
    its surround, the edge of a noisier region or a line through the window does not (one
    strip holds as much). z: how many Poisson standard deviations the window's counts
    exceed what that density puts there. All [H, W] float64."""
    a = int(round(half))
    b = max(a + 1, int(round(surround * half)))
    ii = cv2.integral(np.ascontiguousarray(counts, np.float32), sdepth=cv2.CV_64F)
    inside, area = _rect_sums(ii, (-a, a + 1), (-a, a + 1))
    density = np.full(counts.shape, float(floor))
    for rows, cols in (((-b, -a), (-b, b + 1)), ((a + 1, b + 1), (-b, b + 1)),
                       ((-a, a + 1), (-b, -a)), ((-a, a + 1), (a + 1, b + 1))):
        strip, strip_area = _rect_sums(ii, rows, cols)
        density = np.maximum(density, np.where(strip_area > 0,
                                                strip / np.maximum(strip_area, 1), 0.0))
    expected = density * area
    return (inside - expected) / np.sqrt(expected + 1e-6), inside, expected, density


def _span(centre: float, half: float, size: int) -> tuple[int, int]:
    """[lo, hi) pixel range of a window centred at `centre`, clipped to the image."""
    return max(0, int(math.floor(centre - half))), min(size, int(math.ceil(centre + half)))


def _centroid(counts: np.ndarray, centre: np.ndarray, half: float) -> np.ndarray | None:
    """The counts' centroid (px, pixel centres) in the window around `centre`."""
    h, w = counts.shape
    a0, a1 = _span(centre[0], half, w)
    b0, b1 = _span(centre[1], half, h)
    patch = counts[b0:b1, a0:a1]
    s = float(patch.sum())
    if s <= 0:
        return None
    us = np.arange(a0, a1) + 0.5
    vs = np.arange(b0, b1) + 0.5
    return np.array([float((patch.sum(axis=0) * us).sum() / s),
                     float((patch.sum(axis=1) * vs).sum() / s)])


def _extent(counts: np.ndarray, centre: np.ndarray, half: float, density: float) -> float:
    """sqrt(12) x the standard deviation in u of the window's column sums above twice what
    the frame's mean `density` puts in a column (so that scattered noise adds little): a
    uniform bar's width, px."""
    h, w = counts.shape
    a0, a1 = _span(centre[0], half, w)
    b0, b1 = _span(centre[1], half, h)
    col = np.maximum(counts[b0:b1, a0:a1].sum(axis=0) - 2.0 * density * (b1 - b0), 0.0)
    s = float(col.sum())
    if s <= 0:
        return 0.0
    us = np.arange(a0, a1) + 0.5
    mu = float((col * us).sum() / s)
    return math.sqrt(12.0 * max(0.0, float((col * (us - mu) ** 2).sum() / s)))
