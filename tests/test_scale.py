"""Fan-out of episodes (sebvs/scale): any worker count records the same episode files and
writes the same results.json; failed workers are retried, then named; a dead driver's
finished episodes are adopted; Ray is optional."""
import importlib.util
import json
import os
import shutil
import sys
from dataclasses import dataclass
from pathlib import Path

import h5py
import pytest

from sebvs.cli import main
from sebvs.data.check import check_dataset
from sebvs.data.compare import dataset_names, episode_differences
from sebvs.data.index import DatasetIndex
from sebvs.data.record import SHARD_INFO, STAGING, adopt_staged
from sebvs.scale import RayMissing, Shard, ShardsLost, Task, fan_out, split_episodes

ROOT = Path(__file__).resolve().parents[1]
# tiny nav recordings: 32 px images, half-second episodes
SMALL_RECORD = ["--set", "sim.episode_s=0.5", "--set", "sim.config.width=32",
                "--set", "sim.config.height=32", "--set", "accumulator.out_width=32",
                "--set", "accumulator.out_height=32"]
# the expert alone (no checkpoint to train), three one-second episodes
SMALL_EVAL = ["eval", "--task", "nav", "--modalities=", "--no-baseline", "--sensor", "ideal8",
              "--conditions", "nominal", "--scenarios", "indoor", "--episodes", "3",
              "--set", "sim.episode_s=1.0"]


def test_split_episodes_covers_the_range_in_near_equal_contiguous_parts():
    assert split_episodes(0, 10, 3) == [(0, 3), (3, 6), (6, 10)]
    assert split_episodes(2, 4, 8) == [(2, 3), (3, 4)]         # never an empty part
    assert split_episodes(0, 5, 1) == [(0, 5)]
    assert split_episodes(3, 3, 2) == []


def assert_same_episode(a: Path, b: Path) -> None:
    """Every per-frame array and attribute equal, except what is not the episode's
    (sebvs/data/compare.py: the hop latencies; tick and t_sim from the first frame)."""
    assert episode_differences(a, b) == []
    with h5py.File(a) as fa:
        assert {"rgb", "events/frame", "action", "tick", "t_sim"} <= set(dataset_names(fa))


def test_record_on_two_workers_gives_the_episode_files_of_one(tmp_path):
    topo = str(ROOT / "topologies" / "nav_record.toml")
    outs = {}
    for workers in (1, 2):
        out = outs[workers] = tmp_path / f"w{workers}"
        args = ["record", topo, "--episodes", "3", "--out", str(out), "--runs-dir",
                str(tmp_path / "runs"), "--quiet", "--timeout", "120", *SMALL_RECORD]
        assert main(args + (["--workers", "2"] if workers == 2 else [])) == 0
    one, two = DatasetIndex(outs[1]), DatasetIndex(outs[2])
    assert [e["file"] for e in two.episodes()] == \
        ["episode_0000.h5", "episode_0001.h5", "episode_0002.h5"]
    strip = lambda e: {k: v for k, v in e.items() if k not in ("sha256", "bytes")}  # noqa: E731
    assert [strip(e) for e in one.episodes()] == [strip(e) for e in two.episodes()]
    for path in one.episode_paths():
        assert_same_episode(path, outs[2] / path.name)
    assert check_dataset(outs[2]).ok and not (outs[2] / STAGING).exists()

    # a driver that died before adopting a worker's finished episode: the next run adopts
    # it under the number its run reserved (base 3 + its episode index 1), then numbers on
    stage = outs[2] / STAGING / "dead-0-2-try1"
    stage.mkdir(parents=True)
    (stage / SHARD_INFO).write_text(json.dumps({"base": 3, "first": 0, "stop": 2}))
    shutil.copy(outs[2] / "episode_0001.h5", stage / "episode_0000.h5")
    assert adopt_staged(outs[2]) == ["episode_0004.h5"]
    index = DatasetIndex(outs[2])
    assert [e["file"] for e in index.episodes()][-1] == "episode_0004.h5"
    assert index.next_episode_number() == 5 and not (outs[2] / STAGING).exists()
    assert check_dataset(outs[2]).ok


