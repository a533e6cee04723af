"""Behaviour-cloning samples read lazily from recorded episodes.

    episodes = load_index("datasets/nav", "nav")
    train_eps, val_eps = split_episodes(episodes, 0.2, seed=0)
    frames = EpisodeFrames("datasets/nav", train_eps, "nav", "rgb+event", Normalisation())
    x, y = frames[0]                 # float32 [5, 160, 160], the target float32 [2]

The files are sebvs/data's (``open_episode``, ``DatasetIndex``): an HDF5 per episode with
``rgb``, ``events/frame``, ``action`` (nav) or ``pose`` (arm), ``t_sim`` and ``tick``, and
``index.json`` listing them. Several datasets train together (DAgger's rounds beside the
expert's recording): `load_datasets` tags each index entry with its dataset (``root``), and
every reader here opens ``entry["root"] / entry["file"]`` (the ``root`` argument where an
entry has none). The dataset is an index of (episode, frame) pairs and each item
reads one frame. Episodes open in the reading process (DataLoader workers open their own)
and at most ``OPEN_EPISODES`` stay open, released rather than closed; `EpisodeBlockSampler`
shuffles episodes in blocks that fit the open set. `EpisodeFrames.preload()` reads the
streams a modality needs into memory instead, as stored (train.py does when they fit).
The costs behind each choice: docs/policy.md, "Dataset".
"""
from __future__ import annotations

import hashlib
import os
import random
from collections import OrderedDict
from pathlib import Path

import numpy as np

from sebvs.data.episode import Episode, open_episode
from sebvs.dataset_files import verify_entries
from sebvs.data.index import INDEX, DatasetIndex
from sebvs.runtime.params import short_repr

from .inputs import Modality, Normalisation, model_input

TASKS = ("nav", "arm")
OPEN_EPISODES = 512     # episode files a reader keeps open (least recently used released)


def load_index(root: str | Path, task: str | None = None, verify: bool = True,
               progress: bool = False) -> list[dict]:
    """The episodes listed in ``root``/index.json (refused if it holds another task).

    With ``verify`` (the default) every listed file is first checked against the index's
    size and sha256 (sebvs/dataset_files.py, remembered per process): a damaged episode
    raises EpisodeDamaged naming it before a frame of it is read."""
    root = Path(root)
    if not (root / INDEX).exists():
        raise FileNotFoundError(f"{root}: no {INDEX} (record with `sebvs record`, or check "
                                f"the path)")
    episodes = DatasetIndex(root, task).episodes()
    if not episodes:
        raise ValueError(f"{root}/{INDEX} lists no episodes")
    if verify:
        verify_entries(root, episodes, progress)
    return episodes


def episode_path(root: str | Path, entry: dict) -> Path:
    """Where an index entry's file is: in its own dataset (``entry["root"]``, set by
    `load_datasets`), else in ``root``."""
    return Path(entry.get("root", root)) / entry["file"]


def roots_of(root: str | Path, episodes: list[dict]) -> list[Path]:
    """The datasets the entries come from, in order of first appearance (``root`` for
    entries without their own)."""
    return list(dict.fromkeys(Path(e.get("root", root)) for e in episodes)) or [Path(root)]


def load_datasets(roots: list[str | Path], task: str | None = None, verify: bool = True,
                  progress: bool = False) -> list[dict]:
    """The episodes of several datasets, in the order given, each entry tagged with its
    dataset (``root``: the path as given), for training them together.

    Parameters:
        roots: the dataset directories (at least one; none twice).
        task: the task every one must hold (None: the first one's).
        verify, progress: as `load_index`.

    Returns:
        The index entries of every dataset, the first's first. ValueError, one line
        naming both, for two datasets of different tasks or one given twice.
    """
    roots = [Path(r) for r in roots]
    if not roots:
        raise ValueError("no dataset given")
    seen: dict[Path, Path] = {}
    for r in roots:
        same = seen.setdefault(r.resolve(), r)
        if same is not r:
            raise ValueError(f"dataset {r} is given twice (as {same} and {r})")
    tasks = {}
    for r in roots:
        if not (r / INDEX).exists():
            raise FileNotFoundError(f"{r}: no {INDEX} (record with `sebvs record`, or check "
                                    f"the path)")
        tasks[r] = DatasetIndex(r).task
    known = [(r, t) for r, t in tasks.items() if t is not None]
    for r, t in known[1:]:
        if t != known[0][1]:
            raise ValueError(f"datasets {known[0][0]} (task {known[0][1]}) and {r} (task "
                             f"{t}) hold different tasks: one task per training")
    episodes = []
    for r in roots:
        episodes += [{**e, "root": str(r)} for e in load_index(r, task, verify, progress)]
    return episodes


