"""The formats event and ROS users read: MCAP (ROS 2) export of episodes, AEDAT4 and the
common DSEC-style HDF5 export of event files, the readers that take them all back, and
the one-line errors (docs/formats.md)."""
import json
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from sebvs.data.episode import EpisodeWriter
from sebvs.data.index import DatasetIndex, make_entry
from sebvs.dvs.emulator import EVENT_DTYPE
from sebvs.dvs.eventfile import detect_format, read_events
from sebvs.dvs.h5io import EventFileWriter

ROOT = Path(__file__).resolve().parents[1]
H, W, T = 24, 32, 9
SENSOR = (16, 12)           # event sensor (w, h): half the RGB size, as the paper's v2e


def sebvs(*args):
    return subprocess.run([sys.executable, "-m", "sebvs.cli", *args], cwd=ROOT,
                          capture_output=True, text=True, timeout=120)


def frame_events(rng, k: int, n: int) -> np.ndarray:
    """n events inside frame k's 100 ms, sorted, ns timestamps not on whole microseconds."""
    ev = np.zeros(n, EVENT_DTYPE)
    ev["t"] = np.sort(rng.integers(k * 10**8, (k + 1) * 10**8, n))
    ev["x"] = rng.integers(0, SENSOR[0], n)
    ev["y"] = rng.integers(0, SENSOR[1], n)
    ev["p"] = rng.choice([-1, 1], n)
    return ev


def write_episode(path: Path, task: str, seed: int = 0) -> dict:
    """A small episode with everything an export reads; returns what went in."""
    rng = np.random.default_rng(seed)
    rgb = rng.integers(0, 255, (T, H, W, 3), dtype=np.uint8)
    ev_frames = rng.integers(0, 9, (T, 2, SENSOR[1], SENSOR[0]), dtype=np.uint8)
    target = rng.uniform(-1, 1, (T, 2 if task == "nav" else 6)).astype(np.float32)
    raw = [frame_events(rng, k, 0 if k == 3 else 5 + 7 * k) for k in range(T)]
    attrs = {"scene": task, "conditions": {"v_max": 2.0, "w_max": 0.5}, "seed": seed,
             "event_sensor": list(SENSOR)}
    w = EpisodeWriter(path, task, attrs)
    for k in range(T):
        truth = ({"robot": [0.1 * k, -0.2 * k, 0.3], "target": [2.0, 1.0, 0.25]}
                 if task == "nav" else
                 {"tcp": [0.4, 0.1, 0.3 + 0.01 * k], "expert_pose": [0.5, 0.0, 0.1, np.pi, 0, 0.2],
                  "target": 1})
        if k == 0:
            truth = {}            # no truth in the first frame: no tf message there
        w.append(rgb=rgb[k], event_frame=ev_frames[k], t_sim=0.1 * k, tick=k,
                 truth=truth, raw_events={f: raw[k][f] for f in ("x", "y", "t", "p")},
                 **{"action" if task == "nav" else "pose": target[k]})
    w.finish("time_limit")
    return {"rgb": rgb, "ev_frames": ev_frames, "target": target, "raw": raw}


def make_dataset(root: Path, task: str, episodes: int = 2) -> list[dict]:
    idx = DatasetIndex(root, task)
    made = []
    for i in range(episodes):
        p = idx.path_for(i)
        made.append(write_episode(p, task, seed=i))
        idx.add(make_entry(p))
    return made


def read_mcap(path: Path) -> dict[str, list]:
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    out: dict[str, list] = {}
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for schema, channel, message, ros in reader.iter_decoded_messages():
            out.setdefault(channel.topic, []).append((schema.name, message.log_time, ros))
    return out


