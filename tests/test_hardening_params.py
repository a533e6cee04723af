"""Issue 16: bad values, files and names are refused with one clear line, never a crash.

A: one parameter schema (types, Range bounds, finite floats) for topology values and
   `sebvs ctl RUN ACTOR set`; B: every CLI path ends in one line and exit status 2;
C: a run name cannot leave the runs directory.
"""
import asyncio
import dataclasses
import importlib
import json
import math
import shutil
import time
from pathlib import Path
from typing import Annotated, Optional

import numpy as np
import pytest

from sebvs.cli import main
from sebvs.runtime import Range
from sebvs.runtime.params import REPR_LIMIT, build_params, coerce_param, param_fields
from sebvs.runtime.supervisor import Supervisor
from sebvs.runtime.topology import Topology, TopologyError, load_topology
from tests.test_runtime_topology import BASE

ROOT = Path(__file__).resolve().parents[1]
SYNTHETIC = ROOT / "topologies" / "synthetic.toml"
SMALL = ["source.width=64", "source.height=48", "source.rate_hz=100"]
ACTOR_MODULES = ("accumulator", "baseline", "bench", "camera", "emulator", "expert", "policy",
                 "recorder", "sim", "synthetic", "tracker", "video")


def write(tmp_path, text, name="topo.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


# ---------------------------------------------------------------- A: the schema

def test_range_bounds_and_finite_floats():
    Width = Annotated[int, Range(ge=1, le=8192)]
    assert coerce_param(Width, 640, where="w") == 640
    for bad in (0, -1, 8193):
        with pytest.raises(ValueError, match=r"w: .* out of range \(must be >= 1 and <= 8192\)"):
            coerce_param(Width, bad, where="w")
    with pytest.raises(ValueError, match="expected int"):
        coerce_param(Width, 3.0, where="w")
    for bad in (math.inf, -math.inf, math.nan):
        with pytest.raises(ValueError, match="not a finite number"):
            coerce_param(float, bad, where="w")
    with pytest.raises(ValueError, match="too large for a float"):
        coerce_param(float, 10 ** 400, where="w")
    assert coerce_param(Annotated[float, Range(finite=False)], math.inf, where="w") == math.inf
    assert math.isnan(coerce_param(Annotated[float, Range(finite=False)], math.nan, where="w"))
    with pytest.raises(ValueError, match="must be > 0"):
        coerce_param(Annotated[float, Range(gt=0)], 0, where="w")
    opt = Optional[Annotated[float, Range(gt=0, le=1)]]
    assert coerce_param(opt, None, where="w") is None
    with pytest.raises(ValueError, match="out of range"):   # the bound, not "matches none"
        coerce_param(opt, 2.0, where="w")
    with pytest.raises(ValueError, match=r"w\[1\]: 1.5 is out of range"):
        coerce_param(list[Annotated[float, Range(ge=0, le=1)]], [0.5, 1.5], where="w")


def test_error_messages_do_not_echo_huge_values():
    for tp, value in ((int, "x" * 100_000), (list, "y" * 100_000), (float, [1] * 50_000),
                      (Annotated[int, Range(le=1)], 10 ** 4000)):
        with pytest.raises(ValueError) as err:
            coerce_param(tp, value, where="w")
        assert len(str(err.value)) < REPR_LIMIT + 100 and "..." in str(err.value)
    with pytest.raises(ValueError, match="too long to show"):
        coerce_param(Annotated[int, Range(le=1)], 10 ** 5000, where="w")


def test_every_shipped_actor_accepts_its_own_defaults():
    annotated = 0
    for mod in ACTOR_MODULES:
        module = importlib.import_module(f"sebvs_actors.{mod}")
        for cls in vars(module).values():
            if not (isinstance(cls, type) and hasattr(cls, "Params") and cls.__module__ ==
                    module.__name__):
                continue
            defaults = dataclasses.asdict(cls.Params())
            build_params(cls.Params, defaults, where=cls.__name__)
            annotated += sum("Range(" in repr(tp) for tp in param_fields(cls.Params).values())
    assert annotated >= 30      # the bounds are declared, not only typed


@pytest.mark.parametrize("override, needle", [
    ("source.width=-5", "[actors.source] key 'width': -5 is out of range"),
    ("source.width=0", "key 'width': 0 is out of range"),
    ("source.rate_hz=inf", "[actors.source] key 'rate_hz': inf is not a finite number"),
    ("source.rate_hz=nan", "key 'rate_hz': nan is not a finite number"),
    ("source.rate_hz=0", "key 'rate_hz': 0.0 is out of range"),
    ("sink.work_ms=-1", "[actors.sink] key 'work_ms'"),
    ("topology.queue=0", "[topology] key 'queue': 0 is out of range (must be >= 1"),
    ("topology.queue=-1", "[topology] key 'queue': -1 is out of range"),
    ("topology.queue=100001", "[topology] key 'queue'"),
    ("topology.queue=\"lots\"", "[topology] key 'queue'"),
    ("topology.queue=2.5", "[topology] key 'queue'"),
    ("topology.seed=-1", "[topology] key 'seed': -1 is out of range (must be >= 0 and < "
                         "2147483648)"),
    # 2**31 + 100,000 would wrap onto the test split's first seed (sebvs/data/splits.py)
    ("topology.seed=2147583648", "[topology] key 'seed': 2147583648 is out of range (must "
                                 "be >= 0 and < 2147483648)"),
    ("topology.ready_timeout_s=0", "[topology] key 'ready_timeout_s': 0.0 is out of range"),
    ("topology.ready_timeout_s=inf", "[topology] key 'ready_timeout_s': inf is not a finite"),
    ("topology.ready_timeout_s=nan", "[topology] key 'ready_timeout_s': nan is not a finite"),
    ("topology.max_restarts=-1", "[topology] key 'max_restarts'"),
    ("topology.clock=\"sometimes\"", "[topology] key 'clock': 'sometimes' is not one of"),
    ("topology.seed=true", "[topology] key 'seed': expected int"),
])
def test_topology_values_are_checked_by_the_schema(tmp_path, override, needle):
    with pytest.raises(TopologyError) as err:
        load_topology(write(tmp_path, BASE), [override])
    assert needle in str(err.value) and "topo.toml" in str(err.value)


def test_topology_queue_latest_and_valid_values_load(tmp_path):
    topo = load_topology(write(tmp_path, BASE), ["topology.queue=\"latest\"",
                                                  "topology.ready_timeout_s=5"])
    assert topo.queue == "latest" and topo.actors["sink"].inputs["frames"].queue == "latest"
    assert topo.ready_timeout_s == 5.0 and isinstance(topo.ready_timeout_s, float)
    topo = load_topology(write(tmp_path, BASE), ["topology.queue=100000"])
    assert topo.actors["sink"].inputs["frames"].queue == 100_000


def test_ctl_set_uses_the_same_schema_and_keeps_the_old_value():
    from sebvs_actors.synthetic import PatternSource
    src = PatternSource("source", PatternSource.Params(width=32, height=16))

    async def go():
        await src.setup()
        for key, value, needle in (("width", -1, "out of range"), ("width", 5000, "<= 4096"),
                                   ("rate_hz", math.inf, "not a finite number"),
                                   ("rate_hz", math.nan, "not a finite number"),
                                   ("width", "x" * 10_000, "expected int"),
                                   ("x" * 10_000, 1, "unknown key")):
            with pytest.raises(ValueError, match=needle) as err:
                await src.control(key, value)
            assert len(str(err.value)) < 2 * REPR_LIMIT + 150
        assert (src.params.width, src.params.rate_hz) == (32, 30.0)
        # a new size is accepted and the pattern is redrawn to fit it
        assert await src.control("width", 100) == {"width": 100}
        frame = np.zeros((16, 100, 3), np.uint8)
        src._draw(1.0, frame, None)
        assert frame.any()

    asyncio.run(go())


def test_ctl_set_refusal_leaves_the_live_actor_running(tmp_path):
    sup = Supervisor(load_topology(SYNTHETIC, SMALL), runs_dir=tmp_path, echo=lambda s: None)
    sup.start()

    def ctl(**req):
        reply = sup.request("source", req, 3.0)
        assert reply is not None, req
        return reply

    try:
        for key, value in (("width", -1), ("height", 0), ("rate_hz", float("inf")),
                           ("width", "w" * 100_000)):
            reply = ctl(cmd="set", key=key, value=value)
            assert not reply["ok"] and key in reply["error"]
            assert len(reply["error"]) < 600
        assert ctl(cmd="set", key="width", value=96)["ok"]    # redrawn at the new size
        time.sleep(0.5)
        assert ctl(cmd="get", key="width")["result"] == {"width": 96}
        sent = ctl(cmd="stats")["result"]["actor_stats"]["frames_sent"]
        time.sleep(0.3)
        assert ctl(cmd="stats")["result"]["actor_stats"]["frames_sent"] > sent
        assert sup.procs["source"].popen.poll() is None
    finally:
        code = sup.stop()
    assert code == 0 and sup.failure is None


# ---------------------------------------------------------------- B: the command line

def one_error_line(capsys, argv, code=2):
    assert main(argv) == code
    err = capsys.readouterr().err
    assert "Traceback" not in err
    assert len(err.strip().splitlines()) == 1, err
    return err


@pytest.mark.parametrize("run, needle", [
    (":PatternSource", "got ':PatternSource'"),
    (".synthetic:PatternSource", "got '.synthetic:PatternSource'"),
    ("actors.synthetic:", "got 'actors.synthetic:'"),
    ("actors..synthetic:Sink", "got 'actors..synthetic:Sink'"),
    ("actors.synthetic", "got 'actors.synthetic'"),
    ("actors.nothere:Sink", "cannot import 'actors.nothere'"),
])
def test_cli_bad_run_keys(tmp_path, capsys, run, needle):
    path = write(tmp_path, BASE.replace('"actors.synthetic:PatternSource"', f'"{run}"'))
    for cmd in (["graph", str(path)], ["run", str(path), "--runs-dir", str(tmp_path / "r")]):
        err = one_error_line(capsys, cmd)
        assert needle in err and "[actors.source] key 'run'" in err and "topo.toml" in err
    assert not (tmp_path / "r").exists()


def test_cli_actor_module_that_fails_to_import(tmp_path, capsys, monkeypatch):
    (tmp_path / "broken_actor_mod.py").write_text("raise RuntimeError('boom at import')\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    path = write(tmp_path, BASE.replace('"actors.synthetic:PatternSource"',
                                        '"broken_actor_mod:X"'))
    err = one_error_line(capsys, ["graph", str(path)])
    assert "importing 'broken_actor_mod' failed: RuntimeError: boom at import" in err


