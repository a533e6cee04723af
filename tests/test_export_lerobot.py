"""`sebvs data export --format lerobot`: recorded nav and arm datasets as LeRobotDataset
v3.0, read back frame for frame with pyarrow and a video decoder against the v3.0 layout
(the paths info.json names, the episodes' row and video-time ranges): the same commands
and proprioception, the same event counts, the RGB frames within the codec's error; and
the one-line refusals (docs/formats.md, "LeRobot")."""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pa = pytest.importorskip("pyarrow")
pq = pytest.importorskip("pyarrow.parquet")

from sebvs.cli import main  # noqa: E402
from sebvs.data.episode import EpisodeWriter, open_episode  # noqa: E402
from sebvs.data.export_lerobot import export_lerobot  # noqa: E402
from sebvs.data.index import DatasetIndex, make_entry  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
# the codec's error on a rendered frame (4:2:0, MPEG-4 Part 2 or AV1 at crf 30): measured
# worst frames 3.4 DN mean |error| and 35 dB on the nav scene; single pixels at sharp
# colour edges differ far more (one colour sample per 2 x 2 pixels)
MEAN_ABS_DN, PSNR_DB = 4.0, 30.0
STATS = {"min", "max", "mean", "std", "count", "q01", "q10", "q50", "q90", "q99"}

try:
    import av  # noqa: F401
    ENCODERS = ["opencv", "pyav"]
except ImportError:
    ENCODERS = ["opencv"]


# --- recorded datasets, once per session -----------------------------------------------
@pytest.fixture(scope="session")
def recorded(tmp_path_factory):
    """{task: dataset folder}: nav 2 episodes, arm 1, each 0.5 s (6 frames of 160 x 160
    RGB and event frames, with proprioception) recorded by the shipped topologies."""
    base = tmp_path_factory.mktemp("lerobot_src")
    out = {}
    for task, episodes, extra in (("nav", 2, []), ("arm", 1, ["--set", "sim.randomise={}"])):
        ds = base / task
        assert main(["record", f"topologies/{task}_record.toml", "--episodes", str(episodes),
                     "--out", str(ds), "--runs-dir", str(base / "runs"), "--quiet",
                     "--set", "sim.episode_s=0.5", *extra]) == 0
        out[task] = ds
    return out


