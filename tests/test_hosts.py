"""Actors on several hosts: placement, tcp endpoints per edge, clock offsets, and the
profiler's offset-corrected hop latency. Two "hosts" are two supervisors on 127.0.0.1;
one of them runs with an injected clock skew (SEBVS_CLOCK_SKEW_NS)."""
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from sebvs.runtime.clocksync import estimate_offset
from sebvs.runtime.ports import TcpPorts
from sebvs.runtime.supervisor import Supervisor, _host_ports
from sebvs.runtime.topology import TopologyError, load_topology

ROOT = Path(__file__).resolve().parents[1]
HOSTS = ROOT / "topologies" / "synthetic_hosts.toml"
SKEW_NS = 50_000_000
TOKEN = "f" * 32


# ----------------------------------------------------------------------- offsets
def test_offset_interval_holds_the_true_offset_whatever_the_delays():
    true = 50_000_000
    # (t0, remote, t1): the remote clock read somewhere inside each round trip
    exchanges = [(0, 10 + true, 400), (1000, 1390 + true, 1400),   # late reply, early read
                 (2000, 2050 + true, 2600), (3000, 3100 + true, 3200)]
    est = estimate_offset(exchanges)
    assert est.intersected
    assert abs(est.offset_ns - true) <= est.uncertainty_ns
    # the intersection is tighter than the best single exchange's half round trip
    assert est.uncertainty_ns < est.rtt_ns // 2
    assert est.rtt_ns == 200 and est.exchanges == 4


def test_offset_falls_back_to_the_shortest_round_trip_when_intervals_disagree():
    # the remote clock stepped by 1 ms between two exchanges: no common interval
    est = estimate_offset([(0, 5_000_050, 100), (1000, 6_001_100, 1200)])
    assert not est.intersected
    assert est.offset_ns == 5_000_000 and est.uncertainty_ns == 50 and est.rtt_ns == 100


def test_offset_needs_one_exchange():
    with pytest.raises(ValueError, match="no usable exchange"):
        estimate_offset([(10, 5, 0)])      # t1 < t0


# ----------------------------------------------------------------------- topology
def write(tmp_path, text):
    path = tmp_path / "hosts.toml"
    path.write_text(text)
    return path


BASE = """
[topology]
name = "h"
[hosts.a]
port = 41000
[hosts.b]
address = "127.0.0.1"
port = 42000
[actors.source]
run = "actors.synthetic:PatternSource"
[actors.sink]
run = "actors.synthetic:Sink"
inputs = { frames = "source/frames" }
"""


def test_actors_default_to_the_primary_host_and_ports_are_the_same_everywhere(tmp_path):
    topo = load_topology(write(tmp_path, BASE), ["sink.host=b"])
    assert topo.primary == "a"
    assert topo.actors["source"].host == "a" and topo.actors["sink"].host == "b"
    ports = _host_ports(topo)
    # a: source's control, telemetry, then its output consumed on b; b: sink's two
    assert ports == {("source", "ctl"): "tcp://127.0.0.1:41000",
                     ("source", "tel"): "tcp://127.0.0.1:41001",
                     ("source", "frames"): "tcp://127.0.0.1:41002",
                     ("sink", "ctl"): "tcp://127.0.0.1:42000",
                     ("sink", "tel"): "tcp://127.0.0.1:42001"}
    same_host = load_topology(write(tmp_path, BASE))
    assert ("source", "frames") not in _host_ports(same_host)   # no edge leaves host a


def test_each_supervisor_plans_its_own_actors_and_edges(tmp_path, monkeypatch):
    monkeypatch.setenv("SEBVS_RUN_TOKEN", TOKEN)
    topo = load_topology(write(tmp_path, BASE), ["sink.host=b"])
    a = Supervisor(topo, runs_dir=tmp_path, host="a")
    b = Supervisor(topo, runs_dir=tmp_path, host="b")
    spec_a, spec_b = a._plan(), b._plan()
    assert list(spec_a) == ["source"] and list(spec_b) == ["sink"]
    out = spec_a["source"]["outputs"]["frames"]
    # consumed only on b: one tcp socket, arrays inline (no ring)
    assert out["endpoint"] == "tcp://127.0.0.1:41002" and out["ring"] is None
    assert spec_b["sink"]["inputs"]["frames"]["endpoint"] == "tcp://127.0.0.1:41002"
    assert a.token == b.token == TOKEN
    assert a.primary and not b.primary


def test_an_output_consumed_on_both_hosts_gets_a_ring_and_a_tcp_socket(tmp_path, monkeypatch):
    monkeypatch.setenv("SEBVS_RUN_TOKEN", TOKEN)
    text = BASE + """
[actors.near]
run = "actors.synthetic:Sink"
inputs = { frames = "source/frames" }
"""
    topo = load_topology(write(tmp_path, text), ["sink.host=b"])
    spec = Supervisor(topo, runs_dir=tmp_path, host="a")._plan()
    out = spec["source"]["outputs"]["frames"]
    assert out["endpoint"].startswith("ipc://") and out["ring"]
    assert out["remote"] == "tcp://127.0.0.1:41002"
    assert out["subscribers"] == 1 and out["remote_subscribers"] == 1
    assert spec["near"]["inputs"]["frames"]["endpoint"] == out["endpoint"]


