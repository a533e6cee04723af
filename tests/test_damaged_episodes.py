"""A damaged episode is refused by name wherever it is read, even one that still decodes:
training, export, stats and view check it against the index first (sebvs/dataset_files.py),
and every HDF5 error names its file (sebvs/h5named.py)."""
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest

from sebvs.cli import main
from sebvs.data.episode import open_episode
from sebvs.dataset_files import EpisodeDamaged, damaged, verify_entries
from sebvs.h5named import FileUnreadable

from .test_formats import make_dataset

VICTIM = "episode_0000.h5"


def chunk_span(path: Path, dataset: str = "rgb") -> tuple[int, int]:
    """(byte offset, size) of the first stored chunk of ``dataset``."""
    with h5py.File(path, "r") as f:
        info = f[dataset].id.get_chunk_info(0)
    return int(info.byte_offset), int(info.size)


def damage(path: Path, how: str) -> None:
    """Damage an episode file in place, as a disk or a copy would."""
    data = bytearray(path.read_bytes())
    if how == "truncated":
        del data[len(data) // 2:]
    elif how == "zeroed":
        data[len(data) // 3:len(data) // 3 + 4096] = bytes(4096)
    elif how == "header-flipped":
        data[:64] = bytes(b ^ 0xFF for b in data[:64])
    elif how == "chunk-flipped":       # inside one compressed rgb chunk: it may still decode
        at, size = chunk_span(path)
        n = min(4096, size // 2)
        data[at + size // 4:at + size // 4 + n] = bytes(b ^ 0x5A for b in
                                                        data[at + size // 4:at + size // 4 + n])
    else:
        raise ValueError(how)
    path.write_bytes(bytes(data))


HOW = ("truncated", "zeroed", "header-flipped", "chunk-flipped")


@pytest.fixture(scope="module")
def pristine(tmp_path_factory) -> Path:
    ds = tmp_path_factory.mktemp("pristine") / "ds"
    make_dataset(ds, "nav", episodes=2)
    return ds


@pytest.fixture(params=HOW)
def hurt(request, pristine, tmp_path) -> Path:
    ds = tmp_path / "ds"
    shutil.copytree(pristine, ds)
    damage(ds / VICTIM, request.param)
    return ds


def readers(ds: Path, tmp: Path) -> list[list[str]]:
    ep = str(ds / VICTIM)
    return [["train", "--task", "nav", "--modality", "rgb", "--data", str(ds), "--out",
             str(tmp / "ck"), "--epochs", "1", "--no-progress"],
            ["data", "export", str(ds), "--out", str(tmp / "mcap"), "--quiet"],
            ["data", "export", ep, "--out", str(tmp / "one.mcap"), "--quiet"],
            ["events", "export", ep, "--out", str(tmp / "ev.h5"), "--quiet"],
            ["events", "show", ep, "--out", str(tmp / "ev.png")],
            ["data", "stats", str(ds)]]


def test_every_reader_refuses_a_damaged_episode_by_name(hurt, tmp_path, capsys):
    for argv in readers(hurt, tmp_path):
        code = main(argv)
        err = capsys.readouterr().err
        assert code == (1 if argv[:2] == ["data", "stats"] else 2), (argv, err)
        assert VICTIM in err and "Traceback" not in err, (argv, err)
    assert not (tmp_path / "ck" / "nav-rgb.pt").exists()


def test_view_refuses_a_damaged_episode_by_name(hurt, tmp_path, capsys):
    pytest.importorskip("rerun")
    assert main(["view", str(hurt / VICTIM), "--save", str(tmp_path / "x.rrd")]) == 2
    err = capsys.readouterr().err
    assert VICTIM in err and len(err.strip().splitlines()) == 1


def test_stats_leaves_the_damaged_episode_out_and_counts_the_rest(hurt, capsys):
    assert main(["data", "stats", str(hurt)]) == 1
    out = capsys.readouterr().out
    assert "episodes           1" in out and f"damaged, left out: {VICTIM}" in out


def test_a_flipped_chunk_that_decodes_is_caught_by_the_index(pristine, tmp_path):
    ds = tmp_path / "ds"
    shutil.copytree(pristine, ds)
    damage(ds / VICTIM, "chunk-flipped")
    from sebvs.data.index import DatasetIndex
    entries = DatasetIndex(ds).episodes()
    assert [line.split(":")[0] for line in damaged(ds, entries)] == [VICTIM]
    with pytest.raises(EpisodeDamaged, match=VICTIM) as err:
        verify_entries(ds, entries)
    assert err.value.names == [VICTIM] and "\n" not in str(err.value)


def test_unindexed_damage_still_names_the_file(pristine, tmp_path):
    """A lone episode has no index to check it by: HDF5's own errors carry its name."""
    for how in HOW:
        lone = tmp_path / f"{how}.h5"
        shutil.copy(pristine / VICTIM, lone)
        damage(lone, how)
        raised = None
        try:
            with open_episode(lone) as ep:
                for k in range(len(ep)):
                    ep.rgb[k]
        except FileUnreadable as exc:
            raised = str(exc)
        if how in ("truncated", "header-flipped"):
            assert raised is not None, how
        # a zeroed block or a flipped chunk may decode (LZF has no checksum): that is what
        # the index's sha256 is for
        if raised is not None:
            assert raised.startswith(str(lone)) and "\n" not in raised, (how, raised)


def test_whole_files_are_hashed_once_per_process(pristine, monkeypatch):
    from sebvs import dataset_files
    from sebvs.data.index import DatasetIndex
    entries = DatasetIndex(pristine).episodes()
    calls = []
    real = dataset_files.file_sha256
    monkeypatch.setattr(dataset_files, "file_sha256", lambda p: calls.append(p) or real(p))
    monkeypatch.setattr(dataset_files, "_VERIFIED", {})
    verify_entries(pristine, entries)
    verify_entries(pristine, entries)
    assert len(calls) == len(entries)


def test_an_index_that_is_not_one_is_refused_by_name(pristine, tmp_path, capsys):
    ds = tmp_path / "ds"
    shutil.copytree(pristine, ds)
    for text in (b"\x89MCAP0\r\n", b"[]", b'{"episodes": [{"file": "../../etc/passwd"}]}'):
        (ds / "index.json").write_bytes(text)
        assert main(["data", "stats", str(ds)]) == 2
        err = capsys.readouterr().err
        assert "index.json: not a dataset index" in err, err
