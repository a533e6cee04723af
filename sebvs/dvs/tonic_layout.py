"""Events in Tonic's convention, for Tonic's transforms and the loaders that follow it.

    from sebvs.dvs.tonic_layout import to_tonic
    from sebvs.dvs.eventfile import read_events
    events, attrs = read_events("episode_0000.h5")        # ours: t int64 ns, p +1 / -1
    xytp = to_tonic(events)                               # x, y, t us, p 0 / 1
    frames = tonic.transforms.ToFrame(sensor_size=(attrs["width"], attrs["height"], 2),
                                      time_window=10_000)(xytp)

Ours (EVENT_DTYPE, what the emulator, every event reader and the recorder's raw events
hold): x, y uint16, t int64 nanoseconds, p int8 +1 (ON) / -1 (OFF). Tonic's
(`tonic.io.events_struct`): x, y int16, t int64 microseconds, p bool, True (1) for ON.
Tonic's ToFrame and the other frame transforms use p as the index of the polarity channel,
so our -1 would land in the last channel with the ON events: both polarities merged,
silently. Here OFF becomes channel 0 and ON channel 1.
"""
from __future__ import annotations

from collections.abc import Mapping

import numpy as np

# tonic.io.events_struct, spelled out so that Tonic is not needed to make its arrays
TONIC_DTYPE = np.dtype([("x", "<i2"), ("y", "<i2"), ("t", "<i8"), ("p", "?")])
_XY_MAX = np.iinfo(np.int16).max


def to_tonic(events, t_origin_ns: int = 0) -> np.ndarray:
    """Our events as Tonic's structured array.

    Parameters:
        events: a structured array with fields x, y, t (int ns), p (+1 / -1), as
            sebvs.dvs.emulator.EVENT_DTYPE, or a mapping of equal-length arrays x, y, t,
            p (an episode's raw events, `Episode.raw_events`); [N] either way.
        t_origin_ns: subtracted from t before the conversion (Tonic's datasets start
            near 0; the default keeps our absolute times).

    Returns:
        [N] TONIC_DTYPE: x, y int16, t int64 microseconds (floored: what the event
        files export), p bool, True for ON (p > 0). ValueError, in one line, for a
        missing field, arrays of different lengths, or x, y beyond int16.
    """
    names = events.dtype.names if isinstance(events, np.ndarray) else \
        tuple(events) if isinstance(events, Mapping) else None
    if not names or any(k not in names for k in "xytp"):
        raise ValueError(f"to_tonic: events need fields x, y, t, p, got "
                         f"{', '.join(names) if names else type(events).__name__}")
    cols = {k: np.asarray(events[k]).reshape(-1) for k in "xytp"}
    n = len(cols["x"])
    if any(len(c) != n for c in cols.values()):
        raise ValueError("to_tonic: x, y, t, p have different lengths "
                         f"({', '.join(f'{k} {len(c)}' for k, c in cols.items())})")
    for k in "xy":
        if n and (int(cols[k].max()) > _XY_MAX or int(cols[k].min()) < 0):
            raise ValueError(f"to_tonic: {k} spans {int(cols[k].min())}..{int(cols[k].max())}"
                             f", beyond Tonic's int16 pixel coordinates")
    out = np.empty(n, TONIC_DTYPE)
    out["x"], out["y"] = cols["x"], cols["y"]
    t = cols["t"].astype(np.int64, copy=False) - np.int64(t_origin_ns)
    out["t"] = np.floor_divide(t, 1000)
    out["p"] = cols["p"] > 0
    return out
