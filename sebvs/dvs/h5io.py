"""Writing event files in HDF5, laid out like public event datasets (read back, with the
other formats, by sebvs/dvs/eventfile.py):

    events/x  uint16   events/y  uint16   events/t  int64, microseconds   events/p  int8 (+1/-1)
    ms_to_idx uint64   [i] = index of the first event with t >= i milliseconds
    attrs: width, height, t_offset_us (the stream's first timestamp), emulator (JSON)
Times in the file start at 0; t_offset_us gives them back their absolute value.
"""
from __future__ import annotations

import json
from pathlib import Path

import h5py
import numpy as np

from .emulator import EVENT_DTYPE

CHUNK = 1 << 16


class EventFileWriter:
    """Appends time-sorted event packets to a new HDF5 file."""

    def __init__(self, path: str | Path, width: int, height: int, attrs: dict | None = None):
        self.path = Path(path)
        self.file = h5py.File(self.path, "w")
        g = self.file.create_group("events")
        for name, dtype in (("x", "u2"), ("y", "u2"), ("t", "i8"), ("p", "i1")):
            g.create_dataset(name, shape=(0,), maxshape=(None,), dtype=dtype, chunks=(CHUNK,),
                             compression="lzf")
        self.file.attrs["width"], self.file.attrs["height"] = width, height
        for k, v in (attrs or {}).items():
            self.file.attrs[k] = json.dumps(v) if isinstance(v, (dict, list)) else v
        self.t_offset_ns: int | None = None
        self.count = 0
        self.last_t = None

    def append(self, events: np.ndarray) -> None:
        if events.dtype != EVENT_DTYPE:
            raise ValueError(f"events dtype {events.dtype} is not {EVENT_DTYPE}")
        if not events.size:
            return
        if self.t_offset_ns is None:
            self.t_offset_ns = int(events["t"][0])
            self.file.attrs["t_offset_us"] = self.t_offset_ns // 1000
        t_us = (events["t"] - self.t_offset_ns) // 1000
        if self.last_t is not None and t_us[0] < self.last_t:
            raise ValueError("event packets must arrive in time order")
        self.last_t = int(t_us[-1])
        g = self.file["events"]
        n = self.count + events.size
        for name, values in (("x", events["x"]), ("y", events["y"]), ("t", t_us),
                             ("p", events["p"])):
            g[name].resize((n,))
            g[name][self.count:n] = values
        self.count = n

    def close(self) -> None:
        t = self.file["events/t"][:] if self.count else np.zeros(0, np.int64)
        last_ms = int(t[-1] // 1000) + 1 if t.size else 0
        self.file.create_dataset("ms_to_idx", data=np.searchsorted(
            t, np.arange(last_ms + 1, dtype=np.int64) * 1000).astype(np.uint64))
        self.file.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