@pytest.fixture(scope="module")
def eval_one_worker(tmp_path_factory):
    out = tmp_path_factory.mktemp("eval") / "w1"
    assert main([*SMALL_EVAL, "--out", str(out)]) == 0
    return out


def test_eval_on_two_workers_writes_the_same_results_bytes(eval_one_worker, tmp_path):
    out = tmp_path / "w2"
    assert main([*SMALL_EVAL, "--out", str(out), "--workers", "2"]) == 0
    assert (out / "results.json").read_bytes() == \
        (eval_one_worker / "results.json").read_bytes()
    results = json.loads((out / "results.json").read_text())
    assert len(results["episodes"]) == 3
    # two shards ([0, 1) and [1, 3)) ran; their shard files were merged away
    assert len(list((out / "runs").iterdir())) == 2
    assert not (out / "episodes" / ".shards").exists()
    # resume: everything is finished, so nothing runs again
    assert main([*SMALL_EVAL, "--out", str(out), "--workers", "2"]) == 0
    assert len(list((out / "runs").iterdir())) == 2


def test_eval_on_a_local_ray_writes_the_same_results_bytes(eval_one_worker, tmp_path):
    pytest.importorskip("ray", reason="Ray is an optional extra: pip install -e .[ray]")
    out = tmp_path / "ray"
    assert main([*SMALL_EVAL, "--out", str(out), "--ray", "--workers", "2"]) == 0
    assert (out / "results.json").read_bytes() == \
        (eval_one_worker / "results.json").read_bytes()


def test_failed_workers_are_retried_then_their_episodes_named(tmp_path):
    """A worker that fails (here: its topology file is gone) is retried from its first
    missing episode, up to max_attempts, then the error names the episodes lost."""
    seen = []

    def task_of(shard):
        return Task(str(shard), str(tmp_path / "missing.toml"), {}, str(tmp_path / "runs"))

    def collect(shard, result):
        seen.append((shard.first, shard.stop, shard.attempt, result["code"]))
        assert "no such topology file" in result["failure"]
        return list(range(shard.first, shard.stop))

    with pytest.raises(ShardsLost, match=r"job: episodes 0-2") as err:
        fan_out([Shard("job", 0, 3)], task_of, collect, workers=2, max_attempts=2,
                echo=lambda text: None)
    assert seen == [(0, 3, 1, None), (0, 3, 2, None)]
    assert err.value.missing == {"job": [0, 1, 2]}


def test_a_retry_runs_only_from_the_first_missing_episode(tmp_path):
    runs = []

    def task_of(shard):
        # a short synthetic run (no MuJoCo) that ends at its timeout
        return Task(str(shard), str(ROOT / "topologies" / "synthetic.toml"),
                    {"source": {"width": 32, "height": 32}}, str(tmp_path / "runs"),
                    timeout_s=0.3)

    def collect(shard, result):
        runs.append((shard.first, shard.attempt, result["code"]))
        return [3, 4] if shard.attempt == 1 else []     # the first try lost its last two

    fan_out([Shard("job", 0, 5)], task_of, collect, workers=1, echo=lambda text: None)
    assert runs == [(0, 1, 0), (3, 2, 0)]
    assert len(list((tmp_path / "runs").iterdir())) == 2      # a run directory each


