"""Emulator extremes for the stability sweep (sebvs.numerics.stability, kind "dvs").

Each case feeds a short frame sequence to a fresh emulator (through dvs_adapter) and is
classified:
  detected    the emulator refused with a ValueError that says why
  stable      it returned events, and they are sane: t int64 within the frames' span and
              sorted, x/y inside the image, p in {+1, -1}, no more events per pixel and
              frame than the lin-log range (ln 255 ~ 5.5) over the smallest threshold
              allows, and numpy raised no RuntimeWarning (log(0), overflow, NaN)
  undetected  anything else: another exception, a RuntimeWarning, or insane output
"""
from __future__ import annotations

import math
import warnings

import numpy as np

from . import dvs_adapter
from .sweep import SweepCase, classify_exception


SIZE = 32          # px, the emulated frames (downsample 1): extremes need no resolution
MIN_THRES = 0.01   # DESIGN.md 4: thresholds are clipped at >= 0.01
MAX_PER_FRAME = math.ceil(math.log(255.0) / MIN_THRES) + 1


def _frames(kind: str, n: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """-> (frames (n, SIZE, SIZE) uint8, t_ns (n,) int64; uint64 for "past_int64"), 10 ms
    apart unless the kind is about time."""
    rng = np.random.default_rng(0)
    t = np.arange(n, dtype=np.int64) * 10_000_000
    if kind == "black":
        f = np.zeros((n, SIZE, SIZE), np.uint8)
    elif kind == "saturated":
        f = np.full((n, SIZE, SIZE), 255, np.uint8)
    elif kind == "alternating":
        f = np.stack([np.full((SIZE, SIZE), 255 * (i % 2), np.uint8) for i in range(n)])
    else:   # textured content whose brightness ramps: events on every frame
        base = rng.integers(0, 256, (SIZE, SIZE)).astype(np.float64)
        f = np.stack([np.clip(base * (0.3 + 0.1 * i), 0, 255) for i in range(n)]
                     ).astype(np.uint8)
    if kind == "dt0":
        t[n // 2] = t[n // 2 - 1]                  # two frames at the same time
    elif kind == "dt100":
        t[n // 2:] += 100_000_000_000              # a 100 s gap
    elif kind == "gap1e6":
        t[n // 2:] += 10 ** 15                     # a 1e6 s gap: a restart, no noise flood
    elif kind == "int64_max":
        t[-1] = np.iinfo(np.int64).max             # the last representable nanosecond
    elif kind == "past_int64":
        t = t.astype(np.uint64)
        t[n // 2] = np.uint64(2 ** 63)             # past int64: must be refused, not wrapped
    elif kind == "backwards":
        t[n // 2] = t[n // 2 - 1] - 1_000_000      # time runs back: must be refused
    elif kind == "nan":
        f = f.astype(np.float32)
        f[n // 2, 3, 3] = np.nan                   # a broken float frame: must be refused
    elif kind == "reshaped":
        f = list(f)
        f[n // 2] = f[n // 2][:-1]                 # one frame a row short: must be refused
    return f, t


# name -> (frame kind, parameter overrides)
EXTREMES = {
    "black": ("black", {}),
    "saturated": ("saturated", {}),
    "alternating": ("alternating", {}),
    "dt0": ("dt0", {}),
    "dt100": ("dt100", {"max_gap_s": 1000.0}),   # emulated over the gap, not restarted
    "gap1e6_noisy": ("gap1e6", {"leak_rate_hz": 0.1, "shot_noise_rate_hz": 5.0}),
    "t_int64_max": ("int64_max", {}),
    # the whole ~292-year gap emulated, not restarted: crossing times near 2**63 ns
    "t_int64_max_no_restart": ("int64_max", {"max_gap_s": 1e10}),
    "t_past_int64": ("past_int64", {}),
    "backwards": ("backwards", {}),
    "nan_frame": ("nan", {}),
    "shape_change": ("reshaped", {}),
    "cutoff0": ("ramp", {"cutoff_hz": 0.0}),
    "cutoff1e6": ("ramp", {"cutoff_hz": 1e6}),
    "sigma_huge": ("ramp", {"sigma_thres": 10.0}),
    "alternating_cutoff1e6": ("alternating", {"cutoff_hz": 1e6}),
}


def cases(grid: str = "quick") -> list[SweepCase]:
    presets = ("paper",) if grid == "quick" else tuple(dvs_adapter.presets())
    return [SweepCase("dvs", {"extreme": name, "preset": p}) for p in presets
            for name in EXTREMES]


def check_events(ev: tuple, frames: np.ndarray, t_ns: np.ndarray) -> str | None:
    """None when the events are sane for these frames (see module docstring)."""
    t, x, y, p = ev
    h, w = np.shape(frames[0])[:2]
    if len(t) == 0:
        return None
    if t.dtype != np.int64:
        return f"timestamps are {t.dtype}, not int64 ns"
    if (np.diff(t) < 0).any():
        return "events not sorted by time"
    if t.min() < t_ns.min() or t.max() > t_ns.max():
        return f"timestamps outside the frames' span [{t_ns.min()}, {t_ns.max()}] ns"
    if x.min() < 0 or y.min() < 0 or x.max() >= w or y.max() >= h:
        return "pixel coordinates outside the image"
    if not np.isin(p, (-1, 1)).all():
        return "polarity other than +1/-1"
    per_pixel = np.bincount(np.asarray(y, np.int64) * w + x, minlength=h * w).max()
    if per_pixel > MAX_PER_FRAME * len(frames):
        return f"{per_pixel} events at one pixel over {len(frames)} frames (> lin-log bound)"
    return None


def run(case: SweepCase) -> dict:
    kind, overrides = EXTREMES[case.params["extreme"]]
    overrides = {"downsample": 1.0, **overrides}   # frames are at the emulated size
    frames, t_ns = _frames(kind)
    out = {"name": case.name, "kind": "dvs", "params": case.params, "t": None}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            ev, _ = dvs_adapter.run(case.params["preset"], frames, t_ns, 0, **overrides)
        except Exception as exc:   # noqa: BLE001  (classified, never swallowed silently)
            cls, why = classify_exception(exc)
            return {**out, "class": cls, "reason": why}
    rw = [w for w in caught if issubclass(w.category, RuntimeWarning)]
    if rw:
        return {**out, "class": "undetected",
                "reason": f"{len(rw)} RuntimeWarning(s): {rw[0].message}"}
    bad = check_events(ev, frames, t_ns)
    return {**out, "class": "undetected" if bad else "stable",
            "reason": bad or f"{len(ev[0])} events"}
