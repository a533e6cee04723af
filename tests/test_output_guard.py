"""No command writes over what it did not create: its own input, a dataset's episode files
and its index never; any other existing file only with --force (sebvs/output_guard.py)."""
import hashlib
from pathlib import Path

import cv2
import numpy as np
import pytest

from sebvs.cli import main
from sebvs.output_guard import OutputRefused, check_output_dir, check_output_file

from .test_formats import make_dataset

ROOT = Path(__file__).resolve().parents[1]


def digest(folder: Path) -> dict[str, str]:
    """Every file under ``folder`` and the sha256 of its bytes."""
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture
def dataset(tmp_path) -> Path:
    ds = tmp_path / "ds"
    make_dataset(ds, "nav", episodes=2)
    return ds


@pytest.fixture
def images(tmp_path) -> Path:
    folder = tmp_path / "frames"
    folder.mkdir()
    rng = np.random.default_rng(0)
    for k in range(3):
        cv2.imwrite(str(folder / f"f{k}.png"), rng.integers(0, 255, (16, 16, 3), np.uint8))
    return folder


def test_the_rule_on_files(tmp_path, dataset):
    ep, index = dataset / "episode_0000.h5", dataset / "index.json"
    for path, why in ((ep, "recorded episode"), (dataset / "episode_0001.h5", "recorded"),
                      (index, "dataset's index"), (dataset / "episode_0007.h5", "recorded"),
                      (dataset / "episode_0001.h5.partial", "recorded")):
        with pytest.raises(OutputRefused, match=why):
            check_output_file(path, force=True)
    other = tmp_path / "x.png"
    other.write_bytes(b"old")
    with pytest.raises(OutputRefused, match="exists; give --force"):
        check_output_file(other)
    assert check_output_file(other, force=True) == other
    (tmp_path / "link.png").symlink_to(other)
    with pytest.raises(OutputRefused, match="input"):
        check_output_file(tmp_path / "link.png", inputs=[other], force=True)
    with pytest.raises(OutputRefused, match="a folder"):
        check_output_file(dataset, force=True)
    assert check_output_file(tmp_path / "new.png") == tmp_path / "new.png"


def test_the_rule_on_folders(tmp_path, dataset):
    with pytest.raises(OutputRefused, match="it is a dataset"):
        check_output_dir(dataset, force=True)
    with pytest.raises(OutputRefused, match="input"):
        check_output_dir(dataset, inputs=[dataset], owns=lambda p: True)
    with pytest.raises(OutputRefused, match="a file"):
        check_output_dir(dataset / "index.json")
    busy = tmp_path / "busy"
    busy.mkdir()
    (busy / "notes.txt").write_text("mine")
    with pytest.raises(OutputRefused, match="give --force"):
        check_output_dir(busy)
    assert check_output_dir(busy, force=True) == busy
    assert check_output_dir(busy, owns=lambda p: True) == busy
    assert check_output_dir(tmp_path / "new") == tmp_path / "new"


def hostile_commands(ds: Path, images: Path, tmp: Path) -> list[tuple[list[str], str]]:
    """(argv, what the one-line refusal says) for each writing command and hostile output."""
    ep0, ep1, index = ds / "episode_0000.h5", ds / "episode_0001.h5", ds / "index.json"
    existing = tmp / "existing.out"
    existing.write_bytes(b"keep me")
    topo = str(ROOT / "topologies" / "nav_record.toml")
    return [
        (["data", "export", str(ep0), "--out", str(ep1), "--force"], "recorded episode"),
        (["data", "export", str(ep0), "--out", str(ep0), "--force"], "input"),
        (["data", "export", str(ep0), "--out", str(index), "--force"], "dataset's index"),
        (["data", "export", str(ep0), "--out", str(existing)], "exists"),
        (["data", "export", str(ep0), "--out", str(existing), "--force"], "must end in .mcap"),
        (["events", "export", str(ep0), "--out", str(ep1), "--force"], "recorded episode"),
        (["events", "export", str(ep0), "--out", str(ep0), "--force"], "input"),
        (["events", "export", str(ep0), "--out", str(index), "--force"], "dataset's index"),
        (["events", "export", str(ep0), "--out", str(existing)], "exists"),
        (["events", "show", str(ep0), "--out", str(ep1), "--force"], "recorded episode"),
        (["events", "show", str(ep0), "--out", str(existing)], "exists"),
        (["v2e", str(images), "--fps", "10", "--out", str(ep1), "--force"], "recorded episode"),
        (["v2e", str(images), "--fps", "10", "--out", str(index), "--force"], "dataset's index"),
        (["v2e", str(images), "--fps", "10", "--out", str(existing)], "exists"),
        (["data", "stats", str(ds), "--plot", str(index), "--force"], "dataset's index"),
        (["data", "stats", str(ds), "--plot", str(existing)], "exists"),
        (["record", topo, "--episodes", "1", "--out", str(index)], "a file"),
        (["record", topo, "--episodes", "1", "--out", str(ep1)], "a file"),
        (["record", topo, "--episodes", "1", "--out", str(tmp)], "give --force"),
    ]


