"""The recorder actor in real runs: N episodes, joined rows, RGB-only, kill -9, `sebvs record`."""
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from sebvs.cli import main
from sebvs.data.check import check_dataset
from sebvs.data.episode import open_episode
from sebvs.data.index import DatasetIndex
from sebvs.runtime.supervisor import Supervisor, run_topology
from sebvs.runtime.topology import load_topology
from tests.data_actors import expected_action


def topology(tmp_path, out, *, events=True, task="nav", frames=10, episodes=3, extra="",
             raw=False):
    ev = ', events = "source/events"' if events else ""
    ev += ', raw = "source/raw"' if raw else ""
    path = tmp_path / "record.toml"
    path.write_text(f"""
[topology]
name = "record_test"
seed = 0
[actors.source]
run = "tests.data_actors:DataSource"
frames = {frames}
task = "{task}"
{extra}
[actors.recorder]
run = "actors.recorder:Recorder"
inputs = {{ rgb = "source/rgb", action = "source/action", episode = "source/episode"{ev} }}
out = "{out}"
episodes = {episodes}
""")
    return path


def test_recorder_writes_n_episodes_of_joined_rows_and_stops_the_run(tmp_path):
    out = tmp_path / "ds"
    t0 = time.monotonic()
    run_topology(topology(tmp_path, out, extra="raw_events = 5", raw=True), duration_s=20,
                 runs_dir=tmp_path, overrides=["recorder.raw_events=true"])
    assert time.monotonic() - t0 < 15          # the recorder ended the run, not the timeout
    idx = DatasetIndex(out)
    assert [e["file"] for e in idx.episodes()] == [f"episode_{k:04d}.h5" for k in range(3)]
    assert not list(out.glob("*.partial"))
    for k, path in enumerate(idx.episode_paths()):
        with open_episode(path) as ep:
            assert len(ep) == 10
            ticks = ep.tick[:]
            np.testing.assert_array_equal(ticks, np.arange(10 * k, 10 * k + 10))
            # each row joined from one tick: the source fills frames with tick % 256
            assert (ep.rgb[:, 0, 0, 0] == ticks % 256).all()        # control=False skipped
            assert (ep.event_frame[:, 1, 0, 0] == ticks % 256).all()
            assert ep.rgb.shape == (10, 24, 32, 3) and ep.event_frame.shape == (10, 2, 12, 16)
            np.testing.assert_array_equal(ep.action[:], [expected_action(t) for t in ticks])
            np.testing.assert_array_equal(ep.truth["centroid"][:, 0], ticks)
            assert ep.modality[0] == b"rgb"
            # raw: row k = the packet after tick k - 1 (2 events) + tick k's packet (5)
            off, t_raw = ep.raw_events["offset"][:], ep.raw_events["t"][:]
            assert off[-1] == 7 * 10 - (2 if k == 0 else 0)
            for i, tick in enumerate(ticks):
                ts = t_raw[off[i]:off[i + 1]]
                assert (ts == tick * 1000).sum() == 5 and (ts <= tick * 1000).all()
            assert np.isfinite(ep.latency["source->recorder"][:]).all()
            a = ep.attrs
            assert a["seed"] == 1000 + k and a["conditions"] == {"variant": "unit", "k": k}
            assert a["event_scale"] == 0.5 and a["emulator"] == {"pos_thres": 0.3,
                                                                 "neg_thres": 0.3}
            assert a["end_reason"] == "time_limit" and a["task"] == "nav"
    assert check_dataset(out).ok


def test_rgb_only_arm_recording_and_resumed_numbering(tmp_path):
    out = tmp_path / "ds"
    # no episode number in the rgb meta: rows go to episodes by tick range
    topo = topology(tmp_path, out, events=False, task="arm", frames=6, episodes=2,
                    extra="episode_meta = false")
    run_topology(topo, duration_s=20, runs_dir=tmp_path)
    run_topology(topo, duration_s=20, runs_dir=tmp_path)     # a second session appends
    idx = DatasetIndex(out)
    assert idx.task == "arm"
    assert [e["file"] for e in idx.episodes()] == [f"episode_{k:04d}.h5" for k in range(4)]
    with open_episode(idx.episode_paths()[3]) as ep:
        assert ep.event_frame is None and ep.pose.shape == (6, 6) and ep.action is None
        np.testing.assert_array_equal(ep.pose[:], [expected_action(t, "arm")
                                                   for t in ep.tick[:]])
    assert check_dataset(out).ok