@pytest.mark.parametrize("extra, overrides, message", [
    ("", ["sink.host=c"], r"\[actors.sink\] key 'host': no host 'c' \(hosts: a, b\)"),
    ("[hosts.c]\nport = 80\n", [], r"\[hosts.c\] key 'port'"),
    ("[hosts.c]\nports = 45000\n", [], "unknown key 'ports'"),
    ("", ["source.process=g", "sink.process=g", "sink.host=b"], "a process runs on one host"),
])
def test_bad_placements_are_refused_with_file_table_and_key(tmp_path, extra, overrides, message):
    with pytest.raises(TopologyError, match=message):
        load_topology(write(tmp_path, BASE + extra), overrides)


def test_host_is_required_on_a_multi_host_topology_and_refused_elsewhere(tmp_path, monkeypatch):
    topo = load_topology(write(tmp_path, BASE))
    with pytest.raises(TopologyError, match="start one supervisor per host with --host"):
        Supervisor(topo, runs_dir=tmp_path)
    with pytest.raises(TopologyError, match="no such host"):
        Supervisor(topo, runs_dir=tmp_path, host="z")
    monkeypatch.delenv("SEBVS_RUN_TOKEN", raising=False)
    with pytest.raises(TopologyError, match="host 'b' needs the run's token"):
        Supervisor(topo, runs_dir=tmp_path, host="b")
    one_host = load_topology(ROOT / "topologies" / "synthetic.toml")
    with pytest.raises(TopologyError, match="no \\[hosts.<name>\\] tables"):
        Supervisor(one_host, runs_dir=tmp_path, host="a")


def test_ports_beyond_the_last_are_refused(tmp_path):
    topo = load_topology(write(tmp_path, BASE), ["hosts.b.port=65535", "sink.host=b"])
    with pytest.raises(TopologyError, match="beyond 65535"):
        _host_ports(topo)


# ----------------------------------------------------------------------- two supervisors
def sebvs(args, env_extra, **kw):
    env = dict(os.environ, SEBVS_RUN_TOKEN=TOKEN, **env_extra)
    return subprocess.Popen([sys.executable, "-m", "sebvs.cli", *args], cwd=ROOT, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, **kw)


def ports_overrides():
    ports = TcpPorts()                      # one picker: the two blocks cannot overlap
    return ["--set", f"hosts.a.port={ports.block(8)}",
            "--set", f"hosts.b.port={ports.block(8)}",
            "--set", "source.width=160", "--set", "source.height=160"]   # 75 KiB: the ring


def test_two_hosts_with_a_skewed_clock_report_corrected_hop_latency(tmp_path):
    # `near` reads the source on its own host: that output goes out on both sockets
    sets = ports_overrides() + ["--set", "near.run=actors.synthetic:Sink",
                                "--set", "near.inputs={ frames = \"source/frames\" }"]
    runs = ["--runs-dir", str(tmp_path)]
    b = sebvs(["run", str(HOSTS), "--host", "b", *sets, *runs],
              {"SEBVS_CLOCK_SKEW_NS": str(SKEW_NS)})
    a = sebvs(["run", str(HOSTS), "--host", "a", "--for", "3", *sets, *runs,
               "--profile-json", str(tmp_path / "profile.json")], {})
    out_a, _ = a.communicate(timeout=60)
    out_b, _ = b.communicate(timeout=20)    # the primary's stop ends b's actors and b
    assert a.returncode == 0, out_a
    assert b.returncode == 0, out_b
    infos = [json.loads(p.read_text()) for p in tmp_path.glob("synthetic_hosts-*/run.json")]
    primary = next(i for i in infos if i["host"] == "a")
    clock = primary["hosts"]["b"]["clock"]
    # one physical clock: the injected skew is the true offset, and it lies in the interval
    assert abs(clock["offset_ns"] - SKEW_NS) <= clock["uncertainty_ns"], clock
    assert clock["uncertainty_ns"] < 5_000_000
    assert set(primary["actors"]) == {"source", "relay", "sink", "near"}
    rep = json.loads((tmp_path / "profile.json").read_text())
    edges = {e["edge"]: e for e in rep["edges"]}
    for name in ("source/frames -> relay.frames", "relay/frames -> sink.frames"):
        e = edges[name]
        assert e["count"] > 50, e
        # uncorrected, one hop would read +50 ms and the other -50 ms
        assert 0 < e["p50"] < 20_000, e
        assert e["clock_uncertainty_us"] == pytest.approx(clock["uncertainty_ns"] / 1e3)
    near = edges["source/frames -> near.frames"]      # the ring, on host a
    assert near["count"] > 50 and "clock_uncertainty_us" not in near
    assert 0 < near["p50"] < 20_000
    chain = {c["chain"]: c for c in rep["chains"]}["source > relay > sink"]
    assert "clock_uncertainty_us" not in chain     # both ends on host a: one clock


