"""Event frames from an event stream: what a frame-based policy sees of the events.

Representations, over the window [t - window, t] that ends at a control tick:
    counts     [2, H, W]          ON and OFF counts (the paper's event frames)
    histogram  [2 * bins, H, W]   counts per time bin, ON bins then OFF bins (RVT style)
    voxel      [bins, H, W]       polarity spread over time bins by linear interpolation
The frames are at the output (RGB) resolution: an event at emulator pixel (x, y) lands on
(floor(x * scale + offset_x), floor(y * scale + offset_y)) and fills its scale x scale
block, so a count keeps its meaning per sensor pixel. Counts saturate at `clip` (uint8).
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from .emulator import EVENT_DTYPE

REPRESENTATIONS = ("counts", "histogram", "voxel")


@dataclass(frozen=True)
class EventGeometry:
    """How emulator pixels map onto the RGB image: sensor (w, h) -> output (w, h)."""
    sensor: tuple[int, int]
    output: tuple[int, int]

    @property
    def scale(self) -> tuple[float, float]:
        return (self.output[0] / self.sensor[0], self.output[1] / self.sensor[1])

    @property
    def offset(self) -> tuple[float, float]:
        return (0.0, 0.0)

    def to_meta(self) -> dict:
        return {"event_sensor": list(self.sensor), "event_output": list(self.output),
                "event_scale": list(self.scale), "event_offset": list(self.offset)}


def _concatenate(packets) -> np.ndarray:
    """np.concatenate of EVENT_DTYPE arrays through their bytes: on structured arrays numpy
    promotes the fields pair by pair, tens of us per packet; the bytes are the same."""
    raw = np.concatenate([np.ascontiguousarray(p).view(np.uint8) for p in packets])
    return raw.view(EVENT_DTYPE)


class EventAccumulator:
    """Keeps the events of the last `window_s` and turns them into frames on demand."""

    def __init__(self, geometry: EventGeometry, representation: str = "counts",
                 window_s: float = 0.1, bins: int = 5, clip: int = 255):
        if representation not in REPRESENTATIONS:
            raise ValueError(f"unknown representation {representation!r} "
                             f"(one of {', '.join(REPRESENTATIONS)})")
        if not window_s > 0:
            raise ValueError(f"window_s must be positive, got {window_s}")
        if bins < 1 or not 1 <= clip <= 255:
            raise ValueError(f"bins must be >= 1 and clip in 1..255 (got {bins}, {clip})")
        self.geometry = geometry
        self.representation = representation
        self.window_ns = int(round(window_s * 1e9))
        self.bins = bins
        self.clip = clip
        self._packets: deque[np.ndarray] = deque()
        # the output pixel -> sensor pixel maps (nearest), once per geometry
        (ow, oh), (sw, sh) = geometry.output, geometry.sensor
        self._rows = self._cols = None
        if (ow, oh) != (sw, sh):
            self._rows = np.minimum((np.arange(oh) * sh) // oh, sh - 1)
            self._cols = np.minimum((np.arange(ow) * sw) // ow, sw - 1)

    def clear(self) -> None:
        self._packets.clear()

    def add(self, events: np.ndarray) -> None:
        if events.dtype != EVENT_DTYPE:
            raise ValueError(f"events dtype {events.dtype} is not {EVENT_DTYPE}")
        if events.size:
            self._packets.append(events)

    def _window(self, t_end_ns: int) -> np.ndarray:
        t0 = t_end_ns - self.window_ns
        while self._packets and self._packets[0]["t"][-1] < t0:
            self._packets.popleft()   # packets are time-sorted: the last event is the newest
        if not self._packets:
            return np.zeros(0, EVENT_DTYPE)
        ev = _concatenate(self._packets) if len(self._packets) > 1 else self._packets[0]
        return ev[(ev["t"] >= t0) & (ev["t"] <= t_end_ns)]

    def frame(self, t_end_ns: int) -> np.ndarray:
        """The representation of the window ending at ``t_end_ns``, at the output resolution."""
        ev = self._window(t_end_ns)
        sw, sh = self.geometry.sensor
        x, y = ev["x"].astype(np.int64), ev["y"].astype(np.int64)
        inside = (x < sw) & (y < sh)
        ev, x, y = ev[inside], x[inside], y[inside]
        flat = y * sw + x
        if self.representation == "counts":
            planes = np.stack([np.bincount(flat[ev["p"] > 0], minlength=sw * sh),
                               np.bincount(flat[ev["p"] < 0], minlength=sw * sh)])
        else:
            t0 = t_end_ns - self.window_ns
            pos = (ev["t"] - t0) / max(1, self.window_ns) * self.bins   # in [0, bins]
            if self.representation == "histogram":
                b = np.minimum(pos.astype(np.int64), self.bins - 1)
                channel = np.where(ev["p"] > 0, b, self.bins + b)
                planes = np.bincount(channel * sw * sh + flat,
                                     minlength=2 * self.bins * sw * sh).reshape(2 * self.bins, -1)
            else:   # voxel: each event split between its two nearest bin centres
                c = np.clip(pos - 0.5, 0, self.bins - 1)
                lo = np.floor(c).astype(np.int64)
                hi = np.minimum(lo + 1, self.bins - 1)
                w_hi = (c - lo).astype(np.float32)
                p = ev["p"].astype(np.float32)
                vox = np.bincount(lo * sw * sh + flat, weights=p * (1 - w_hi),
                                  minlength=self.bins * sw * sh)
                vox += np.bincount(hi * sw * sh + flat, weights=p * w_hi,
                                   minlength=self.bins * sw * sh)
                return self._to_output(vox.reshape(self.bins, sh, sw).astype(np.float32))
        planes = np.minimum(planes, self.clip).astype(np.uint8).reshape(-1, sh, sw)
        return self._to_output(planes)

    def _to_output(self, planes: np.ndarray) -> np.ndarray:
        """Sensor grid -> output grid: each sensor pixel fills its block (nearest)."""
        if self._rows is None:
            return planes
        # rows first, then take along the last axis: both results are C-contiguous, where
        # indexing the last axis of the row-indexed view gave a strided array to copy again
        return np.take(planes[:, self._rows], self._cols, axis=2)
