"""Training sweeps (`sebvs train-sweep`): grid files, one directory per point, sweep.json and
sweep.md, resume, a failing point, and the same losses on one worker, two, and Ray."""
import importlib.util
import json
import os
import shutil

import pytest
import torch

from sebvs.cli import main
from sebvs.policy.inputs import Normalisation
from sebvs.policy.sweep import SweepError, plan_sweep
from sebvs.policy.sweep_grid import GridError, load_grid, parse_grid
from sebvs.policy.train import train
from sebvs.scale import disjoint_cpu_sets
from tests.policy_data import make_dataset

torch.set_num_threads(1)
# a 2 x 2 grid: two modalities, two seeds; 1 epoch on 32 frames of 32 px
GRID = """task = "nav"
data = "{data}"

[train]
epochs = {epochs}
size = 32
max_frames = 32
batch = 8

[axes]
modality = ["rgb", "event"]
seed = [0, 1]
"""
NAMES = {"modality=rgb__seed=0", "modality=rgb__seed=1",
         "modality=event__seed=0", "modality=event__seed=1"}


@pytest.fixture(scope="module")
def grid_file(tmp_path_factory):
    root = tmp_path_factory.mktemp("sweep")
    data = make_dataset(root / "data", episodes=4, frames=16, target="gain")
    path = root / "grid.toml"
    path.write_text(GRID.format(data=data, epochs=1))
    return path


def sweep(grid, out, *extra) -> int:
    return main(["train-sweep", str(grid), "--out", str(out), "--threads", "1",
                 "--no-progress", *extra])


def losses(out) -> dict:
    points = json.loads((out / "sweep.json").read_text())["points"]
    return {p["name"]: p["best_val_loss"] for p in points}


@pytest.fixture(scope="module")
def one_worker(grid_file, tmp_path_factory):
    out = tmp_path_factory.mktemp("one") / "sweep"
    assert sweep(grid_file, out) == 0
    return out


def test_points_are_the_product_of_the_axes_named_by_their_values():
    raw = {"task": "arm", "data": "d", "train": {"modality": "rgb+event", "epochs": 3},
           "axes": {"lr": [5e-4, 1e-3], "stem": ["patch", "conv"], "seed": [2]}}
    grid = parse_grid(raw)
    names = [p.name for p in grid.points()]
    assert names == ["modality=rgb+event__seed=2__lr=0.0005__stem=patch",
                     "modality=rgb+event__seed=2__lr=0.0005__stem=conv",
                     "modality=rgb+event__seed=2__lr=0.001__stem=patch",
                     "modality=rgb+event__seed=2__lr=0.001__stem=conv"]
    # the names depend on the values, not on the order the file lists the axes in
    raw["axes"] = dict(reversed(list(raw["axes"].items())))
    assert sorted(p.name for p in parse_grid(raw).points()) == sorted(names)
    p = grid.points()[1]
    assert p.settings == {"modality": "rgb+event", "epochs": 3, "seed": 2, "lr": 5e-4,
                          "stem": "conv"}
    # the rgb+diff control sweeps like the paper's modalities
    assert [p.name for p in parse_grid({"task": "arm", "data": "d", "axes": {
        "modality": ["rgb+event", "rgb+diff"]}}).points()] == \
        ["modality=rgb+event__seed=0", "modality=rgb+diff__seed=0"]
    assert parse_grid({"task": "nav", "data": "d", "train": {"modality": "rgb"},
                       "axes": {"size": ["paper"]}}).points()[0].name == \
        "modality=rgb__seed=0__size=640"


@pytest.mark.parametrize("raw, message", [
    ({"task": "nav", "data": "d", "axes": {"seed": [0]}}, "modality: not set"),
    ({"task": "nav", "data": "d", "train": {"modality": "rgb", "lrate": 1}},
     r"\[train\] lrate: unknown setting"),
    ({"task": "nav", "data": "d", "train": {"modality": "rgb"}, "axes": {"lr": 1e-3}},
     r"\[axes\] lr: expected a non-empty list"),
    ({"task": "nav", "data": "d", "train": {"modality": "rgb"}, "axes": {"lr": [1e-3, 0.001]}},
     r"\[axes\] lr: 0.001 listed twice"),
    ({"task": "nav", "data": "d", "axes": {"modality": ["rgb", "depth"]}},
     r"\[axes\] modality\[1\]: expected one of rgb, event, rgb\+event, rgb\+diff, got 'depth'"),
    ({"task": "nav", "data": "d", "train": {"modality": "rgb", "size": 40}},
     r"\[train\] size: size 40 must be a positive multiple of 16"),
    ({"task": "nav", "data": "d", "train": {"modality": "rgb", "epochs": 0}},
     r"\[train\] epochs: must be at least 1"),
    ({"task": "nav", "data": "d", "train": {"modality": "rgb", "threads": 2}},
     r"\[train\] threads: set on the command line \(--threads\)"),
    ({"task": "nav", "data": "d", "train": {"modality": "rgb"}, "axes": {"modality": ["rgb"]}},
     r"\[axes\] modality: also set in \[train\]"),
    ({"task": "nav", "data": "d", "seed": 1}, "seed: unknown key"),
    ({"data": "d"}, "task: expected one of nav, arm"),
])
def test_a_bad_grid_names_the_key_and_why(raw, message):
    with pytest.raises(GridError, match=message):
        parse_grid(raw, "g.toml")


