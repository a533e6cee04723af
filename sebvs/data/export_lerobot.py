"""`sebvs data export --format lerobot`: a dataset as a LeRobotDataset v3.0 (docs/formats.md).

The layout LeRobot's v3.0 dataset class reads (lerobot.datasets.lerobot_dataset):

    meta/info.json                               codebase_version "v3.0", fps, features, paths
    meta/stats.json                              per feature: min max mean std count q01..q99
    meta/tasks.parquet                           task text (the pandas index) -> task_index
    meta/episodes/chunk-000/file-000.parquet     one row per episode: length, where its rows
                                                 and video frames lie, its own stats
    data/chunk-CCC/file-FFF.parquet              one row per frame, episodes one after another
    videos/<key>/chunk-CCC/file-FFF.mp4          one video per camera, episodes one after another
    meta/sebvs_export.json                       ours: source episode of each episode_index,
                                                 the event frames' channels, the encoder

Features (one frame per control tick, fps = the recording's control rate):

    observation.images.<camera>  video   [H, W, 3]    the RGB frame (<camera>: the topology's)
    observation.events           uint8   [C, H', W']  the recorded event frame, exact counts
    observation.state            float32 [D]          proprioception, named by proprio_names
    action                       float32 [2] | [6]    nav [v, w] in [-1, 1]; arm pre-grasp pose
    timestamp, frame_index, episode_index, index, task_index    LeRobot's own columns

The event frames are an array feature, not a second video: they are small integer counts
(mostly 0 and 1) that a lossy codec turns into other numbers, and a lossless mp4 would hand
a policy 3 channels of count/255 in place of the ON and OFF planes.
"""
from __future__ import annotations

import json
import math
import os
import re
import shutil
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

import numpy as np
from tqdm import tqdm

import sebvs

from ..extras import require
from ..output_guard import OutputRefused
from .episode import open_episode
from .export_mcap import episodes_of

CODEBASE_VERSION = "v3.0"
CHUNKS_SIZE = 1000              # files per chunk folder (LeRobot's default)
DATA_FILE_MB = 100              # a data parquet file is closed past this size (LeRobot's)
VIDEO_FILE_MB = 200             # a video file likewise
DATA_PATH = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
VIDEO_PATH = "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"
EPISODES_PATH = "meta/episodes/chunk-000/file-000.parquet"
INFO_PATH, STATS_PATH, TASKS_PATH = "meta/info.json", "meta/stats.json", "meta/tasks.parquet"
MARKER = "meta/sebvs_export.json"
PARTIAL = ".partial"
EVENTS_KEY, STATE_KEY, ACTION_KEY = "observation.events", "observation.state", "action"

ACTION_NAMES = {"nav": ("v", "w"), "arm": ("x", "y", "z", "roll", "pitch", "yaw")}
TASK_TEXT = {"nav": "drive to the red target cube and follow it",
             "arm": "move the gripper to the pre-grasp pose above the object"}
ROBOT_TYPE = {"nav": "sebvs_nav_diff_drive", "arm": "sebvs_ur5"}
# anyone's MJCF (scene "mjcf"): the model's actuators, whatever drove them
OTHER_TASK_TEXT = "drive the model's actuators as recorded"
QUANTILES = (0.01, 0.10, 0.50, 0.90, 0.99)
QUANTILE_KEYS = tuple(f"q{round(q * 100):02d}" for q in QUANTILES)
# LeRobot's own columns, every dataset has them
DEFAULT_FEATURES = {"timestamp": "float32", "frame_index": "int64", "episode_index": "int64",
                    "index": "int64", "task_index": "int64"}
PARQUET_COMPRESSION = {"zstd": "zstd", "lz4": "lz4", "none": "none"}


# --- what the dataset holds -----------------------------------------------------------
@dataclass(frozen=True)
class Layout:
    """What every episode of the export shares, read before anything is written.

    Parameters:
        task: "nav", "arm" or "mjcf" (anyone's model: its actuators' commands).
        action_width: the command's length.
        fps: frames per second (the control rate the episodes were recorded at).
        camera: the camera's name, the video feature's last part.
        rgb_hw: (H, W) of the RGB frames.
        events_shape: (C, H', W') of the event frames, or None when the episodes have none.
        state_names: the proprioception's component names, or None when omitted.
        frames: frames of each episode, in order.
    """
    task: str
    action_width: int
    fps: int
    camera: str
    rgb_hw: tuple[int, int]
    events_shape: tuple[int, int, int] | None
    state_names: tuple[str, ...] | None
    frames: tuple[int, ...]

    @property
    def video_key(self) -> str:
        return f"observation.images.{self.camera}"


