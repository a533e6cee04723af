"""Episode files and the dataset index: round trip, atomic index, resumed numbering."""
import json
import os
from pathlib import Path

import numpy as np
import pytest

import sebvs
from sebvs.data.check import check_dataset
from sebvs.data.episode import EpisodeWriter, open_episode
from sebvs.data.index import DatasetIndex, file_sha256, make_entry
from sebvs.data.recording import EpisodeRecorder, TickJoiner, hop_latencies

H, W, T = 24, 32, 12
ATTRS = {"scene": "nav", "conditions": {"variant": "indoor", "speed": "fast"}, "seed": 42,
         "topology": {"name": "t"}, "emulator": {"pos_thres": 0.3},
         "event_scale": 0.5, "event_offset": [1.0, 2.0]}


def write_episode(path, task="nav", frames=T, raw=False, compression="lzf"):
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 255, (frames, H, W, 3), dtype=np.uint8)
    ev = rng.integers(0, 9, (frames, 2, H // 2, W // 2), dtype=np.uint8)
    tgt = rng.uniform(-1, 1, (frames, 2 if task == "nav" else 6)).astype(np.float32)
    w = EpisodeWriter(path, task, ATTRS, compression=compression)
    for t in range(frames):
        kw = {"action" if task == "nav" else "pose": tgt[t]}
        if raw:
            kw["raw_events"] = {"x": np.full(t, 3), "y": np.full(t, 4),
                                "t": np.arange(t) + 1000 * t, "p": np.ones(t)}
        w.append(rgb=rgb[t], event_frame=ev[t], t_sim=0.05 * t, tick=100 + t,
                 latency={"sim->camera": 10.0 + t} if t else {"camera->recorder": 5.0},
                 truth={"centroid": [t, -t], "visible": t % 2 == 0},
                 modality="rgb+event" if t > 5 else "rgb", **kw)
    assert path.with_name(path.name + ".partial").exists() and not path.exists()
    assert w.finish("time_limit") == path
    return rgb, ev, tgt


@pytest.mark.parametrize("task", ["nav", "arm"])
def test_episode_round_trips_every_array_and_attribute(tmp_path, task):
    path = tmp_path / "episode_0000.h5"
    rgb, ev, tgt = write_episode(path, task, raw=True)
    assert not path.with_name(path.name + ".partial").exists()
    with open_episode(path) as ep:
        assert len(ep) == T and ep.task == task
        np.testing.assert_array_equal(ep.rgb[:], rgb)
        assert ep.rgb.chunks == (1, H, W, 3)            # one frame per chunk
        np.testing.assert_array_equal(ep.event_frame[:], ev)
        np.testing.assert_array_equal(ep.target[:], tgt)
        assert (ep.action if task == "nav" else ep.pose) is not None
        assert ep.target.dtype == np.float32 and ep.target.shape == (T, 2 if task == "nav" else 6)
        np.testing.assert_allclose(ep.t_sim[:], 0.05 * np.arange(T))
        assert ep.t_sim.dtype == np.float64
        np.testing.assert_array_equal(ep.tick[:], 100 + np.arange(T))
        lat = ep.latency["sim->camera"][:]
        assert lat.dtype == np.float32 and np.isnan(lat[0]) and lat[3] == 13.0
        assert ep.latency["camera->recorder"][0] == 5.0
        np.testing.assert_array_equal(ep.truth["centroid"][:, 0], np.arange(T))
        np.testing.assert_array_equal(ep.truth["visible"][:2], [1.0, 0.0])
        assert ep.modality[0] == b"rgb" and ep.modality[T - 1] == b"rgb+event"
        off = ep.raw_events["offset"][:]
        assert len(off) == T + 1 and off[-1] == sum(range(T))
        k = 5
        np.testing.assert_array_equal(ep.raw_events["t"][off[k]:off[k + 1]],
                                      np.arange(k) + 1000 * k)
        a = ep.attrs
        assert a["task"] == task and a["scene"] == "nav" and a["seed"] == 42
        assert a["conditions"] == ATTRS["conditions"] and a["topology"] == {"name": "t"}
        assert a["emulator"] == {"pos_thres": 0.3}
        assert a["event_scale"] == 0.5 and a["event_offset"] == [1.0, 2.0]
        assert a["version"] == sebvs.__version__
        assert a["end_reason"] == "time_limit" and a["frames"] == T


def test_policy_dataset_reads_recorded_episodes(tmp_path):
    """The policy's loader (sebvs.policy.dataset) reads what the writer writes."""
    from sebvs.policy.dataset import load_index
    idx = DatasetIndex(tmp_path, "nav")
    for n in range(2):
        p = idx.path_for(idx.next_episode_number())
        write_episode(p)
        idx.add(make_entry(p))
    assert [e["frames"] for e in load_index(tmp_path)] == [T, T]


def test_writer_checks_inputs_and_abort_removes_the_partial(tmp_path):
    path = tmp_path / "e.h5"
    w = EpisodeWriter(path, "nav", {})
    with pytest.raises(ValueError, match="action"):
        w.append(rgb=np.zeros((4, 4, 3), np.uint8), t_sim=0, tick=0, pose=np.zeros(6))
    with pytest.raises(ValueError, match="rgb"):
        w.append(rgb=np.zeros((4, 4), np.uint8), t_sim=0, tick=0, action=[0, 0])
    w.append(rgb=np.zeros((4, 4, 3), np.uint8), t_sim=0, tick=0, action=[0, 0])
    with pytest.raises(ValueError, match="event_frame"):
        w.append(rgb=np.zeros((4, 4, 3), np.uint8), t_sim=0, tick=1, action=[0, 0],
                 event_frame=np.zeros((2, 2, 2), np.uint8))
    w.abort()
    assert not list(tmp_path.iterdir())
    with EpisodeWriter(path, "nav", {}) as w:       # a block left without finish: dropped
        w.append(rgb=np.zeros((4, 4, 3), np.uint8), t_sim=0, tick=0, action=[0, 0])
    assert not list(tmp_path.iterdir())
    with pytest.raises(ValueError, match="task"):
        EpisodeWriter(path, "fly", {})


def test_event_counts_above_255_are_clipped(tmp_path):
    path = tmp_path / "e.h5"
    w = EpisodeWriter(path, "nav", {}, compression="none")
    w.append(rgb=np.zeros((4, 4, 3), np.uint8), event_frame=np.full((2, 2, 2), 300, np.int32),
             t_sim=0, tick=0, action=[0, 0])
    w.finish()
    with open_episode(path) as ep:
        assert ep.event_frame.dtype == np.uint8 and ep.event_frame[0].max() == 255
        assert ep.rgb.compression is None


def test_index_add_is_atomic_and_numbering_resumes(tmp_path, monkeypatch):
    idx = DatasetIndex(tmp_path, "nav")
    assert idx.next_episode_number() == 0
    p0 = idx.path_for(0)
    write_episode(p0, frames=3)
    e0 = make_entry(p0)
    assert e0["sha256"] == file_sha256(p0) and e0["bytes"] == p0.stat().st_size
    assert e0["frames"] == 3 and e0["seed"] == 42 and e0["reason"] == "time_limit"
    assert e0["conditions"] == ATTRS["conditions"]
    idx.add(e0)
    before = (tmp_path / "index.json").read_text()
    # a crash while the index is rewritten leaves the old index whole
    p1 = idx.path_for(1)
    write_episode(p1, frames=3)

    def boom(src, dst):
        raise OSError("crash")
    monkeypatch.setattr(os, "replace", boom)
    with pytest.raises(OSError):
        DatasetIndex(tmp_path).add(make_entry(p1))
    monkeypatch.undo()
    assert (tmp_path / "index.json").read_text() == before
    # a reopened dataset resumes after the highest number, in the index or on disk
    (tmp_path / "episode_0004.h5.partial").write_bytes(b"lost")
    idx2 = DatasetIndex(tmp_path)
    assert idx2.task == "nav" and len(idx2.episodes()) == 1
    assert idx2.next_episode_number() == 5
    idx2.add(make_entry(p1))
    data = json.loads((tmp_path / "index.json").read_text())
    assert data["version"] == 1 and data["task"] == "nav"
    assert [e["file"] for e in data["episodes"]] == ["episode_0000.h5", "episode_0001.h5"]
    assert idx2.episode_paths() == [p0, p1]
    with pytest.raises(ValueError, match="already"):
        idx2.add(make_entry(p1))
    with pytest.raises(ValueError, match="task"):
        DatasetIndex(tmp_path, "arm")
    # a crash between an episode's rename and its index entry: the next session adopts it
    p2 = idx2.path_for(2)
    write_episode(p2, frames=3)
    (tmp_path / "episode_0003.h5").write_bytes(b"not hdf5")    # unreadable: left alone
    assert DatasetIndex(tmp_path).adopt_unindexed() == ["episode_0002.h5"]
    assert len(DatasetIndex(tmp_path).episodes()) == 3


def test_joiner_completes_rows_and_drops_ticks_that_cannot_complete():
    j = TickJoiner({"rgb", "action"}, max_pending=4)
    assert j.add("rgb", 0, "r0") is None
    assert j.add("action", 0, "a0") == (0, {"rgb": "r0", "action": "a0"})
    j.add("rgb", 1, "r1")                  # its action never comes
    j.add("rgb", 2, "r2")
    assert j.add("action", 2, "a2")[0] == 2
    assert j.incomplete == 1 and j.dropped_ticks == [1] and not j.pending
    assert j.add("action", 1, "late") is None and j.late == 1
    for t in range(3, 9):                  # a stalled stream: memory stays bounded
        j.add("rgb", t, t)
    assert sorted(j.pending) == [5, 6, 7, 8] and j.incomplete == 3


def test_hop_latencies_from_stamps():
    stamps = [["sim", 0, 1_000_000], ["camera", 1_050_000, 3_000_000]]
    assert hop_latencies(stamps, 3_020_000, "recorder") == {"sim->camera": 50.0,
                                                           "camera->recorder": 20.0}


def test_rows_go_to_their_episode_whatever_the_marker_order(tmp_path):
    """Markers travel on their own socket: a row may beat its start, or the previous end."""
    rec = EpisodeRecorder(tmp_path, "nav")
    row = lambda t, k: rec.row(t, rgb=np.full((4, 4, 3), t, np.uint8), t_sim=t / 10,
                               action=[t, 0], episode=k)
    row(0, 0)                                      # before any start: held
    rec.start({"episode": 0, "seed": 5, "scene": "s", "config": {}}, 0)
    row(1, 0)
    row(2, 1)                                      # episode 1's first row, before 0's end
    assert rec.end("time_limit", 1)[0]["frames"] == 2
    rec.start({"episode": 1, "seed": 6, "scene": "s", "config": {}}, 2)
    row(3, 1)
    row(1, 0)                                      # a stray row of a finished episode
    assert rec.end("diverged", 3)[0]["file"] == "episode_0001.h5"
    assert rec.outside == 1 and rec.frames == 4 and not rec.open
    with open_episode(tmp_path / "episode_0001.h5") as ep:
        assert list(ep.tick[:]) == [2, 3] and ep.attrs["seed"] == 6
        assert ep.attrs["end_reason"] == "diverged"
    rec.start({"episode": 2}, 4)
    row(4, 2)
    assert rec.close() == [] and rec.discarded == 1        # in progress at shutdown
    assert not list(tmp_path.glob("*.partial"))


def test_rows_without_an_episode_number_that_beat_the_end_marker_go_to_the_next_episode(
        tmp_path):
    """Without the sim's episode number in a row, a recorder places it by tick: a row of
    the next episode that beats this one's end marker lands here until the marker says
    where the episode ended. Then it moves, with its latency, truth, modality and raw
    events, and the episode keeps exactly its own rows."""
    rec = EpisodeRecorder(tmp_path, "nav")

    def row(t):
        raw = {"x": np.full(t + 1, t, np.uint16), "y": np.zeros(t + 1, np.uint16),
               "t": np.full(t + 1, 1000 * t, np.int64), "p": np.ones(t + 1, np.int8)}
        return rec.row(t, rgb=np.full((4, 4, 3), t, np.uint8), t_sim=t / 10, action=[t, 0],
                       latency={"sim->camera": float(t)}, truth={"centroid": [t, t]},
                       modality="rgb", raw_events=raw, attrs={"event_scale": 0.5})
    rec.start({"episode": 0, "seed": 5, "scene": "s", "config": {}}, 0)
    for t in range(5):
        row(t)                                     # ticks 3 and 4 are the next episode's
    assert rec.end("time_limit", 2)[0]["frames"] == 3
    rec.start({"episode": 1, "seed": 6, "scene": "s", "config": {}}, 3)
    row(5)
    assert rec.end("time_limit", 5)[0]["frames"] == 3 and rec.outside == 0
    for name, ticks in (("episode_0000.h5", [0, 1, 2]), ("episode_0001.h5", [3, 4, 5])):
        with open_episode(tmp_path / name) as ep:
            assert list(ep.tick[:]) == ticks and list(ep.rgb[:, 0, 0, 0]) == ticks
            assert list(ep.action[:, 0]) == ticks
            assert list(ep.latency["sim->camera"]) == ticks
            assert list(ep.truth["centroid"][:, 0]) == ticks
            assert list(ep.modality) == [b"rgb"] * 3
            off, x = ep.raw_events["offset"][:], ep.raw_events["x"][:]
            assert [list(x[off[i]:off[i + 1]]) for i in range(3)] == \
                [[t] * (t + 1) for t in ticks]
            assert ep.attrs["event_scale"] == 0.5
    assert check_dataset(tmp_path).ok


def test_rows_past_a_late_end_that_are_no_longer_held_are_counted(tmp_path):
    rec = EpisodeRecorder(tmp_path, "nav", max_orphans=2)
    rec.start({"episode": 0, "seed": 5, "scene": "s", "config": {}}, 0)
    for t in range(6):
        rec.row(t, rgb=np.full((4, 4, 3), t, np.uint8), t_sim=t / 10, action=[t, 0])
    assert rec.end("time_limit", 1)[0]["frames"] == 2
    assert rec.outside == 2 and [t for t, _ in rec.orphans] == [4, 5]    # 2, 3 were let go


def test_rows_before_any_start_beyond_the_limit_are_counted_and_the_rest_kept(tmp_path):
    rec = EpisodeRecorder(tmp_path, "nav", max_orphans=2)
    for t in range(4):                             # the start marker is late: all held
        rec.row(t, rgb=np.full((4, 4, 3), t, np.uint8), t_sim=t / 10, action=[t, 0],
                episode=0)
    assert rec.outside == 2 and [t for t, _ in rec.orphans] == [2, 3]    # 0, 1 let go
    rec.start({"episode": 0, "seed": 5, "scene": "s", "config": {}}, 0)
    assert rec.end("time_limit", 3)[0]["frames"] == 2 and rec.outside == 2
    with open_episode(tmp_path / "episode_0000.h5") as ep:
        assert list(ep.tick[:]) == [2, 3]


def test_an_episode_taken_away_at_its_rename_is_still_indexed_and_the_next_row_kept(
        tmp_path, monkeypatch):
    """A fan-out driver adopts a worker's episode file the moment it has its final name
    (sebvs/data/record.py): the worker's entry is made before the rename, so the file
    leaving at once neither raises nor costs the next episode its first row."""
    import hashlib
    import sebvs.data.episode as episode_module
    driver = tmp_path / "driver"
    driver.mkdir()
    real_replace = os.replace

    def replace_then_adopt(src, dst):
        real_replace(src, dst)
        if str(dst).endswith(".h5"):
            real_replace(dst, driver / Path(dst).name)
    monkeypatch.setattr(episode_module.os, "replace", replace_then_adopt)
    rec = EpisodeRecorder(tmp_path / "stage", "nav")
    row = lambda t, k: rec.row(t, rgb=np.full((4, 4, 3), t, np.uint8), t_sim=t / 10,
                               action=[t, 0], episode=k)
    rec.start({"episode": 0, "seed": 5, "scene": "s", "config": {}}, 0)
    row(0, 0)
    row(1, 0)
    rec.end("time_limit", 2)                       # its last row (tick 2) never comes
    rec.start({"episode": 1, "seed": 6, "scene": "s", "config": {}}, 3)
    done = row(3, 1)                               # finishes episode 0 on the way
    assert [e["file"] for e in done] == ["episode_0000.h5"]
    moved = driver / "episode_0000.h5"
    assert done[0]["frames"] == 2 and \
        done[0]["sha256"] == hashlib.sha256(moved.read_bytes()).hexdigest()
    assert rec.end("time_limit", 3)[0]["frames"] == 1       # episode 1 kept its first row
