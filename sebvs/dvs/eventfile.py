"""Read any event file the project writes or exports, whatever its layout.

Formats, told apart by content (not by the name alone):

    sebvs-h5   our own HDF5 (sebvs/dvs/h5io.py: `sebvs v2e`): events/{x,y,t,p}, t int64 us
               from the attribute t_offset_us, p int8 +1/-1, ms_to_idx
    common-h5  the DSEC layout (sebvs/dvs/common_h5.py): events/{x,y,t,p}, t uint32 us
               from the dataset t_offset, p uint8 1/0, ms_to_idx
    episode    an episode file with raw events (sebvs/data/episode.py): events/{x,y,t,p}
               with t int64 ns, absolute, p +1/-1, and events/offset per frame
    aedat4     iniVation's AEDAT 4 (sebvs/dvs/aedat4.py, read through dv-processing)

Every reader hands out EVENT_DTYPE arrays with absolute nanosecond timestamps and
polarity +1/-1, in time order, so the rest of the project never sees a layout.
"""
from __future__ import annotations

from pathlib import Path
from typing import Iterator

import h5py
import numpy as np

from ..dataset_files import verify_file
from ..h5named import named, open_h5
from .emulator import EVENT_DTYPE
from .eventsource import CHUNK, EventFile

FORMATS = ("sebvs-h5", "common-h5", "episode", "aedat4")
AEDAT4_MAGIC = b"#!AER-DAT4"


def detect_format(path: str | Path) -> str:
    """Which of FORMATS ``path`` is; ValueError (one line) for anything else."""
    p = Path(path)
    if not p.exists():
        raise ValueError(f"{p}: no such file")
    if p.is_dir():
        raise ValueError(f"{p}: a folder, not an event file")
    with open(p, "rb") as f:
        head = f.read(len(AEDAT4_MAGIC))
    if head == AEDAT4_MAGIC:
        return "aedat4"
    if head.startswith(b"#!AER-DAT"):
        raise ValueError(f"{p}: an AEDAT file older than version 4; convert it with DV first")
    if h5py.is_hdf5(p):
        with open_h5(p) as f:
            has_events = all(f"events/{k}" in f for k in ("x", "y", "t", "p"))
            if "rgb" in f:
                if has_events and "events/offset" in f:
                    return "episode"
                raise ValueError(f"{p}: an episode without raw events (record it with the "
                                 f"recorder's raw_events = true)")
            if has_events:
                # DSEC keeps its offset as a dataset and polarity as 0/1; we keep an
                # attribute and +1/-1
                if "t_offset" in f or f["events/p"].dtype.kind == "u":
                    return "common-h5"
                return "sebvs-h5"
    raise ValueError(f"{p}: not an event file (expected HDF5 with events/x, y, t, p, an "
                     f"episode with raw events, or AEDAT4)")


def _attrs(f: h5py.File) -> dict:
    return {k: (v.decode() if isinstance(v, bytes) else v.item() if hasattr(v, "item") else v)
            for k, v in f.attrs.items()}


def _named_events(f: h5py.File) -> dict:
    """events/x, y, t, p of ``f``, their failed reads naming the file (sebvs/h5named.py)."""
    return {k: named(f[f"events/{k}"]) for k in ("x", "y", "t", "p")}


def _size_from_events(chunks: Iterator[np.ndarray]) -> tuple[int, int]:
    """(width, height) = 1 + the largest x and y (DSEC files do not store the size)."""
    w = h = 0
    for ev in chunks:
        if ev.size:
            w, h = max(w, int(ev["x"].max()) + 1), max(h, int(ev["y"].max()) + 1)
    return w, h


