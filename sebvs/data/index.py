"""The dataset index: ``index.json`` beside the episode files.

    {"version": 1, "task": "nav",
     "episodes": [{"file": "episode_0000.h5", "frames": 412, "seed": 7,
                   "conditions": {...}, "sha256": "...", "bytes": 123456,
                   "reason": "timeout"}, ...]}

The index is the list of episodes a dataset *has*: an episode file is renamed into place
first and added here last, by writing a temporary file and ``os.replace`` (atomic on
POSIX), so a crash at any moment leaves either the old or the new index, never a torn one.
"""
from __future__ import annotations

import json
import os
from pathlib import Path

from ..dataset_files import EPISODE_RE, INDEX, episode_name, file_sha256  # noqa: F401

INDEX_VERSION = 1


def write_json_atomic(path: Path, data: dict) -> None:
    """tmp file in the same directory, fsync, os.replace: readers see old or new, whole."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    with open(tmp, "w") as f:
        json.dump(data, f, indent=1, default=str)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def make_entry(path: str | Path, reason: str | None = None, name: str | None = None) -> dict:
    """An index entry for a finished episode file (reads its attributes, hashes it);
    ``name``: the file's name in the index, when the entry is made before its rename."""
    from .episode import open_episode
    path = Path(path)
    with open_episode(path) as ep:
        attrs, frames = ep.attrs, len(ep)
    return {"file": name or path.name, "frames": frames, "seed": attrs.get("seed"),
            "conditions": attrs.get("conditions", {}), "sha256": file_sha256(path),
            "bytes": path.stat().st_size,
            "reason": attrs.get("end_reason", "") if reason is None else reason}


def read_index(path: Path) -> dict:
    """``index.json`` as a dict, or ValueError (one line, naming it) for a file that is not
    an index: not UTF-8 JSON, not an object, or episodes that are not named files."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (ValueError, RecursionError) as exc:     # UnicodeDecodeError is a ValueError
        raise ValueError(f"{path}: not a dataset index ({type(exc).__name__})") from None
    episodes = data.get("episodes") if isinstance(data, dict) else None
    if not isinstance(episodes, list) or not all(
            isinstance(e, dict) and isinstance(e.get("file"), str)
            and "/" not in e["file"] and e["file"] not in ("", ".", "..") for e in episodes):
        raise ValueError(f"{path}: not a dataset index (expected {{\"episodes\": [{{\"file\": "
                         f"NAME, ...}}, ...]}} with plain file names)")
    return data


class DatasetIndex:
    """``index.json`` of dataset directory ``root`` (created on the first ``add``)."""

    def __init__(self, root: str | Path, task: str | None = None):
        self.root = Path(root)
        self.path = self.root / INDEX
        if self.path.exists():
            self.data = read_index(self.path)
            if task is not None and self.data.get("task") not in (None, task):
                raise ValueError(f"{self.root}: dataset holds task {self.data['task']!r}, "
                                 f"not {task!r}")
        else:
            self.data = {"version": INDEX_VERSION, "task": task, "episodes": []}
        if task is not None:
            self.data["task"] = task

    @property
    def task(self) -> str | None:
        return self.data.get("task")

    def episodes(self) -> list[dict]:
        return list(self.data["episodes"])

    def episode_paths(self) -> list[Path]:
        return [self.root / e["file"] for e in self.data["episodes"]]

    def add(self, entry: dict) -> None:
        """Append one episode entry and rewrite the index atomically."""
        self.root.mkdir(parents=True, exist_ok=True)
        if any(e["file"] == entry["file"] for e in self.data["episodes"]):
            raise ValueError(f"{entry['file']} is already in {self.path}")
        self.data["episodes"].append(dict(entry))
        write_json_atomic(self.path, self.data)

    def insert(self, entry: dict) -> None:
        """``add`` in episode-number order (fan-out workers finish out of order): the
        index lists a dataset's episodes as one process recording them would."""
        self.root.mkdir(parents=True, exist_ok=True)
        if any(e["file"] == entry["file"] for e in self.data["episodes"]):
            raise ValueError(f"{entry['file']} is already in {self.path}")
        self.data["episodes"].append(dict(entry))
        if all(EPISODE_RE.match(e["file"]) for e in self.data["episodes"]):
            # stable: a name outside the scheme would keep the order as written
            self.data["episodes"].sort(
                key=lambda e: int(EPISODE_RE.match(e["file"]).group(1)))
        write_json_atomic(self.path, self.data)

    def numbers(self) -> set[int]:
        """Episode numbers the index lists."""
        return {int(m.group(1)) for e in self.data["episodes"]
                if (m := EPISODE_RE.match(e["file"]))}

    def adopt_unindexed(self) -> list[str]:
        """Index finished episode files that the index lacks; returns their names.

        A file gets its final name only after it was completely written and fsynced, so one
        missing from the index was cut off by a crash between the rename and ``add``: it is
        whole, and adopting it keeps "a crash loses at most the episode in progress" true.
        """
        if not self.root.is_dir():
            return []
        listed = {e["file"] for e in self.data["episodes"]}
        adopted = []
        for p in sorted(self.root.iterdir()):
            m = EPISODE_RE.match(p.name)
            if not m or m.group(2) or p.name in listed:
                continue
            try:
                entry = make_entry(p)
            except Exception:       # unreadable: leave it for `sebvs data check` to report
                continue
            self.add(entry)
            adopted.append(p.name)
        return adopted

    def next_episode_number(self) -> int:
        """One past the highest number in the index or on disk (``.partial`` files included,
        so a lost episode's file is never overwritten by a new recording)."""
        numbers = [-1]
        names = [e["file"] for e in self.data["episodes"]]
        if self.root.is_dir():
            names += [p.name for p in self.root.iterdir()]
        for name in names:
            m = EPISODE_RE.match(name)
            if m:
                numbers.append(int(m.group(1)))
        return max(numbers) + 1

    def path_for(self, number: int) -> Path:
        return self.root / episode_name(number)
