"""The realtime tail: control deadlines counted by the clock, and process priorities."""
import subprocess
import sys
from pathlib import Path

import pytest

from sebvs.runtime.deadlines import DeadlineMonitor
from sebvs.runtime.topology import TopologyError, load_topology

ROOT = Path(__file__).resolve().parents[1]
MS = 1_000_000


def test_a_tick_misses_when_its_action_is_not_in_before_the_next_tick():
    d = DeadlineMonitor(100 * MS)
    assert d.published(0, 0) == 0
    d.action(0, 3 * MS)                         # in time
    assert d.published(1, 100 * MS) == 0
    assert d.published(2, 200 * MS) == 1        # tick 1 got nothing within its period
    d.action(1, 230 * MS)                       # ...and its action still arrives, late
    d.action(2, 204 * MS)
    d.action(2, 205 * MS)                       # a repeat is not timed twice
    d.action(99, 206 * MS)                      # nor a tick never published
    s = d.summary()
    assert (s["ticks"], s["misses"], s["answered"]) == (3, 1, 3)
    assert s["latency_max_ms"] == pytest.approx(130.0)   # the late one is in the tail
    assert s["latency_p50_ms"] == pytest.approx(4.0)
    assert s["miss_rate"] == pytest.approx(1 / 3)       # tick 2 answered: a hit already


def test_an_episode_end_is_not_a_deadline():
    d = DeadlineMonitor(50 * MS)
    d.published(0, 0)
    d.close_episode()                          # the episode ended before tick 1
    assert d.published(1, 10_000 * MS) == 0
    assert d.summary()["misses"] == 0 and d.summary()["ticks"] == 1


def test_period_must_be_positive():
    with pytest.raises(ValueError, match="period_ns must be positive"):
        DeadlineMonitor(0)


@pytest.mark.parametrize("value, ok", [(5, True), (-20, True), ('"realtime"', True),
                                       (20, False), ('"high"', False), ("true", False)])
def test_priority_key_takes_a_nice_value_or_realtime(tmp_path, value, ok):
    path = tmp_path / "t.toml"
    path.write_text(f"""
[topology]
name = "p"
[actors.source]
run = "actors.synthetic:PatternSource"
priority = {value}
[actors.sink]
run = "actors.synthetic:Sink"
inputs = {{ frames = "source/frames" }}
""")
    if ok:
        assert load_topology(path).actors["source"].priority in (5, -20, "realtime")
    else:
        with pytest.raises(TopologyError, match=r"\[actors.source\] key 'priority'"):
            load_topology(path)


def test_group_members_must_agree_on_priority():
    with pytest.raises(TopologyError, match="different priorities"):
        load_topology(ROOT / "topologies" / "synthetic.toml",
                      ["source.process=g", "relay.process=g", "source.priority=5"])


def test_set_priority_reaches_every_thread_and_a_refusal_is_reported():
    # in a child process: a nice value cannot be undone without privileges
    code = """
import os, threading, time
from sebvs.runtime.worker import set_priority
t = threading.Thread(target=time.sleep, args=(2,), daemon=True); t.start()
assert set_priority(7) is None
tids = [int(x) for x in os.listdir('/proc/self/task')]
print(sorted({os.getpriority(os.PRIO_PROCESS, tid) for tid in tids}))
os.setpriority = lambda *a: (_ for _ in ()).throw(PermissionError(1, 'Operation not permitted'))
print(set_priority(-5))
"""
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                         text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    assert lines[0] == "[7]"                    # the main thread and the other one
    assert "priority -5 not granted" in lines[1] and "CAP_SYS_NICE" in lines[1]


def test_an_actor_runs_at_its_topology_priority(tmp_path):
    import os
    from sebvs.runtime.supervisor import Supervisor
    ours = os.getpriority(os.PRIO_PROCESS, 0)
    if ours > 6:
        pytest.skip(f"this process runs at nice {ours}: lowering a child's to 6 needs privileges")
    topo = load_topology(ROOT / "topologies" / "synthetic.toml",
                         ["source.width=64", "source.height=48", "sink.priority=6"])
    sup = Supervisor(topo, runs_dir=tmp_path, echo=lambda s: None)
    sup.start()
    try:
        def nice(actor):   # field 19 of /proc/<pid>/stat, after the parenthesised name
            stat = Path(f"/proc/{sup.procs[actor].popen.pid}/stat").read_text()
            return int(stat.rsplit(")", 1)[1].split()[16])
        assert nice("sink") == 6
        assert nice("source") == ours              # inherited, as without the key
    finally:
        sup.stop()


NAV_POLICY = ROOT / "topologies" / "nav_policy.toml"
REALTIME = ['topology.clock="realtime"']


def test_on_the_realtime_clock_the_loops_actors_default_to_realtime():
    from sebvs.runtime.topology import loop_members
    topo = load_topology(NAV_POLICY, [*REALTIME, "camera.priority=5"])
    loop = {"sim", "camera", "emulator", "accumulator", "policy"}
    assert loop_members(topo) == loop
    got = {n: (a.priority, a.loop_priority) for n, a in topo.actors.items()}
    # the tracker is off the loop; the camera's own priority stays
    assert got == {**{n: ("realtime", True) for n in loop - {"camera"}},
                   "camera": (5, False), "tracker": (None, False)}
    topo = load_topology(NAV_POLICY, [*REALTIME, 'topology.loop_priority="none"'])
    assert {a.priority for a in topo.actors.values()} == {None}
    topo = load_topology(NAV_POLICY, ['topology.loop_priority=-5'])       # lockstep
    assert {a.priority for a in topo.actors.values()} == {None}
    # a group follows its loop member: a process is one priority
    topo = load_topology(NAV_POLICY, [*REALTIME, "policy.process=g", "tracker.process=g"])
    assert topo.actors["tracker"].priority == "realtime"
    with pytest.raises(TopologyError, match="key 'loop_priority': expected"):
        load_topology(NAV_POLICY, [*REALTIME, 'topology.loop_priority="fast"'])


def test_a_refused_realtime_priority_is_said_in_one_line_at_start(tmp_path, monkeypatch):
    from sebvs.runtime import supervisor
    monkeypatch.setattr(supervisor, "realtime_refused",
                        lambda: "SCHED_FIFO not granted ([Errno 1] Operation not permitted)")
    said = []
    sup = supervisor.Supervisor(load_topology(NAV_POLICY, REALTIME), runs_dir=tmp_path,
                                echo=said.append)
    sup._say_priority_refused()
    assert len(said) == 1 and said[0].startswith(
        "sebvs: sim, camera, emulator, accumulator, policy run at the default priority, not "
        "realtime (the loop's default): SCHED_FIFO not granted"), said
