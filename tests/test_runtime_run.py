"""The runtime with real processes: run, control, profiler, crashes, slow consumers, Ctrl-C."""
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import zmq

from sebvs.runtime.profiler import ProfileCollector, format_report
from sebvs.runtime.supervisor import Supervisor, run_topology
from sebvs.runtime.topology import load_topology

ROOT = Path(__file__).resolve().parents[1]
SYNTHETIC = ROOT / "topologies" / "synthetic.toml"
SMALL = ["source.width=64", "source.height=48", "source.rate_hz=100"]


def alive(pid):
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    # a zombie is dead for our purpose
    try:
        return Path(f"/proc/{pid}/stat").read_text().split()[2] != "Z"
    except FileNotFoundError:
        return False


def assert_clean(sup: Supervisor):
    """No actor process, shared-memory ring or socket directory left behind."""
    for p in sup.procs.values():
        assert p.popen.poll() is not None, f"{p.name} still running"
    assert not list(Path("/dev/shm").glob(f"sebvs-{sup.run_id}-*"))
    assert not sup.sockdir.exists()


def start(tmp_path, overrides=(), path=SYNTHETIC, echo=None):
    sup = Supervisor(load_topology(path, list(overrides)), runs_dir=tmp_path,
                     echo=echo or (lambda s: None))
    sup.start()
    return sup


def ctl(sup, actor, **req):
    reply = sup.request(actor, req, 3.0)
    assert reply is not None, f"{actor} did not answer {req}"
    return reply


def test_synthetic_run_delivers_frames_and_cleans_up(tmp_path):
    sup = start(tmp_path, SMALL)
    try:
        info = json.loads((sup.rundir / "run.json").read_text())
        assert info["status"] == "running"
        assert set(info["actors"]) == {"source", "relay", "sink"}
        assert all(a["pid"] for a in info["actors"].values())
        time.sleep(0.6)
        stats = ctl(sup, "sink", cmd="stats")["result"]
        assert stats["inputs"]["frames"]["handled"] > 20
        assert stats["actor_stats"]["checksum"] > 0
        assert stats["inputs"]["frames"]["malformed"] == 0
    finally:
        t0 = time.monotonic()
        code = sup.stop()
        assert time.monotonic() - t0 < 2.0
    assert code == 0
    assert_clean(sup)
    info = json.loads((sup.rundir / "run.json").read_text())
    assert info["status"] == "ended"
    assert (sup.rundir / "logs" / "sink.log").exists()


def test_large_frames_travel_through_shared_memory(tmp_path):
    sup = start(tmp_path, ["source.rate_hz=50", "relay.mode=copy"])   # 640x640x3
    try:
        time.sleep(0.5)
        assert list(Path("/dev/shm").glob(f"sebvs-{sup.run_id}-source-frames-*"))
        assert list(Path("/dev/shm").glob(f"sebvs-{sup.run_id}-relay-frames-*"))
        st = ctl(sup, "sink", cmd="stats")["result"]["inputs"]["frames"]
        assert st["handled"] > 5 and st["dropped_overwritten"] == 0 and st["torn"] == 0
    finally:
        sup.stop()
    assert_clean(sup)


def test_cpus_pin_every_thread_of_the_actor(tmp_path):
    cpu = max(os.sched_getaffinity(0))
    sup = start(tmp_path, SMALL + [f"sink.cpus=[{cpu}]"])
    try:
        time.sleep(0.3)
        st = ctl(sup, "sink", cmd="stats")["result"]["inputs"]["frames"]
        assert st["handled"] > 5
        pid = sup.procs["sink"].popen.pid
        threads = [int(t) for t in os.listdir(f"/proc/{pid}/task")]
        assert len(threads) >= 2          # the main thread and ZeroMQ's I/O thread at least
        assert {t: os.sched_getaffinity(t) for t in threads} == {t: {cpu} for t in threads}
        relay = sup.procs["relay"].popen.pid
        assert os.sched_getaffinity(relay) == os.sched_getaffinity(0)   # unpinned: inherited
        info = json.loads((sup.rundir / "run.json").read_text())
        assert info["actors"]["sink"]["cpus"] == [cpu]
    finally:
        sup.stop()
    assert_clean(sup)


def test_probe_sees_stamps_and_arrays(tmp_path):
    topo = tmp_path / "probe.toml"
    topo.write_text(f"""
[topology]
name = "probe"
[actors.source]
run = "actors.synthetic:PatternSource"
width = 32
height = 24
rate_hz = 200.0
max_frames = 20
[actors.relay]
run = "actors.synthetic:Relay"
inputs = {{ frames = "source/frames" }}
[actors.probe]
run = "actors.synthetic:Probe"
inputs = {{ frames = "relay/frames" }}
path = "{tmp_path / 'probe'}"
""")
    run_topology(topo, duration_s=20, runs_dir=tmp_path)
    entries = json.loads((tmp_path / "probe.json").read_text())
    assert len(entries) >= 15
    first = entries[0]
    assert [s[0] for s in first["stamps"]] == ["source", "relay"]
    assert first["arrays"]["rgb"] == [[24, 32, 3], "|u1"]
    ticks = [e["tick"] for e in entries]
    assert ticks == sorted(ticks)