# --- MCAP ------------------------------------------------------------------------------
@pytest.mark.parametrize("task", ["nav", "arm"])
def test_mcap_export_has_every_topic_count_and_payload(tmp_path, task):
    from sebvs.data.export_mcap import unpack_mono
    made = make_dataset(tmp_path / "ds", task)
    r = sebvs("data", "export", str(tmp_path / "ds"), "--format", "mcap", "--quiet")
    assert r.returncode == 0, r.stderr
    info = json.loads(r.stdout)
    assert info["episodes"] == 2 and info["frames"] == 2 * T
    files = sorted((tmp_path / "ds" / "mcap").glob("*.mcap"))
    assert [f.name for f in files] == ["episode_0000.mcap", "episode_0001.mcap"]
    got = read_mcap(files[1])
    src = made[1]
    cmd = "/cmd_vel" if task == "nav" else "/cmd_pose"
    with_events = sum(1 for ev in src["raw"] if ev.size)
    assert {t: len(m) for t, m in got.items()} == {
        "/camera/image_raw": T, "/events": with_events, "/events/frame": T,
        "/events/image": T, cmd: T, "/tf": T - 1}
    assert got["/camera/image_raw"][0][0] == "sensor_msgs/msg/Image"
    assert got["/events"][0][0] == "event_camera_msgs/msg/EventPacket"
    assert got["/tf"][0][0] == "tf2_msgs/msg/TFMessage"
    # images: the episode's bytes, stamped with the frame's simulation time
    for k, (_, log_time, img) in enumerate(got["/camera/image_raw"]):
        assert (img.encoding, img.height, img.width, img.step) == ("rgb8", H, W, 3 * W)
        assert bytes(img.data) == src["rgb"][k].tobytes()
        assert log_time == round(0.1 * k * 1e9)
        assert img.header.stamp.sec * 10**9 + img.header.stamp.nanosec == log_time
    frame = got["/events/frame"][4][2]
    assert frame.encoding == "8UC2"
    np.testing.assert_array_equal(
        np.frombuffer(bytes(frame.data), np.uint8).reshape(SENSOR[1], SENSOR[0], 2),
        src["ev_frames"][4].transpose(1, 2, 0))
    # events: every packet decodes to the frame's events, nanoseconds intact
    packets = got["/events"]
    assert all(p.encoding == "mono" and (p.width, p.height) == SENSOR for _, _, p in packets)
    decoded = np.concatenate([unpack_mono(p.time_base, bytes(p.events)) for _, _, p in packets])
    np.testing.assert_array_equal(decoded, np.concatenate(src["raw"]))
    assert [p.seq for _, _, p in packets] == list(range(len(packets)))
    # commands and poses
    if task == "nav":
        tw = got["/cmd_vel"][2][2]
        v, w = np.clip(src["target"][2], -1, 1)
        assert tw.linear.x == pytest.approx(2.0 * v) and tw.angular.z == pytest.approx(0.5 * w)
        tf = got["/tf"][0][2].transforms
        assert [x.child_frame_id for x in tf] == ["base_link", "target"]
        base = tf[0].transform
        assert base.translation.x == pytest.approx(0.1) and base.rotation.z == pytest.approx(
            np.sin(0.15))
    else:
        pose = got["/cmd_pose"][2][2]
        assert pose.header.frame_id == "world"
        assert pose.pose.position.z == pytest.approx(float(src["target"][2][2]))
        q = pose.pose.orientation
        assert q.x ** 2 + q.y ** 2 + q.z ** 2 + q.w ** 2 == pytest.approx(1.0)
        tf = got["/tf"][0][2].transforms       # truth "target" is an index here: no frame
        assert [x.child_frame_id for x in tf] == ["tcp", "expert_pose"]
        assert tf[1].transform.rotation.x == pytest.approx(np.cos(0.1))   # roll pi, yaw 0.2


def test_mcap_one_episode_to_a_file_and_metadata(tmp_path):
    from mcap.reader import make_reader
    ep = tmp_path / "episode_0000.h5"
    write_episode(ep, "nav")
    out = tmp_path / "one.mcap"
    r = sebvs("data", "export", str(ep), "--out", str(out), "--quiet", "--compression", "lz4")
    assert r.returncode == 0, r.stderr
    with open(out, "rb") as f:
        reader = make_reader(f)
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
        summary = reader.get_summary()
    assert meta["sebvs"]["task"] == "nav" and meta["sebvs"]["v_max"] == "2.0"
    assert summary.statistics.message_count == 6 * T - 1 - 1   # no events at k=3, no tf at 0
    assert not list(tmp_path.glob("*.partial"))