def test_a_bad_grid_file_is_one_line_and_status_2(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text('task = "nav"\ndata = "d"\n[axes]\nmodality = ["rgb"]\nlr = [-1.0]\n')
    assert sweep(bad, tmp_path / "out") == 2
    assert capsys.readouterr().err == \
        f"sebvs train-sweep: grid {bad}: [axes] lr[0]: must be positive, got -1.0\n"
    with pytest.raises(GridError, match="no such file"):
        load_grid(tmp_path / "missing.toml")


def test_each_point_trains_as_sebvs_train_into_its_own_directory(one_worker, grid_file,
                                                                 tmp_path):
    assert {d.name for d in one_worker.iterdir() if d.is_dir()} == NAMES
    summary = json.loads((one_worker / "sweep.json").read_text())
    assert summary["task"] == "nav" and summary["train"]["epochs"] == 1
    assert summary["axes"] == {"modality": ["rgb", "event"], "seed": [0, 1]}
    for p in summary["points"]:
        modality = p["settings"]["modality"]
        config = json.loads((one_worker / p["dir"] / f"nav-{modality}.json").read_text())
        assert p["status"] == "trained" and p["error"] is None
        assert p["best_val_loss"] == config["training"]["best_val_loss"]
        assert p["epochs_run"] == 1 and p["parameters"] == config["parameters"]
        assert p["settings"]["size"] == 32 and p["settings"]["lr"] == 2e-4    # nav default
        assert (one_worker / p["dir"] / "train.log").read_text().count("epoch 1:") == 1
    # the same weights as `train` (what `sebvs train` calls) with the point's settings
    train(grid_file.parent / "data", tmp_path, "nav", ["event"], progress=False,
          log=lambda line: None, epochs=1, batch=8, max_frames=32, seed=1, threads=1,
          norm=Normalisation(size=32))
    direct = torch.load(tmp_path / "nav-event.pt", weights_only=True)
    swept = torch.load(one_worker / "modality=event__seed=1" / "nav-event.pt",
                       weights_only=True)
    assert all(torch.equal(direct[k], swept[k]) for k in direct)


def test_the_table_sorts_points_and_seed_groups_by_validation_loss(one_worker):
    table = (one_worker / "sweep.md").read_text()
    best = losses(one_worker)
    rows = [line for line in table.splitlines() if line.startswith("| modality=")]
    assert [r.split(" | ")[0][2:] for r in rows] == sorted(best, key=best.get)
    groups = table.split("## Per setting")[1].split("## Every point")[0]
    means = {m: (best[f"modality={m}__seed=0"] + best[f"modality={m}__seed=1"]) / 2
             for m in ("rgb", "event")}
    group_rows = [line for line in groups.splitlines() if line.startswith(("| rgb ", "| event "))]
    assert [r.split(" | ")[0][2:] for r in group_rows] == sorted(means, key=means.get)
    assert all(f"| 2 | {means[m]:.5g} |" in table for m in means)
    assert "4 point(s): 4 trained." in table


def test_a_rerun_skips_trained_points_and_refuses_changed_settings(one_worker, grid_file,
                                                                   tmp_path, capsys):
    out = tmp_path / "again"
    shutil.copytree(one_worker, out)
    weights = {n: next((out / n).glob("*.pt")) for n in NAMES}
    before = {n: pt.stat().st_mtime_ns for n, pt in weights.items()}
    assert sweep(grid_file, out) == 0
    assert "4 trained before (skipped), nothing to train" in capsys.readouterr().err
    assert {n: pt.stat().st_mtime_ns for n, pt in weights.items()} == before
    summary = json.loads((out / "sweep.json").read_text())
    assert {p["status"] for p in summary["points"]} == {"skipped"}
    assert losses(out) == losses(one_worker)     # read back from the points' configs
    assert main(["train-sweep", str(grid_file), "--out", str(out), "--dry-run"]) == 0
    assert capsys.readouterr().out.count("trained before (best val loss") == 4
    # the grid edited under the same output: the old points are not taken for new ones
    edited = grid_file.with_name("edited.toml")
    edited.write_text(GRID.format(data=grid_file.parent / "data", epochs=2))
    with pytest.raises(SweepError, match=r"trained before with epochs=1, but the grid now "
                                         r"asks for epochs=2"):
        plan_sweep(load_grid(edited), out)


def test_a_failing_point_is_recorded_and_the_others_train(grid_file, tmp_path, capsys):
    out = tmp_path / "sweep"
    out.mkdir()
    (out / "modality=rgb__seed=1").write_text("in the way")    # the point cannot make its dir
    assert sweep(grid_file, out) == 1
    points = {p["name"]: p for p in json.loads((out / "sweep.json").read_text())["points"]}
    failed = points["modality=rgb__seed=1"]
    assert failed["status"] == "failed" and failed["error"].startswith("FileExistsError")
    assert {p["status"] for n, p in points.items() if n != failed["name"]} == {"trained"}
    table = (out / "sweep.md").read_text()
    assert "## Failed" in table and "| modality=rgb__seed=1 | FileExistsError" in table
    assert "| rgb | 1 of 2 |" in table
    assert "[2/4] modality=rgb__seed=1: FAILED: FileExistsError" in capsys.readouterr().err
    # once the obstacle is gone the next run trains that point alone
    (out / "modality=rgb__seed=1").unlink()
    assert sweep(grid_file, out) == 0
    assert "3 trained before (skipped), 1 to train" in capsys.readouterr().err


def test_two_workers_give_the_same_weights_as_one(one_worker, grid_file, tmp_path, capfd):
    out = tmp_path / "two"
    # bars not turned off here: running points at once must turn them off by itself
    assert main(["train-sweep", str(grid_file), "--out", str(out), "--threads", "1",
                 "--workers", "2"]) == 0
    assert losses(out) == losses(one_worker)
    for name in NAMES:
        m = name.split("__")[0].split("=")[1]
        a, b = (torch.load(d / name / f"nav-{m}.pt", weights_only=True)
                for d in (one_worker, out))
        assert all(torch.equal(a[k], b[k]) for k in a)
    err = capfd.readouterr().err
    assert sum(f"[{k}/4]" in err for k in range(1, 5)) == 4
    assert "batch/s" not in err            # no per-point bars when points run at once
    run = json.loads((out / "sweep.json").read_text())["run"]
    if len(os.sched_getaffinity(0)) >= 2:   # a worker per CPU
        assert len(run["cpu_sets"]) == 2 and not set(run["cpu_sets"][0]) & set(run["cpu_sets"][1])


def test_cpu_sets_are_disjoint_and_only_when_there_are_enough(monkeypatch):
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1, 2, 3, 4, 5, 6, 7})
    assert disjoint_cpu_sets(2, 3) == [(0, 1, 2), (3, 4, 5)]
    assert disjoint_cpu_sets(8, 1) == [(i,) for i in range(8)]
    assert disjoint_cpu_sets(3, 3) is None


def test_the_sweep_on_a_local_ray_gives_the_same_losses(one_worker, grid_file, tmp_path):
    pytest.importorskip("ray", reason="Ray is an optional extra: pip install -e .[ray]")
    out = tmp_path / "ray"
    assert sweep(grid_file, out, "--ray") == 0
    assert losses(out) == losses(one_worker)
    run = json.loads((out / "sweep.json").read_text())["run"]
    assert run["ray"] == "" and run["threads"] == 1


def test_ray_missing_and_gpu_options_are_one_line_errors(grid_file, tmp_path, monkeypatch,
                                                         capsys):
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "ray" else real(name, *a))
    assert sweep(grid_file, tmp_path / "r", "--ray") == 2
    assert sweep(grid_file, tmp_path / "g", "--gpus-per-task", "1") == 2
    err = capsys.readouterr().err.splitlines()
    assert err[0] == "sebvs train-sweep: --ray needs Ray, which is not installed: " \
                     "pip install -e .[ray]"
    assert err[1].startswith("sebvs train-sweep: --gpus-per-task is for --ray with --device cuda")