def test_malformed_messages_are_counted_and_the_receiver_survives(tmp_path):
    topo = tmp_path / "garbage.toml"
    topo.write_text("""
[topology]
name = "garbage"
[actors.source]
run = "tests.runtime_actors:GarbageSource"
[actors.sink]
run = "actors.synthetic:Sink"
inputs = { frames = "source/frames" }
""")
    sup = start(tmp_path, path=topo)
    try:
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            st = ctl(sup, "sink", cmd="stats")["result"]["inputs"]["frames"]
            if st["handled"] >= 6:
                break
            time.sleep(0.1)
        assert st["handled"] == 6, st           # the good ones before and after the garbage
        assert st["malformed"] == 7, st
        assert sup.procs["sink"].popen.poll() is None
    finally:
        sup.stop()
    log = (sup.rundir / "logs" / "sink.log").read_text()
    assert "malformed message dropped" in log
    assert_clean(sup)


def test_kill_9_is_noticed_reported_and_stops_the_run(tmp_path):
    messages = []
    sup = start(tmp_path, SMALL, echo=lambda s: messages.append((time.monotonic(), s)))
    relay_pid = sup.procs["relay"].popen.pid
    killed_at = []

    def kill_later():
        time.sleep(0.5)
        killed_at.append(time.monotonic())
        os.kill(relay_pid, signal.SIGKILL)

    threading.Thread(target=kill_later).start()
    code = sup.wait(10)
    assert code == 1
    noticed = [t for t, s in messages if "'relay' died" in s]
    assert noticed and noticed[0] - killed_at[0] < 1.0
    assert "SIGKILL" in sup.failure and "last lines" in sup.failure
    assert_clean(sup)
    for p in sup.procs.values():
        assert not alive(p.popen.pid)


def test_restart_policy_restarts_a_dead_actor(tmp_path):
    sup = start(tmp_path, SMALL + ["topology.restart=restart", "relay.mode=copy", "source.width=320",
                                   "source.height=240"])   # 230 KB frames: through rings
    first_pid = sup.procs["relay"].popen.pid
    seen = {}

    def kill_and_watch():
        time.sleep(0.3)
        os.kill(sup.procs["relay"].popen.pid, signal.SIGKILL)
        time.sleep(0.2)
        seen["before"] = ctl(sup, "sink", cmd="stats")["result"]["inputs"]["frames"]["handled"]
        time.sleep(2.0)
        seen["after"] = ctl(sup, "sink", cmd="stats")["result"]["inputs"]["frames"]["handled"]
        seen["rings"] = [p.name for p in Path("/dev/shm").glob(f"sebvs-{sup.run_id}-relay-*")]

    watcher = threading.Thread(target=kill_and_watch)
    watcher.start()
    code = sup.wait(3.0)   # supervises (and restarts) meanwhile, then stops the run
    watcher.join()
    assert code == 0
    assert sup.procs["relay"].restarts == 1
    assert sup.procs["relay"].popen.pid != first_pid
    assert seen["after"] > seen["before"] + 20   # frames flow again through the new relay
    assert seen["rings"] and all(f"-{first_pid}-" not in n for n in seen["rings"])
    assert_clean(sup)


@pytest.mark.parametrize("queue, counter", [(4, "dropped_gap"), ('"latest"', "dropped_latest")])
def test_slow_consumer_drops_and_counts_instead_of_queueing(tmp_path, queue, counter):
    sup = start(tmp_path, ["source.width=64", "source.height=48", "source.rate_hz=400",
                           "sink.work_ms=20", f"sink.inputs.frames={{from=\"relay/frames\", "
                                              f"queue={queue}}}"])
    try:
        time.sleep(1.5)
        st = ctl(sup, "sink", cmd="stats")["result"]["inputs"]["frames"]
        sent = ctl(sup, "source", cmd="stats")["result"]["outputs"]["frames"]["sent"]
    finally:
        sup.stop()
    assert st["handled"] < 0.5 * sent
    assert st[counter] > 0
    # what is neither handled nor counted as dropped is at most what queues can hold
    assert sent - st["handled"] - st["dropped_gap"] - st["dropped_latest"] < 200


def test_control_get_set_errors_and_stats(tmp_path):
    sup = start(tmp_path, SMALL)
    try:
        assert ctl(sup, "sink", cmd="get")["result"] == {"work_ms": 0.0}
        r = ctl(sup, "sink", cmd="set", key="work_ms", value=1)
        assert r["ok"] and r["result"] == {"work_ms": 1.0}
        bad = ctl(sup, "sink", cmd="set", key="nope", value=1)
        assert not bad["ok"] and "unknown key 'nope'" in bad["error"]
        bad = ctl(sup, "sink", cmd="set", key="work_ms", value="slow")
        assert not bad["ok"] and "expected float" in bad["error"]
        assert not ctl(sup, "relay", cmd="set", key="mode", value="teleport")["ok"]
        assert not ctl(sup, "sink", cmd="fly")["ok"]
        # garbage on the control socket is answered too
        s = zmq.Context.instance().socket(zmq.DEALER)
        s.connect(sup.specs["sink"]["control"])
        s.send(b"\xc1 not msgpack")
        assert s.poll(3000)
        s.close(0)
        assert ctl(sup, "sink", cmd="ping")["ok"]
        assert sup.procs["sink"].popen.poll() is None
    finally:
        sup.stop()


