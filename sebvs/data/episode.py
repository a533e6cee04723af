"""One HDF5 file per episode: writer (crash-safe) and lazy reader.

Layout of ``episode_NNNN.h5`` (T frames, one row per control tick):

    rgb            [T, H, W, 3]  uint8    camera image
    events/frame   [T, 2K, H, W] uint8    ON/OFF event counts over the accumulator's window
                                          (K = 1), or K time bins per polarity (histogram)
    events/x,y     [N]           uint16   raw events (optional), all frames concatenated
    events/t       [N]           int64    timestamps, ns
    events/p       [N]           int8     polarity +1/-1
    events/offset  [T + 1]       int64    events of frame k are [offset[k], offset[k+1])
    action         [T, 2]        float32  nav command [v, w] in [-1, 1]     (task "nav")
    pose           [T, 6]        float32  arm pre-grasp pose [x,y,z,r,p,y]  (task "arm")
    action         [T, nu]       float32  actuator commands of an mjcf scene (task "mjcf":
                                          one per actuator, sebvs/sim/mjcf_scene.py)
    t_sim          [T]           float64  simulation time of the observation, s
    tick           [T]           int64    control tick index
    latency/<hop>  [T]           float32  per-frame hop latency, microseconds (NaN: not seen)
    truth/<name>   [T, ...]      float    privileged ground truth (NaN: not given that frame)
    modality       [T]           S16      input modality of a driving policy (optional)
    proprio        [T, D]        float32  the robot's proprioception at the tick (optional;
                                          NaN: not given that frame): sebvs/sim/proprio.py,
                                          components named by the attribute proprio_names
    drive          [T, D]        float32  the command that drove the sim at the tick, where
                                          another actor than the labelling expert drove
                                          (optional; DAgger: the policy's, attribute driver)

Attributes: task, scene, conditions (JSON), seed, topology (JSON), emulator (JSON),
event_scale, event_offset, version, end_reason, frames, plus any extra scalar or JSON
value the caller passes.

Crash safety: the writer works on ``<path>.partial`` and renames it to ``<path>`` only in
``finish``, after flushing and fsyncing, so a file with the final name is always complete.
A ``.partial`` left behind by a crash is a lost in-progress episode (``sebvs data check``
reports it; readers never list it).
"""
from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import h5py
import numpy as np

import sebvs

from ..h5named import FileUnreadable, first_line, named, open_h5

# task -> (target dataset, its width); None: the model's (mjcf: nu), fixed by the first row
TASK_TARGET = {"nav": ("action", 2), "arm": ("pose", 6), "mjcf": ("action", None)}
PARTIAL = ".partial"
# attributes stored as JSON text (dicts/lists); decoded by Episode.attrs
JSON_ATTRS = ("conditions", "topology", "emulator")
REQUIRED_ATTRS = ("task", "scene", "conditions", "seed", "topology", "emulator",
                  "event_scale", "event_offset", "version", "end_reason", "frames")
COMPRESSIONS = ("none", "lzf", "gzip")
MODALITY_DTYPE = "S16"


