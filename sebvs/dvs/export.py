"""`sebvs events export`: an event file of any readable layout to AEDAT4 or the common
HDF5 layout (sebvs/dvs/eventfile.py reads, sebvs/dvs/aedat4.py and common_h5.py write).

The output is written under ``<stem>.partial<suffix>`` (dv-processing opens only names
ending in .aedat4) and renamed when complete, so a file with the final name is never a
cut-off export.
"""
from __future__ import annotations

import os
from pathlib import Path

from tqdm import tqdm

from ..extras import require
from .eventfile import open_events

EXPORT_FORMATS = ("aedat4", "h5")
SUFFIX_FORMAT = {".aedat4": "aedat4", ".h5": "h5", ".hdf5": "h5"}


def format_for(out: str | Path, fmt: str | None) -> str:
    """The export format: ``fmt`` if given, else the output's suffix."""
    if fmt:
        if fmt not in EXPORT_FORMATS:
            raise ValueError(f"unknown format {fmt!r} ({', '.join(EXPORT_FORMATS)})")
        return fmt
    suffix = Path(out).suffix.lower()
    if suffix not in SUFFIX_FORMAT:
        raise ValueError(f"{out}: say --format ({', '.join(EXPORT_FORMATS)}); the suffix "
                         f"{suffix or '(none)'} does not tell")
    return SUFFIX_FORMAT[suffix]


def export_events(source: str | Path, out: str | Path, fmt: str | None = None,
                  progress: bool = True) -> dict:
    """Write the events of ``source`` to ``out`` as ``fmt`` (aedat4 | h5); returns a
    summary (events, width, height, formats, bytes). ValueError / OSError say why not."""
    fmt = format_for(out, fmt)
    source, out = Path(source), Path(out)
    if out.exists() and source.exists() and out.resolve() == source.resolve():
        raise ValueError(f"{out}: the output would overwrite the input")
    if out.is_dir():
        raise ValueError(f"{out}: a folder; give the output file's name")
    if fmt == "aedat4" and out.suffix != ".aedat4":
        # dv-processing refuses to open any other name, so DV could not read it back
        raise ValueError(f"{out}: an AEDAT4 file's name must end in .aedat4")
    partial = out.with_name(out.stem + ".partial" + out.suffix)
    with open_events(source) as src:
        if fmt == "aedat4":     # before anything is written: a missing extra in one line
            require("dv_processing", "dv-processing", "formats", "--format aedat4")
        try:                            # an unwritable place fails here, in one line
            with open(partial, "wb"):
                pass
        except OSError as exc:
            raise OSError(f"{out}: cannot write ({exc.strerror})") from None
        bar = tqdm(total=src.count, unit="ev", unit_scale=True, disable=not progress,
                   desc=f"export {fmt}")
        try:
            n = _write(src, partial, fmt, bar)
        except BaseException:
            partial.unlink(missing_ok=True)
            raise
        finally:
            bar.close()
        info = {"events": n, "width": src.width, "height": src.height,
                "from": src.format, "format": fmt}
    os.replace(partial, out)
    return {**info, "out": str(out), "bytes": out.stat().st_size}


def _write(src, path: Path, fmt: str, bar) -> int:
    if fmt == "aedat4":
        from .aedat4 import write_aedat4
        return write_aedat4(path, src.chunks(), src.width, src.height, progress=bar)
    from .common_h5 import CommonH5Writer
    t0, t1 = src.time_range_ns
    with CommonH5Writer(path, src.width, src.height, t0 // 1000,
                        span_us=t1 // 1000 - t0 // 1000,
                        attrs={"source": str(src.path)}) as w:
        for ev in src.chunks():
            w.append(ev)
            bar.update(ev.size)
        return w.written
