"""`sebvs train-dagger` end to end on a tiny scale: round 0 trains on the expert's recording,
round 1 records with that policy driving and the expert labelling, then trains on both;
a second call skips what the ledger says is finished, and resumes a round stopped
between its training and its ledger line; other settings are refused in one line."""
import json
import os
from pathlib import Path

import pytest

from sebvs.cli import main
from sebvs.data.check import check_dataset
from sebvs.data.episode import open_episode
from sebvs.data.index import DatasetIndex
from sebvs.policy.dagger import (LEDGER, DaggerError, DaggerSettings, check_seeds, round_seed,
                                 run_dagger)
from sebvs.policy.inputs import Normalisation

ROOT = Path(__file__).resolve().parents[1]
# tiny nav recordings (as tests/test_scale.py's): 32 px images and event frames
SMALL = ("sim.config.width=32", "sim.config.height=32", "accumulator.out_width=32",
         "accumulator.out_height=32")


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    """The expert's recording: two one-second nav episodes on topology seed 0."""
    out = tmp_path_factory.mktemp("dagger") / "base"
    sets = [a for line in SMALL for a in ("--set", line)]
    assert main(["record", str(ROOT / "topologies" / "nav_record.toml"), "--episodes", "2",
                 "--out", str(out), "--runs-dir", str(out.parent / "runs"), "--quiet",
                 "--set", "sim.episode_s=1.0", *sets]) == 0
    return out


def settings(base, **kw) -> DaggerSettings:
    return DaggerSettings("nav", "rgb", (str(base),), episodes=2, episode_s=1.0, sets=SMALL,
                          train=dict(epochs=1, batch=8, norm=Normalisation(size=32)), **kw)


def runs_of(out: Path) -> list[str]:
    return sorted(str(p.relative_to(out)) for p in out.glob("round-*/runs/*"))


def test_a_round_records_with_the_policy_driving_and_trains_on_everything(base, tmp_path):
    out, lines = tmp_path / "dagger", []
    ledger = run_dagger(settings(base), out, rounds=1, progress=False, log=lines.append)
    assert [r["round"] for r in ledger["rounds"]] == [0, 1]
    assert json.loads((out / LEDGER).read_text()) == ledger
    r1 = ledger["rounds"][1]
    assert r1["seed"] == round_seed(500, 1) == 500
    assert r1["driver"] == str(out / "round-0" / "checkpoints" / "nav-rgb.pt")
    assert r1["data"]["episodes"] == 2 and r1["data"]["frames"] == 22
    assert r1["disagreement"] > 0 and r1["wall_s"] > 0
    assert any(line.startswith("dagger round 1/1: recording 2 episode(s) on topology seed 500")
               for line in lines)
    # the round's data: checked, driven by the rgb policy, labelled by the expert
    data = out / "round-1" / "data"
    assert check_dataset(data).ok
    for path in DatasetIndex(data).episode_paths():
        with open_episode(path) as ep:
            assert ep.attrs["driver"] == "policy:rgb"
            assert ep.attrs["topology"]["content"]["topology"]["seed"] == 500
            assert ep.drive.shape == ep.action.shape == (11, 2)
            assert (ep.drive[:] != ep.action[:]).any()
    # round 1's policy trained on the base data and round 1's together
    cfg = json.loads((out / "round-1" / "checkpoints" / "nav-rgb.json").read_text())
    assert [d["path"] for d in cfg["dataset"]["datasets"]] == [str(base), str(data)]
    assert r1["datasets"] == [{k: d[k] for k in ("path", "hash")}
                              for d in cfg["dataset"]["datasets"]]

    # a second call: every round finished, nothing recorded or trained again
    pt = out / "round-1" / "checkpoints" / "nav-rgb.pt"
    stamp, runs, lines = os.stat(pt).st_mtime_ns, runs_of(out), []
    assert run_dagger(settings(base), out, rounds=1, progress=False, log=lines.append) == ledger
    assert os.stat(pt).st_mtime_ns == stamp and runs_of(out) == runs
    assert lines[-1].startswith("dagger: round 1 finished before")

    # stopped after round 1's training, before its ledger line: its episodes are all
    # there (nothing to fill) and its checkpoint was trained on these datasets (taken)
    stopped = {**ledger, "rounds": ledger["rounds"][:1]}
    (out / LEDGER).write_text(json.dumps(stopped))
    lines = []
    again = run_dagger(settings(base), out, rounds=1, progress=False, log=lines.append)
    assert os.stat(pt).st_mtime_ns == stamp and runs_of(out) == runs
    assert any("taken as it is" in line for line in lines)
    assert again["rounds"][1]["data"] == r1["data"]
    assert again["rounds"][1]["checkpoint"] == r1["checkpoint"]

    # other settings are refused in one line, nothing written
    with pytest.raises(DaggerError) as info:
        run_dagger(settings(base, first_seed=600), out, rounds=1, progress=False,
                   log=lines.append)
    text = str(info.value)
    assert "\n" not in text and "--first-seed was 500, now 600" in text
    assert json.loads((out / LEDGER).read_text()) == again

    # one more round: driven by round 1's policy, on the next seed, trained on all three;
    # round 1 left as it was
    index_bytes = (data / "index.json").read_bytes()
    ledger = run_dagger(settings(base), out, rounds=2, progress=False, log=lines.append)
    r2 = ledger["rounds"][2]
    assert (r2["round"], r2["seed"], r2["driver"]) == (2, 501, str(pt))
    assert [d["path"] for d in r2["datasets"]] == \
        [str(base), str(data), str(out / "round-2" / "data")]
    assert ledger["rounds"][:2] == again["rounds"]
    assert os.stat(pt).st_mtime_ns == stamp and (data / "index.json").read_bytes() == index_bytes


def test_the_command_refuses_seeds_outside_train_and_the_base_data_s(base, tmp_path, capsys):
    with pytest.raises(DaggerError, match=r"round 2's topology seed 1000 .* outside the "
                                          r"train split \(0-999\)"):
        check_seeds(settings(base, first_seed=999), 2)
    with pytest.raises(DaggerError, match=f"seed 0 is one base dataset {base} was recorded"):
        check_seeds(settings(base, first_seed=0), 1)
    assert check_seeds(settings(base), 3) == [500, 501, 502]
    args = ["train-dagger", "--modality", "rgb", "--data", str(base), "--out",
            str(tmp_path / "d"), "--rounds", "1", "--episodes", "2"]
    assert main([*args, "--task", "nav", "--first-seed", "0"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--first-seed" in err, err
    # the arm has no DAgger topology: its policy's poses change no frame
    assert main([*args, "--task", "arm"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "no DAgger topology for task 'arm'" in err, err
    # --init names a folder that must hold the modality's checkpoint
    assert main([*args, "--task", "nav", "--init", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "no nav-rgb.pt in it" in err, err
    assert not (tmp_path / "d" / LEDGER).exists()
