"""How close one event stream is to a reference stream of the same scene: the figures that
judge a luma sampling scheme (sebvs/dvs/adaptive.py) against a dense fixed-rate one.

    counts = count_maps(events, (h, w))          # [2, h, w] ON / OFF events per pixel
    report = compare_streams(test, reference, (h, w))
    report.count_ratio, report.count_correlation, report.median_time_error_ms

Events are EVENT_DTYPE arrays (x, y, t ns, p in {+1, -1}), as the emulator emits them.
The time error pairs each test event with the nearest reference event of the same pixel and
polarity (not one-to-one: a pixel's events in the two streams are a few at most and close
in number, and the nearest neighbour needs no assignment); pairs further apart than
`max_match_ms` are not matched, and the matched fraction says how many were.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from .emulator import pixel_time_order


def count_maps(events: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """ON and OFF events per pixel: int64 [2, h, w] (index 0 ON, 1 OFF)."""
    h, w = shape
    channel = (events["p"] < 0).astype(np.int64)
    flat = (channel * h + events["y"].astype(np.int64)) * w + events["x"]
    return np.bincount(flat, minlength=2 * h * w).reshape(2, h, w)


def pearson(a: np.ndarray, b: np.ndarray) -> float:
    """Pearson correlation of two arrays of the same size; NaN when either is constant."""
    a = np.asarray(a, np.float64).ravel()
    b = np.asarray(b, np.float64).ravel()
    a = a - a.mean()
    b = b - b.mean()
    den = float(np.sqrt((a * a).sum() * (b * b).sum()))
    return float((a * b).sum() / den) if den > 0 else float("nan")


def _keys(events: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """One int64 per event naming its pixel and polarity."""
    h, w = shape
    return ((events["y"].astype(np.int64) * w + events["x"]) * 2
            + (events["p"] < 0).astype(np.int64))


def nearest_time_errors(test: np.ndarray, reference: np.ndarray, shape: tuple[int, int]
                        ) -> np.ndarray:
    """|t - t_ref| in ns (float64 [len(test)]) from each test event to the nearest reference
    event of the same pixel and polarity; inf where the reference has none there."""
    if test.size == 0:
        return np.empty(0)
    if reference.size == 0:
        return np.full(test.size, np.inf)
    ref_key = _keys(reference, shape)
    order = pixel_time_order(ref_key, reference["t"].astype(np.int64))
    ref_key, ref_t = ref_key[order], reference["t"][order].astype(np.int64)
    key, t = _keys(test, shape), test["t"].astype(np.int64)
    # the first reference event of the same key at or after t, and the one before it
    lo = np.searchsorted(ref_key, key, side="left")
    hi = np.searchsorted(ref_key, key, side="right")
    # within [lo, hi) the times are sorted: search each test time there
    pos = lo + _search_within(ref_t, lo, hi, t)
    err = np.full(test.size, np.inf)
    for cand in (pos - 1, pos):
        ok = (cand >= lo) & (cand < hi)
        d = np.abs(ref_t[np.where(ok, cand, 0)] - t).astype(np.float64)
        err = np.where(ok, np.minimum(err, d), err)
    return err


def _search_within(values: np.ndarray, lo: np.ndarray, hi: np.ndarray, x: np.ndarray
                   ) -> np.ndarray:
    """For each i, the insertion offset of x[i] into the sorted run values[lo[i]:hi[i]]:
    a vectorised binary search (the runs are a pixel's events, a handful each)."""
    left = np.zeros_like(lo)
    right = hi - lo
    while True:
        active = left < right
        if not active.any():
            return left
        mid = (left + right) // 2
        below = np.zeros_like(active)
        idx = np.where(active, lo + mid, 0)
        below[active] = values[idx[active]] < x[active]
        left = np.where(active & below, mid + 1, left)
        right = np.where(active & ~below, mid, right)


@dataclass
class Fidelity:
    """A test stream against its reference (see the module docstring)."""
    events: int                  # in the test stream
    reference_events: int
    count_ratio: float           # events / reference_events
    count_correlation: float     # Pearson of the [2, h, w] ON/OFF count maps
    median_time_error_ms: float  # over matched test events
    matched_fraction: float      # of the test events, those with a reference event
                                 # within max_match_ms at the same pixel and polarity

    def as_dict(self) -> dict:
        return asdict(self)


def compare_streams(test: np.ndarray, reference: np.ndarray, shape: tuple[int, int],
                    max_match_ms: float = 10.0) -> Fidelity:
    """The fidelity figures of `test` against `reference` (EVENT_DTYPE arrays) on a sensor
    of `shape` (h, w)."""
    err = nearest_time_errors(test, reference, shape)
    matched = err <= max_match_ms * 1e6
    return Fidelity(
        events=int(test.size), reference_events=int(reference.size),
        count_ratio=float(test.size / reference.size) if reference.size else float("nan"),
        count_correlation=pearson(count_maps(test, shape), count_maps(reference, shape)),
        median_time_error_ms=float(np.median(err[matched]) * 1e-6) if matched.any()
        else float("nan"),
        matched_fraction=float(matched.mean()) if test.size else float("nan"))