def dataset_hash(root: str | Path, episodes: list[dict]) -> str:
    """sha256 over index.json (if any) of each dataset the entries come from, and each
    episode's name and byte size.

    Cheap (no frame is read) and changes when an episode is re-recorded, added or removed.
    Entries of one dataset (``root``) hash as they always did.
    """
    h = hashlib.sha256()
    for r in roots_of(root, episodes):
        index = r / INDEX
        if index.exists():
            h.update(index.read_bytes())
    for e in episodes:
        h.update(f"{e['file']}:{episode_path(root, e).stat().st_size}\n".encode())
    return h.hexdigest()


def _stored_bytes(h: "hashlib._Hash", stream) -> None:
    """Feed an HDF5 dataset to ``h`` as stored: its shape and type, then each chunk's bytes
    as written (compressed, undecoded: hashing them costs a read, not a decode), or the
    values of an unchunked one."""
    h.update(f"{stream.name}:{stream.shape}:{stream.dtype.str}\n".encode())
    if stream.chunks is None:
        h.update(np.ascontiguousarray(stream[()]).tobytes())
        return
    for i in range(stream.id.get_num_chunks()):
        offset = stream.id.get_chunk_info(i).chunk_offset
        mask, data = stream.id.read_direct_chunk(offset)
        h.update(f"{offset}:{mask}:{len(data)}\n".encode())
        h.update(data)


def content_digest(root: str | Path, episodes: list[dict], modality: Modality | str) -> str:
    """sha256 over what a training of ``modality`` reads of the episodes, in their order:
    each episode's name, the image streams the modality takes (``rgb``, ``events/frame``)
    as stored, its targets, and its ticks counted from its first.

    Unlike `dataset_hash`, it does not see what a recording measures on the wall clock
    (hop latencies, and so the index's per-file sha256) or counts from the start of the run
    that recorded it (``tick``), so the same recording made again (the same topology, seed
    and episodes; docs/scale.md) has the same digest, and a changed pixel, event, target or
    episode does not. Two equal digests mean equal training inputs; the converse needs the
    same compression (the chunks are hashed as stored, undecoded). It reads the stored
    bytes once (seconds for gigabytes; nothing is decoded but the small unchunked arrays)."""
    modality = Modality.parse(modality)
    h = hashlib.sha256()
    for e in episodes:
        h.update(f"{e['file']}\n".encode())
        ep = open_episode(episode_path(root, e))
        try:
            if modality.reads_rgb:
                _stored_bytes(h, ep.rgb)
            if modality.has_events:
                if ep.event_frame is None:
                    raise ValueError(f"{ep.path}: no events/frame, needed by modality "
                                     f"{modality!r}")
                _stored_bytes(h, ep.event_frame)
            _stored_bytes(h, ep.target)
            tick = np.asarray(ep.tick[()], np.int64)
            h.update((tick - tick[:1]).tobytes())
        finally:
            ep.release()
    return h.hexdigest()


def event_frames_of(root: str | Path, episodes: list[dict]) -> dict:
    """What a dataset's event frames are, from its first episode: {"representation":
    "counts" | "histogram" | "time_surface", "bins": K time bins per polarity (1 for a time
    surface), "window_s": the accumulator's window (a time surface's tau), "sensor": the
    emulator's [w, h], "output": the frames' [w, h]} (window and sensor None where the
    recording did not say). Training takes K from here, and the checkpoint keeps the whole
    so that an evaluation can make its event frames the same way.
    Voxel grids (signed, float) are refused: no model input is defined for them.
    Entries of several datasets (`load_datasets`) must agree: ValueError, one line naming
    the first two that do not and what differs."""
    found = {}
    for e in episodes:      # each dataset's first episode
        r = Path(e.get("root", root))
        if r not in found:
            found[r] = _event_frames_of(episode_path(root, e))
    (r0, f0), *rest = found.items()
    for r, f in rest:
        differs = [k for k in f0 if f0[k] != f[k]]
        if differs:
            k = differs[0]
            raise ValueError(f"datasets {r0} and {r} hold different event frames ({k} "
                             f"{f0[k]} and {f[k]}): one event representation per training")
    return f0


