"""The stream probe (sebvs/probe) on tiny synthetic recordings with truth (tests/probe_data.py):
it localises a square its stream shows far below the mean-centroid baseline, tells visible
frames from hidden ones (AUC near 1), finds nothing in a stream that holds nothing, and
refuses a dataset without truth in one line."""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.probe_data import make_truth_dataset
from sebvs.probe import ProbeDataError, Recipe, load_frames, probe, roc_auc

ROOT = Path(__file__).resolve().parents[1]
# the fixed recipe at the tiny images' size (32 px: the synthetic frames' own). Its map is
# then 4 x 4 cells of 8 px (40 px in the report's 160 px), and the cell cross-entropy at
# its full weight would pull every centre onto a cell's (14 px error here): a fifth of it
SMALL = Recipe(size=32, epochs=12, batch=16, cell_weight=0.2)


@pytest.fixture(scope="module")
def square(tmp_path_factory):
    return make_truth_dataset(tmp_path_factory.mktemp("probe") / "square", hidden=0.3)


def test_the_probe_localises_a_visible_square_far_below_the_mean_baseline(square):
    frames = load_frames(square)
    assert frames.rgb.shape == (240, 32, 32, 3) and frames.events.shape == (240, 2, 32, 32)
    for sensor in ("rgb", "event", "both"):
        r = probe(frames, sensor, SMALL, seed=0)
        assert r["train_frames"] == 8 * 24 and r["test_frames"] == 2 * 24
        assert r["test_episodes"] == ["episode_0008.h5", "episode_0009.h5"]
        # px of a 160 px wide image: the square is 6 px of 32 (30 px at 160)
        assert r["error_px"]["median"] < 0.25 * r["baseline_px"]["median"], (sensor, r)
        assert r["error_px"]["median"] < 8.0, (sensor, r)
        assert r["auc"] > 0.95, (sensor, r)
        assert r["auc_baseline"] == 0.5


def test_a_stream_without_the_square_gives_no_better_than_the_baseline(tmp_path):
    noise = make_truth_dataset(tmp_path / "noise", hidden=0.3, events="noise")
    r = probe(load_frames(noise, sensors=("event",)), "event", SMALL, seed=0)
    assert r["error_px"]["median"] > 0.6 * r["baseline_px"]["median"], r
    assert 0.3 < r["auc"] < 0.7, r


def test_a_dataset_without_truth_is_refused_in_one_line(tmp_path):
    bare = make_truth_dataset(tmp_path / "bare", episodes=2, truth=False)
    with pytest.raises(ProbeDataError, match="truth/centroid") as info:
        load_frames(bare)
    assert "\n" not in str(info.value)
    done = subprocess.run([sys.executable, "-m", "sebvs.probe", str(bare), "--quiet"],
                          cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "truth/centroid" in lines[0] and "Traceback" not in done.stderr


def test_the_command_writes_json_resumes_and_prints_a_table(tmp_path):
    # the command runs the fixed recipe (160 px input): a few frames keep it quick
    small = make_truth_dataset(tmp_path / "drv" / "short", episodes=10, frames=4)
    out = tmp_path / "probe.json"
    cmd = [sys.executable, "-m", "sebvs.cli", "probe", str(small), "--sensors", "event",
           "--json", str(out), "--quiet"]
    done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout)["summary"][0]["test_frames"] == 8
    data = json.loads(out.read_text())
    assert data["recipe"] == Recipe().to_dict()
    assert len(data["fits"]) == 1 and data["summary"][0]["sensor"] == "event"
    assert data["fits"][0]["driver"] == "drv" and data["fits"][0]["cell"] == "short"
    first = data["fits"][0]
    # run again: the fit is kept, not made again
    again = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert again.returncode == 0, again.stderr
    assert json.loads(out.read_text())["fits"] == [first]
    table = subprocess.run([sys.executable, "-m", "sebvs.probe", "--table", str(out)],
                           cwd=ROOT, capture_output=True, text=True, timeout=60).stdout
    assert table.startswith("| cell |") and "event: median / p90 px, AUC" in table
    assert "drv/short" in table


def test_the_command_refuses_to_overwrite_a_file_it_did_not_write(tmp_path):
    small = make_truth_dataset(tmp_path / "small", episodes=10, frames=2)
    other = tmp_path / "notes.json"
    other.write_text('{"mine": 1}\n')
    done = subprocess.run([sys.executable, "-m", "sebvs.probe", str(small), "--json",
                           str(other), "--quiet"], cwd=ROOT, capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 2 and "--force" in done.stderr
    assert len(done.stderr.strip().splitlines()) == 1 and "Traceback" not in done.stderr
    assert other.read_text() == '{"mine": 1}\n'
    bad = subprocess.run([sys.executable, "-m", "sebvs.probe", str(small), "--sensors",
                          "sonar"], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and "sonar" in bad.stderr and "Traceback" not in bad.stderr


def test_sebvs_probe_is_a_command_that_explains_itself():
    done = subprocess.run([sys.executable, "-m", "sebvs.cli", "probe", "--help"], cwd=ROOT,
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0
    for words in ("sim's truth", "held-out episodes", "baseline", "AUC", "--json"):
        assert words in done.stdout, words


def test_too_few_episodes_for_the_split_are_refused(tmp_path):
    few = make_truth_dataset(tmp_path / "few", episodes=3)
    with pytest.raises(ValueError, match="3 episode"):
        probe(load_frames(few), "rgb", Recipe(), seed=0)


def test_roc_auc():
    assert roc_auc([0.1, 0.4, 0.35, 0.8], [False, False, True, True]) == 0.75
    assert roc_auc([1, 1, 1], [True, False, True]) == 0.5
    assert roc_auc([1, 2], [True, True]) is None
    rng = np.random.default_rng(0)
    assert abs(roc_auc(rng.normal(size=4000), rng.uniform(size=4000) < 0.5) - 0.5) < 0.05
