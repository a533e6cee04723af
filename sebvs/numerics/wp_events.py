"""Event-emulation work-precision metrics: a stream sampled at a low rate against a reference.

Events are given as four equal-length arrays: t (int64 ns), x, y (int pixel column/row),
p (polarity: > 0 ON, <= 0 OFF). All metrics compare a *test* stream with a *reference*
stream of the same scene motion, emulated from frames sampled far faster.

  count_frames      accumulated ON/OFF counts per control tick: (ticks, 2, H, W) int32
  relative_l1       sum |A - B| / sum B over every tick, polarity and pixel
  timestamp_errors  |t - t_ref| (ns) per test event, matched to the nearest reference event
                    of the same pixel and polarity (events of a pixel/polarity the
                    reference never fired are left out and counted)
"""
from __future__ import annotations

import numpy as np

from sebvs.dvs.emulator import EVENT_DTYPE
from sebvs.dvs.fidelity import nearest_time_errors


def polarity_index(p: np.ndarray) -> np.ndarray:
    """0 for ON (p > 0), 1 for OFF: the channel order of the accumulator's frames."""
    return (np.asarray(p) <= 0).astype(np.int64)


def count_frames(t: np.ndarray, x: np.ndarray, y: np.ndarray, p: np.ndarray,
                 shape: tuple[int, int], t0_ns: int, period_ns: int, ticks: int) -> np.ndarray:
    """Counts per tick window [t0 + k*period, t0 + (k+1)*period): (ticks, 2, H, W) int32.

    Events outside the `ticks` windows are dropped (the streams are compared over the same
    span of simulated time)."""
    h, w = shape
    k = (np.asarray(t, np.int64) - int(t0_ns)) // int(period_ns)
    keep = (k >= 0) & (k < ticks)
    flat = ((k[keep] * 2 + polarity_index(p)[keep]) * h + np.asarray(y)[keep]) * w \
        + np.asarray(x)[keep]
    counts = np.bincount(flat.astype(np.int64), minlength=ticks * 2 * h * w)
    return counts.reshape(ticks, 2, h, w).astype(np.int32)


def relative_l1(test: np.ndarray, ref: np.ndarray) -> float:
    """sum |test - ref| / sum |ref| (1.0 when the test stream is empty; inf when the
    reference is empty but the test is not, 0 when both are)."""
    diff = float(np.abs(test.astype(np.int64) - ref.astype(np.int64)).sum())
    base = float(np.abs(ref.astype(np.int64)).sum())
    if base == 0:
        return 0.0 if diff == 0 else float("inf")
    return diff / base


def timestamp_errors(test: tuple, ref: tuple, shape: tuple[int, int]) -> tuple[np.ndarray, int]:
    """Nearest-event matching per pixel and polarity (sebvs/dvs/fidelity.py's, the one
    matcher of the project).

    test, ref: (t ns, x, y, p) arrays. -> (abs errors ns (n_matched,) int64, n_unmatched):
    a test event is unmatched when the reference has no event at its pixel and polarity.
    """
    err = nearest_time_errors(_as_events(test), _as_events(ref), shape)
    has = np.isfinite(err)
    return err[has].astype(np.int64), int((~has).sum())


def _as_events(ev: tuple) -> np.ndarray:
    """(t, x, y, p) arrays -> EVENT_DTYPE, polarity +1 (p > 0) or -1 (p <= 0)."""
    t, x, y, p = (np.asarray(a) for a in ev)
    out = np.empty(len(t), EVENT_DTYPE)
    out["t"], out["x"], out["y"] = t, x, y
    out["p"] = np.where(p > 0, 1, -1)
    return out


def event_errors(test: tuple, ref: tuple, shape: tuple[int, int], t0_ns: int,
                 period_ns: int, ticks: int) -> dict:
    """All metrics of one test stream: rel_l1, ts_median_us, ts_p90_us, count_ratio,
    unmatched (fraction of test events with no reference event at their pixel/polarity)."""
    a = count_frames(*test, shape, t0_ns, period_ns, ticks)
    b = count_frames(*ref, shape, t0_ns, period_ns, ticks)
    err, unmatched = timestamp_errors(test, ref, shape)
    n_test, n_ref = len(test[0]), len(ref[0])
    return {"rel_l1": relative_l1(a, b),
            "ts_median_us": float(np.median(err)) / 1e3 if len(err) else None,
            "ts_p90_us": float(np.percentile(err, 90)) / 1e3 if len(err) else None,
            "count_ratio": n_test / n_ref if n_ref else None,
            "unmatched": unmatched / n_test if n_test else 0.0,
            "events": n_test, "ref_events": n_ref}