def _camera_name(ep) -> str:
    """The camera actor's `camera` in the recording's topology, else "camera"; only
    characters a feature name may hold (LeRobot refuses '/')."""
    content = (ep.attrs.get("topology") or {}).get("content") or {}
    for actor in (content.get("actors") or {}).values():
        if isinstance(actor, dict) and str(actor.get("run", "")).endswith("camera:Camera"):
            name = re.sub(r"[^A-Za-z0-9_-]", "_", str(actor.get("camera") or ""))
            if name:
                return name
    return "camera"


def _fps(path: Path, t_sim: np.ndarray) -> int | None:
    """The whole frame rate of an episode's t_sim [T], or None for a single frame.

    Raises:
        ValueError: the frames are not evenly spaced at a whole rate (LeRobot's time axis
            is frame_index / fps, so a missing frame would shift every later one).
    """
    if t_sim.size < 2:
        return None
    dt = np.diff(t_sim)
    rate = 1.0 / float(np.median(dt))
    fps = round(rate)
    if fps < 1 or abs(rate - fps) > 1e-3 * fps:
        raise ValueError(f"{path}: frames come every {1 / rate:.6g} s, not a whole frame "
                         f"rate; LeRobot needs an integer fps")
    off = np.flatnonzero(np.abs(dt * fps - 1.0) > 1e-3)
    if off.size:
        k = int(off[0]) + 1
        raise ValueError(f"{path}: frame {k} comes {dt[k - 1]:.6g} s after frame {k - 1}, "
                         f"not 1/{fps} s ({off.size} uneven step(s)); LeRobot's time axis "
                         f"is frame_index / fps, so an episode with missing frames cannot go")
    return fps


def plan(episodes: list[Path]) -> tuple[Layout, list[str]]:
    """Read what the export needs from every episode and check they agree.

    Parameters:
        episodes: the episode files, in export order.

    Returns:
        (layout, notes): notes are one line each on what the export leaves out.

    Raises:
        ValueError: one line naming the episode that differs or cannot go, and why.
    """
    first: dict = {}
    rate: tuple[int, Path] | None = None        # the first episode's fps, and which
    frames, with_state, without_state, without_events = [], [], [], []
    for path in episodes:
        with open_episode(path) as ep:
            if len(ep) == 0:
                raise ValueError(f"{path}: the episode has no frames")
            events = tuple(ep.event_frame.shape[1:]) if ep.event_frame is not None else None
            state = None
            if ep.proprio is not None:
                proprio = ep.proprio[:]
                bad = ~np.isfinite(proprio).all(axis=1)
                if bad.any():
                    raise ValueError(f"{path}: proprio holds NaN/inf in {int(bad.sum())} of "
                                     f"{len(proprio)} rows (frame {int(np.flatnonzero(bad)[0])} "
                                     f"first); observation.state must be whole")
                names = ep.proprio_names
                if len(names) != proprio.shape[1]:
                    names = tuple(f"proprio_{i}" for i in range(proprio.shape[1]))
                state = names
            this = {"task": ep.task, "camera": _camera_name(ep), "rgb": tuple(ep.rgb.shape[1:3]),
                    "events": events, "state": state, "action": int(ep.target.shape[1])}
            fps = _fps(path, np.asarray(ep.t_sim[:], np.float64))
            frames.append(len(ep))
        if fps is not None and rate is None:
            rate = (fps, path)
        elif fps is not None and fps != rate[0]:
            raise ValueError(f"{path}: {fps} frames/s, while {rate[1].name} has {rate[0]}; "
                             f"one LeRobot dataset has one fps")
        (with_state if state is not None else without_state).append(path.name)
        if events is None:
            without_events.append(path.name)
        if not first:
            first = {**this, "path": path}
            continue
        for key, what in (("task", "task"), ("camera", "camera"), ("rgb", "RGB size (H, W)"),
                          ("action", "command length"),
                          ("events", "event frame shape (C, H, W)"),
                          ("state", "proprioception components")):
            if this[key] != first[key] and not (key in ("events", "state")
                                                and None in (this[key], first[key])):
                raise ValueError(f"{path}: {what} {this[key]} differs from {first['path'].name}'s "
                                 f"{first[key]}; one LeRobot dataset has one set of features")
    if with_state and without_state:
        raise ValueError(f"{without_state[0]}: no proprioception, while {with_state[0]} has it "
                         f"({len(without_state)} of {len(episodes)} episodes lack it); one "
                         f"LeRobot dataset has one set of features: export those with it alone")
    if without_events and len(without_events) < len(episodes):
        raise ValueError(f"{without_events[0]}: no event frames, while other episodes have "
                         f"them; one LeRobot dataset has one set of features")
    if rate is None:
        raise ValueError(f"{episodes[0]}: every episode has a single frame; the frame rate "
                         f"cannot be told")
    h, w = first["rgb"]
    if h % 2 or w % 2:
        raise ValueError(f"{first['path']}: RGB frames of {w} x {h}; the mp4 video (4:2:0) "
                         f"needs an even width and height")
    notes = []
    if without_state:
        notes.append(f"no {STATE_KEY}: the episodes hold no proprioception (recorded before "
                     f"recordings stored it, or without the sim's proprio wired)")
    if without_events:
        notes.append(f"no {EVENTS_KEY}: the episodes hold no event frames")
    layout = Layout(task=first["task"], action_width=first["action"], fps=rate[0], camera=first["camera"],
                    rgb_hw=(int(h), int(w)), events_shape=first["events"],
                    state_names=first["state"], frames=tuple(frames))
    return layout, notes


