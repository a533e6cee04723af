"""Process groups: several actors in one process (`process = "G"`, `placement = "auto"`)."""
import json
import os
import signal
import threading
import time
from pathlib import Path

import pytest

from sebvs.runtime.supervisor import Supervisor, run_topology
from sebvs.runtime.topology import CPUS_ENV, TopologyError, load_topology, run_cpus

ROOT = Path(__file__).resolve().parents[1]
SYNTHETIC = ROOT / "topologies" / "synthetic.toml"
SMALL = ["source.width=64", "source.height=48", "source.rate_hz=100"]
VISION = ['source.process="vision"', 'relay.process="vision"']


def start(tmp_path, overrides=(), path=SYNTHETIC):
    sup = Supervisor(load_topology(path, list(overrides)), runs_dir=tmp_path,
                     echo=lambda s: None)
    sup.start()
    return sup


def stats(sup, actor):
    reply = sup.request(actor, {"cmd": "stats"}, 3.0)
    assert reply is not None and reply["ok"], f"{actor}: {reply}"
    return reply["result"]


def assert_clean(sup):
    for p in sup.procs.values():
        assert p.popen.poll() is not None, f"{p.name} still running"
    assert not list(Path("/dev/shm").glob(f"sebvs-{sup.run_id}-*"))
    assert not sup.sockdir.exists()


# ---------------------------------------------------------------------- topology


@pytest.mark.parametrize("value, words", [
    ("3", "expected a group name"),
    ('""', "expected a group name"),
    ('"a/b"', "expected a group name"),
    ("[\"vision\"]", "expected a group name"),
    ('"sink"', "has the name of actor 'sink', which is not in it"),
])
def test_bad_process_values_are_named(value, words):
    with pytest.raises(TopologyError) as err:
        load_topology(SYNTHETIC, [f"relay.process={value}"])
    assert "[actors.relay] key 'process'" in str(err.value) and words in str(err.value)


def test_a_group_pinning_different_cpus_is_refused():
    cpu = max(os.sched_getaffinity(0))
    with pytest.raises(TopologyError, match="pin different CPUs .*relay: unpinned"):
        load_topology(SYNTHETIC, VISION + [f"source.cpus=[{cpu}]"])
    topo = load_topology(SYNTHETIC, VISION + [f"source.cpus=[{cpu}]", f"relay.cpus=[{cpu}]"])
    assert topo.processes() == {"vision": ["source", "relay"], "sink": ["sink"]}


def test_placement_isolated_and_auto():
    alone = {n: [n] for n in ("source", "relay", "sink")}
    assert load_topology(SYNTHETIC).processes(cpus_available=2) == alone   # no `process` keys
    topo = load_topology(SYNTHETIC, VISION)              # default placement: "grouped"
    grouped = {"vision": ["source", "relay"], "sink": ["sink"]}
    assert topo.processes(cpus_available=2) == topo.processes(cpus_available=64) == grouped
    topo = load_topology(SYNTHETIC, VISION + ["topology.placement=isolated"])
    assert topo.processes(cpus_available=2) == alone     # isolation: one key away
    topo = load_topology(SYNTHETIC, VISION + ["topology.placement=auto"])
    assert topo.processes(cpus_available=2) == grouped   # a small machine: grouped
    assert topo.processes(cpus_available=16) == alone    # a big one: isolated
    one = {"all": ["source", "relay", "sink"]}
    assert topo.processes(cpus_available=1) == one       # one CPU to itself: one process
    assert topo.resolved_placement(cpus_available=1) == "single"
    topo = load_topology(SYNTHETIC, VISION + ["topology.placement=single"])
    assert topo.processes(cpus_available=64) == one
    with pytest.raises(TopologyError, match="placement"):
        load_topology(SYNTHETIC, ['topology.placement="packed"'])


def test_auto_reads_the_cpu_share_a_pool_gives_its_run(monkeypatch):
    """$SEBVS_CPUS (set by `--workers N` for each worker) is what "auto" counts on."""
    topo = load_topology(SYNTHETIC, VISION + ["topology.placement=auto"])
    monkeypatch.setenv(CPUS_ENV, "1")
    assert run_cpus() == 1 and list(topo.processes()) == ["all"]
    monkeypatch.setenv(CPUS_ENV, "3")
    assert run_cpus() == 3 and topo.resolved_placement() == "grouped"
    monkeypatch.setenv(CPUS_ENV, "many")       # not a count: the CPUs this process may use
    assert run_cpus() == len(os.sched_getaffinity(0))


def test_single_placement_needs_actors_that_can_share_a_process():
    cpu = max(os.sched_getaffinity(0))
    with pytest.raises(TopologyError, match="'placement'.*pin different CPUs"):
        load_topology(SYNTHETIC, ["topology.placement=single", f"source.cpus=[{cpu}]"])
    # "auto" on one CPU falls back to the `process` keys rather than refuse
    topo = load_topology(SYNTHETIC, VISION + ["topology.placement=auto", f"sink.cpus=[{cpu}]"])
    assert topo.resolved_placement(cpus_available=1) == "grouped"