def test_a_primary_without_its_other_host_fails_naming_it(tmp_path):
    a = sebvs(["run", str(HOSTS), "--host", "a", *ports_overrides(), "--runs-dir", str(tmp_path),
               "--set", "topology.ready_timeout_s=2"], {})
    out, _ = a.communicate(timeout=60)
    assert a.returncode == 1
    assert "on other hosts: relay" in out and "--host NAME` running on b" in out, out


def test_hosts_running_different_topologies_are_told_apart(tmp_path):
    sets = ports_overrides()
    runs = ["--runs-dir", str(tmp_path)]
    b = sebvs(["run", str(HOSTS), "--host", "b", *sets, *runs, "--set", "relay.mode=copy"], {})
    a = sebvs(["run", str(HOSTS), "--host", "a", "--for", "3", *sets, *runs,
               "--set", "topology.ready_timeout_s=20"], {})
    try:
        out, _ = a.communicate(timeout=60)
    finally:
        b.kill()
        b.communicate()
    assert a.returncode == 1
    assert "host 'b' runs another topology" in out, out


def test_cpus_are_checked_by_the_host_that_runs_the_actor(tmp_path, monkeypatch):
    monkeypatch.setenv("SEBVS_RUN_TOKEN", TOKEN)
    # CPU 4095 exists on no machine here: the file still loads (b may be bigger)...
    topo = load_topology(write(tmp_path, BASE), ["sink.host=b", "sink.cpus=[4095]"])
    Supervisor(topo, runs_dir=tmp_path, host="a")._plan()     # a runs only the source
    # ...and b's own supervisor refuses it, naming the actor
    with pytest.raises(TopologyError, match=r"\[actors.sink\] key 'cpus': CPU 4095 not"):
        Supervisor(topo, runs_dir=tmp_path, host="b")._plan()


# ----------------------------------------------------------------------- profiler
def two_host_info(tmp_path, clock_b):
    return {"name": "h", "run_id": "x", "rundir": str(tmp_path), "started_at": "",
            "actors": {"source": {"host": "a", "control": "tcp://127.0.0.1:1",
                                  "telemetry": "tcp://127.0.0.1:2", "consumed": ["frames"]},
                       "relay": {"host": "b", "control": "tcp://127.0.0.1:3",
                                 "telemetry": "tcp://127.0.0.1:4", "consumed": ["frames"]},
                       "sink": {"host": "a", "control": "tcp://127.0.0.1:5",
                                "telemetry": "tcp://127.0.0.1:6", "consumed": []}},
            "hosts": {"a": {"clock": {"offset_ns": 0, "uncertainty_ns": 0}},
                      "b": {"clock": clock_b}}}


def test_profiler_moves_other_hosts_stamps_onto_the_primary_clock(tmp_path):
    from sebvs.runtime.profiler import ProfileCollector
    info = two_host_info(tmp_path, {"offset_ns": SKEW_NS, "uncertainty_ns": 40_000})
    col = ProfileCollector(info)
    try:
        # true times: source sends at 1 ms, relay receives at 1.3 ms (its clock: +50 ms),
        # relay sends at 1.5 ms, sink receives at 1.9 ms and ends at 2.0 ms
        relay_rec = ["frames", "source/frames", 0, 0, 0.0, [["source", 0, 1_000_000]],
                     1_300_000 + SKEW_NS, 1_500_000 + SKEW_NS, 0, 0, 0]
        sink_rec = ["frames", "relay/frames", 0, 0, 0.0,
                    [["source", 0, 1_000_000], ["relay", 1_300_000 + SKEW_NS,
                                                1_500_000 + SKEW_NS]],
                    1_900_000, 2_000_000, 0, 0, 0]
        col.ingest({"actor": "relay", "records": [relay_rec]})
        col.ingest({"actor": "sink", "records": [sink_rec]})
        rep = col.report()
    finally:
        col.close()
    edges = {e["edge"]: e for e in rep["edges"]}
    assert edges["source/frames -> relay.frames"]["p50"] == pytest.approx(300.0)
    assert edges["relay/frames -> sink.frames"]["p50"] == pytest.approx(400.0)
    assert edges["relay/frames -> sink.frames"]["clock_uncertainty_us"] == pytest.approx(40.0)
    chain = rep["chains"][0]
    assert chain["p50"] == pytest.approx(1000.0) and "clock_uncertainty_us" not in chain
    assert not rep["skipped"]["profiler"]


def test_profiler_says_when_a_hosts_offset_is_not_known_yet(tmp_path):
    from sebvs.runtime.profiler import ProfileCollector, format_report
    col = ProfileCollector(two_host_info(tmp_path, None))
    try:
        col.ingest({"actor": "relay", "records": [
            ["frames", "source/frames", 0, 0, 0.0, [["source", 0, 1_000]], 2_000, 3_000,
             0, 0, 0]]})
        rep = col.report()
    finally:
        col.close()
    assert rep["edges"][0]["clock_uncertainty_us"] is None
    assert "clocks +-unknown" in format_report(rep)