class H5EventFile(EventFile):
    """Both HDF5 layouts with microsecond times from an offset: ours and DSEC's."""

    def __init__(self, path: Path, fmt: str):
        super().__init__(path)
        self.format = fmt
        self.file = open_h5(path)
        self.attrs = _attrs(self.file)
        self.count = int(self.file["events/t"].shape[0])
        if fmt == "common-h5":
            self.offset_us = int(self.file["t_offset"][()]) if "t_offset" in self.file else 0
        else:
            self.offset_us = int(self.attrs.get("t_offset_us", 0))
        if "width" in self.attrs and "height" in self.attrs:
            self.width, self.height = int(self.attrs["width"]), int(self.attrs["height"])
        else:
            self.width, self.height = _size_from_events(self.chunks())

    @property
    def time_range_ns(self) -> tuple[int, int]:
        t = named(self.file["events/t"])
        if not self.count:
            return 0, 0
        return ((int(t[0]) + self.offset_us) * 1000, (int(t[-1]) + self.offset_us) * 1000)

    def _slice(self, lo: int, hi: int) -> np.ndarray:
        g = _named_events(self.file)
        ev = np.zeros(max(0, hi - lo), EVENT_DTYPE)
        ev["x"], ev["y"] = g["x"][lo:hi], g["y"][lo:hi]
        ev["t"] = (g["t"][lo:hi].astype(np.int64) + self.offset_us) * 1000
        ev["p"] = np.where(g["p"][lo:hi] > 0, 1, -1)      # +1/-1 and 1/0 alike
        return ev

    def chunks(self, size: int = CHUNK) -> Iterator[np.ndarray]:
        for lo in range(0, self.count, size):
            yield self._slice(lo, min(lo + size, self.count))

    def read(self, t0_ms: float | None = None, t1_ms: float | None = None) -> np.ndarray:
        # ms_to_idx counts milliseconds from the offset, which both writers set to the
        # first event: a window reads only its own events
        idx = named(self.file["ms_to_idx"])[:] if "ms_to_idx" in self.file else None
        if idx is None or not len(idx):
            return super().read(t0_ms, t1_ms)
        lo = int(idx[min(int(t0_ms), len(idx) - 1)]) if t0_ms is not None else 0
        hi = int(idx[min(int(t1_ms), len(idx) - 1)]) if t1_ms is not None else self.count
        return self._slice(lo, hi)

    def close(self) -> None:
        self.file.close()


class EpisodeEventFile(EventFile):
    """The raw events of an episode file: nanoseconds, already absolute."""

    format = "episode"

    def __init__(self, path: Path):
        super().__init__(path)
        self.file = open_h5(path)
        self.attrs = _attrs(self.file)
        self.count = int(self.file["events/t"].shape[0])
        sensor = self.attrs.get("event_sensor")
        if sensor is not None and np.size(sensor) == 2:
            self.width, self.height = (int(v) for v in np.ravel(sensor))
        else:
            self.width, self.height = _size_from_events(self.chunks())

    @property
    def time_range_ns(self) -> tuple[int, int]:
        t = named(self.file["events/t"])
        return (int(t[0]), int(t[-1])) if self.count else (0, 0)

    def chunks(self, size: int = CHUNK) -> Iterator[np.ndarray]:
        g = _named_events(self.file)
        for lo in range(0, self.count, size):
            hi = min(lo + size, self.count)
            ev = np.zeros(hi - lo, EVENT_DTYPE)
            for k in ("x", "y", "t"):
                ev[k] = g[k][lo:hi]
            ev["p"] = np.where(g["p"][lo:hi] > 0, 1, -1)
            yield ev

    def close(self) -> None:
        self.file.close()


def open_events(path: str | Path) -> EventFile:
    """Open an event file of any of FORMATS (use as a context manager)."""
    p = Path(path)
    fmt = detect_format(p)
    if fmt == "aedat4":
        from .aedat4 import Aedat4EventFile
        return Aedat4EventFile(p)
    if fmt == "episode":
        # an episode still listed in its dataset's index must be the file it recorded
        verify_file(p)
        return EpisodeEventFile(p)
    return H5EventFile(p, fmt)


def read_events(path: str | Path, t0_ms: float | None = None,
                t1_ms: float | None = None) -> tuple[np.ndarray, dict]:
    """(events, attrs) of [t0_ms, t1_ms), milliseconds from the file's first event, from a
    file of any of FORMATS; timestamps absolute, in ns. attrs are the file's own plus
    width, height and format."""
    with open_events(path) as f:
        ev = f.read(t0_ms, t1_ms)
        attrs = {**f.attrs, "width": f.width, "height": f.height, "format": f.format}
    return ev, attrs
