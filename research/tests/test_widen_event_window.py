"""research/sensors/widen_event_window.py: a recording's event frames widened to K control
periods equal the sum of K adjacent ticks' frames, the rest of each file is untouched, and
the result is a dataset the checks and the trainer read."""
import json
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from sebvs.data.check import check_dataset
from sebvs.data.episode import open_episode
from sebvs.policy.dataset import event_frames_of
from tests.policy_data import make_dataset

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "sensors"))
import widen_event_window as tool  # noqa: E402


def test_widened_frames_are_sums_of_adjacent_ticks_clipped_at_255():
    rng = np.random.default_rng(3)
    frames = rng.integers(0, 256, (9, 2, 4, 5), dtype=np.uint8)
    got = tool.widened(frames, 3)
    for t in range(9):
        want = frames[max(0, t - 2):t + 1].astype(np.int64).sum(axis=0)
        np.testing.assert_array_equal(got[t], np.minimum(want, 255))
    assert got.dtype == np.uint8 and (got == 255).any()    # the clip was exercised
    with pytest.raises(ValueError, match=r"\[T, 2, H, W\]"):
        tool.widened(np.zeros((4, 6, 2, 2), np.uint8), 2)


def test_a_dataset_is_widened_whole_and_resumes(tmp_path):
    src = make_dataset(tmp_path / "src", episodes=3, frames=10, height=16, width=16)
    dst = tmp_path / "wide"
    assert tool.main([str(src), str(dst), "--periods", "3", "--quiet"]) == 0
    assert check_dataset(dst).problems == []
    assert event_frames_of(dst, json.loads((dst / "index.json").read_text())["episodes"]
                           )["window_s"] == pytest.approx(0.3)
    for e in json.loads((src / "index.json").read_text())["episodes"]:
        with open_episode(src / e["file"]) as a, open_episode(dst / e["file"]) as b:
            np.testing.assert_array_equal(b.event_frame[...],
                                          tool.widened(a.event_frame[...], 3))
            np.testing.assert_array_equal(b.rgb[...], a.rgb[...])
            np.testing.assert_array_equal(b.target[...], a.target[...])
            assert b.attrs["derived"]["periods"] == 3
            assert b.attrs["derived"]["from"] == str((src / e["file"]).resolve())
            assert b.attrs["event_window_s"] == pytest.approx(3 * a.attrs["event_window_s"])
    # an interrupted run: the last episode never reached the index
    index = json.loads((dst / "index.json").read_text())
    last = index["episodes"].pop()
    (dst / "index.json").write_text(json.dumps(index))
    before = {e["file"]: (dst / e["file"]).stat().st_mtime_ns for e in index["episodes"]}
    result = tool.widen_dataset(src, dst, 3, progress=False)
    assert result["widened"] == 1 and result["kept"] == 2
    assert {e["file"]: (dst / e["file"]).stat().st_mtime_ns
            for e in index["episodes"]} == before
    assert [e["file"] for e in json.loads((dst / "index.json").read_text())["episodes"]] \
        == [e["file"] for e in index["episodes"]] + [last["file"]]


def test_what_cannot_be_widened_is_refused_naming_the_file(tmp_path, capsys):
    hist = make_dataset(tmp_path / "hist", episodes=1, frames=6, height=16, width=16,
                        event_bins=2)
    assert tool.main([str(hist), str(tmp_path / "out"), "--periods", "2", "--quiet"]) == 2
    assert "episode_0000.h5" in capsys.readouterr().err
    assert not list((tmp_path / "out").glob("*.h5*"))       # nothing half-written left
    plain = make_dataset(tmp_path / "plain", episodes=1, frames=6, height=16, width=16)
    with h5py.File(plain / "episode_0000.h5", "r+") as f:
        del f.attrs["event_window_s"]
    with pytest.raises(ValueError, match="episode_0000.h5: no event_window_s"):
        tool.widen_dataset(plain, tmp_path / "out2", 2, progress=False)
    with pytest.raises(ValueError, match="--periods"):
        tool.widen_dataset(plain, tmp_path / "out3", 1, progress=False)
    with pytest.raises(ValueError, match="another directory"):
        tool.widen_dataset(plain, plain, 2, progress=False)


def test_a_failed_copy_leaves_no_partial_file_and_loses_no_finished_episode(tmp_path,
                                                                            monkeypatch):
    src = make_dataset(tmp_path / "src", episodes=2, frames=6, height=16, width=16)
    dst = tmp_path / "wide"
    real = tool.shutil.copyfile
    calls = []

    def full_disk_on_second(a, b):
        calls.append(a)
        if len(calls) == 2:
            Path(b).write_bytes(b"half")
            raise OSError(28, "No space left on device")
        return real(a, b)
    monkeypatch.setattr(tool.shutil, "copyfile", full_disk_on_second)
    with pytest.raises(OSError, match="No space left"):
        tool.widen_dataset(src, dst, 2, progress=False)
    assert sorted(p.name for p in dst.iterdir()) == ["episode_0000.h5", "index.json"]
    monkeypatch.setattr(tool.shutil, "copyfile", real)
    assert tool.widen_dataset(src, dst, 2, progress=False)["widened"] == 1
    assert check_dataset(dst).problems == []
