"""HDF5 files whose every error names the file: the project's readers open through here.

    from sebvs.h5named import open_h5
    f = open_h5("datasets/nav/episode_0003.h5")
    f["rgb"][0]          # FileUnreadable: "...episode_0003.h5: rgb: cannot be read (...)"

HDF5 says what failed but not where: "Unable to synchronously open file (truncated file:
eof = 1334924, ...)" or "Can't synchronously read data (filter returned failure during
read)", with no path, from whichever command met the file. `open_h5` turns a failure to
open into ``FileUnreadable`` naming the file, and `named` wraps a dataset so that a failed
read (a damaged chunk is found only when it is decoded) names the file and the dataset.
"""
from __future__ import annotations

from pathlib import Path

import h5py


class FileUnreadable(ValueError):
    """An HDF5 file that cannot be opened or read; the message names the file."""


def first_line(exc: BaseException) -> str:
    text = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
    return text if len(text) <= 200 else text[:200] + "..."


def open_h5(path: str | Path) -> h5py.File:
    """``h5py.File(path, "r")``, or FileUnreadable naming ``path`` and HDF5's reason.

    Parameters:
        path: the file to open read-only.

    Returns:
        The open h5py.File.
    """
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"{p}: no such file")
    try:
        return h5py.File(p, "r")
    except OSError as exc:
        raise FileUnreadable(f"{p}: not a readable HDF5 file ({first_line(exc)})") from None


class NamedDataset(h5py.Dataset):
    """An h5py.Dataset whose failed reads raise FileUnreadable naming its file and path."""

    def _unreadable(self, exc: BaseException) -> FileUnreadable:
        return FileUnreadable(f"{self.file.filename}: {self.name.lstrip('/')}: cannot be "
                              f"read ({first_line(exc)})")

    def __getitem__(self, args, new_dtype=None):
        try:
            return super().__getitem__(args, new_dtype=new_dtype)
        except OSError as exc:
            raise self._unreadable(exc) from None

    def read_direct(self, dest, source_sel=None, dest_sel=None):
        try:
            return super().read_direct(dest, source_sel, dest_sel)
        except OSError as exc:
            raise self._unreadable(exc) from None


def named(ds: h5py.Dataset) -> NamedDataset:
    """``ds`` as a NamedDataset: the same HDF5 object, its reads' errors named."""
    return NamedDataset(ds.id)
