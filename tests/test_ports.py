"""tcp ports a run hands out: free, never twice, out of the kernel's ephemeral range; and a
supervisor whose start fails (here: a port taken between probe and bind) leaves nothing."""
import socket

import pytest

from sebvs.runtime import ports
from sebvs.runtime.ports import LOWEST, TcpPorts, ephemeral_start


class Draws:
    """randrange answering from a script, then from the real generator."""

    def __init__(self, *script):
        self.script = list(script)
        self.real = ports.random.SystemRandom()

    def randrange(self, lo, hi):
        return self.script.pop(0) if self.script else self.real.randrange(lo, hi)


def test_the_ephemeral_range_start_is_read_and_defaults_to_iana(tmp_path):
    f = tmp_path / "ip_local_port_range"
    f.write_text("40000\t60999\n")
    assert ephemeral_start(f) == 40000
    f.write_text("garbage\n")
    assert ephemeral_start(f) == ports.IANA_EPHEMERAL_START
    assert ephemeral_start(tmp_path / "missing") == ports.IANA_EPHEMERAL_START


def test_ports_lie_below_the_ephemeral_range_and_none_is_given_twice():
    picker = TcpPorts()
    got = [picker.one() for _ in range(60)]
    assert len(set(got)) == len(got)
    assert all(LOWEST <= p < ephemeral_start() for p in got)


def test_a_port_already_given_or_bound_is_passed_over():
    picker = TcpPorts()
    first = picker.one()
    with socket.socket() as held:
        held.bind(("127.0.0.1", 0))
        held.listen()
        busy = held.getsockname()[1]
        other = next(p for p in range(LOWEST + 7, LOWEST + 500)
                     if p not in (first, busy) and ports.bindable("127.0.0.1", range(p, p + 1)))
        picker._random = Draws(first, busy, other)
        assert picker.one() == other


def test_blocks_of_one_picker_do_not_overlap():
    picker = TcpPorts()
    a = picker.block(8)
    picker._random = Draws(a + 4)          # overlaps a's block: drawn again
    b = picker.block(8)
    assert not set(range(a, a + 8)) & set(range(b, b + 8))


def test_no_room_below_the_ephemeral_range_falls_back_to_the_kernels_pick(monkeypatch):
    monkeypatch.setattr(ports, "ephemeral_start", lambda: LOWEST + 2)
    picker = TcpPorts()
    assert picker.one() > 0
    with pytest.raises(RuntimeError, match="no 100000 consecutive free tcp ports"):
        TcpPorts(tries=3).block(100000)


def test_a_failed_start_stops_what_it_had_started(tmp_path):
    """The second port handed out (the source's second output) is taken between the
    supervisor's probe and the source's bind: start() raises, and the sink it had spawned,
    the socket directory and the zmq context are gone without a stop() from the caller."""
    from sebvs.runtime.supervisor import RunFailed, Supervisor
    from sebvs.runtime.topology import load_topology
    from tests.test_runtime_hardening import source_sink_topology

    topo = source_sink_topology(tmp_path, "taken", topology='transport = "tcp"',
                                source="width = 32\nheight = 32\nrate_hz = 100.0")
    sup = Supervisor(load_topology(topo), runs_dir=tmp_path, echo=lambda s: None)
    with socket.socket() as held:
        held.bind(("127.0.0.1", 0))
        held.listen()
        taken = held.getsockname()[1]
        one, handed = sup.ports.one, []

        def one_taken_later():
            handed.append(taken if len(handed) == 1 else one())
            return handed[-1]
        sup.ports.one = one_taken_later
        with pytest.raises(RunFailed, match=f"Address already in use.*{taken}"):
            sup.start()
    assert sup.status == "ended" and sup.ctx.closed
    assert not sup.sockdir.exists()
    assert all(p.popen.poll() is not None for p in sup.procs.values() if p.popen)
    assert sup.stop() == 1                 # a caller's stop() after it is harmless


def test_a_start_refused_before_any_actor_says_why_in_run_json(tmp_path, monkeypatch):
    import json

    from sebvs.runtime.supervisor import RunFailed, Supervisor
    from sebvs.runtime.topology import load_topology
    from tests.test_runtime_hardening import source_sink_topology

    monkeypatch.setenv("SEBVS_CURVE", "sometimes")
    topo = source_sink_topology(tmp_path, "refused", topology='transport = "tcp"')
    sup = Supervisor(load_topology(topo), runs_dir=tmp_path, echo=lambda s: None)
    with pytest.raises(RunFailed, match="SEBVS_CURVE"):
        sup.start()
    info = json.loads((sup.rundir / "run.json").read_text())
    assert info["status"] == "ended" and "SEBVS_CURVE" in info["failure"]
    assert sup.ctx.closed and not sup.sockdir.exists()