def test_ray_missing_is_one_clear_line(monkeypatch, tmp_path, capsys):
    monkeypatch.setitem(sys.modules, "ray", None)       # import ray raises ImportError
    with pytest.raises(RayMissing, match=r"pip install -e \.\[ray\]"):
        fan_out([Shard("job", 0, 1)], lambda s: None, lambda s, r: [], ray="")
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "ray" else real(name, *a))
    assert main([*SMALL_EVAL, "--out", str(tmp_path / "e"), "--ray"]) == 2
    assert main(["record", str(ROOT / "topologies" / "nav_record.toml"), "--episodes", "1",
                 "--out", str(tmp_path / "d"), "--ray"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["sebvs eval: --ray needs Ray, which is not installed: pip install -e .[ray]",
                   "sebvs record: --ray needs Ray, which is not installed: "
                   "pip install -e .[ray]"]


def test_a_lost_worker_is_retried(tmp_path):
    """A worker killed mid-run (kill -9: no result comes back) counts as lost; its
    episodes run again on a new worker. Its actors die with it (PDEATHSIG)."""
    import multiprocessing
    import os
    import signal
    import tempfile
    import time

    results, killed = [], []

    def task_of(shard):
        # the first try would run 60 s: it is killed once its run has started
        return Task(str(shard), str(ROOT / "topologies" / "synthetic.toml"),
                    {"source": {"width": 32, "height": 32}}, str(tmp_path / "runs"),
                    timeout_s=60.0 if shard.attempt == 1 else 0.3)

    def kill_first_worker():
        if killed or not list((tmp_path / "runs").glob("*/run.json")):
            return
        for child in multiprocessing.active_children():
            if child.name.startswith("sebvs-worker"):
                os.kill(child.pid, signal.SIGKILL)
                killed.append(child.pid)

    def collect(shard, result):
        results.append((shard.attempt, result))
        return [0, 1] if result is None else []

    t0 = time.monotonic()
    fan_out([Shard("job", 0, 2)], task_of, collect, on_poll=kill_first_worker,
            echo=lambda text: None)
    assert time.monotonic() - t0 < 40
    assert killed and [(a, r is None) for a, r in results] == [(1, True), (2, False)]
    # what the killed supervisor could not remove: its run's sockets and rings
    for info in (tmp_path / "runs").glob("*/run.json"):
        run_id = json.loads(info.read_text())["run_id"]
        for shm in Path("/dev/shm").glob(f"sebvs-{run_id}-*"):
            shm.unlink(missing_ok=True)
        shutil.rmtree(Path(tempfile.gettempdir()) / f"sebvs-{run_id}", ignore_errors=True)


@dataclass(frozen=True)
class _Probe:
    label: str
    parent_pid: int | None = None


def _report_cpu_share(task: _Probe) -> dict:
    """A pool worker that reports the CPU share it was given."""
    import os
    from sebvs.runtime.topology import CPUS_ENV
    return {"label": task.label, "code": 0, "failure": None, "cpus": os.environ.get(CPUS_ENV)}


@pytest.mark.parametrize("workers, share", [(2, "2"), (4, "1"), (8, "1")])
def test_each_local_worker_is_told_its_share_of_the_cpus(monkeypatch, workers, share):
    """N workers on a machine of C CPUs each count on C // N of them (at least one), so a
    worker's `placement = "auto"` runs its topology in one process when that is one CPU."""
    monkeypatch.setenv("SEBVS_CPUS", "4")          # the driver's machine: four CPUs
    shares = []

    def collect(shard, result):
        shares.append(result["cpus"])
        return []

    fan_out([Shard("job", k, k + 1) for k in range(workers)], lambda s: _Probe(str(s)),
            collect, workers=workers, worker=_report_cpu_share, echo=lambda text: None)
    assert shares == [share] * workers


_DRIVER_STATE = {"mark": None}      # set in the driver: a forked worker inherits it


def _report_driver_state(task: _Probe) -> dict:
    return {"label": task.label, "code": 0, "failure": None, "mark": _DRIVER_STATE["mark"]}


@pytest.mark.parametrize("start, inherited", [("spawn", None), ("fork", "set")])
def test_forked_workers_inherit_the_driver_s_state_and_spawned_ones_do_not(
        monkeypatch, start, inherited):
    """Topology runs fork their workers (they then skip re-importing the actor classes the
    driver's topology check imported); training sweeps spawn them."""
    monkeypatch.setitem(_DRIVER_STATE, "mark", "set")
    marks = []

    def collect(shard, result):
        marks.append(result["mark"])
        return []

    fan_out([Shard("job", 0, 1)], lambda s: _Probe(str(s)), collect, worker=_report_driver_state,
            echo=lambda text: None, start=start)
    assert marks == [inherited]
    with pytest.raises(ValueError, match="start must be"):
        fan_out([Shard("job", 0, 1)], lambda s: _Probe(str(s)), collect, start="thread")


def test_a_recording_into_a_dataset_plays_on_with_the_seeds_episodes(tmp_path):
    """Two episodes, then one, then two more on two workers, into the same dataset: it is
    the five-episode recording made at once, not episodes 0-1 again and again."""
    from sebvs.data.compare import compare_datasets
    topo = str(ROOT / "topologies" / "nav_record.toml")

    def record(out, episodes, *extra):
        assert main(["record", topo, "--episodes", str(episodes), "--out", str(out),
                     "--runs-dir", str(tmp_path / "runs"), "--quiet", "--timeout", "120",
                     *SMALL_RECORD, *extra]) == 0

    record(tmp_path / "whole", 5)
    record(tmp_path / "parts", 2)
    record(tmp_path / "parts", 1)
    record(tmp_path / "parts", 2, "--workers", "2")      # episodes 3 and 4, a shard each
    result = compare_datasets(tmp_path / "whole", tmp_path / "parts")
    assert result.identical and len(result.same) == 5, result.different
    seeds = [e["seed"] for e in DatasetIndex(tmp_path / "parts").episodes()]
    assert len(set(seeds)) == 5


def test_fill_records_the_holes_a_stopped_fan_out_leaves(tmp_path, capsys):
    """A dataset missing episodes 1 and 3 of 0-4 (each worker's last, as a stop leaves it):
    --fill records exactly those, the same episodes as an unbroken run, and then has
    nothing left to do."""
    from sebvs.data.compare import compare_datasets
    from sebvs.data.record import contiguous_ranges
    assert contiguous_ranges([0, 1, 2, 5, 7, 8]) == [(0, 3), (5, 6), (7, 9)]
    assert contiguous_ranges([]) == []
    topo = str(ROOT / "topologies" / "nav_record.toml")

    def record(out, episodes, *extra):
        return main(["record", topo, "--episodes", str(episodes), "--out", str(out),
                     "--runs-dir", str(tmp_path / "runs"), "--quiet", "--timeout", "120",
                     *SMALL_RECORD, *extra])

    assert record(tmp_path / "whole", 5) == 0
    holes = tmp_path / "holes"
    shutil.copytree(tmp_path / "whole", holes)
    index = json.loads((holes / "index.json").read_text())
    index["episodes"] = [e for e in index["episodes"]
                         if e["file"] not in ("episode_0001.h5", "episode_0003.h5")]
    (holes / "index.json").write_text(json.dumps(index))
    for k in (1, 3):
        (holes / f"episode_000{k}.h5").unlink()
    assert DatasetIndex(holes).next_episode_number() == 5    # plain resuming skips them
    capsys.readouterr()
    assert record(holes, 5, "--fill", "--workers", "2") == 0
    said = capsys.readouterr()
    assert "filling 2 missing episode(s) of 0-4" in said.err
    assert "2 of 2 episode(s) recorded" in said.out
    result = compare_datasets(tmp_path / "whole", holes)
    assert result.identical and len(result.same) == 5, result.different
    assert record(holes, 5, "--fill") == 0
    assert "already holds episodes 0-4; nothing to fill" in capsys.readouterr().err


def test_workers_auto_is_the_cpus_this_process_may_use(monkeypatch):
    import argparse

    from sebvs.data.cli import workers_arg
    monkeypatch.delenv("SEBVS_CPUS", raising=False)
    assert workers_arg("auto") == len(os.sched_getaffinity(0))
    monkeypatch.setenv("SEBVS_CPUS", "3")         # a pool's share of the machine
    assert workers_arg("auto") == 3
    assert workers_arg("4") == 4
    for bad in ("0", "-1", "two", ""):
        with pytest.raises(argparse.ArgumentTypeError, match="expected a number of workers"):
            workers_arg(bad)