def test_kill_9_loses_only_the_episode_in_progress(tmp_path):
    out = tmp_path / "ds"
    topo = load_topology(topology(tmp_path, out, frames=100, episodes=0))   # 0.5 s episodes
    sup = Supervisor(topo, runs_dir=tmp_path, echo=lambda s: None)
    sup.start()
    try:
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline:
            reply = sup.request("recorder", {"cmd": "stats"}, 2)
            st = reply["result"]["actor_stats"]
            if st["episodes"] >= 2 and 20 <= st["frames_in_progress"] <= 70:
                break
            time.sleep(0.02)
        else:
            raise AssertionError(f"never mid-episode: {st}")
        os.kill(sup.procs["recorder"].popen.pid, signal.SIGKILL)
        assert sup.wait(10) == 1 and "SIGKILL" in sup.failure
    finally:
        sup.stop()
    idx = DatasetIndex(out)
    finished = idx.episodes()
    assert len(finished) >= 2
    partials = sorted(p.name for p in out.glob("*.partial"))
    assert partials == [f"episode_{len(finished):04d}.h5.partial"]
    rep = check_dataset(out)
    assert not rep.problems and rep.lost == partials and not rep.ok
    for path in idx.episode_paths():
        with open_episode(path) as ep:
            assert len(ep) == 100
    # numbering resumes past the lost episode; it is never overwritten
    assert idx.next_episode_number() == len(finished) + 1


def test_sebvs_record_runs_to_n_episodes_and_resumes(tmp_path, capsys):
    out = tmp_path / "ds"
    topo = topology(tmp_path, tmp_path / "ignored", frames=8, episodes=0)
    args = ["record", str(topo), "--episodes", "2", "--out", str(out), "--runs-dir",
            str(tmp_path), "--quiet", "--timeout", "20"]
    assert main(args) == 0
    assert main(args) == 0
    printed = capsys.readouterr().out
    assert "2 of 2 episode(s) recorded, 16 frames" in printed
    assert "now holds 4 episode(s)" in printed
    idx = DatasetIndex(out)
    assert len(idx.episodes()) == 4 and not (tmp_path / "ignored").exists()
    with open_episode(idx.episode_paths()[0]) as ep:
        assert ep.attrs["topology"]["content"]["actors"]["source"]["frames"] == 8
    assert check_dataset(out).ok


def test_recorded_topology_attribute_has_the_runs_overrides_applied(tmp_path, capsys):
    """--set changes what runs, so the stored topology (and the emulator settings read from
    it) must show the change, not the file as it lies on disk."""
    out = tmp_path / "ds"
    topo = topology(tmp_path, tmp_path / "ignored", frames=8, episodes=0)
    assert main(["record", str(topo), "--episodes", "1", "--out", str(out), "--runs-dir",
                 str(tmp_path), "--quiet", "--timeout", "20", "--set", "source.frames=5"]) == 0
    with open_episode(DatasetIndex(out).episode_paths()[0]) as ep:
        stored = ep.attrs["topology"]
        assert len(ep) == 5
    assert stored["content"]["actors"]["source"]["frames"] == 5
    assert stored["overrides"] == ["source.frames=5"]