def test_every_writing_command_refuses_in_one_line_and_changes_nothing(
        tmp_path, dataset, images, capsys):
    before = digest(tmp_path)
    for argv, expected in hostile_commands(dataset, images, tmp_path):
        before = digest(tmp_path)
        assert main([*argv, "--quiet"] if argv[:2] == ["data", "export"] else argv) == 2, argv
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and expected in err, (argv, err)
        assert digest(tmp_path) == before, argv


def test_view_refuses_to_save_over_an_episode(tmp_path, dataset, capsys):
    pytest.importorskip("rerun")
    ep0, ep1 = dataset / "episode_0000.h5", dataset / "episode_0001.h5"
    before = digest(dataset)
    for out, expected in ((ep1, "recorded episode"), (ep0, "input"),
                          (dataset / "index.json", "dataset's index")):
        assert main(["view", str(ep0), "--save", str(out), "--force"]) == 2
        assert expected in capsys.readouterr().err
    assert digest(dataset) == before


def test_force_replaces_an_existing_output_whole(tmp_path, dataset, capsys):
    out = tmp_path / "ep.mcap"
    out.write_bytes(b"old")
    assert main(["data", "export", str(dataset / "episode_0000.h5"), "--out", str(out),
                 "--quiet"]) == 2
    assert out.read_bytes() == b"old"
    assert main(["data", "export", str(dataset / "episode_0000.h5"), "--out", str(out),
                 "--quiet", "--force"]) == 0
    assert out.read_bytes()[:5] == b"\x89MCAP"
    capsys.readouterr()


def test_a_second_export_of_a_dataset_needs_force(dataset, capsys):
    assert main(["data", "export", str(dataset), "--quiet"]) == 0
    first = digest(dataset / "mcap")
    assert main(["data", "export", str(dataset), "--quiet"]) == 2
    assert "exists; give --force" in capsys.readouterr().err
    assert main(["data", "export", str(dataset), "--quiet", "--force"]) == 0
    assert digest(dataset / "mcap").keys() == first.keys()


def test_train_writes_neither_into_its_dataset_nor_over_a_finished_checkpoint(
        tmp_path, capsys):
    from tests.policy_data import make_dataset as make_policy_dataset
    data = make_policy_dataset(tmp_path / "data", episodes=3, frames=8)
    before = digest(data)
    train = ["train", "--task", "nav", "--modality", "rgb", "--data", str(data),
             "--epochs", "1", "--size", "32", "--no-progress"]
    assert main([*train, "--out", str(data)]) == 2
    assert "this command's input" in capsys.readouterr().err
    assert digest(data) == before
    ck = tmp_path / "ck"
    assert main([*train, "--out", str(ck)]) == 0
    trained = digest(ck)
    assert main([*train, "--out", str(ck)]) == 2
    assert "nav-rgb.pt: exists; give --force" in capsys.readouterr().err
    assert digest(ck) == trained
    assert main([*train, "--out", str(ck), "--force"]) == 0


@pytest.mark.parametrize("seed", ["-1", str(2 ** 31), str(2 ** 32 + 5), "x"])
def test_train_refuses_a_seed_outside_the_one_range(seed, capsys):
    with pytest.raises(SystemExit) as stop:
        main(["train", "--task", "nav", "--modality", "rgb", "--data", "d", "--out", "o",
              "--seed", seed])
    assert stop.value.code == 2 and "--seed" in capsys.readouterr().err


def test_eval_writes_neither_into_a_dataset_nor_into_its_checkpoints(tmp_path, dataset,
                                                                     capsys):
    ck = tmp_path / "ck"
    ck.mkdir()
    (ck / "nav-rgb.pt").write_bytes(b"weights")
    busy = tmp_path / "busy"
    busy.mkdir()
    (busy / "notes.txt").write_text("mine")
    for out, expected in ((dataset, "it is a dataset"), (ck, "this command's input"),
                          (busy, "give --force"), (dataset / "index.json", "a file")):
        assert main(["eval", "--modalities", "rgb", "--checkpoints", str(ck), "--episodes",
                     "1", "--out", str(out)]) == 2
        err = capsys.readouterr().err
        assert expected in err and len(err.strip().splitlines()) == 1, err
    assert (ck / "nav-rgb.pt").read_bytes() == b"weights"


def test_eval_refuses_a_seed_that_would_wrap(capsys):
    with pytest.raises(SystemExit) as stop:
        main(["eval", "--seed", str(2 ** 31 + 100_000), "--out", "o"])
    assert stop.value.code == 2 and "2**31" in capsys.readouterr().err
