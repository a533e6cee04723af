"""`sebvs data export --format mcap`: episodes as ROS 2 bags in MCAP (docs/formats.md).

One .mcap per episode, named as the episode (episode_0003.h5 -> episode_0003.mcap): an
episode is the unit the dataset, `ros2 bag play` and Foxglove's timeline all work in, and
each episode's clock starts where its run's did. Topics (frame ids in brackets):

    /camera/image_raw  sensor_msgs/msg/Image             rgb8, every frame [camera]
    /events            event_camera_msgs/msg/EventPacket "mono" encoding, one packet per
                                                         frame that has raw events [camera]
    /events/frame      sensor_msgs/msg/Image             the recorded event frame, counts as
                                                         8UC<channels> (ON..., OFF...)
    /events/image      sensor_msgs/msg/Image             the same, as an ON blue / OFF red
                                                         rgb8 picture to look at
    /cmd_vel           geometry_msgs/msg/Twist           nav: [v, w] in m/s and rad/s
    /cmd_pose          geometry_msgs/msg/PoseStamped     arm: the pre-grasp pose [world]
    /tf                tf2_msgs/msg/TFMessage            world -> base_link, target (nav),
                                                         tcp, expert_pose (arm), from truth

Every message is logged at its frame's simulation time (t_sim); headers carry the same,
except an event packet's, which carries its first event's time. The episode's attributes
go into the file's metadata record "sebvs".

The "mono" encoding of ros-event-camera (event_camera_codecs decodes it) is one
little-endian 64-bit word per event: bit 63 polarity (1 = ON), bits 48-62 y, bits 32-47 x,
bits 0-31 the event's time minus the packet's time_base, in ns.
"""
from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np
from tqdm import tqdm

from ..dataset_files import verify_entries, verify_file
from ..dvs.emulator import EVENT_DTYPE
from ..h5named import open_h5
from ..extras import require
from .episode import open_episode
from .ros2_msgs import schema_text

RGB_TOPIC = "/camera/image_raw"
EVENTS_TOPIC = "/events"
EVENT_FRAME_TOPIC = "/events/frame"
EVENT_IMAGE_TOPIC = "/events/image"
TWIST_TOPIC = "/cmd_vel"
POSE_TOPIC = "/cmd_pose"
TF_TOPIC = "/tf"
WORLD, CAMERA = "world", "camera"
EVENT_ENCODING = "mono"
UINT32_SPAN = (1 << 32) - 1     # a mono packet's dt field: ~4.29 s of nanoseconds

# truth/<name> -> (tf child frame, layout of the row): the poses episodes carry
POSE_FRAMES = {"robot": ("base_link", "xy_yaw"),        # nav: robot base [x, y, yaw]
               "target": ("target", "xyz"),             # nav: target cube centre
               "tcp": ("tcp", "xyz"),                   # arm: tool centre point
               "expert_pose": ("expert_pose", "xyz_rpy")}  # arm: where the expert aims
LAYOUT_WIDTH = {"xy_yaw": 3, "xyz": 3, "xyz_rpy": 6}
MSG_TYPES = {RGB_TOPIC: "sensor_msgs/msg/Image", EVENTS_TOPIC: "event_camera_msgs/msg/EventPacket",
             EVENT_FRAME_TOPIC: "sensor_msgs/msg/Image", EVENT_IMAGE_TOPIC: "sensor_msgs/msg/Image",
             TWIST_TOPIC: "geometry_msgs/msg/Twist", POSE_TOPIC: "geometry_msgs/msg/PoseStamped",
             TF_TOPIC: "tf2_msgs/msg/TFMessage"}


# --- event packets --------------------------------------------------------------------
def pack_mono(ev: np.ndarray) -> tuple[int, bytes]:
    """(time_base ns, payload) of time-ordered events spanning at most UINT32_SPAN ns."""
    base = int(ev["t"][0])
    dt = (ev["t"] - base).astype(np.uint64)
    if ev.size and int(dt[-1]) > UINT32_SPAN:
        raise ValueError("a mono packet spans at most 2**32 - 1 ns")
    words = (dt | (ev["x"].astype(np.uint64) << np.uint64(32))
             | ((ev["y"].astype(np.uint64) & np.uint64(0x7FFF)) << np.uint64(48))
             | ((ev["p"] > 0).astype(np.uint64) << np.uint64(63)))
    return base, words.astype("<u8").tobytes()


