"""Training on several datasets at once (DAgger's rounds beside the expert's recording):
each entry read from its own dataset, one split by episode, every dataset in the config's
record; datasets of different tasks or event frames refused in one line naming both."""
import json
from pathlib import Path

import numpy as np
import pytest
import torch

from sebvs.cli import main
from sebvs.policy.dataset import EpisodeFrames, dataset_hash, load_datasets, load_index
from sebvs.policy.inputs import Modality, Normalisation
from sebvs.policy.train import load_training_data, settings_for, train
from tests.policy_data import make_dataset

torch.set_num_threads(1)
QUIET = dict(progress=False, log=lambda s: None)
NORM = Normalisation(size=32)


@pytest.fixture(scope="module")
def two(tmp_path_factory):
    root = tmp_path_factory.mktemp("multi")
    return (make_dataset(root / "a", episodes=4, frames=8, seed=1),
            make_dataset(root / "b", episodes=3, frames=6, seed=2))


def test_entries_are_read_from_their_own_dataset(two):
    a, b = two
    episodes = load_datasets([a, b], "nav")
    # both datasets name their files episode_0000.h5...: the entry's root tells them apart
    assert [e["file"] for e in episodes[:2]] == [e["file"] for e in episodes[4:6]]
    assert [e["root"] for e in episodes] == [str(a)] * 4 + [str(b)] * 3
    both = EpisodeFrames(a, episodes, "nav", "rgb+event", NORM)
    alone = EpisodeFrames(b, load_index(b, "nav"), "nav", "rgb+event", NORM)
    assert len(both) == 4 * 8 + 3 * 6
    for i in range(len(alone)):
        x, y = both[32 + i]
        x_b, y_b = alone[i]
        np.testing.assert_array_equal(x, x_b)
        np.testing.assert_array_equal(y, y_b)
    assert not np.array_equal(both[0][0], both[32][0])    # a's episode 0 is not b's


def test_one_dataset_splits_and_hashes_as_before(two):
    a, _ = two
    s = settings_for("nav", norm=NORM)
    rgb = Modality.parse("rgb")
    one, listed = load_training_data(a, rgb, s, **QUIET), load_training_data([a], rgb, s, **QUIET)
    try:
        assert [e["file"] for e in one.val_episodes] == [e["file"] for e in listed.val_episodes]
        assert all("root" not in e for e in listed.episodes)   # the index's entries as they are
        assert dataset_hash(a, one.episodes) == dataset_hash(a, listed.episodes)
    finally:
        one.close()
        listed.close()


def test_two_datasets_train_together_and_the_config_records_both(two, tmp_path):
    a, b = two
    res = train([a, b], tmp_path, "nav", ["rgb"], epochs=1, batch=8, norm=NORM, **QUIET)
    record = json.loads((tmp_path / "nav-rgb.json").read_text())["dataset"]
    assert record == res["rgb"]["dataset"]
    assert [d["path"] for d in record["datasets"]] == [str(a), str(b)]
    assert [d["episodes"] for d in record["datasets"]] == [4, 3]
    assert record["datasets"][0]["hash"] == dataset_hash(a, load_index(a))
    assert record["datasets"][1]["hash"] == dataset_hash(b, load_index(b))
    assert record["hash"] not in (record["datasets"][0]["hash"], record["datasets"][1]["hash"])
    # the old keys still work for readers: path, and names that path / name resolves
    assert record["path"] == str(a)
    names = record["train_episodes"] + record["val_episodes"]
    assert len(names) == 7 and len(set(names)) == 7
    files = {Path(record["path"]) / n for n in names}
    assert files == {a / f"episode_{k:04d}.h5" for k in range(4)} | \
        {(b / f"episode_{k:04d}.h5").resolve() for k in range(3)}
    assert record["train_frames"] + record["val_frames"] == 4 * 8 + 3 * 6
    # one dataset: its record as before, plus the one-entry list
    single = train(a, tmp_path / "one", "nav", ["rgb"], epochs=1, batch=8, norm=NORM,
                   **QUIET)["rgb"]["dataset"]
    assert all("/" not in n for n in single["train_episodes"] + single["val_episodes"])
    assert single["datasets"] == [{"path": str(a), "hash": single["hash"], "episodes": 4}]


def test_datasets_of_other_tasks_or_event_frames_are_refused_naming_both(two, tmp_path):
    a, _ = two
    arm = make_dataset(tmp_path / "arm", episodes=2, frames=4, task="arm")
    with pytest.raises(ValueError) as info:
        load_datasets([a, arm])
    text = str(info.value)
    assert "\n" not in text and str(a) in text and str(arm) in text and "task" in text
    bins = make_dataset(tmp_path / "bins", episodes=2, frames=4, event_bins=2)
    s = settings_for("nav", norm=NORM)
    with pytest.raises(ValueError) as info:
        load_training_data([a, bins], Modality.parse("event"), s, **QUIET)
    text = str(info.value)
    assert "\n" not in text and str(a) in text and str(bins) in text
    assert "event representation" in text
    # the same dataset twice would count its episodes twice
    with pytest.raises(ValueError, match="given twice"):
        load_datasets([a, a])


def test_sebvs_train_takes_data_repeated_and_refuses_a_mismatch_in_one_line(two, tmp_path,
                                                                            capsys):
    a, b = two
    arm = make_dataset(tmp_path / "arm", episodes=2, frames=4, task="arm")
    base = ["train", "--task", "nav", "--modality", "rgb", "--size", "32", "--epochs", "1",
            "--no-progress"]
    assert main([*base, "--data", str(a), "--data", str(b), "--out", str(tmp_path / "ck")]) == 0
    cfg = json.loads((tmp_path / "ck" / "nav-rgb.json").read_text())
    assert [d["path"] for d in cfg["dataset"]["datasets"]] == [str(a), str(b)]
    capsys.readouterr()
    code = main([*base, "--data", str(a), "--data", str(arm), "--out", str(tmp_path / "x")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and str(arm) in err, err
    # training into one of its datasets is refused, whichever --data it is
    code = main([*base, "--data", str(a), "--data", str(b), "--out", str(b)])
    assert code == 2 and "input" in capsys.readouterr().err