# --- video ----------------------------------------------------------------------------
class VideoFile:
    """One mp4 of RGB frames at a fixed rate, frame k shown at k / fps.

    PyAV (when installed) encodes AV1 with SVT-AV1 at LeRobot's own settings (crf 30, a
    key frame every 2 frames, preset 12), else H.264 or MPEG-4 Part 2, whichever its FFmpeg
    has; without PyAV, OpenCV's VideoWriter writes MPEG-4 Part 2 ("mp4v", the mp4 codec
    every OpenCV build's FFmpeg encodes). All are 4:2:0 (yuv420p), which LeRobot's
    decoders (torchcodec, PyAV) read.

    Parameters:
        path: the .mp4 to write.
        fps: frames per second.
        width, height: the frame size (even).
        encoder: "auto", "pyav" or "opencv".
    """

    AV_CODECS = (("libsvtav1", {"g": "2", "crf": "30", "preset": "12"}),
                 ("libx264", {"g": "2", "crf": "23"}),
                 ("mpeg4", {"g": "2", "qscale": "3"}))

    def __init__(self, path: Path, fps: int, width: int, height: int, encoder: str = "auto"):
        self.path, self.frames = path, 0
        path.parent.mkdir(parents=True, exist_ok=True)
        self.backend, self.codec = pick_encoder(encoder)
        if self.backend == "pyav":
            import os

            import av
            # SVT-AV1 prints its configuration at info level on stderr, a dozen lines per
            # video among the command's own; errors only (read when the encoder opens)
            os.environ.setdefault("SVT_LOG", "1")
            self._container = av.open(str(path), "w")
            opts = dict(self.AV_CODECS)[self.codec]
            self._stream = self._container.add_stream(self.codec, rate=fps, options=opts)
            self._stream.width, self._stream.height = width, height
            self._stream.pix_fmt = "yuv420p"
            self._stream.time_base = Fraction(1, fps)
        else:
            import cv2
            self._writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"),
                                           float(fps), (width, height))
            if not self._writer.isOpened():
                raise OSError(f"{path}: OpenCV's VideoWriter cannot write mp4v here; "
                              f"pip install 'sebvs[lerobot]' (PyAV)")

    @property
    def codec_name(self) -> str:
        """The codec as FFmpeg names it (LeRobot's info.json `video.codec`)."""
        return {"libsvtav1": "av1", "libx264": "h264", "mpeg4": "mpeg4"}[self.codec]

    def write(self, rgb: np.ndarray) -> None:
        """Append frames rgb [N, H, W, 3] uint8."""
        if self.backend == "pyav":
            import av
            for frame in rgb:
                vf = av.VideoFrame.from_ndarray(np.ascontiguousarray(frame), format="rgb24")
                vf.pts = self.frames
                self.frames += 1
                for packet in self._stream.encode(vf):
                    self._container.mux(packet)
        else:
            for frame in rgb:
                self._writer.write(np.ascontiguousarray(frame[:, :, ::-1]))   # OpenCV: BGR
                self.frames += 1

    def size(self) -> int:
        """Bytes written so far (the encoder may hold a few frames back)."""
        try:
            return self.path.stat().st_size
        except OSError:
            return 0

    def close(self) -> None:
        if self.backend == "pyav":
            for packet in self._stream.encode():
                self._container.mux(packet)
            self._container.close()
        else:
            self._writer.release()


