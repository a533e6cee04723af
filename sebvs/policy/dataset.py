"""Behaviour-cloning samples read lazily from recorded episodes.

Layout (one HDF5 file per episode, see sebvs/data): ``rgb`` [T, H, W, 3] uint8,
``events/frame`` [T, 2, H, W] uint8, ``action`` [T, 2] float32 (nav) or ``pose`` [T, 6]
float32 (arm), ``t_sim``, ``tick``; ``index.json`` in the dataset directory lists the
episodes as {"file", "frames", "seed", ...}.

Nothing is loaded whole: the dataset is an index of (episode, frame) pairs and each item
reads one frame. HDF5 handles are opened on first use in the process that reads (h5py
handles must not cross a fork), so DataLoader workers each open their own.
"""
from __future__ import annotations

import hashlib
import json
import os
import random
from pathlib import Path

import h5py
import numpy as np

from .inputs import MODALITY_INPUTS, Normalisation, check_modality, model_input

TARGET_KEY = {"nav": "action", "arm": "pose"}
STREAM_KEY = {"rgb": "rgb", "events": "events/frame"}
EPISODE_SUFFIXES = (".h5", ".hdf5")


def load_index(root: str | Path) -> list[dict]:
    """Episodes of a dataset directory: index.json's list, or the HDF5 files found there."""
    root = Path(root)
    index = root / "index.json"
    if index.exists():
        data = json.loads(index.read_text())
        episodes = data["episodes"] if isinstance(data, dict) else data
        return [dict(e) for e in episodes]
    files = sorted(p for p in root.iterdir() if p.suffix in EPISODE_SUFFIXES)
    if not files:
        raise FileNotFoundError(f"{root}: no index.json and no episode files (*.h5)")
    out = []
    for p in files:
        with h5py.File(p, "r") as f:
            out.append({"file": p.name, "frames": int(f["rgb"].shape[0])})
    return out


def dataset_hash(root: str | Path, episodes: list[dict]) -> str:
    """sha256 over index.json (if any) and each episode's name and byte size.

    Cheap (no frame is read) and changes when an episode is re-recorded, added or removed.
    """
    root = Path(root)
    h = hashlib.sha256()
    index = root / "index.json"
    if index.exists():
        h.update(index.read_bytes())
    for e in episodes:
        h.update(f"{e['file']}:{(root / e['file']).stat().st_size}\n".encode())
    return h.hexdigest()


def split_episodes(episodes: list[dict], val_fraction: float, seed: int
                   ) -> tuple[list[dict], list[dict]]:
    """Seeded split by episode (never by frame): frames of one episode are near-duplicates,
    so a frame split would leak the validation set into training."""
    if len(episodes) < 2:
        raise ValueError(f"need at least 2 episodes to split train/validation, got {len(episodes)}")
    order = list(range(len(episodes)))
    random.Random(seed).shuffle(order)
    n_val = min(len(episodes) - 1, max(1, round(len(episodes) * val_fraction)))
    val = sorted(order[:n_val])
    train = sorted(order[n_val:])
    return [episodes[i] for i in train], [episodes[i] for i in val]


class EpisodeFrames:
    """A map-style dataset: item i -> (x float32 [C, S, S], y float32 [2] or [6]).

    Args:
        root: dataset directory; episodes: entries of its index (``file``, ``frames``).
        task: "nav" (target ``action``) or "arm" (target ``pose``).
        modality: which streams make x (see inputs.py); norm: how they are prepared.
        max_frames: if > 0, keep at most this many items, evenly strided over all frames
            (a quick run still sees every episode).
    """

    def __init__(self, root: str | Path, episodes: list[dict], task: str, modality: str,
                 norm: Normalisation, max_frames: int = 0):
        check_modality(modality)
        if task not in TARGET_KEY:
            raise ValueError(f"unknown task {task!r} (nav, arm)")
        self.root, self.task, self.modality, self.norm = Path(root), task, modality, norm
        self.files = [e["file"] for e in episodes]
        pairs = [(ei, t) for ei, e in enumerate(episodes) for t in range(int(e["frames"]))]
        if max_frames and len(pairs) > max_frames:
            pick = np.linspace(0, len(pairs) - 1, max_frames).round().astype(int)
            pairs = [pairs[i] for i in pick]
        self.pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
        self._handles: dict[int, h5py.File] = {}
        self._pid = os.getpid()

    def __len__(self) -> int:
        return len(self.pairs)

    def _file(self, ei: int) -> h5py.File:
        if self._pid != os.getpid():      # a forked worker: never reuse the parent's handles
            self._handles, self._pid = {}, os.getpid()
        f = self._handles.get(ei)
        if f is None:
            f = self._handles[ei] = h5py.File(self.root / self.files[ei], "r")
        return f

    def __getitem__(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        ei, t = (int(v) for v in self.pairs[i])
        f = self._file(ei)
        streams = {s: f[STREAM_KEY[s]][t] for s in MODALITY_INPUTS[self.modality]}
        x = model_input(self.modality, self.norm, **streams)
        y = np.asarray(f[TARGET_KEY[self.task]][t], dtype=np.float32)
        return x, y

    def episodes_of(self) -> set[str]:
        return {self.files[ei] for ei in np.unique(self.pairs[:, 0])}

    def close(self) -> None:
        for f in self._handles.values():
            f.close()
        self._handles = {}

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        state["_handles"] = {}
        return state