def _event_frames_of(path: Path) -> dict:
    """`event_frames_of` for one episode file."""
    with open_episode(path) as ep:
        if ep.event_frame is None:
            raise ValueError(f"{path}: no events/frame")
        planes = int(ep.event_frame.shape[1])
        planes_size = (int(ep.event_frame.shape[3]), int(ep.event_frame.shape[2]))  # (w, h)
        representation = ep.attrs.get("event_representation") or "counts"
        window = ep.attrs.get("event_window_s")
        sensor = ep.attrs.get("event_sensor")
    if representation == "voxel":
        raise ValueError(f"{path}: event frames are voxel grids; policies take 'counts', "
                         f"'histogram' or 'time_surface' frames (record with "
                         f"accumulator.representation=\"histogram\")")
    if representation not in ("counts", "histogram", "time_surface") or planes % 2 or \
            (representation in ("counts", "time_surface") and planes != 2):
        raise ValueError(f"{path}: event frames of {planes} planes, representation "
                         f"{representation!r}: expected counts or a time surface [2, H, W], "
                         f"or a histogram [2K, H, W]")
    return {"representation": representation, "bins": planes // 2,
            "window_s": float(window) if isinstance(window, (int, float)) else None,
            "sensor": [int(v) for v in sensor] if _is_size(sensor) else None,
            "output": [int(v) for v in planes_size] if _is_size(planes_size) else None}


def emulator_of(root: str | Path, episodes: list[dict]) -> dict:
    """The event emulator a dataset was recorded with, from every episode's ``emulator``
    attribute (the recorder's: "preset", and "resolved", the preset's parameters).

    Training keeps it in the checkpoint config, so that an evaluation runs the emulator's
    noise model the policy was trained on (docs/dvs.md, "Noise and preset versions").

    Parameters:
        root: the dataset directory.
        episodes: entries of its index (``file``).

    Returns:
        {"preset": the preset's name (None where the episodes do not say, or do not
        agree), "preset_version": 1 or 2}; an episode whose attribute names no version
        was recorded by version 1. ValueError, one line, for episodes that mix versions
        or name one that is not 1 or 2.
    """
    from sebvs.dvs.params import PRESET_VERSIONS
    root = Path(root)
    presets, versions = set(), {}          # version -> the first episode recorded with it
    for e in episodes:
        ep = open_episode(episode_path(root, e))
        try:
            emulator = ep.attrs.get("emulator")
        finally:
            ep.release()
        emulator = emulator if isinstance(emulator, dict) else {}
        resolved = emulator.get("resolved")
        version = resolved.get("preset_version", 1) if isinstance(resolved, dict) else 1
        if type(version) is not int or version not in PRESET_VERSIONS:
            raise ValueError(f"{episode_path(root, e)}: emulator preset_version "
                             f"{short_repr(version)} is not one of "
                             f"{', '.join(map(str, PRESET_VERSIONS))}")
        versions.setdefault(version, str(episode_path(root, e)) if "root" in e else e["file"])
        presets.add(emulator.get("preset") if isinstance(emulator.get("preset"), str)
                    else None)
    if len(versions) > 1:
        (v1, f1), (v2, f2) = sorted(versions.items())[:2]
        raise ValueError(f"{root}: episodes recorded with emulator preset_version {v1} "
                         f"({f1}) and {v2} ({f2}): one noise model per dataset")
    return {"preset": presets.pop() if len(presets) == 1 else None,
            "preset_version": next(iter(versions), 1)}


def _is_size(value) -> bool:
    return (isinstance(value, (list, tuple)) and len(value) == 2
            and all(isinstance(v, (int, float)) and v > 0 for v in value))


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


def previous_rgb(ep: Episode, t: int) -> np.ndarray:
    """The RGB frame of the control tick before row t's, from the same episode; row t's own
    where there is none (the episode's first row, or a lost row before t): no change, as the
    policy actor sees it at an episode's start (sebvs/policy/infer.py, `PreviousFrame`)."""
    if t > 0:
        ticks = ep.tick[t - 1:t + 1]
        if int(ticks[1]) - int(ticks[0]) == 1:
            return ep.rgb[t - 1]
    return ep.rgb[t]


class HeldRows:
    """Some rows (at least one) of a recorded [T, ...] stream, in memory: indexed by the
    row's frame number like the full stream, for the frame numbers it holds (a KeyError for
    any other)."""

    def __init__(self, rows: np.ndarray, data: np.ndarray):
        self.rows, self.data = rows, data
        self.shape = (int(rows[-1]) + 1, *data.shape[1:])
        self.nbytes = data.nbytes

    def __getitem__(self, t: int) -> np.ndarray:
        i = int(np.searchsorted(self.rows, t))
        if i == self.rows.size or self.rows[i] != t:
            raise KeyError(f"frame {t} is not held (held: {self.rows.size} rows)")
        return self.data[i]