def pick_encoder(encoder: str = "auto") -> tuple[str, str]:
    """(backend, codec) for ``encoder`` "auto" (PyAV if installed, else OpenCV), "pyav" or
    "opencv"; MissingExtra when "pyav" is asked for and not installed."""
    if encoder not in ("auto", "pyav", "opencv"):
        raise ValueError(f"encoder {encoder!r}: expected auto, pyav or opencv")
    if encoder != "opencv":
        try:
            import av
        except ImportError:
            if encoder == "pyav":
                require("av", "av (PyAV)", "lerobot", "the PyAV video encoder")
        else:
            for codec, _ in VideoFile.AV_CODECS:
                try:
                    av.codec.Codec(codec, "w")
                    return "pyav", codec
                except Exception:       # this FFmpeg build lacks it: the next one
                    continue
            if encoder == "pyav":
                raise ValueError("PyAV's FFmpeg has none of the encoders libsvtav1, libx264, "
                                 "mpeg4")
    return "opencv", "mpeg4"


# --- statistics -----------------------------------------------------------------------
def vector_stats(x: np.ndarray) -> dict[str, np.ndarray]:
    """LeRobot's statistics of a per-frame feature.

    Parameters:
        x: [N, D] values (N frames).

    Returns:
        min, max, mean, std, q01..q99: [D] float64; count: [1] (N).
    """
    x = np.asarray(x, np.float64).reshape(len(x), -1)
    out = {"min": x.min(0), "max": x.max(0), "mean": x.mean(0), "std": x.std(0)}
    for key, v in zip(QUANTILE_KEYS, np.quantile(x, QUANTILES, axis=0)):
        out[key] = v
    out["count"] = np.array([len(x)], np.int64)
    return out


def _histogram_quantiles(hist: np.ndarray, qs) -> np.ndarray:
    """np.quantile's values (linear interpolation between order statistics) from a
    histogram of the integers 0..len(hist)-1."""
    n = int(hist.sum())
    ends = np.cumsum(hist)                       # order statistics < ends[v] are <= v
    out = []
    for q in qs:
        pos = q * (n - 1)
        lo, hi = np.searchsorted(ends, [math.floor(pos) + 1, math.ceil(pos) + 1])
        out.append(lo + (hi - lo) * (pos - math.floor(pos)))
    return np.asarray(out, np.float64)


def plane_stats(planes: np.ndarray, scale: float = 1.0) -> dict[str, np.ndarray]:
    """Per-channel statistics of 8-bit images over every pixel of every frame, shaped
    [C, 1, 1] as LeRobot keeps an image's; exact, from one histogram per channel.

    Parameters:
        planes: [N, C, H, W] uint8.
        scale: multiplies the values (1/255 -> LeRobot's [0, 1] images; 1 for counts).

    Returns:
        min, max, mean, std, q01..q99: [C, 1, 1] float64; count: [1] (N).
    """
    n, c = planes.shape[:2]
    levels = np.arange(256, dtype=np.float64)
    cols = {k: [] for k in ("min", "max", "mean", "std", *QUANTILE_KEYS)}
    for ch in range(c):
        hist = np.bincount(planes[:, ch].reshape(-1), minlength=256).astype(np.float64)
        seen = np.flatnonzero(hist)
        mean = (hist * levels).sum() / hist.sum()
        var = (hist * (levels - mean) ** 2).sum() / hist.sum()
        cols["min"].append(seen[0])
        cols["max"].append(seen[-1])
        cols["mean"].append(mean)
        cols["std"].append(math.sqrt(var))
        for key, v in zip(QUANTILE_KEYS, _histogram_quantiles(hist, QUANTILES)):
            cols[key].append(v)
    out = {k: (np.asarray(v, np.float64) * scale).reshape(c, 1, 1) for k, v in cols.items()}
    out["count"] = np.array([n], np.int64)
    return out