def profile_synthetic_chain(sup, seconds: float) -> dict:
    """Attach a profiler to a running source > relay > sink topology for ``seconds``, stop
    the run, check that the report has both hops, both handlers and the chain; the report."""
    try:
        col = ProfileCollector(sup.info)
        col.poll(seconds)
        rep = col.report()
        col.close()
    finally:
        sup.stop()
    edges = {e["edge"]: e for e in rep["edges"]}
    assert set(edges) == {"source/frames -> relay.frames", "relay/frames -> sink.frames"}
    assert all(e["count"] > 20 and 0 < e["p50"] < 1e5 for e in edges.values())
    assert rep["chains"][0]["chain"] == "source > relay > sink"
    assert {(h["actor"], h["input"]) for h in rep["handlers"]} == {("relay", "frames"),
                                                                   ("sink", "frames")}
    return rep


def test_profiler_attaches_and_reports_every_hop(tmp_path):
    rep = profile_synthetic_chain(start(tmp_path, SMALL), 1.5)
    text = format_report(rep)
    assert "source > relay > sink" in text and "p99" in text


def test_tcp_transport_carries_buffers_inline(tmp_path):
    sup = start(tmp_path, SMALL + ["topology.transport=tcp", "source.width=320",
                                   "source.height=240"])
    try:
        assert sup.specs["sink"]["inputs"]["frames"]["endpoint"].startswith("tcp://127.0.0.1:")
        time.sleep(0.6)
        st = ctl(sup, "sink", cmd="stats")["result"]["inputs"]["frames"]
        assert st["handled"] > 10 and st["malformed"] == 0
        assert not list(Path("/dev/shm").glob(f"sebvs-{sup.run_id}-*"))
    finally:
        sup.stop()


def test_cli_run_ctl_ps_and_ctrl_c(tmp_path):
    env = dict(os.environ, SEBVS_RUNS_DIR=str(tmp_path))
    cmd = [sys.executable, "-m", "sebvs.cli", "run", str(SYNTHETIC)] + \
        [a for o in SMALL for a in ("--set", o)]
    proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 20
        run_json = None
        while time.monotonic() < deadline:
            found = list(tmp_path.glob("synthetic-*/run.json"))
            if found and json.loads(found[0].read_text())["status"] == "running":
                run_json = json.loads(found[0].read_text())
                break
            time.sleep(0.1)
        assert run_json, "run never reached running"

        def sebvs(*args):
            return subprocess.run([sys.executable, "-m", "sebvs.cli", *args], cwd=ROOT,
                                  env=env, capture_output=True, text=True, timeout=30)

        ps = sebvs("ps")
        assert run_json["run_id"] in ps.stdout
        got = sebvs("ctl", run_json["run_id"], "relay", "get", "mode")
        assert json.loads(got.stdout) == {"mode": "forward"}
        bad = sebvs("ctl", run_json["rundir"], "relay", "set", "mode=teleport")
        assert bad.returncode == 1 and "teleport" in bad.stdout
        assert sebvs("ctl", "relay", "stats").returncode == 0   # newest live run
        prof = sebvs("profile", "--for", "1", "--json", str(tmp_path / "p.json"),
                     "--plot", str(tmp_path / "p.png"))
        assert "source > relay > sink" in prof.stdout
        assert json.loads((tmp_path / "p.json").read_text())["edges"]
        assert (tmp_path / "p.png").stat().st_size > 10_000
        t0 = time.monotonic()
        proc.send_signal(signal.SIGINT)
        proc.wait(5)
        assert time.monotonic() - t0 < 2.0
    finally:
        if proc.poll() is None:
            proc.kill()
    for a in run_json["actors"].values():
        assert not alive(a["pid"])
    assert not list(Path("/dev/shm").glob(f"sebvs-{run_json['run_id']}-*"))
    assert not Path(run_json["sockdir"]).exists()


def test_graph_cli_marks_pruned(tmp_path):
    out = subprocess.run([sys.executable, "-m", "sebvs.cli", "graph", str(SYNTHETIC),
                          "--set", "sink.inputs.frames=\"source/frames\""], cwd=ROOT,
                         capture_output=True, text=True)
    assert out.returncode == 0
    assert "relay  (actors.synthetic:Relay)  [pruned" in out.stdout


def test_cli_reports_topology_errors(tmp_path):
    out = subprocess.run([sys.executable, "-m", "sebvs.cli", "run", str(SYNTHETIC),
                          "--set", "source.colour=3"], cwd=ROOT, capture_output=True, text=True)
    assert out.returncode == 2
    assert "[actors.source]: unknown key 'colour'" in out.stderr