# --- a reader of the v3.0 layout: pyarrow and a video decoder --------------------------
def decode_video(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(frames [N, H, W, 3] uint8 RGB, presentation times [N] s) of an mp4."""
    try:
        import av
    except ImportError:
        import cv2
        cap = cv2.VideoCapture(str(path))
        frames, times = [], []
        while True:
            ok, frame = cap.read()
            if not ok:
                break
            times.append(cap.get(cv2.CAP_PROP_POS_MSEC) / 1000)
            frames.append(frame[:, :, ::-1])
        cap.release()
        return np.array(frames), np.array(times)
    with av.open(str(path)) as c:
        decoded = [(f.to_ndarray(format="rgb24"), float(f.pts * f.time_base))
                   for f in c.decode(video=0)]
    return np.array([f for f, _ in decoded]), np.array([t for _, t in decoded])


def column(table, name: str, shape: tuple) -> np.ndarray:
    """A parquet column of scalars, fixed-size lists or nested lists as [N, *shape]."""
    col = table.column(name).combine_chunks()
    while pa.types.is_list(col.type) or pa.types.is_fixed_size_list(col.type):
        col = col.flatten()
    return col.to_numpy(zero_copy_only=False).reshape((len(table),) + tuple(shape))


def read_lerobot(root: Path) -> dict:
    """Every file of a LeRobotDataset v3.0 folder, found through meta/ as LeRobot finds
    them; returns info, stats, tasks, episodes (rows) and per-episode arrays."""
    info = json.loads((root / "meta/info.json").read_text())
    stats = json.loads((root / "meta/stats.json").read_text())
    tasks = pq.read_table(root / "meta/tasks.parquet")
    pandas_meta = json.loads(tasks.schema.metadata[b"pandas"])
    task_text = tasks.column(pandas_meta["index_columns"][0]).to_pylist()
    episodes = pq.read_table(sorted((root / "meta/episodes").glob("*/*.parquet"))[0]).to_pylist()
    feats = info["features"]
    videos = [k for k, f in feats.items() if f["dtype"] == "video"]
    data_files, video_files, out = {}, {}, []
    for ep in episodes:
        key = (ep["data/chunk_index"], ep["data/file_index"])
        if key not in data_files:
            data_files[key] = pq.read_table(root / info["data_path"].format(
                chunk_index=key[0], file_index=key[1]))
        table = data_files[key]
        rows = np.flatnonzero(column(table, "episode_index", ()) == ep["episode_index"])
        part = table.take(pa.array(rows))
        arrays = {name: column(part, name, () if f["shape"] == [1] else f["shape"])
                  for name, f in feats.items() if f["dtype"] != "video"}
        for vkey in videos:
            vk = (vkey, ep[f"videos/{vkey}/chunk_index"], ep[f"videos/{vkey}/file_index"])
            if vk not in video_files:
                video_files[vk] = decode_video(root / info["video_path"].format(
                    video_key=vkey, chunk_index=vk[1], file_index=vk[2]))
            frames, times = video_files[vk]
            t0 = ep[f"videos/{vkey}/from_timestamp"]
            # the frames LeRobot's decoders return: shown at from_timestamp + timestamp
            picked = [int(np.argmin(np.abs(times - (t0 + t)))) for t in arrays["timestamp"]]
            assert np.abs(times[picked] - (t0 + arrays["timestamp"])).max() < 1e-4
            arrays[vkey] = frames[picked]
        out.append(arrays)
    video_frames: dict[str, int] = {}
    for (vkey, _, _), (frames, _) in video_files.items():
        video_frames[vkey] = video_frames.get(vkey, 0) + len(frames)
    return {"info": info, "stats": stats, "tasks": task_text, "episodes": episodes,
            "arrays": out, "video_frames": video_frames}


def source_arrays(ds: Path) -> list[dict]:
    out = []
    for path in DatasetIndex(ds).episode_paths():
        with open_episode(path) as ep:
            out.append({"rgb": ep.rgb[:], "events": ep.event_frame[:], "target": ep.target[:],
                        "proprio": ep.proprio[:], "names": ep.proprio_names, "file": path.name})
    return out


# --- the round trip ----------------------------------------------------------------------
@pytest.mark.parametrize("encoder", ENCODERS)
@pytest.mark.parametrize("task", ["nav", "arm"])
def test_the_export_reads_back_frame_for_frame(recorded, tmp_path, task, encoder):
    out = tmp_path / "lerobot"
    summary = export_lerobot(recorded[task], out, progress=False, encoder=encoder)
    src = source_arrays(recorded[task])
    got = read_lerobot(out)
    info, camera = got["info"], "front" if task == "nav" else "wrist"
    vkey = f"observation.images.{camera}"
    frames = sum(len(s["rgb"]) for s in src)
    assert info["codebase_version"] == "v3.0" and info["fps"] == 10
    assert (info["total_episodes"], info["total_frames"], info["total_tasks"]) == (
        len(src), frames, 1)
    assert info["splits"] == {"train": f"0:{len(src)}"}
    feats = info["features"]
    assert set(feats) == {vkey, "observation.events", "observation.state", "action",
                          "timestamp", "frame_index", "episode_index", "index", "task_index"}
    assert feats[vkey]["dtype"] == "video" and feats[vkey]["shape"] == [160, 160, 3]
    assert feats[vkey]["info"]["video.fps"] == 10
    assert feats[vkey]["info"]["video.codec"] == summary["video_codec"]
    assert feats["observation.events"] == {"dtype": "uint8", "shape": [2, 160, 160],
                                           "names": ["channels", "height", "width"]}
    assert feats["observation.state"]["names"] == list(src[0]["names"])
    assert feats["action"]["shape"] == [2 if task == "nav" else 6]
    assert got["tasks"] and got["episodes"][0]["tasks"] == got["tasks"]
    start = 0
    for e, (row, arrays, s) in enumerate(zip(got["episodes"], got["arrays"], src)):
        n = len(s["rgb"])
        assert (row["episode_index"], row["length"]) == (e, n)
        assert (row["dataset_from_index"], row["dataset_to_index"]) == (start, start + n)
        assert row[f"videos/{vkey}/from_timestamp"] == pytest.approx(start / 10)
        np.testing.assert_array_equal(arrays["index"], start + np.arange(n))
        np.testing.assert_array_equal(arrays["frame_index"], np.arange(n))
        np.testing.assert_allclose(arrays["timestamp"], np.arange(n) / 10, atol=1e-6)
        np.testing.assert_array_equal(arrays["action"], s["target"])        # the commands
        np.testing.assert_array_equal(arrays["observation.state"], s["proprio"])
        np.testing.assert_array_equal(arrays["observation.events"], s["events"])   # counts
        assert s["events"][1:].sum() > 0                   # a real stream, not zeros
        err = np.abs(arrays[vkey].astype(int) - s["rgb"].astype(int))
        mean_abs = err.mean(axis=(1, 2, 3))
        psnr = 10 * np.log10(255.0 ** 2 / np.maximum((err ** 2).mean(axis=(1, 2, 3)), 1e-9))
        assert mean_abs.max() <= MEAN_ABS_DN and psnr.min() >= PSNR_DB, (mean_abs, psnr)
        start += n
    assert got["video_frames"] == {vkey: frames}      # every episode's frames, one file
    # stats.json: every feature, LeRobot's statistics, counts of the whole dataset
    stats = got["stats"]
    assert set(stats) == set(feats) and all(set(s) == STATS for s in stats.values())
    target = np.concatenate([s["target"] for s in src])
    np.testing.assert_allclose(stats["action"]["mean"], target.mean(0), rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(stats["action"]["max"], target.max(0))
    assert stats["action"]["count"] == [frames]
    assert np.shape(stats[vkey]["mean"]) == (3, 1, 1) and 0 <= np.min(stats[vkey]["min"])
    assert np.max(stats[vkey]["max"]) <= 1
    events = np.concatenate([s["events"] for s in src])
    assert np.ravel(stats["observation.events"]["max"]).tolist() == events.max(
        axis=(0, 2, 3)).tolist()
    marker = json.loads((out / "meta/sebvs_export.json").read_text())
    assert [e["file"] for e in marker["episodes"]] == [s["file"] for s in src]
    assert marker["events"]["channels"] == ["on", "off"]


# --- the command and its refusals ----------------------------------------------------------
def small_dataset(root: Path, proprio=(True, True), ticks=(0, 1, 2, 3)) -> Path:
    """Episodes of 4 frames of 8 x 8 (what the refusals need, in milliseconds)."""
    idx = DatasetIndex(root, "nav")
    for i, with_proprio in enumerate(proprio):
        path = idx.path_for(i)
        w = EpisodeWriter(path, "nav", {"scene": "nav", "conditions": {}, "seed": i})
        for k in ticks:
            w.append(rgb=np.full((8, 8, 3), 10 * k, np.uint8), action=[0.1 * k, -0.1],
                     t_sim=0.1 * k, tick=k, event_frame=np.full((2, 4, 4), k, np.uint8),
                     proprio=[1.0, 2.0, 3.0] if with_proprio else None)
        if with_proprio:
            w.set_attrs({"proprio_names": ["a", "b", "c"]})
        w.finish("time_limit")
        idx.add(make_entry(path))
    return root


def run_cli(*args) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "sebvs.cli", "data", "export", *args],
                          cwd=ROOT, capture_output=True, text=True, timeout=120)


def test_the_command_exports_and_refuses_a_path_that_exists_in_one_line(tmp_path):
    ds = small_dataset(tmp_path / "ds")
    out = tmp_path / "lr"
    r = run_cli(str(ds), "--format", "lerobot", "--out", str(out), "--quiet")
    assert r.returncode == 0, r.stderr
    summary = json.loads(r.stdout)
    assert (summary["episodes"], summary["frames"], summary["fps"]) == (2, 8, 10)
    assert (out / "meta/info.json").is_file() and not (tmp_path / "lr.partial").exists()
    before = sorted((p.relative_to(out), p.stat().st_mtime_ns) for p in out.rglob("*"))
    for target in (out, ds):
        r = run_cli(str(ds), "--format", "lerobot", "--out", str(target), "--quiet")
        assert r.returncode == 2 and r.stdout == ""
        assert len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr
        assert r.stderr.startswith(f"sebvs data export: {target}:")
    assert sorted((p.relative_to(out), p.stat().st_mtime_ns) for p in out.rglob("*")) == before
    # --force replaces an earlier export of ours, and nothing else
    assert export_lerobot(ds, out, progress=False, force=True)["frames"] == 8
    one = export_lerobot(ds / "episode_0001.h5", progress=False)     # one episode: beside it
    assert (one["out"], one["episodes"], one["frames"]) == (str(ds / "episode_0001_lerobot"), 1, 4)
    other = tmp_path / "other"
    other.mkdir()
    (other / "keep.txt").write_text("mine")
    r = run_cli(str(ds), "--format", "lerobot", "--out", str(other), "--force", "--quiet")
    assert r.returncode == 2 and "not a LeRobot export of sebvs" in r.stderr
    assert (other / "keep.txt").read_text() == "mine"


def test_episodes_without_proprioception_export_without_observation_state(tmp_path):
    ds = small_dataset(tmp_path / "ds", proprio=(False, False))
    out = tmp_path / "lr"
    r = run_cli(str(ds), "--format", "lerobot", "--out", str(out), "--quiet")
    assert r.returncode == 0, r.stderr
    assert r.stderr.strip().splitlines() == [
        "sebvs data export: note: no observation.state: the episodes hold no proprioception "
        "(recorded before recordings stored it, or without the sim's proprio wired)"]
    feats = json.loads((out / "meta/info.json").read_text())["features"]
    assert "observation.state" not in feats and "observation.events" in feats
    assert "observation.state" not in pq.read_schema(out / "data/chunk-000/file-000.parquet").names


@pytest.mark.parametrize("case, message", [
    ("mixed", "episode_0001.h5: no proprioception, while episode_0000.h5 has it"),
    ("gap", "frame 2 comes 0.2 s after frame 1, not 1/10 s"),
], ids=["mixed_proprio", "missing_frame"])
def test_an_export_that_cannot_be_one_lerobot_dataset_is_refused_in_one_line(
        tmp_path, case, message):
    ds = (small_dataset(tmp_path / "ds", proprio=(True, False)) if case == "mixed"
          else small_dataset(tmp_path / "ds", ticks=(0, 1, 3, 4)))
    out = tmp_path / "lr"
    r = run_cli(str(ds), "--format", "lerobot", "--out", str(out), "--quiet")
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert message in r.stderr and "Traceback" not in r.stderr
    assert not out.exists() and not (tmp_path / "lr.partial").exists()


def test_without_pyarrow_the_export_names_the_extra(tmp_path, monkeypatch, capsys):
    ds = small_dataset(tmp_path / "ds")
    monkeypatch.setitem(sys.modules, "pyarrow.parquet", None)      # import fails
    assert main(["data", "export", str(ds), "--format", "lerobot", "--out",
                 str(tmp_path / "lr"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["sebvs data export: --format lerobot needs pyarrow: pip install "
                   "'sebvs[lerobot]'"]
    assert not (tmp_path / "lr").exists()


def test_full_files_roll_over_to_the_next_file_number(tmp_path, monkeypatch):
    """Past the size limits each episode starts a new data and video file; the episodes'
    rows say where, and the reader finds every frame there."""
    import sebvs.data.export_lerobot as lerobot
    monkeypatch.setattr(lerobot, "DATA_FILE_MB", 0)
    monkeypatch.setattr(lerobot, "VIDEO_FILE_MB", 0)
    ds = small_dataset(tmp_path / "ds")
    out = tmp_path / "lr"
    export_lerobot(ds, out, progress=False, encoder="opencv")
    got = read_lerobot(out)
    assert [(e["data/file_index"], e["videos/observation.images.camera/file_index"],
             e["videos/observation.images.camera/from_timestamp"]) for e in got["episodes"]] \
        == [(0, 0, 0.0), (1, 1, 0.0)]
    assert sorted(p.name for p in (out / "data/chunk-000").iterdir()) == [
        "file-000.parquet", "file-001.parquet"]
    for arrays in got["arrays"]:
        np.testing.assert_array_equal(arrays["action"][:, 0], np.float32(0.1 * np.arange(4)))
        np.testing.assert_array_equal(arrays["observation.events"][:, 0, 0, 0], np.arange(4))
    assert got["info"]["data_files_size_in_mb"] == 0