class CachedEpisode:
    """The streams of one episode a modality reads, in memory: ``rgb`` [T, H, W, 3] and
    ``event_frame`` [T, 2K, H, W] uint8 (None where not read), ``tick`` [T], ``target``
    [T, 2|6] float32; the attributes `previous_rgb` and `EpisodeFrames` use.

    ``rows`` (sorted frame numbers), when given, holds only those rows of the images (as
    `HeldRows`): a run capped by ``max_frames`` reads a few frames of each episode."""

    def __init__(self, ep: Episode, modality: Modality, rows: np.ndarray | None = None):
        self.path, self.task = ep.path, ep.task

        def read(stream):
            if rows is None:
                return stream[:]
            # a row at a time: one chunk each (h5py's list selection took 59 ms for 12 rows)
            return HeldRows(rows, np.stack([stream[int(t)] for t in rows]))
        self.rgb = read(ep.rgb) if modality.reads_rgb else None
        self.event_frame = read(ep.event_frame) if modality.has_events else None
        self.tick = ep.tick[:]
        self.target = np.asarray(ep.target[:], np.float32)

    @property
    def nbytes(self) -> int:
        return sum(a.nbytes for a in (self.rgb, self.event_frame, self.tick, self.target)
                   if a is not None)


def available_memory() -> int:
    """Bytes this machine can give without swapping (MemAvailable), else its free pages."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")


class EpisodeFrames:
    """A map-style dataset: item i -> (x float32 [C, S, S], y float32 [2] or [6]).

    Args:
        root: dataset directory; episodes: entries of its index (``file``, ``frames``;
            ``root``, their own dataset, where they come from several: `load_datasets`).
        task: "nav" (target ``action``) or "arm" (target ``pose``).
        modality: which streams make x (see inputs.py); norm: how they are prepared.
        max_frames: if > 0, keep at most this many items, evenly strided over all frames
            (a quick run still sees every episode).
    """

    def __init__(self, root: str | Path, episodes: list[dict], task: str,
                 modality: Modality | str, norm: Normalisation, max_frames: int = 0):
        modality = Modality.parse(modality)
        if task not in TASKS:
            raise ValueError(f"unknown task {task!r} (nav, arm)")
        self.root, self.task, self.modality, self.norm = Path(root), task, modality, norm
        self.files = [e["file"] for e in episodes]
        self.paths = [episode_path(self.root, e) for e in episodes]
        self.frame_counts = [int(e["frames"]) for e in episodes]
        pairs = [(ei, t) for ei, e in enumerate(episodes) for t in range(int(e["frames"]))]
        if max_frames and len(pairs) > max_frames:
            pick = np.linspace(0, len(pairs) - 1, max_frames).round().astype(int)
            pairs = [pairs[i] for i in pick]
        self.pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
        self._handles: OrderedDict[int, Episode] = OrderedDict()
        self._pid = os.getpid()
        self._cached: dict[int, CachedEpisode] = {}

    def __len__(self) -> int:
        return len(self.pairs)

    def frame_bytes(self) -> int:
        """What preload() would hold in frames: the rows it reads of the used episodes (every
        frame, as the index counts them, unless ``max_frames`` cut the episode) times the
        streams' bytes per frame, sized from the first episode's frame shapes."""
        used = np.unique(self.pairs[:, 0])
        if not len(used):
            return 0
        ep = self._episode(int(used[0]))
        per_frame = int(np.prod(ep.rgb.shape[1:])) if self.modality.reads_rgb else 0
        if self.modality.has_events:
            per_frame += int(np.prod(ep.event_frame.shape[1:]))
        return per_frame * sum(self.frame_counts[ei] if rows is None else rows.size
                               for ei, rows in self._rows_read())

    def _rows_read(self):
        """(episode, rows) for every used episode: None when every frame is used (the whole
        streams are read), else the sorted frame numbers its items read, with the one before
        each where the modality takes the previous frame."""
        prev = self.modality.reads_previous_frame
        for ei, ts in self._items_by_episode():
            if ts.size == self.frame_counts[ei]:
                yield ei, None
                continue
            if prev:
                ts = np.concatenate([ts, ts[ts > 0] - 1])
            yield ei, np.unique(ts)

    def _items_by_episode(self):
        """(episode, its items' frame numbers) per used episode, in episode order. The pairs
        run in episode order (built so, and max_frames' stride keeps it): one slice each."""
        used, first, count = np.unique(self.pairs[:, 0], return_index=True, return_counts=True)
        for ei, a, n in zip(used, first, count):
            yield int(ei), self.pairs[a:a + n, 1]

    def preload(self, progress: bool = False) -> int:
        """Read the used rows of every used episode's streams into memory (CachedEpisode);
        the bytes held. Items then come from memory; the files are released."""
        from tqdm import tqdm
        used = list(self._rows_read())
        for ei, rows in tqdm(used, desc="frames to memory", unit="episode",
                             disable=not progress, leave=False):
            if ei not in self._cached:
                self._cached[ei] = CachedEpisode(self._episode(ei), self.modality, rows)
                handle = self._handles.pop(ei, None)
                if handle is not None:
                    handle.release()
        return sum(c.nbytes for c in self._cached.values())

    def _episode(self, ei: int) -> Episode | CachedEpisode:
        cached = self._cached.get(ei)
        if cached is not None:
            return cached
        if self._pid != os.getpid():      # a forked worker: never reuse the parent's handles
            self._handles, self._pid = OrderedDict(), os.getpid()
        ep = self._handles.get(ei)
        if ep is not None:
            self._handles.move_to_end(ei)
        else:
            while len(self._handles) >= OPEN_EPISODES:
                self._handles.popitem(last=False)[1].release()
            ep = open_episode(self.paths[ei])
            if ep.task != self.task:
                ep.close()
                raise ValueError(f"{ep.path}: episode of task {ep.task!r}, training {self.task!r}")
            if self.modality.has_events:
                planes = None if ep.event_frame is None else int(ep.event_frame.shape[1])
                if planes != 2 * self.norm.event_bins:
                    ep.close()
                    raise ValueError(
                        f"{ep.path}: no events/frame, needed by modality {self.modality!r}"
                        if planes is None else
                        f"{ep.path}: event frames of {planes} planes, the model takes "
                        f"{2 * self.norm.event_bins} (event_bins {self.norm.event_bins}): "
                        f"one event representation per dataset")
            self._handles[ei] = ep
        return ep

    def __getitem__(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        ei, t = (int(v) for v in self.pairs[i])
        ep = self._episode(ei)
        frames = {"rgb": ep.rgb, "events": ep.event_frame}
        streams = {s: previous_rgb(ep, t) if s == "rgb_prev" else frames[s][t]
                   for s in self.modality.streams}
        x = model_input(self.modality, self.norm, **streams)
        y = np.asarray(ep.target[t], dtype=np.float32)
        return x, y

    def targets(self) -> np.ndarray:
        """Every item's target, [N, 2] or [N, 6] float32, without reading any image."""
        out = [np.asarray(self._episode(ei).target[:], np.float32)[ts]
               for ei, ts in self._items_by_episode()]
        return np.concatenate(out) if out else np.zeros((0, 6), np.float32)

    def episodes_of(self) -> set[str]:
        return {self.files[ei] for ei in np.unique(self.pairs[:, 0])}

    def close(self) -> None:
        for ep in self._handles.values():
            ep.release()
        self._handles = OrderedDict()
        self._cached = {}

    def open_episodes(self) -> int:
        return len(self._handles)

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        state["_handles"] = OrderedDict()
        return state


class EpisodeBlockSampler:
    """Shuffled item order that touches at most ``block`` episodes at a time.

    Each pass permutes the episodes, cuts the permutation into blocks of ``block`` episodes
    and yields each block's items in a random order. With ``block <= OPEN_EPISODES`` every
    episode file is opened once per pass; a batch still mixes frames of up to ``block``
    episodes. Seeded through ``generator`` (a torch.Generator), like RandomSampler.

    Args:
        episode_of_item: [N] episode number of each item (``EpisodeFrames.pairs[:, 0]``).
    """

    def __init__(self, episode_of_item, block: int = OPEN_EPISODES, generator=None):
        if block < 1:
            raise ValueError(f"block must be >= 1 episode, got {block}")
        self.episode_of_item = np.asarray(episode_of_item, dtype=np.int64)
        self.block, self.generator = block, generator
        self.episodes = np.unique(self.episode_of_item)
        order = np.argsort(self.episode_of_item, kind="stable")
        bounds = np.searchsorted(self.episode_of_item[order], self.episodes)
        self._items = np.split(order, bounds[1:])      # items of each episode, in order

    def __len__(self) -> int:
        return len(self.episode_of_item)

    def __iter__(self):
        import torch
        perm = torch.randperm(len(self.episodes), generator=self.generator).numpy()
        for start in range(0, len(perm), self.block):
            items = np.concatenate([self._items[e] for e in perm[start:start + self.block]])
            inner = torch.randperm(len(items), generator=self.generator).numpy()
            yield from items[inner].tolist()