def test_kill_9_of_the_whole_run_keeps_finished_episodes(tmp_path):
    """`sebvs record` and every actor killed at once: indexed episodes stay whole."""
    out, runs = tmp_path / "ds", tmp_path / "runs"
    topo = topology(tmp_path, tmp_path / "ignored", frames=100, episodes=0)
    proc = subprocess.Popen([sys.executable, "-m", "sebvs.cli", "record", str(topo),
                             "--episodes", "50", "--out", str(out), "--runs-dir", str(runs),
                             "--quiet"], cwd=Path(__file__).resolve().parents[1],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    pids = []
    try:
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline:
            idx = out / "index.json"
            if idx.exists() and len(json.loads(idx.read_text())["episodes"]) >= 2 \
                    and list(out.glob("*.partial")):
                break
            time.sleep(0.02)
        info = json.loads(next(runs.glob("*/run.json")).read_text())
        pids = [a["pid"] for a in info["actors"].values()]
        for pid in [proc.pid] + pids:
            os.kill(pid, signal.SIGKILL)
    finally:
        proc.kill()
        proc.wait()
    deadline = time.monotonic() + 5
    while any(Path(f"/proc/{p}").exists() and
              Path(f"/proc/{p}/stat").read_text().split()[2] != "Z" for p in pids) \
            and time.monotonic() < deadline:
        time.sleep(0.05)
    for shm in Path("/dev/shm").glob(f"sebvs-{info['run_id']}-*"):
        shm.unlink()        # nobody was left to remove the rings and sockets
    shutil.rmtree(Path(tempfile.gettempdir()) / f"sebvs-{info['run_id']}", ignore_errors=True)
    rep = check_dataset(out)
    assert rep.episodes >= 2 and not rep.problems and len(rep.lost) <= 1
    for path in DatasetIndex(out).episode_paths():
        with open_episode(path) as ep:
            assert len(ep) == 100


def test_recorder_passes_on_each_recorded_tick_s_action(tmp_path):
    """Wired to the sim in lockstep, the recorder's `action` paces the sim to the whole chain."""
    out = tmp_path / "ds"
    topo = topology(tmp_path, out, frames=5, episodes=2)
    text = topo.read_text().replace("actors.recorder:Recorder",
                                    "actors.recorder:LockstepRecorder") + f"""
[actors.probe]
run = "actors.synthetic:Probe"
inputs = {{ action = "recorder/action" }}
path = "{tmp_path / 'probe'}"
"""
    topo.write_text(text)
    run_topology(topo, duration_s=20, runs_dir=tmp_path)
    entries = json.loads((tmp_path / "probe.json").read_text())
    ticks = [e["tick"] for e in entries]
    assert ticks[:10] == list(range(10))
    assert entries[3]["arrays"] == {"action": [[2], "<f4"]}
    assert entries[3]["meta"] == {"modality": "rgb"}
    arrays = np.load(tmp_path / "probe.npz")
    np.testing.assert_array_equal(arrays["3.action.action"], expected_action(3))


def _small_filesystem(path: Path, size: str) -> bool:
    """A tmpfs of `size` at `path`, for the test's own full disk; False where this user
    may not mount one (the test then skips)."""
    path.mkdir(parents=True, exist_ok=True)
    if os.geteuid() != 0:
        return False
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(path)],
                          capture_output=True)
    return done.returncode == 0


def test_a_disk_that_fills_during_record_loses_no_finished_episode(tmp_path, capsys):
    import pytest
    mnt = tmp_path / "small"
    if not _small_filesystem(mnt, "6m"):
        pytest.skip("cannot mount a small tmpfs here (needs root): the full-disk case")
    try:
        out = mnt / "ds"
        code = main(["record", "topologies/nav_record.toml", "--episodes", "40", "--out",
                     str(out), "--runs-dir", str(tmp_path / "runs"), "--quiet",
                     "--set", "sim.episode_s=2.0", "--set", "sim.randomise={}"])
        err = capsys.readouterr().err
        assert code == 1
        stopped = [line for line in err.splitlines() if "recording stopped:" in line]
        assert len(stopped) == 1 and "No space left on device" in stopped[0], err
        assert "SIGSEGV" not in err and "died" not in err
        index = DatasetIndex(out)
        finished = sorted(p.name for p in out.glob("episode_*.h5"))
        assert len(finished) >= 2
        assert sorted(e["file"] for e in index.episodes()) == finished   # all indexed
        assert f"{len(finished)} finished episode(s) intact and indexed" in stopped[0]
        partial = list(out.glob("*.partial"))
        assert len(partial) == 1 and partial[0].name in stopped[0]       # marked
        assert not (out / ".space_reserve").exists()
        for name in finished:                       # every finished file reads whole
            with open_episode(out / name) as ep:
                assert len(ep) == 21 and ep.attrs["frames"] == 21
    finally:
        subprocess.run(["umount", str(mnt)], capture_output=True)