# ---------------------------------------------------------------------- running


def test_a_group_runs_its_members_in_one_process_with_per_actor_control(tmp_path):
    sup = start(tmp_path, SMALL + VISION)
    try:
        time.sleep(0.8)
        st = {a: stats(sup, a) for a in ("source", "relay", "sink")}
        assert st["source"]["pid"] == st["relay"]["pid"] != st["sink"]["pid"]
        assert st["relay"]["actor"] == "relay" and st["source"]["actor"] == "source"
        assert st["relay"]["inputs"]["frames"]["handled"] > 20
        assert st["sink"]["inputs"]["frames"]["handled"] > 20
        assert st["sink"]["actor_stats"]["checksum"] > 0
        # the in-group edge is inproc; the edge out of the group stays ipc
        assert sup.specs["relay"]["inputs"]["frames"]["endpoint"] == "inproc://source.frames"
        assert sup.specs["sink"]["inputs"]["frames"]["endpoint"].startswith("ipc://")
        # set reaches the member it names, and only it
        assert sup.request("relay", {"cmd": "set", "key": "mode", "value": "copy"})["ok"]
        assert sup.request("relay", {"cmd": "get", "key": "mode"})["result"] == {"mode": "copy"}
        assert not sup.request("source", {"cmd": "get", "key": "mode"})["ok"]
        info = json.loads((sup.rundir / "run.json").read_text())
        assert info["processes"]["vision"]["actors"] == ["source", "relay"]
        assert info["actors"]["relay"]["process"] == "vision"
        assert info["actors"]["relay"]["pid"] == info["actors"]["source"]["pid"]
        assert (sup.rundir / "logs" / "vision.log").exists()
        assert (sup.rundir / "logs" / "relay.log").resolve() == \
            (sup.rundir / "logs" / "vision.log").resolve()
    finally:
        t0 = time.monotonic()
        code = sup.stop()
        assert time.monotonic() - t0 < 2.0
    assert code == 0
    assert_clean(sup)


def test_the_profiler_sees_every_member_by_name(tmp_path):
    from tests.test_runtime_run import profile_synthetic_chain
    sup = start(tmp_path, SMALL + VISION + ['sink.process="vision"'])
    processes = set(sup.procs)
    profile_synthetic_chain(sup, 1.2)     # every hop, handler and the chain, by actor name
    assert processes == {"vision"}


def test_stamps_name_every_actor_of_a_group(tmp_path):
    topo = tmp_path / "probe.toml"
    topo.write_text(f"""
[topology]
name = "probe"
[actors.source]
run = "actors.synthetic:PatternSource"
width = 320
height = 240
rate_hz = 200.0
max_frames = 20
process = "all"
[actors.relay]
run = "actors.synthetic:Relay"
inputs = {{ frames = "source/frames" }}
mode = "copy"
process = "all"
[actors.probe]
run = "actors.synthetic:Probe"
inputs = {{ frames = "relay/frames" }}
path = "{tmp_path / 'probe'}"
process = "all"
""")
    assert load_topology(topo).processes() == {"all": ["source", "relay", "probe"]}
    run_topology(topo, duration_s=20, runs_dir=tmp_path)
    entries = json.loads((tmp_path / "probe.json").read_text())
    assert len(entries) >= 15
    for e in entries:
        assert [s[0] for s in e["stamps"]] == ["source", "relay"]
        assert e["stamps"][1][1] <= e["stamps"][1][2] <= e["recv_ns"]   # recv <= send <= next
    assert entries[0]["arrays"]["rgb"] == [[240, 320, 3], "|u1"]   # 230 KB: through a ring


def test_a_member_raising_in_its_handler_does_not_hurt_its_group_mates(tmp_path):
    sup = start(tmp_path, SMALL + ['flaky.run="tests.group_actors:Flaky"',
                                   'flaky.inputs={frames="source/frames"}',
                                   'sink.inputs={frames="flaky/frames"}',
                                   'source.process="vision"', 'flaky.process="vision"',
                                   'sink.process="vision"'])
    try:
        time.sleep(0.8)
        assert set(sup.procs) == {"vision"}
        relay = stats(sup, "flaky")["inputs"]["frames"]
        sink = stats(sup, "sink")["inputs"]["frames"]
        assert relay["errors"] > 10 and relay["error_kinds"] == {"ValueError": relay["errors"]}
        assert sink["handled"] > 10 and sink["errors"] == 0
        assert stats(sup, "source")["outputs"]["frames"]["sent"] > 20
        assert sup.procs["vision"].popen.poll() is None
    finally:
        sup.stop()
    assert_clean(sup)


