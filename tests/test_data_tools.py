"""`sebvs data check` and `sebvs data stats` on small datasets written with EpisodeWriter."""
import shutil

import numpy as np
import pytest

from sebvs.cli import main
from sebvs.data.episode import EpisodeWriter
from sebvs.data.index import DatasetIndex, make_entry, write_json_atomic


def make_dataset(root, task="nav", episodes=3, frames=20, side=32, conditions=None):
    idx = DatasetIndex(root, task)
    rng = np.random.default_rng(1)
    for k in range(episodes):
        path = idx.path_for(idx.next_episode_number())
        cond = conditions[k] if conditions else {"c": 1}
        w = EpisodeWriter(path, task, {"scene": task, "conditions": cond, "seed": 3})
        for t in range(frames):
            y = rng.uniform(-1, 1, 2 if task == "nav" else 6)
            w.append(rgb=rng.integers(0, 255, (side, side, 3), dtype=np.uint8),
                     event_frame=rng.integers(0, 3, (2, side // 2, side // 2), dtype=np.uint8),
                     t_sim=0.05 * t, tick=t, **{"action" if task == "nav" else "pose": y})
        w.finish("time_limit")
        idx.add(make_entry(path))
    return idx


def run_check(root, capsys):
    code = main(["data", "check", str(root)])
    return code, capsys.readouterr().out


def test_check_passes_a_good_dataset(tmp_path, capsys):
    make_dataset(tmp_path)
    code, out = run_check(tmp_path, capsys)
    assert code == 0, out
    assert "3 indexed episode(s), 60 frames: OK" in out


@pytest.mark.parametrize("damage", ["corrupt", "truncated", "missing", "partial", "unindexed"])
def test_check_names_a_damaged_episode_and_fails(tmp_path, capsys, damage):
    make_dataset(tmp_path)
    victim = tmp_path / "episode_0001.h5"
    if damage == "corrupt":
        data = bytearray(victim.read_bytes())
        mid = len(data) // 2
        data[mid:mid + 64] = bytes(64)      # same size, different bytes
        victim.write_bytes(bytes(data))
        expect = "sha256 differs"
    elif damage == "truncated":
        victim.write_bytes(victim.read_bytes()[: victim.stat().st_size // 3])
        expect = "truncated"
    elif damage == "missing":
        victim.unlink()
        expect = "missing"
    elif damage == "partial":
        victim = tmp_path / "episode_0003.h5.partial"
        victim.write_bytes(b"\x89HDF half an episode")
        expect = "lost in-progress episode"
    else:
        victim = tmp_path / "episode_0007.h5"
        shutil.copy(tmp_path / "episode_0000.h5", victim)
        expect = "not in index.json"
    code, out = run_check(tmp_path, capsys)
    assert code == 1
    lines = [ln for ln in out.splitlines() if ln.startswith(victim.name)]
    assert lines and any(expect in ln for ln in lines), out
    # the other episodes are not blamed
    assert not any(ln.startswith("episode_0000.h5") or ln.startswith("episode_0002.h5")
                   for ln in out.splitlines()), out


def test_check_fails_without_an_index(tmp_path, capsys):
    code, out = run_check(tmp_path, capsys)
    assert code == 1 and "index.json: missing" in out


@pytest.mark.parametrize("task", ["nav", "arm"])
def test_stats_prints_a_summary_and_renders_the_plot(tmp_path, capsys, task):
    make_dataset(tmp_path / "ds", task)
    png = tmp_path / "fig3.png"
    assert main(["data", "stats", str(tmp_path / "ds"), "--plot", str(png)]) == 0
    out = capsys.readouterr().out
    assert "episodes           3" in out and "frames             60" in out
    assert "labelled commands  60" in out and "simulation         0.1 min" in out
    assert png.stat().st_size > 10_000 and png.read_bytes()[:4] == b"\x89PNG"


def test_stats_shows_the_coverage_of_what_varies(tmp_path, capsys):
    hz = [5.5 + k for k in range(9)]                    # drawn from a range
    conds = [{"variant": "indoor" if k < 3 else "outdoor", "lighting": "low",
              "flicker_hz": hz[k], "belt": [0.08, 0.25][k % 2], "width": 32} for k in range(9)]
    make_dataset(tmp_path / "ds", "nav", frames=10, episodes=9, conditions=conds)
    assert main(["data", "stats", str(tmp_path / "ds")]) == 0
    out = capsys.readouterr().out
    assert "variant        indoor 3 / 30, outdoor 6 / 60" in out
    assert "flicker_hz     5.5 .. 13.5" in out
    assert "belt           0.08 5 / 50, 0.25 4 / 40" in out        # a few choices: a row each
    assert "lighting" not in out and "width" not in out          # the same everywhere


def test_compare_finds_the_same_recording_and_names_what_differs(tmp_path, capsys):
    import h5py
    a, b = tmp_path / "a", tmp_path / "b"
    make_dataset(a)
    shutil.copytree(a, b)
    with h5py.File(b / "episode_0000.h5", "r+") as f:
        f["tick"][...] = f["tick"][()] + 40         # another run's tick numbers: the same
        f.create_dataset("latency/sim->camera", data=np.ones(20, np.float32))
        f["t_sim"][...] = f["t_sim"][()] + 2.0
    assert main(["data", "compare", str(a), str(b), "--quiet"]) == 1   # latency only in b
    out = capsys.readouterr().out
    assert "episode_0000.h5: dataset latency/sim->camera: only in" in out
    with h5py.File(a / "episode_0000.h5", "r+") as f:
        f.create_dataset("latency/sim->camera", data=np.zeros(20, np.float32))
    assert main(["data", "compare", str(a), str(b), "--quiet"]) == 0
    assert "3 episode pair(s) compared: 3 the same, 0 different" in capsys.readouterr().out

    with h5py.File(b / "episode_0002.h5", "r+") as f:
        f["action"][7, 1] += 0.5
        f.attrs["seed"] = 4
    (b / "episode_0001.h5").unlink()
    idx = DatasetIndex(b)
    idx.data["episodes"] = [e for e in idx.episodes() if e["file"] != "episode_0001.h5"]
    write_json_atomic(idx.path, idx.data)
    assert main(["data", "compare", str(a), str(b), "--quiet"]) == 1
    out = capsys.readouterr().out
    assert "episode_0002.h5: dataset action: 1 element(s) differ, first at (7, 1)" in out
    assert "episode_0002.h5: attribute seed: '3' against '4'" in out
    assert f"episode_0001.h5: only in {a}" in out
    assert "2 episode pair(s) compared: 1 the same, 1 different; 1 only in" in out
    assert main(["data", "compare", str(a), str(tmp_path / "nowhere")]) == 2
