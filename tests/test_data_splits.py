"""The protocol's seed ranges, and `sebvs record` refusing the held-out ones."""
from pathlib import Path

import pytest

from sebvs.cli import main
from sebvs.data.splits import SPLITS, check_recording_seed, split_of

NAV_RECORD = Path(__file__).resolve().parents[1] / "topologies" / "nav_record.toml"


def test_ranges_are_disjoint_and_keep_the_seeds_already_used():
    ranges = sorted(SPLITS.values(), key=lambda r: r.first)
    assert all(a.last < b.first for a, b in zip(ranges, ranges[1:]))
    assert all(s in SPLITS["train"] for s in range(9))     # the shipped datasets: 0-8
    assert 1000 in SPLITS["dev"] and 2000 in SPLITS["dev"]  # docs/results.md's figures
    assert split_of(SPLITS["test"].first) == "test" and split_of(10 ** 9) is None
    assert split_of(999) == "train" and split_of(1000) == "dev"


def test_recording_seed_check():
    assert check_recording_seed(0) is None
    assert "dev" in check_recording_seed(1000)
    for seed in (SPLITS["test"].first, SPLITS["test"].last):
        with pytest.raises(ValueError, match="test split"):
            check_recording_seed(seed)


@pytest.mark.parametrize("how", ["set", "file"])
def test_record_refuses_a_test_seed_before_anything_starts(tmp_path, capsys, how):
    topology, extra = NAV_RECORD, ["--set", f"topology.seed={SPLITS['test'].first + 3}"]
    if how == "file":      # a seed written in the topology file is refused the same way
        text = NAV_RECORD.read_text().replace("seed = 0", f"seed = {SPLITS['test'].last}")
        topology, extra = tmp_path / "record.toml", []
        topology.write_text(text)
    code = main(["record", str(topology), "--episodes", "1", "--out", str(tmp_path / "data"),
                 "--runs-dir", str(tmp_path / "runs"), "--quiet", *extra])
    err = capsys.readouterr().err
    assert code == 2
    assert len(err.strip().splitlines()) == 1 and "test split's reserved range" in err
    assert not (tmp_path / "data").exists() and not (tmp_path / "runs").exists()