def aggregate_stats(parts: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """Combine per-episode statistics: min of mins, max of maxes, the count-weighted mean,
    the pooled standard deviation, and the count-weighted mean of each quantile (LeRobot's
    rule for the dataset's stats.json)."""
    counts = np.array([float(p["count"][0]) for p in parts])
    total = counts.sum()
    shape = (-1,) + (1,) * (np.ndim(parts[0]["mean"]))
    w = (counts / total).reshape(shape)
    means = np.stack([p["mean"] for p in parts])
    mean = (w * means).sum(0)
    var = (w * (np.stack([p["std"] for p in parts]) ** 2 + (means - mean) ** 2)).sum(0)
    out = {"min": np.min([p["min"] for p in parts], 0), "max": np.max([p["max"] for p in parts], 0),
           "mean": mean, "std": np.sqrt(var), "count": np.array([int(total)], np.int64)}
    for key in parts[0]:
        if key.startswith("q"):
            out[key] = (w * np.stack([p[key] for p in parts])).sum(0)
    return out


def _jsonable(stats: dict[str, dict[str, np.ndarray]]) -> dict:
    return {feat: {k: np.asarray(v).tolist() for k, v in s.items()} for feat, s in stats.items()}


# --- parquet --------------------------------------------------------------------------
def _fixed_list(pa, x: np.ndarray, dtype):
    """A [N, D] array as a fixed-size list column (a `datasets` Sequence of length D)."""
    x = np.ascontiguousarray(x, dtype=dtype)
    return pa.FixedSizeListArray.from_arrays(pa.array(x.reshape(-1)), x.shape[1])


def _nested_list(pa, x: np.ndarray):
    """A [N, A, B, C] array as list<list<list<>>> (a `datasets` Array3D's storage)."""
    col = pa.array(np.ascontiguousarray(x).reshape(-1))
    size = x.size
    for n in reversed(x.shape[1:]):
        col = pa.ListArray.from_arrays(pa.array(np.arange(0, size + 1, n, dtype=np.int32)), col)
        size //= n
    return col


def _tasks_table(pa, tasks: list[str]):
    """meta/tasks.parquet: task_index with the task text as the pandas index, the table
    LeRobot reads with pandas.read_parquet and looks tasks up in by text."""
    table = pa.table({"task_index": pa.array(range(len(tasks)), pa.int64()),
                      "__index_level_0__": pa.array(tasks, pa.string())})
    meta = {"index_columns": ["__index_level_0__"],
            "column_indexes": [{"name": None, "field_name": None, "pandas_type": "unicode",
                                "numpy_type": "object", "metadata": {"encoding": "UTF-8"}}],
            "columns": [{"name": "task_index", "field_name": "task_index",
                         "pandas_type": "int64", "numpy_type": "int64", "metadata": None},
                        {"name": None, "field_name": "__index_level_0__",
                         "pandas_type": "unicode", "numpy_type": "object", "metadata": None}],
            "creator": {"library": "pyarrow", "version": pa.__version__},
            "pandas_version": "2.2.0"}
    return table.replace_schema_metadata({b"pandas": json.dumps(meta).encode()})


class RollingFiles:
    """Files of one kind numbered chunk-CCC/file-FFF, the next one started once the
    current one passes ``limit_mb`` (checked between episodes, as LeRobot does)."""

    def __init__(self, root: Path, pattern: str, limit_mb: float, **fmt):
        self.root, self.pattern, self.limit = root, pattern, limit_mb * 1024 * 1024
        self.fmt, self.chunk, self.file, self.handle = fmt, 0, 0, None

    def path(self) -> Path:
        return self.root / self.pattern.format(chunk_index=self.chunk, file_index=self.file,
                                               **self.fmt)

    def roll_if_full(self, size: int) -> bool:
        """Close the current file when ``size`` passed the limit; True when it did."""
        if self.handle is None or size < self.limit:
            return False
        self.handle.close()
        self.handle = None
        self.file += 1
        if self.file == CHUNKS_SIZE:
            self.chunk, self.file = self.chunk + 1, 0
        return True


# --- the export -----------------------------------------------------------------------
def _features(layout: Layout, codec: str) -> dict:
    h, w = layout.rgb_hw
    feats = {layout.video_key: {
        "dtype": "video", "shape": [h, w, 3], "names": ["height", "width", "channels"],
        "info": {"video.height": h, "video.width": w, "video.codec": codec,
                 "video.pix_fmt": "yuv420p", "video.is_depth_map": False,
                 "video.fps": layout.fps, "video.channels": 3, "has_audio": False}}}
    if layout.events_shape is not None:
        feats[EVENTS_KEY] = {"dtype": "uint8", "shape": list(layout.events_shape),
                             "names": ["channels", "height", "width"]}
    if layout.state_names is not None:
        feats[STATE_KEY] = {"dtype": "float32", "shape": [len(layout.state_names)],
                            "names": list(layout.state_names)}
    names = ACTION_NAMES.get(layout.task) or tuple(f"ctrl_{i}"
                                                   for i in range(layout.action_width))
    feats[ACTION_KEY] = {"dtype": "float32", "shape": [len(names)], "names": list(names)}
    for key, dtype in DEFAULT_FEATURES.items():
        feats[key] = {"dtype": dtype, "shape": [1], "names": None}
    return feats


def _event_channels(channels: int) -> list[str]:
    """Names of the event frame's channels: ON then OFF, per time bin where there are K."""
    if channels == 2:
        return ["on", "off"]
    k = channels // 2
    return [f"on_bin{i}" for i in range(k)] + [f"off_bin{i}" for i in range(k)]


def _write_dataset(root: Path, episodes: list[Path], layout: Layout, encoder: str,
                   compression: str, bar) -> dict:
    """Write every file of the dataset under ``root`` (a new folder); returns the marker's
    content."""
    import pyarrow as pa
    import pyarrow.parquet as pq
    task_text = TASK_TEXT.get(layout.task, OTHER_TASK_TEXT)
    data = RollingFiles(root, DATA_PATH, DATA_FILE_MB)
    videos = RollingFiles(root, VIDEO_PATH, VIDEO_FILE_MB, video_key=layout.video_key)
    h, w = layout.rgb_hw
    rows, stats_parts, sources = [], [], []
    start, codec, backend, event_info = 0, None, None, None
    video_start = 0                 # frames already in the current video file
    for ep_index, path in enumerate(episodes):
        with open_episode(path) as ep:
            n = len(ep)
            rgb = ep.rgb[:]
            target = np.asarray(ep.target[:], np.float32)
            events = ep.event_frame[:] if layout.events_shape is not None else None
            state = (np.asarray(ep.proprio[:], np.float32) if layout.state_names is not None
                     else None)
            sources.append({"episode_index": ep_index, "file": path.name,
                            "seed": ep.attrs.get("seed"), "frames": n,
                            "end_reason": ep.attrs.get("end_reason")})
            if events is not None and event_info is None:
                event_info = {"channels": _event_channels(events.shape[1]),
                              "representation": ep.attrs.get("event_representation", "counts"),
                              "window_s": ep.attrs.get("event_window_s"),
                              "unit": "events per pixel in the frame's window, clipped at 255"}
        # video: the episode's frames go on in the current file unless it is full
        if videos.roll_if_full(videos.handle.size() if videos.handle else 0):
            video_start = 0
        if videos.handle is None:
            videos.handle = VideoFile(videos.path(), layout.fps, w, h, encoder)
            codec, backend = videos.handle.codec_name, videos.handle.backend
        video = videos.handle
        video.write(rgb)
        if bar is not None:
            bar.update(n)
        frame_index = np.arange(n, dtype=np.int64)
        columns = {}
        if events is not None:
            columns[EVENTS_KEY] = _nested_list(pa, events)
        if state is not None:
            columns[STATE_KEY] = _fixed_list(pa, state, np.float32)
        columns[ACTION_KEY] = _fixed_list(pa, target, np.float32)
        scalars = {"timestamp": (frame_index / layout.fps).astype(np.float32),
                   "frame_index": frame_index,
                   "episode_index": np.full(n, ep_index, np.int64),
                   "index": start + frame_index,
                   "task_index": np.zeros(n, np.int64)}
        columns.update({k: pa.array(v) for k, v in scalars.items()})
        table = pa.table(columns)
        data.roll_if_full(data.path().stat().st_size if data.handle else 0)
        if data.handle is None:
            data.path().parent.mkdir(parents=True, exist_ok=True)
            data.handle = pq.ParquetWriter(data.path(), table.schema, compression=compression)
        data.handle.write_table(table)
        # statistics, per episode as LeRobot keeps them
        ep_stats = {layout.video_key: plane_stats(np.moveaxis(rgb, -1, 1), 1 / 255)}
        if events is not None:
            ep_stats[EVENTS_KEY] = plane_stats(events)
        if state is not None:
            ep_stats[STATE_KEY] = vector_stats(state)
        ep_stats[ACTION_KEY] = vector_stats(target)
        for key, v in scalars.items():
            ep_stats[key] = vector_stats(v[:, None])
        stats_parts.append(ep_stats)
        row = {"episode_index": ep_index, "tasks": [task_text], "length": n,
               "data/chunk_index": data.chunk, "data/file_index": data.file,
               "dataset_from_index": start, "dataset_to_index": start + n,
               f"videos/{layout.video_key}/chunk_index": videos.chunk,
               f"videos/{layout.video_key}/file_index": videos.file,
               f"videos/{layout.video_key}/from_timestamp": video_start / layout.fps,
               f"videos/{layout.video_key}/to_timestamp": (video_start + n) / layout.fps,
               "meta/episodes/chunk_index": 0, "meta/episodes/file_index": 0}
        for feat, s in ep_stats.items():
            for k, v in s.items():
                row[f"stats/{feat}/{k}"] = np.asarray(v).tolist()
        rows.append(row)
        start += n
        video_start += n
    videos.handle.close()
    data.handle.close()
    episodes_table = pa.Table.from_pylist(rows)
    (root / EPISODES_PATH).parent.mkdir(parents=True, exist_ok=True)
    pq.write_table(episodes_table, root / EPISODES_PATH, compression=compression)
    pq.write_table(_tasks_table(pa, [task_text]), root / TASKS_PATH)
    stats = {feat: aggregate_stats([p[feat] for p in stats_parts]) for feat in stats_parts[0]}
    (root / STATS_PATH).write_text(json.dumps(_jsonable(stats), indent=2))
    info = {"codebase_version": CODEBASE_VERSION, "robot_type": ROBOT_TYPE.get(layout.task, f"sebvs_{layout.task}"),
            "total_episodes": len(episodes), "total_frames": start, "total_tasks": 1,
            "chunks_size": CHUNKS_SIZE, "data_files_size_in_mb": DATA_FILE_MB,
            "video_files_size_in_mb": VIDEO_FILE_MB, "fps": layout.fps,
            "splits": {"train": f"0:{len(episodes)}"}, "data_path": DATA_PATH,
            "video_path": VIDEO_PATH, "features": _features(layout, codec)}
    (root / INFO_PATH).write_text(json.dumps(info, indent=4))
    return {"sebvs": sebvs.__version__, "complete": True, "episodes": sources,
            "encoder": {"backend": backend, "codec": codec}, "events": event_info}


def _is_our_export(path: Path) -> bool:
    try:
        return "sebvs" in json.loads((path / MARKER).read_text())
    except (OSError, ValueError, TypeError):
        return False


def check_target(out: Path, source: Path, force: bool) -> None:
    """Refuse an output folder that exists (one line), unless ``force`` and it is an
    earlier LeRobot export of sebvs (meta/sebvs_export.json); never the source or a folder
    that holds it."""
    src = source.resolve()
    if out.resolve() == src or out.resolve() in src.parents:
        raise OutputRefused(f"{out}: refused, it holds this command's input {source}")
    for p in (out, out.with_name(out.name + PARTIAL)):
        if not (p.exists() or p.is_symlink()):
            continue
        if not force:
            what = ("exists (left by an interrupted export?)" if p != out else "exists")
            raise OutputRefused(f"{p}: {what}; give a new folder, or --force to replace an "
                                f"earlier LeRobot export there")
        if not p.is_dir() or p.is_symlink() or not _is_our_export(p):
            raise OutputRefused(f"{p}: refused, it is not a LeRobot export of sebvs "
                                f"(no {MARKER}); --force replaces only those")


def export_lerobot(source: str | Path, out: str | Path | None = None, progress: bool = True,
                   force: bool = False, compression: str = "zstd",
                   encoder: str = "auto") -> dict:
    """Export a dataset directory (or one episode file) as a LeRobotDataset v3.0 folder.

    Parameters:
        source: dataset directory (index.json) or one episode .h5 file.
        out: the folder to make (default ``<dataset>/lerobot``, or ``<episode>_lerobot``
            beside one episode); it must not exist, except with ``force`` when it is an
            earlier export of this command.
        progress: show a progress bar.
        force: replace an earlier LeRobot export of sebvs at ``out``.
        compression: parquet compression, "zstd", "lz4" or "none".
        encoder: the video encoder, "auto" (PyAV if installed, else OpenCV), "pyav" or
            "opencv" (VideoFile).

    Returns:
        A summary: episodes, frames, fps, features, the video codec, bytes, out, notes
        (one line each on what the export leaves out).

    Raises:
        ValueError / OutputRefused / OSError: one line naming what is wrong; MissingExtra
        when pyarrow is not installed. Nothing is left at ``out`` then.
    """
    require("pyarrow.parquet", "pyarrow", "lerobot", "--format lerobot")
    if compression not in PARQUET_COMPRESSION:
        raise ValueError(f"compression {compression!r}: expected {', '.join(PARQUET_COMPRESSION)}")
    pick_encoder(encoder)
    source = Path(source)
    episodes = episodes_of(source)
    if not episodes:
        raise ValueError(f"{source}: the dataset has no episodes")
    if out is None:
        out = source / "lerobot" if source.is_dir() else source.with_name(source.stem + "_lerobot")
    out = Path(out)
    check_target(out, source, force)
    layout, notes = plan(episodes)
    partial = out.with_name(out.name + PARTIAL)
    if partial.exists():
        shutil.rmtree(partial)          # an earlier export's, check_target made sure
    try:
        (partial / "meta").mkdir(parents=True)
    except OSError as exc:
        raise OSError(f"{out}: cannot make the folder ({exc.strerror})") from None
    (partial / MARKER).write_text(json.dumps({"sebvs": sebvs.__version__, "complete": False}))
    try:
        with tqdm(total=sum(layout.frames), unit="frame", disable=not progress,
                  desc="export lerobot") as bar:
            marker = _write_dataset(partial, episodes, layout, encoder,
                                    PARQUET_COMPRESSION[compression], bar)
        marker["source"] = str(source)
        (partial / MARKER).write_text(json.dumps(marker, indent=2, default=str))
        if out.exists():                # an earlier export of ours, --force
            old = out.with_name(out.name + ".old")
            if old.exists():
                shutil.rmtree(old)
            os.replace(out, old)
            os.replace(partial, out)
            shutil.rmtree(old)
        else:
            os.replace(partial, out)
    except BaseException:
        shutil.rmtree(partial, ignore_errors=True)
        raise
    size = sum(f.stat().st_size for f in out.rglob("*") if f.is_file())
    info = json.loads((out / INFO_PATH).read_text())
    return {"format": "lerobot", "codebase_version": CODEBASE_VERSION,
            "episodes": len(episodes), "frames": sum(layout.frames), "fps": layout.fps,
            "features": sorted(info["features"]),
            "video_codec": info["features"][layout.video_key]["info"]["video.codec"],
            "bytes": size, "out": str(out), "notes": notes}