def _fsync_dir(path: Path) -> None:
    """Make a rename durable (the directory entry), where the OS allows it."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _attr_value(key: str, value: Any) -> Any:
    """h5py accepts scalars and strings; dicts and lists go as JSON text."""
    if key in JSON_ATTRS or isinstance(value, (dict, list, tuple)):
        return json.dumps(value if value is not None else {}, sort_keys=True, default=str)
    if value is None:
        return ""
    if isinstance(value, np.generic):
        return value.item()
    return value


class EpisodeWriter:
    """Appends frames to ``<path>.partial``; ``finish`` renames it to ``path``.

    Args:
        path: final file name (e.g. ``datasets/nav/episode_0003.h5``).
        task: "nav" (target ``action`` [2]), "arm" (target ``pose`` [6]) or "mjcf"
            (target ``action`` [nu], nu from the first frame).
        attrs: file attributes (scene, conditions, seed, topology, emulator, event_scale,
            event_offset, ...). Missing required ones are written empty so every file has
            the same keys; ``version`` and ``task`` are filled in here.
        compression: "lzf" (default: fast, pays on rendered images and sparse event
            frames), "gzip" (smaller, slower) or "none".
    Datasets are created on the first ``append`` (shapes come from the data), chunked one
    frame per chunk along T so a reader of one frame decompresses one frame.
    """

    GROW = 64   # rows added per resize: fewer HDF5 metadata updates than one per frame

    def __init__(self, path: str | Path, task: str, attrs: dict | None = None,
                 compression: str = "lzf"):
        if task not in TASK_TARGET:
            raise ValueError(f"unknown task {task!r} ({', '.join(TASK_TARGET)})")
        if compression not in COMPRESSIONS:
            raise ValueError(f"unknown compression {compression!r} ({', '.join(COMPRESSIONS)})")
        self.path = Path(path)
        self.partial = self.path.with_name(self.path.name + PARTIAL)
        self.task = task
        self.target_key, self.target_dim = TASK_TARGET[task]
        self.compression = None if compression == "none" else compression
        self.frames = 0
        self.raw_count = 0
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.f = h5py.File(self.partial, "w")
        attrs = dict(attrs or {})
        attrs["task"] = task
        attrs["version"] = sebvs.__version__
        for key in REQUIRED_ATTRS:
            attrs.setdefault(key, {} if key in JSON_ATTRS else ("" if key != "frames" else 0))
        self._json_keys: set[str] = set()
        self.set_attrs(attrs)
        self._big: dict[str, h5py.Dataset] = {}   # per-frame images, written as they come
        self._cap = 0
        # small per-frame columns stay in memory and are written by finish(): one HDF5
        # write per column instead of one per frame (a lost .partial loses them anyway)
        self._target: list = []
        self._t_sim: list = []
        self._tick: list = []
        self._latency: dict[str, dict[int, float]] = {}
        self._truth: dict[str, dict[int, np.ndarray]] = {}
        self._modality: dict[int, bytes] = {}
        self._proprio: dict[int, np.ndarray] = {}
        self._drive: dict[int, np.ndarray] = {}

    def set_attrs(self, attrs: dict) -> None:
        """Set or update file attributes (dicts and lists are stored as JSON text)."""
        for key, value in attrs.items():
            if key in JSON_ATTRS or isinstance(value, (dict, list, tuple)):
                self._json_keys.add(key)
            self.f.attrs[key] = _attr_value(key, value)
        # which attributes are JSON text, so the reader decodes exactly those
        self.f.attrs["json_keys"] = json.dumps(sorted(self._json_keys))

    @property
    def sim_seconds(self) -> float:
        """Simulated time spanned by the frames so far (last t_sim - first)."""
        return self._t_sim[-1] - self._t_sim[0] if self._t_sim else 0.0

    def _create_big(self, name: str, row_shape: tuple) -> h5py.Dataset:
        kw = {"compression": self.compression} if self.compression else {}
        ds = self.f.create_dataset(name, shape=(0,) + tuple(row_shape),
                                   maxshape=(None,) + tuple(row_shape), dtype=np.uint8,
                                   chunks=(1,) + tuple(row_shape), **kw)
        self._big[name] = ds
        return ds

    def append(self, *, rgb: np.ndarray, t_sim: float, tick: int,
               event_frame: np.ndarray | None = None, action: np.ndarray | None = None,
               pose: np.ndarray | None = None, latency: dict[str, float] | None = None,
               truth: dict[str, Any] | None = None, modality: str | None = None,
               raw_events: dict[str, np.ndarray] | None = None,
               proprio: np.ndarray | None = None, drive: np.ndarray | None = None) -> int:
        """Write one frame; returns its row index.

        rgb [H, W, 3] uint8; event_frame [2, H', W'] counts (clipped to 0..255);
        action [2] (nav) or pose [6] (arm) float; latency {hop: microseconds};
        truth {name: number or array, same shape every frame}; raw_events {"x", "y",
        "t", "p"} equal-length 1-D; proprio [D] float, the same D every frame; drive
        [D] float, the command that drove the tick (same D every frame). rgb,
        event_frame and raw_events must be given in every frame or in none; latency,
        truth, modality, proprio and drive may be missing (NaN / empty there).
        """
        target = pose if self.target_key == "pose" else action
        if target is None:
            raise ValueError(f"task {self.task!r} needs {self.target_key}=")
        target = np.asarray(target, np.float32).reshape(-1)
        if self.target_dim is None:
            self.target_dim = target.size       # mjcf: the model's nu, the same every row
        if target.shape != (self.target_dim,):
            raise ValueError(f"{self.target_key} must have {self.target_dim} values, "
                             f"got shape {target.shape}")
        rgb = np.asarray(rgb)
        if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
            raise ValueError(f"rgb must be uint8 [H, W, 3], got {rgb.dtype} {rgb.shape}")
        if self.frames == 0:
            self._create_big("rgb", rgb.shape)
            if event_frame is not None:
                self._create_big("events/frame", np.shape(event_frame))
            if raw_events is not None:
                self._raw_init()
        ev = self._big.get("events/frame")
        if (ev is None) != (event_frame is None):
            raise ValueError("event_frame must be given in every frame or in none")
        if self.frames >= self._cap:
            self._cap += self.GROW
            for ds in self._big.values():
                ds.resize(self._cap, axis=0)
        i = self.frames
        self._big["rgb"][i] = rgb
        if ev is not None:
            event_frame = np.asarray(event_frame)
            if event_frame.dtype.kind not in "ub" and event_frame.dtype.kind != "i":
                # a voxel grid is signed and fractional: as uint8 it would be silently wrong
                raise ValueError(f"event_frame must hold counts (integers), got "
                                 f"{event_frame.dtype}: record 'counts' or 'histogram' frames")
            if event_frame.dtype != np.uint8:
                event_frame = np.clip(event_frame, 0, 255).astype(np.uint8)
            ev[i] = event_frame
        if raw_events is not None or "events/x" in self.f:
            self._raw_append(raw_events)
        self._target.append(target)
        self._t_sim.append(float(t_sim))
        self._tick.append(int(tick))
        for hop, us in (latency or {}).items():
            self._latency.setdefault(hop, {})[i] = float(us)
        for key, value in (truth or {}).items():
            try:
                value = np.asarray(value, np.float64)
            except (TypeError, ValueError):
                continue            # not numeric: not a truth array
            self._truth.setdefault(key, {})[i] = value
        if modality is not None:
            self._modality[i] = str(modality).encode()[:16]
        for name, value, rows in (("proprio", proprio, self._proprio),
                                  ("drive", drive, self._drive)):
            if value is not None:
                _keep_row(name, value, rows, i)
        self.frames += 1
        return i

    @property
    def ticks(self) -> list[int]:
        """The ticks of the rows so far, in order (a copy)."""
        return list(self._tick)

    def truncate(self, n: int) -> None:
        """Keep the first ``n`` rows and forget the rest: rows a recorder put in this
        episode before learning where it ends (sebvs.data.recording). The next append
        writes row ``n``."""
        if not 0 <= n <= self.frames:
            raise ValueError(f"truncate({n}): the episode has {self.frames} rows")
        if n == self.frames:
            return
        del self._target[n:], self._t_sim[n:], self._tick[n:]
        for columns in (self._latency, self._truth):
            for key in list(columns):
                rows = {i: v for i, v in columns[key].items() if i < n}
                if rows:
                    columns[key] = rows
                else:
                    del columns[key]        # no row left to give the column its shape
        self._modality = {i: v for i, v in self._modality.items() if i < n}
        self._proprio = {i: v for i, v in self._proprio.items() if i < n}
        self._drive = {i: v for i, v in self._drive.items() if i < n}
        if "events/offset" in self.f:
            off = self.f["events/offset"]
            self.raw_count = int(off[n])
            off.resize(n + 1, axis=0)
            for key in ("x", "y", "t", "p"):
                self.f[f"events/{key}"].resize(self.raw_count, axis=0)
        self.frames = n     # the image datasets keep their capacity; close() trims them

    # --- raw events: 1-D, variable length per frame -----------------------------------
    def _raw_init(self) -> None:
        kw = {"compression": self.compression} if self.compression else {}
        for key, dtype in (("x", np.uint16), ("y", np.uint16), ("t", np.int64), ("p", np.int8)):
            self.f.create_dataset(f"events/{key}", shape=(0,), maxshape=(None,), dtype=dtype,
                                  chunks=(65536,), **kw)
        self.f.create_dataset("events/offset", shape=(1,), maxshape=(None,), dtype=np.int64,
                              chunks=(1024,), data=[0])

    def _raw_append(self, raw: dict[str, np.ndarray] | None) -> None:
        if "events/x" not in self.f:
            raise ValueError("raw_events must be given from the first frame on")
        n = 0 if raw is None else len(raw["x"])
        if n:
            for key in ("x", "y", "t", "p"):
                ds = self.f[f"events/{key}"]
                ds.resize(self.raw_count + n, axis=0)
                ds[self.raw_count:] = np.asarray(raw[key]).astype(ds.dtype, copy=False)
        self.raw_count += n
        off = self.f["events/offset"]
        off.resize(self.frames + 2, axis=0)
        off[self.frames + 1] = self.raw_count

    # --- ending -------------------------------------------------------------------------
    def finish(self, reason: str = "") -> Path:
        """Write the columns, trim, flush, fsync, close, rename to the final name; returns it."""
        self.close(reason)
        return self.publish()

    def close(self, reason: str = "") -> Path:
        """Write the columns, trim, flush, fsync and close the file under its partial name
        (complete, not yet published); returns that path."""
        self._write_columns()
        for ds in self._big.values():
            ds.resize(self.frames, axis=0)
        self.f.attrs["end_reason"] = reason
        self.f.attrs["frames"] = self.frames
        self.f.flush()
        self.f.close()
        # fsync the bytes before the rename, so the final name never points at a torn file
        fd = os.open(self.partial, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        return self.partial

    def publish(self) -> Path:
        """Rename the closed file to its final name (the moment readers may take it)."""
        os.replace(self.partial, self.path)
        _fsync_dir(self.path.parent)
        return self.path

    def _write_columns(self) -> None:
        n, f = self.frames, self.f
        f.create_dataset(self.target_key, data=np.asarray(self._target, np.float32)
                         .reshape(n, self.target_dim or 0))
        f.create_dataset("t_sim", data=np.asarray(self._t_sim, np.float64).reshape(n))
        f.create_dataset("tick", data=np.asarray(self._tick, np.int64).reshape(n))
        for hop, rows in self._latency.items():
            col = np.full(n, np.nan, np.float32)
            col[list(rows)] = list(rows.values())
            f.create_dataset("latency/" + hop.replace("/", "|"), data=col)
        for key, rows in self._truth.items():
            shape = next(iter(rows.values())).shape
            col = np.full((n,) + shape, np.nan, np.float64)
            for i, v in rows.items():
                if v.shape == shape:
                    col[i] = v
            f.create_dataset("truth/" + key.replace("/", "|"), data=col)
        if self._modality:
            col = np.zeros(n, MODALITY_DTYPE)
            for i, v in self._modality.items():
                col[i] = v
            f.create_dataset("modality", data=col)
        for key, rows in (("proprio", self._proprio), ("drive", self._drive)):
            if rows:
                col = np.full((n, next(iter(rows.values())).size), np.nan, np.float32)
                for i, v in rows.items():
                    col[i] = v
                f.create_dataset(key, data=col)

    def abandon(self) -> None:
        """Close after a failed write (a full disk), keeping the .partial file as the mark
        of the lost episode. HDF5 flushes its caches on close and, if that fails too,
        keeps the file and crashes the process at exit; the caller frees room first
        (EpisodeRecorder's space reserve), so this close normally succeeds."""
        self._big.clear()
        try:
            self.f.close()
        except Exception:       # nothing more to save; the handles are gone either way
            pass

    def abort(self) -> None:
        """Drop the episode: close and delete the partial file."""
        try:
            self.f.close()
        finally:
            self.partial.unlink(missing_ok=True)

    def __enter__(self) -> "EpisodeWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        # leaving the block without finish() (or on an exception) drops the episode: only
        # an explicit finish makes a file with the final name
        if self.f.id.valid:
            self.abort()


class Episode:
    """A finished episode opened read-only; arrays are lazy h5py datasets (index to read).

    ``rgb`` [T, H, W, 3], ``event_frame`` [T, 2, H, W] or None, ``target`` (``action``
    [T, 2] or ``pose`` [T, 6]), ``t_sim`` [T], ``tick`` [T], ``latency`` {hop: [T]},
    ``truth`` {name: [T, ...]}, ``modality`` [T] or None, ``raw_events`` (x, y, t, p,
    offset datasets) or None, ``proprio`` [T, D] float32 or None (episodes recorded before
    the recorder stored it, or without the sim's `proprio` wired), its components
    ``proprio_names`` (a tuple, empty without); ``drive`` [T, D] float32 or None (the
    command that drove each tick, where a policy drove and the expert labelled);
    ``attrs`` is a plain dict with JSON attributes decoded.
    """

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.file = open_h5(self.path)
        try:
            self._read_layout()
        except FileUnreadable:
            self.file.close()
            raise
        except (KeyError, ValueError, TypeError, OSError) as exc:
            # a file that opens but is not an episode (no rgb, a torn attribute): the
            # reason with the name, whatever the reader
            self.file.close()
            raise FileUnreadable(f"{self.path}: not an episode file "
                                 f"({type(exc).__name__}: {first_line(exc)})") from None

    def _read_layout(self) -> None:
        f = self.file
        self.attrs = {}
        raw_keys = f.attrs.get("json_keys", "[]")
        json_keys = set(json.loads(raw_keys.decode() if isinstance(raw_keys, bytes)
                                   else raw_keys)) | set(JSON_ATTRS)
        for k, v in f.attrs.items():
            if k == "json_keys":
                continue
            if isinstance(v, bytes):
                v = v.decode()
            if isinstance(v, np.generic):
                v = v.item()
            if k in json_keys and isinstance(v, str):
                v = json.loads(v) if v else {}
            self.attrs[k] = v
        self.task = self.attrs.get("task", "nav" if "action" in f else "arm")
        self.target_key = TASK_TARGET[self.task][0]
        # every array read names this file when a chunk fails to decode (h5named)
        self.rgb = named(f["rgb"])
        self.event_frame = named(f["events/frame"]) if "events/frame" in f else None
        self.target = named(f[self.target_key])
        self.action = named(f["action"]) if "action" in f else None
        self.pose = named(f["pose"]) if "pose" in f else None
        self.t_sim = named(f["t_sim"])
        self.tick = named(f["tick"])
        self.latency = {k: named(v) for k, v in f["latency"].items()} if "latency" in f else {}
        self.truth = {k: named(v) for k, v in f["truth"].items()} if "truth" in f else {}
        self.modality = named(f["modality"]) if "modality" in f else None
        self.raw_events = ({k: named(f[f"events/{k}"]) for k in ("x", "y", "t", "p", "offset")}
                           if "events/x" in f else None)
        self.proprio = named(f["proprio"]) if "proprio" in f else None
        self.drive = named(f["drive"]) if "drive" in f else None
        names = self.attrs.get("proprio_names") or ()
        self.proprio_names = tuple(str(n) for n in names) if isinstance(names, list) else ()

    def __len__(self) -> int:
        return int(self.rgb.shape[0])

    def close(self) -> None:
        self.file.close()

    def release(self) -> None:
        """Drop every h5py object of this episode: the file closes as its last reference
        goes (if the caller kept a dataset, when that one goes). 0.4 ms against 11 ms and
        more for close(), which walks every open HDF5 object of the process (512 open
        episodes here); for readers that hold many episodes and own all references."""
        self.__dict__ = {"path": self.path}

    def __enter__(self) -> "Episode":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def open_episode(path: str | Path) -> Episode:
    """Open a finished episode file (use as a context manager).

    The one place episodes are opened: a file that cannot be opened, is not an episode or
    later fails to decode a chunk raises FileUnreadable (a ValueError) naming it;
    FileNotFoundError when there is none. Whether the file is still the one its dataset's
    index recorded is sebvs/data/verify.py's to say."""
    return Episode(path)


def _keep_row(name: str, value, rows: dict, i: int) -> None:
    """Row ``i`` of a float32 stream of one width every frame (proprio, drive); ValueError
    naming the stream when its width changes."""
    value = np.asarray(value, np.float32).reshape(-1)
    first = next(iter(rows.values()), value)
    if value.shape != first.shape:
        raise ValueError(f"{name} must have {first.size} values every frame, got "
                         f"{value.size}")
    rows[i] = value