def test_a_member_that_fails_is_named_in_the_failure_and_run_json(tmp_path):
    sup = start(tmp_path, SMALL + ['crasher.run="tests.group_actors:Crasher"',
                                   'crasher.process="vision"', 'relay.process="vision"',
                                   'relay.inputs={frames="crasher/frames"}'])
    code = sup.wait(10)
    assert code == 1
    assert "actor 'crasher' died" in sup.failure
    assert "RuntimeError: crasher blew up on purpose" in sup.failure
    assert "process group 'vision' (relay, crasher)" in sup.failure
    info = json.loads((sup.rundir / "run.json").read_text())
    assert info["failed_actor"] == "crasher" and info["failed_process"] == "vision"
    assert "actor 'crasher' died" in info["failure"]
    assert_clean(sup)


def test_a_group_killed_from_outside_names_all_its_members(tmp_path):
    sup = start(tmp_path, SMALL + VISION)
    pid = sup.procs["vision"].popen.pid
    threading.Timer(0.4, os.kill, (pid, signal.SIGKILL)).start()
    assert sup.wait(10) == 1
    assert "process group 'vision' died" in sup.failure and "SIGKILL" in sup.failure
    assert "actors source, relay" in sup.failure
    info = json.loads((sup.rundir / "run.json").read_text())
    assert info["failed_actor"] is None and info["failed_process"] == "vision"
    assert_clean(sup)


def test_restart_restarts_the_whole_group(tmp_path):
    sup = start(tmp_path, SMALL + VISION + ["topology.restart=restart"])
    first = sup.procs["vision"].popen.pid
    seen = {}

    def kill_and_watch():
        time.sleep(0.3)
        os.kill(first, signal.SIGKILL)
        time.sleep(1.5)
        seen["relay"] = stats(sup, "relay")
        seen["before"] = stats(sup, "sink")["inputs"]["frames"]["handled"]
        time.sleep(0.5)
        seen["after"] = stats(sup, "sink")["inputs"]["frames"]["handled"]

    watcher = threading.Thread(target=kill_and_watch)
    watcher.start()
    code = sup.wait(3.0)
    watcher.join()
    assert code == 0
    assert sup.procs["vision"].restarts == 1
    assert seen["relay"]["pid"] == sup.procs["vision"].popen.pid != first
    assert seen["after"] > seen["before"] + 10      # frames flow again from the new group
    assert_clean(sup)


# ---------------------------------------------------------------------- lockstep output


def _episode_contents(path):
    """Every dataset and attribute of an episode file, but the measured hop latencies
    (wall-clock figures: they differ between any two runs, placement or not)."""
    import h5py
    import numpy as np
    data = {}
    with h5py.File(path, "r") as f:
        f.visititems(lambda name, obj: data.__setitem__(name, np.array(obj[()]))
                     if isinstance(obj, h5py.Dataset) and not name.startswith("latency/")
                     else None)
        attrs = {k: (v.tolist() if hasattr(v, "tolist") else v) for k, v in f.attrs.items()}
    return data, attrs


def test_lockstep_recording_is_the_same_in_any_placement(tmp_path):
    """One short episode of topologies/nav_record.toml in one process per actor, in two
    process groups (not the file's own split, so the test holds whatever the file says)
    and in one process: every recorded array and attribute is the same."""
    import numpy as np
    groups = [f'{a}.process="{g}"' for g, actors in
              (("front", ("sim", "camera", "expert")),
               ("back", ("emulator", "accumulator", "recorder"))) for a in actors]
    contents = {}
    for placement in ("isolated", "grouped", "single"):
        out = tmp_path / placement
        rundir = run_topology(ROOT / "topologies" / "nav_record.toml",
                              [*groups, f"topology.placement={placement}", "sim.episode_s=0.6",
                               "recorder.episodes=1", f"recorder.out={json.dumps(str(out))}"],
                              duration_s=60, runs_dir=tmp_path / "runs")
        procs = json.loads((rundir / "run.json").read_text())["processes"]
        assert len(procs) == {"isolated": 6, "grouped": 2, "single": 1}[placement]
        contents[placement] = _episode_contents(out / "episode_0000.h5")
    a, a_attrs = contents["isolated"]
    assert {"rgb", "events/frame", "action", "tick"} <= set(a) and len(a["tick"]) >= 5
    for placement in ("grouped", "single"):
        b, b_attrs = contents[placement]
        assert set(a) == set(b), placement
        for name in a:
            np.testing.assert_array_equal(a[name], b[name], err_msg=f"{placement}: {name}")
        assert a_attrs.keys() == b_attrs.keys()
        for key in a_attrs:
            assert np.array_equal(a_attrs[key], b_attrs[key]) \
                if isinstance(a_attrs[key], list) else a_attrs[key] == b_attrs[key], key