def test_cli_unreadable_topology_files(tmp_path, capsys):
    bad = tmp_path / "latin1.toml"
    bad.write_bytes(BASE.replace('name = "t"', 'name = "caf\xe9"').encode("latin-1"))
    assert "not UTF-8 text" in one_error_line(capsys, ["graph", str(bad)])
    folder = tmp_path / "folder.toml"
    folder.mkdir()
    assert "is a directory" in one_error_line(capsys, ["run", str(folder)])
    assert "no such topology file" in one_error_line(capsys, ["graph", str(tmp_path / "no")])
    deep = write(tmp_path, "[topology]\nname = \"t\"\nx = " + "[" * 5000 + "]" * 5000 + "\n",
                 "deep.toml")
    assert "deep.toml" in one_error_line(capsys, ["graph", str(deep)])


def test_cli_debug_flag_shows_the_traceback(tmp_path):
    folder = tmp_path / "folder.toml"
    folder.mkdir()
    with pytest.raises(TopologyError, match="is a directory"):
        main(["--debug", "graph", str(folder)])


@pytest.mark.parametrize("content, needle", [
    ("{not json", "not valid JSON"),
    ("[1, 2]", "not a JSON object"),
    ('{"name": "x"}', "key 'run_id' missing"),
    (json.dumps({"name": "x", "run_id": "1", "rundir": "d", "started_at": "t",
                 "actors": {"source": {"control": "garbage", "telemetry": "ipc:///x"}}}),
     "'control' is not an ipc:// or tcp:// endpoint"),
    (b"\xff\xfe", "not UTF-8 text"),
])
def test_cli_corrupt_run_json(tmp_path, capsys, content, needle):
    rundir = tmp_path / "run"
    rundir.mkdir()
    (rundir / "run.json").write_bytes(content if isinstance(content, bytes) else content.encode())
    for cmd in (["ctl", str(rundir), "source", "get"], ["profile", str(rundir), "--for", "0.1"]):
        err = one_error_line(capsys, cmd)
        assert needle in err and "run.json" in err