def unpack_mono(time_base: int, payload: bytes) -> np.ndarray:
    """EVENT_DTYPE events (t in ns, p +1/-1) of a "mono" EventPacket's payload."""
    words = np.frombuffer(payload, "<u8")
    ev = np.zeros(words.size, EVENT_DTYPE)
    ev["t"] = (words & np.uint64(0xFFFFFFFF)).astype(np.int64) + int(time_base)
    ev["x"] = (words >> np.uint64(32)) & np.uint64(0xFFFF)
    ev["y"] = (words >> np.uint64(48)) & np.uint64(0x7FFF)
    ev["p"] = np.where(words >> np.uint64(63), 1, -1)
    return ev


def split_packets(ev: np.ndarray) -> list[np.ndarray]:
    """Time-ordered events cut where one packet's dt would overflow (never, at control
    rates: a frame's events span one control period)."""
    out, lo = [], 0
    while lo < ev.size:
        hi = int(np.searchsorted(ev["t"], int(ev["t"][lo]) + UINT32_SPAN, side="right"))
        out.append(ev[lo:hi])
        lo = hi
    return out


# --- small message builders -----------------------------------------------------------
def _stamp(t_ns: int) -> dict:
    return {"sec": int(t_ns // 1_000_000_000), "nanosec": int(t_ns % 1_000_000_000)}


def _header(t_ns: int, frame: str) -> dict:
    return {"stamp": _stamp(t_ns), "frame_id": frame}


def _image(t_ns: int, hwc: np.ndarray, encoding: str) -> dict:
    hwc = np.ascontiguousarray(hwc, np.uint8)
    h, w = hwc.shape[:2]
    return {"header": _header(t_ns, CAMERA), "height": h, "width": w, "encoding": encoding,
            "is_bigendian": 0, "step": w * (hwc.shape[2] if hwc.ndim == 3 else 1),
            "data": hwc.tobytes()}


def quaternion_rpy(roll: float, pitch: float, yaw: float) -> dict:
    """Quaternion of R = Rz(yaw) Ry(pitch) Rx(roll), the arm's convention (sebvs/sim/ik.py)
    and ROS's fixed-axis roll-pitch-yaw."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return {"x": sr * cp * cy - cr * sp * sy, "y": cr * sp * cy + sr * cp * sy,
            "z": cr * cp * sy - sr * sp * cy, "w": cr * cp * cy + sr * sp * sy}


def _pose_parts(row: np.ndarray, layout: str) -> tuple[dict, dict]:
    """(translation {x, y, z}, rotation quaternion) of one truth row."""
    if layout == "xy_yaw":
        return {"x": row[0], "y": row[1], "z": 0.0}, quaternion_rpy(0.0, 0.0, row[2])
    rot = quaternion_rpy(*row[3:6]) if layout == "xyz_rpy" else quaternion_rpy(0, 0, 0)
    return {"x": row[0], "y": row[1], "z": row[2]}, rot


def _nav_scale(attrs: dict) -> tuple[float, float]:
    """(v_max m/s, w_max rad/s) the episode's [v, w] commands were scaled by in the sim:
    its conditions, else its topology's sim config, else the nav scene's defaults."""
    cond = attrs.get("conditions") if isinstance(attrs.get("conditions"), dict) else {}
    config: dict = {}
    topo = attrs.get("topology") if isinstance(attrs.get("topology"), dict) else {}
    for actor in (topo.get("content") or {}).get("actors", {}).values():
        if isinstance(actor, dict) and actor.get("scene") == "nav":
            config = actor.get("config") or {}
    from ..sim.nav import NavScene
    out = []
    for key in ("v_max", "w_max"):
        value = cond.get(key, config.get(key, NavScene.defaults[key]))
        out.append(float(value))
    return out[0], out[1]


def _metadata(ep, v_w: tuple[float, float] | None) -> dict[str, str]:
    meta = {k: v if isinstance(v, str) else json.dumps(v, default=str)
            for k, v in ep.attrs.items()}
    meta["source"] = ep.path.name
    meta["event_encoding"] = EVENT_ENCODING
    if v_w is not None:
        meta["v_max"], meta["w_max"] = (repr(v) for v in v_w)
    return meta


# --- one episode ----------------------------------------------------------------------
def _pose_columns(ep) -> list[tuple[str, str, np.ndarray]]:
    """(child frame, layout, [T, width] array) of the truth columns that are poses."""
    cols = []
    for name, (child, layout) in POSE_FRAMES.items():
        ds = ep.truth.get(name)
        if ds is not None and ds.ndim == 2 and ds.shape[1] == LAYOUT_WIDTH[layout]:
            cols.append((child, layout, ds[:]))
    return cols


def export_episode(path: str | Path, out: str | Path, bar=None,
                   compression: str = "zstd") -> dict[str, int]:
    """Write episode ``path`` as MCAP ``out`` (via ``<out>.partial``); returns the message
    count per topic. ``bar``: a tqdm bar advanced by one per frame."""
    writer_mod = require("mcap_ros2.writer", "mcap-ros2-support", "formats", "--format mcap")
    from mcap.writer import CompressionType
    from ..dvs.render import event_image

    path, out = Path(path), Path(out)
    check_episode_file(path)
    ep = open_episode(path)
    partial = out.with_name(out.name + ".partial")
    counts: dict[str, int] = {}
    try:
        n = len(ep)
        t_ns = np.round(np.asarray(ep.t_sim[:], np.float64) * 1e9).astype(np.int64)
        target = np.asarray(ep.target[:], np.float64)
        v_w = _nav_scale(ep.attrs) if ep.task == "nav" else None
        poses = _pose_columns(ep)
        raw = ep.raw_events
        offsets = raw["offset"][:] if raw is not None else None
        width, height = _event_sensor(ep)
        with open(partial, "wb") as fh:
            w = writer_mod.Writer(fh, compression=CompressionType[compression.upper()])
            schemas: dict[str, object] = {}

            def write(topic: str, msg: dict, t: int) -> None:
                if topic not in schemas:
                    schemas[topic] = w.register_msgdef(MSG_TYPES[topic],
                                                       schema_text(MSG_TYPES[topic]))
                w.write_message(topic, schemas[topic], msg, log_time=t, publish_time=t,
                                sequence=counts.get(topic, 0))
                counts[topic] = counts.get(topic, 0) + 1

            w.add_metadata("sebvs", _metadata(ep, v_w))
            for k in range(n):
                t = int(t_ns[k])
                write(RGB_TOPIC, _image(t, ep.rgb[k], "rgb8"), t)
                if raw is not None and offsets[k + 1] > offsets[k]:
                    ev = _raw_slice(raw, int(offsets[k]), int(offsets[k + 1]))
                    for part in split_packets(ev):
                        base, payload = pack_mono(part)
                        write(EVENTS_TOPIC, {
                            "header": _header(base, CAMERA), "height": height,
                            "width": width, "seq": counts.get(EVENTS_TOPIC, 0),
                            "time_base": base, "encoding": EVENT_ENCODING,
                            "is_bigendian": False, "events": payload}, t)
                if ep.event_frame is not None:
                    frame = ep.event_frame[k]
                    write(EVENT_FRAME_TOPIC, _image(t, frame.transpose(1, 2, 0),
                                                    f"8UC{frame.shape[0]}"), t)
                    bins = frame.shape[0] // 2        # ON bins, then OFF bins
                    on_off = np.stack([frame[:bins].sum(0), frame[bins:].sum(0)])
                    write(EVENT_IMAGE_TOPIC, _image(t, event_image(on_off), "rgb8"), t)
                if ep.task == "nav":
                    v, wz = np.clip(target[k], -1.0, 1.0)     # as the sim applies them
                    write(TWIST_TOPIC, {"linear": {"x": float(v) * v_w[0], "y": 0.0, "z": 0.0},
                                        "angular": {"x": 0.0, "y": 0.0,
                                                    "z": float(wz) * v_w[1]}}, t)
                else:
                    pos, rot = _pose_parts(target[k], "xyz_rpy")
                    write(POSE_TOPIC, {"header": _header(t, WORLD),
                                       "pose": {"position": pos, "orientation": rot}}, t)
                transforms = []
                for child, layout, col in poses:
                    row = col[k]
                    if np.isfinite(row).all():
                        trans, rot = _pose_parts(row.tolist(), layout)
                        transforms.append({"header": _header(t, WORLD), "child_frame_id": child,
                                           "transform": {"translation": trans,
                                                         "rotation": rot}})
                if transforms:
                    write(TF_TOPIC, {"transforms": transforms}, t)
                if bar is not None:
                    bar.update(1)
            w.finish()
    except BaseException:
        partial.unlink(missing_ok=True)
        raise
    finally:
        ep.close()
    os.replace(partial, out)
    return counts


def _raw_slice(raw: dict, lo: int, hi: int) -> np.ndarray:
    ev = np.zeros(hi - lo, EVENT_DTYPE)
    for key in ("x", "y", "t", "p"):
        ev[key] = raw[key][lo:hi]
    return ev


def _event_sensor(ep) -> tuple[int, int]:
    """(width, height) of the event sensor: the recorded event_sensor attribute, else the
    event frame's size, else the RGB frame's."""
    sensor = ep.attrs.get("event_sensor")
    if sensor is not None and np.size(sensor) == 2:
        w, h = (int(v) for v in np.ravel(sensor))
        return w, h
    if ep.event_frame is not None:
        h, w = ep.event_frame.shape[-2:]      # [T, C, H, W]
    else:
        h, w = ep.rgb.shape[1:3]              # [T, H, W, 3]
    return int(w), int(h)


# --- a dataset ------------------------------------------------------------------------
def check_episode_file(path: Path) -> None:
    """ValueError (one line) unless ``path`` is an episode file."""
    import h5py
    if not h5py.is_hdf5(path):
        raise ValueError(f"{path}: not an episode file (not HDF5)")
    with open_h5(path) as f:
        if "rgb" not in f or not ("action" in f or "pose" in f):
            hint = ("; an event file: `sebvs events export` takes it" if "events/x" in f
                    else "")
            raise ValueError(f"{path}: not an episode file (no rgb and action/pose){hint}")


def episodes_of(source: Path) -> list[Path]:
    """The episode files of a dataset directory (in index order) or the one file given,
    each checked against its index first (sebvs/dataset_files.py): a damaged episode is
    refused by name before anything is written."""
    if source.is_file():
        check_episode_file(source)
        verify_file(source)
        return [source]
    if source.is_dir():
        from .index import INDEX, DatasetIndex
        if not (source / INDEX).exists():
            raise ValueError(f"{source}: not a dataset (no {INDEX})")
        index = DatasetIndex(source)
        verify_entries(source, index.episodes())
        return index.episode_paths()
    raise ValueError(f"{source}: no such file or folder")


def export_mcap(source: str | Path, out: str | Path | None = None, progress: bool = True,
                compression: str = "zstd", force: bool = False) -> dict:
    """Export a dataset directory (one .mcap per episode into ``out``, default
    ``<dataset>/mcap/``) or one episode file (into ``out``: a file, or a folder to put
    ``<episode>.mcap`` in; default beside the episode). Returns a summary.

    Every target is checked before anything is written (sebvs/output_guard.py): an
    existing .mcap is replaced only with ``force``; an episode, a dataset's index or the
    source itself never. A target must end in .mcap, so that what it holds is what its
    name says."""
    from ..output_guard import OutputRefused, check_output_file
    require("mcap_ros2.writer", "mcap-ros2-support", "formats", "--format mcap")
    source = Path(source)
    episodes = episodes_of(source)
    if not episodes:
        raise ValueError(f"{source}: the dataset has no episodes")
    if source.is_dir():
        out_dir = Path(out) if out is not None else source / "mcap"
        if out_dir.exists() and not out_dir.is_dir():
            raise ValueError(f"{out_dir}: a file; a dataset exports to a folder")
        try:
            out_dir.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise OSError(f"{out_dir}: cannot make the folder ({exc.strerror})") from None
        targets = [out_dir / (p.stem + ".mcap") for p in episodes]
    else:
        o = Path(out) if out is not None else source.with_suffix(".mcap")
        targets = [o / (source.stem + ".mcap") if o.is_dir() else o]
    for target in targets:
        check_output_file(target, inputs=episodes, force=force)
        if target.suffix != ".mcap":
            raise OutputRefused(f"{target}: an MCAP file's name must end in .mcap")
    _check_writable(targets[0])       # before the bar: an unwritable place in one line
    frames = _frame_total(source, episodes)
    topics: dict[str, int] = {}
    with tqdm(total=frames, unit="frame", disable=not progress, desc="export mcap") as bar:
        for ep_path, target in zip(episodes, targets):
            for topic, n in export_episode(ep_path, target, bar, compression).items():
                topics[topic] = topics.get(topic, 0) + n
    size = sum(t.stat().st_size for t in targets)
    return {"episodes": len(targets), "frames": frames, "topics": topics, "bytes": size,
            "out": str(targets[0] if source.is_file() else targets[0].parent)}


def _check_writable(target: Path) -> None:
    probe = target.with_name(target.name + ".partial")
    try:
        with open(probe, "wb"):
            pass
        probe.unlink()
    except OSError as exc:
        raise OSError(f"{target}: cannot write ({exc.strerror})") from None


def _frame_total(source: Path, episodes: list[Path]) -> int | None:
    """Frames to export, for the progress bar (from the index, without opening files)."""
    if source.is_dir():
        from .index import DatasetIndex
        frames = [e.get("frames") for e in DatasetIndex(source).episodes()]
        return sum(frames) if all(isinstance(f, int) for f in frames) else None
    with open_episode(episodes[0]) as ep:
        return len(ep)
