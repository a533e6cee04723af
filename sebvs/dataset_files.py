"""A dataset's files: their names, and whether each is still what its index recorded.

    from sebvs.dataset_files import verify_entries
    verify_entries("datasets/nav", entries)      # EpisodeDamaged names the damaged files

A dataset is a folder of episode files (``episode_NNNN.h5``) and their index
(``index.json``, sebvs/data/index.py). This module sits below every package, so that a
command of any layer can tell a recording's files from its own outputs
(sebvs/output_guard.py) and refuse a damaged episode before it reads one.

An episode whose bytes changed after it was indexed (a flipped bit in a compressed chunk,
a truncation, a file written over) can still decode, into frames nobody recorded. Training
and export would learn from or pass on those frames without a word, so both refuse them:
every episode they read is compared with the index's ``bytes`` (free) and ``sha256`` (one
read of the file, about 1 GB/s here). A file once found whole is remembered for this
process by its path, size and modification time, so the next epoch, modality or command in
the same process pays nothing; a file written again gets a new mtime and is hashed anew.
Entries without a ``sha256`` (indexes older than the field) are checked for size only.
"""
from __future__ import annotations

import hashlib
import json
import os
import re
from pathlib import Path
from typing import Iterable

INDEX = "index.json"
EPISODE_RE = re.compile(r"^episode_(\d+)\.h5(\.partial)?$")

# (real path, size, mtime ns) -> the sha256 it was found to have
_VERIFIED: dict[tuple[str, int, int], str] = {}


def episode_name(number: int) -> str:
    return f"episode_{number:04d}.h5"


def file_sha256(path: str | Path, block: int = 1 << 20) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(block):
            h.update(chunk)
    return h.hexdigest()


class EpisodeDamaged(ValueError):
    """Episodes whose files differ from what their index recorded; the message names them."""

    def __init__(self, message: str, names: list[str]):
        super().__init__(message)
        self.names = names


def episode_problem(path: str | Path, entry: dict) -> str | None:
    """Why an indexed episode's file is not the one the index recorded, or None.

    Parameters:
        path: the episode file.
        entry: its index entry (``bytes`` and ``sha256`` are compared when present).

    Returns:
        One phrase ("missing", "sha256 differs from the index ..."), or None when whole.
    """
    p = Path(path)
    try:
        st = p.stat()
    except FileNotFoundError:
        return f"missing (listed in {INDEX})"
    except OSError as exc:
        return f"cannot be read ({exc.strerror})"
    if "bytes" in entry and entry["bytes"] != st.st_size:
        return (f"{st.st_size} bytes, the index says {entry['bytes']} (truncated or "
                f"written over)")
    want = entry.get("sha256")
    if not want:
        return None
    key = (os.path.realpath(p), st.st_size, st.st_mtime_ns)
    if _VERIFIED.get(key) == want:
        return None
    try:
        have = file_sha256(p)
    except OSError as exc:
        return f"cannot be read ({exc.strerror})"
    if have != want:
        return "sha256 differs from the index (damaged or written over)"
    _VERIFIED[key] = have
    return None


def damaged(root: str | Path, entries: Iterable[dict], progress: bool = False) -> list[str]:
    """``"<file>: <why>"`` for each indexed episode of ``root`` that is not whole.

    Parameters:
        root: the dataset folder.
        entries: index entries to check (``DatasetIndex.episodes()`` or a subset).
        progress: a progress bar over the bytes hashed.

    Returns:
        One line per damaged episode, in the entries' order; empty when all are whole.
    """
    from tqdm import tqdm
    root, entries = Path(root), list(entries)
    out = []
    with tqdm(total=sum(int(e.get("bytes") or 0) for e in entries), unit="B",
              unit_scale=True, desc="verify", disable=not progress, leave=False) as bar:
        for e in entries:
            why = episode_problem(root / e["file"], e)
            if why:
                out.append(f"{e['file']}: {why}")
            bar.update(int(e.get("bytes") or 0))
    return out


def verify_entries(root: str | Path, entries: Iterable[dict], progress: bool = False) -> None:
    """Raise EpisodeDamaged (one line naming the files) unless every entry's file is whole.

    Parameters:
        root: the dataset folder.
        entries: the index entries about to be read.
        progress: a progress bar over the bytes hashed.
    """
    bad = damaged(root, entries, progress)
    if bad:
        more = f" and {len(bad) - 3} more" if len(bad) > 3 else ""
        raise EpisodeDamaged(f"{root}: refused, {len(bad)} episode(s) differ from {INDEX}: "
                             f"{'; '.join(bad[:3])}{more} (`sebvs data check {root}` lists "
                             f"them; re-record or remove them from the index)",
                             [b.split(":", 1)[0] for b in bad])


def index_entry(path: str | Path) -> dict | None:
    """The index entry that lists episode file ``path`` in its folder's index, if any."""
    p = Path(path)
    index = p.parent / INDEX
    try:
        data = json.loads(index.read_text())
    except (OSError, ValueError):
        return None
    episodes = data.get("episodes") if isinstance(data, dict) else None
    return next((e for e in episodes or [] if isinstance(e, dict) and e.get("file") == p.name),
                None)


def verify_file(path: str | Path) -> None:
    """Raise EpisodeDamaged when episode file ``path`` is listed in its folder's index and
    differs from what the index recorded (a file no index lists has nothing to check)."""
    entry = index_entry(path)
    if entry is None:
        return
    why = episode_problem(path, entry)
    if why:
        raise EpisodeDamaged(f"{path}: refused, {why}", [Path(path).name])