def test_cli_ctl_set_needs_key_value(tmp_path, capsys):
    rundir = tmp_path / "run"
    rundir.mkdir()
    (rundir / "run.json").write_text(json.dumps({
        "name": "x", "run_id": "1", "rundir": str(rundir), "started_at": "t",
        "actors": {"source": {"control": "ipc:///nonexistent/ctl",
                              "telemetry": "ipc:///nonexistent/tel"}}}))
    assert "set expects key=value" in one_error_line(capsys, ["ctl", str(rundir), "source",
                                                              "set", "width"])
    assert "has no actor 'nope'" in one_error_line(capsys, ["ctl", str(rundir), "nope", "get"])


@pytest.mark.parametrize("argv", [["run", str(SYNTHETIC), "--for", "nan"],
                                  ["run", str(SYNTHETIC), "--for", "-1"],
                                  ["profile", "--for", "inf"],
                                  ["ctl", "source", "get", "--timeout", "0"]])
def test_cli_durations_must_be_positive_and_finite(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    assert "finite number of seconds" in capsys.readouterr().err


@pytest.fixture(scope="module")
def bad_checkpoints(tmp_path_factory):
    """nav-rgb checkpoints: truncated, and one whose pickle would run a command."""
    import os
    import torch
    root = tmp_path_factory.mktemp("ckpt")
    marker = root / "pwned"

    class Evil:
        def __reduce__(self):
            return os.system, (f"touch {marker}",)

    dirs = {}
    for kind in ("truncated", "malicious", "bad_config"):
        d = root / kind
        d.mkdir()
        shutil.copy(ROOT / "checkpoints" / "nav-rgb.json", d / "nav-rgb.json")
        dirs[kind] = d
    (dirs["truncated"] / "nav-rgb.pt").write_bytes(
        (ROOT / "checkpoints" / "nav-rgb.pt").read_bytes()[:2000])
    torch.save({"weight": Evil()}, dirs["malicious"] / "nav-rgb.pt")
    shutil.copy(ROOT / "checkpoints" / "nav-rgb.pt", dirs["bad_config"] / "nav-rgb.pt")
    (dirs["bad_config"] / "nav-rgb.json").write_text("{\"task\": \"nav\", ")
    return dirs, marker


@pytest.mark.parametrize("kind, needle", [
    ("truncated", "damaged or not a torch state_dict"),
    ("malicious", "refused, it holds pickled objects"),
    ("bad_config", "nav-rgb.json: unreadable"),
    ("missing", "not found"),
])
def test_cli_eval_refuses_bad_checkpoints_before_any_run(tmp_path, capsys, bad_checkpoints,
                                                        kind, needle):
    dirs, marker = bad_checkpoints
    ckpt = dirs.get(kind, tmp_path / "none")
    out = tmp_path / "out"
    err = one_error_line(capsys, ["eval", "--task", "nav", "--modalities", "rgb",
                                  "--episodes", "1", "--no-expert", "--checkpoints", str(ckpt),
                                  "--out", str(out)])
    assert needle in err and "nav-rgb" in err
    assert not marker.exists()              # nothing in the file ran
    assert not out.exists()                 # refused before any run started


# ---------------------------------------------------------------- C: run names

@pytest.mark.parametrize("name", ["../../x", "a/b", "/abs", ".hidden", "..", "", "a b",
                                  "x" * 101, "caf\u00e9", "a\\b"])
def test_run_names_cannot_leave_the_runs_directory(tmp_path, capsys, name):
    path = write(tmp_path, BASE.replace('name = "t"', f"name = {json.dumps(name)}"))
    with pytest.raises(TopologyError, match=r"\[topology\] key 'name'.*not a run name"):
        load_topology(path)
    runs = tmp_path / "runs"
    err = one_error_line(capsys, ["run", str(path), "--runs-dir", str(runs)])
    assert "key 'name'" in err
    assert not runs.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["topo.toml"]


@pytest.mark.parametrize("name", ["synthetic", "nav_policy", "run-1.2", "A_b-c.d"])
def test_plain_run_names_load(tmp_path, name):
    assert load_topology(write(tmp_path, BASE.replace('name = "t"', f'name = "{name}"'))) \
        .name == name


def test_supervisor_keeps_the_run_directory_inside_runs_dir(tmp_path):
    topo = load_topology(write(tmp_path, BASE))
    escaping = Topology(path=topo.path, name="../../escape", actors=topo.actors)
    runs = tmp_path / "runs"
    with pytest.raises(TopologyError, match="outside"):
        Supervisor(escaping, runs_dir=runs)
    sup = Supervisor(topo, runs_dir=runs)
    assert sup.rundir.parent == runs.resolve()
    sup.ctx.term()
