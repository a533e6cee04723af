"""What every event-file reader is (sebvs/dvs/eventfile.py dispatches by format, and
sebvs/dvs/aedat4.py reads through dv-processing): a base of its own, so that the readers
and the dispatch do not import each other."""
from __future__ import annotations

from pathlib import Path
from typing import Iterator

import numpy as np

from .emulator import EVENT_DTYPE

CHUNK = 1 << 20          # events per chunk when a file is streamed


class EventFile:
    """An event file opened for reading: ``width``, ``height``, ``count`` (None where
    the format does not say without reading), ``time_range_ns`` (first, last),
    ``chunks()`` to stream, ``read()`` for a time window, ``attrs`` (the file's own)."""

    format = ""

    def __init__(self, path: Path):
        self.path = path
        self.width = self.height = 0
        self.count: int | None = None
        self.attrs: dict = {}

    @property
    def time_range_ns(self) -> tuple[int, int]:
        raise NotImplementedError

    def chunks(self, size: int = CHUNK) -> Iterator[np.ndarray]:
        raise NotImplementedError

    def read(self, t0_ms: float | None = None, t1_ms: float | None = None) -> np.ndarray:
        """Events of [t0_ms, t1_ms), milliseconds from the file's first event."""
        parts = list(self.chunks())
        ev = np.concatenate(parts) if parts else np.zeros(0, EVENT_DTYPE)
        return _window(ev, t0_ms, t1_ms)

    def close(self) -> None:
        pass

    def __enter__(self) -> "EventFile":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _window(ev: np.ndarray, t0_ms: float | None, t1_ms: float | None) -> np.ndarray:
    if not ev.size or (t0_ms is None and t1_ms is None):
        return ev
    first = int(ev["t"][0])
    lo = 0 if t0_ms is None else np.searchsorted(ev["t"], first + round(t0_ms * 1e6))
    hi = ev.size if t1_ms is None else np.searchsorted(ev["t"], first + round(t1_ms * 1e6))
    return ev[lo:hi]