def test_quaternion_matches_the_arms_rotation():
    from sebvs.data.export_mcap import quaternion_rpy
    from sebvs.sim.ik import rpy_to_mat
    rpy = (0.3, -0.7, 2.1)
    q = quaternion_rpy(*rpy)
    x, y, z, w = q["x"], q["y"], q["z"], q["w"]
    R = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                  [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                  [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
    np.testing.assert_allclose(R, rpy_to_mat(*rpy), atol=1e-12)


def test_mono_packets_split_before_the_dt_field_overflows():
    from sebvs.data.export_mcap import pack_mono, split_packets, unpack_mono
    ev = np.zeros(4, EVENT_DTYPE)
    ev["t"] = [0, 2**32 - 1, 2**32, 3 * 2**32]
    ev["x"], ev["y"], ev["p"] = [1, 65535, 3, 4], [5, 32767, 7, 8], [1, -1, 1, -1]
    parts = split_packets(ev)
    assert [p.size for p in parts] == [2, 1, 1]
    back = np.concatenate([unpack_mono(*pack_mono(p)) for p in parts])
    np.testing.assert_array_equal(back, ev)


# --- event files ------------------------------------------------------------------------
def write_event_file(path: Path, n: int = 5000, seed: int = 0) -> np.ndarray:
    """Our own HDF5 layout (microseconds, as `sebvs v2e` writes it); returns the events as
    read_events gives them back (absolute ns)."""
    rng = np.random.default_rng(seed)
    ev = np.zeros(n, EVENT_DTYPE)
    ev["t"] = np.sort(rng.integers(0, 3 * 10**6, n)) * 1000 + 7 * 10**9
    ev["x"], ev["y"] = rng.integers(0, 40, n), rng.integers(0, 30, n)
    ev["p"] = rng.choice([-1, 1], n)
    with EventFileWriter(path, 40, 30, {"source": "test"}) as w:
        for part in np.array_split(ev, 7):
            w.append(part)
    back, _ = read_events(path)
    np.testing.assert_array_equal(back, ev)
    return ev


def test_aedat4_export_reads_back_identically_with_dv_processing(tmp_path):
    import dv_processing as dv
    src = tmp_path / "ev.h5"
    ev = write_event_file(src)
    out = tmp_path / "ev.aedat4"
    r = sebvs("events", "export", str(src), "--format", "aedat4", "--out", str(out), "--quiet")
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["events"] == ev.size
    rec = dv.io.MonoCameraRecording(str(out))          # dv-processing's own reader
    assert tuple(rec.getEventResolution()) == (40, 30)
    batches = []
    while (b := rec.getNextEventBatch()) is not None:
        batches.append(b.numpy())
    got = np.concatenate(batches)
    np.testing.assert_array_equal(got["timestamp"], ev["t"] // 1000)
    np.testing.assert_array_equal(got["x"], ev["x"])
    np.testing.assert_array_equal(got["y"], ev["y"])
    np.testing.assert_array_equal(got["polarity"], ev["p"] > 0)
    back, attrs = read_events(out)                     # and through our reader
    np.testing.assert_array_equal(back, ev)
    assert attrs["format"] == "aedat4" and (attrs["width"], attrs["height"]) == (40, 30)


def test_common_h5_export_round_trips_and_has_the_dsec_layout(tmp_path):
    src = tmp_path / "ev.h5"
    ev = write_event_file(src)
    out = tmp_path / "dsec.h5"
    r = sebvs("events", "export", str(src), "--format", "h5", "--out", str(out), "--quiet")
    assert r.returncode == 0, r.stderr
    with h5py.File(out, "r") as f:
        assert {k: f["events"][k].dtype.str for k in "xytp"} == {
            "x": "<u2", "y": "<u2", "t": "<u4", "p": "|u1"}
        t_offset = int(f["t_offset"][()])
        t = f["events/t"][:].astype(np.int64)
        np.testing.assert_array_equal(t + t_offset, ev["t"] // 1000)
        np.testing.assert_array_equal(f["events/p"][:], (ev["p"] > 0).astype(np.uint8))
        idx = f["ms_to_idx"][:]
        assert idx[0] == 0 and np.all(t[idx[5]:] >= 5000) and np.all(t[:idx[5]] < 5000)
        assert f["events/t"].compression == "gzip"
    back, attrs = read_events(out)
    np.testing.assert_array_equal(back, ev)
    assert attrs["format"] == "common-h5"
    part, _ = read_events(out, 100, 200)
    ref, _ = read_events(src, 100, 200)
    np.testing.assert_array_equal(part, ref)


def test_episode_events_export_and_every_format_shows(tmp_path):
    ep = tmp_path / "episode_0000.h5"
    made = write_episode(ep, "nav")
    raw = np.concatenate(made["raw"])
    assert detect_format(ep) == "episode"
    files = {}
    for fmt, name in (("aedat4", "ep.aedat4"), ("h5", "ep_dsec.h5")):
        files[fmt] = tmp_path / name
        r = sebvs("events", "export", str(ep), "--out", str(files[fmt]), "--quiet")
        assert r.returncode == 0, r.stderr
        back, attrs = read_events(files[fmt])
        np.testing.assert_array_equal(back["t"], raw["t"] // 1000 * 1000)   # microseconds
        np.testing.assert_array_equal(back[["x", "y", "p"]], raw[["x", "y", "p"]])
        assert (attrs["width"], attrs["height"]) == SENSOR
    for f in (files["aedat4"], files["h5"], ep):
        png = tmp_path / (f.name + ".png")
        r = sebvs("events", "show", str(f), "--out", str(png), "--frames", "2",
                  "--window-ms", "200")
        assert r.returncode == 0, r.stderr
        assert png.stat().st_size > 2000


# --- errors -------------------------------------------------------------------------------
def test_errors_are_one_line_and_exit_2(tmp_path):
    ep = tmp_path / "episode_0000.h5"
    write_episode(ep, "arm")
    ev = tmp_path / "ev.h5"
    write_event_file(ev, 100)
    junk = tmp_path / "junk.h5"
    junk.write_text("not hdf5")
    (tmp_path / "plain").mkdir()
    cases = [
        (("data", "export", str(tmp_path / "missing")), "no such file"),
        (("data", "export", str(tmp_path / "plain")), "not a dataset"),
        (("data", "export", str(ev)), "not an episode file"),
        (("data", "export", str(ep), "--out", "/proc/nope/x.mcap"), "x.mcap"),
        (("events", "export", str(tmp_path / "missing.h5"), "--out", str(tmp_path / "o.h5")),
         "no such file"),
        (("events", "export", str(junk), "--out", str(tmp_path / "o.h5")), "not an event file"),
        (("events", "export", str(ev), "--out", str(tmp_path / "o.bin")), "--format"),
        (("events", "export", str(ev), "--out", str(tmp_path / "o.dat"), "--format", "aedat4"),
         "must end in .aedat4"),
        (("events", "export", str(ev), "--out", "/proc/nope/o.h5"), "o.h5"),
        (("events", "show", str(junk), "--out", str(tmp_path / "s.png")), "not an event file"),
    ]
    for args, said in cases:
        r = sebvs(*args)
        lines = r.stderr.strip().splitlines()
        assert r.returncode == 2 and len(lines) == 1 and said in lines[0], (args, r.stderr)
    assert not list(tmp_path.glob("*partial*"))


def test_missing_extras_name_the_extra(tmp_path, monkeypatch):
    from sebvs.data.export_mcap import export_mcap
    from sebvs.dvs.export import export_events
    from sebvs.extras import MissingExtra
    ev = tmp_path / "ev.h5"
    write_event_file(ev, 50)
    aedat = tmp_path / "ev.aedat4"
    export_events(ev, aedat, progress=False)
    ep = tmp_path / "episode_0000.h5"
    write_episode(ep, "nav")
    monkeypatch.setitem(sys.modules, "dv_processing", None)
    monkeypatch.setitem(sys.modules, "mcap_ros2.writer", None)
    with pytest.raises(MissingExtra, match=r"needs dv-processing: pip install 'sebvs\[formats\]'"):
        export_events(ev, tmp_path / "x.aedat4", progress=False)
    with pytest.raises(MissingExtra, match="needs dv-processing"):
        read_events(aedat)
    with pytest.raises(MissingExtra,
                       match=r"needs mcap-ros2-support: pip install 'sebvs\[formats\]'"):
        export_mcap(ep, tmp_path / "x.mcap", progress=False)
    export_events(ev, tmp_path / "x.h5", progress=False)      # the h5 layout needs neither
    assert not (tmp_path / "x.aedat4").exists()
