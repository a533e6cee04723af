"""Bad input on the data path: every message either decodes or is counted by kind, and the
input reads on; ring names from headers open nothing but this run's own plain files."""
import asyncio
import os
import tempfile
import time
from pathlib import Path

import msgpack
import numpy as np
import pytest
import zmq

from sebvs.runtime import shm
from sebvs.runtime.inputs import MAX_SEQ_GAP, Inputs
from sebvs.runtime.shm import RingReader, RingWriter
from sebvs.runtime.wire import SCHEMA_VERSION, WireError, array_spec, decode_header, \
    encode_header

RUN = f"hard{os.getpid()}"


def header(**kw) -> bytes:
    base = dict(source="src", output="frames", seq=0, t_sim=0.0, tick=0,
                stamps=[["src", 0, 1]], arrays=[], meta={})
    base.update(kw)
    return encode_header(**base)


def raw_header(**fields) -> bytes:
    h = {"v": SCHEMA_VERSION, "src": "src", "out": "frames", "seq": 0, "ts": 0.0,
         "tick": 0, "st": [], "a": [], "m": {}}
    h.update(fields)
    return msgpack.packb({k: v for k, v in h.items() if v is not ...}, use_bin_type=True)


# --------------------------------------------------------------------------- decoder
@pytest.mark.parametrize("raw, kind", [
    (raw_header(ts=...), "field"),                  # a header without its timestamp
    (raw_header(tick=...), "field"),
    (raw_header(seq=-1), "field"),
    (raw_header(seq=2 ** 64 - 1), "field"),
    (raw_header(seq=True), "field"),
    (raw_header(st=[["a"]]), "stamps"),
    (raw_header(st=[[1, 2, 3]]), "stamps"),
    (raw_header(st=[["a", 0, 1]] * 65), "stamps"),
    (raw_header(ts="now"), "field"),
])
def test_headers_that_decode_as_msgpack_but_are_not_ours(raw, kind):
    with pytest.raises(WireError) as err:
        decode_header(raw)
    assert err.value.kind == kind


@pytest.mark.parametrize("desc, kind", [
    (["a", [[["x"]], 4], [1], None], "dtype"),          # a field without its format
    (["a", [[], 0], [1], None], "dtype"),
    (["a", [[["x", "<f4", 0]] * 100, 400], [1], None], "dtype"),
    (["a", {"x": 1}, [1], None], "dtype"),
    (["a", "<f4", [2 ** 64, 0], None], "shape"),         # empty, but numpy refuses it
    (["a", "<f4", [True], None], "shape"),
    (["a", "<f4", [1], ["sebvs-x", -1, 0, 0]], "ring"),
    (["a", "<f4", [1], ["sebvs-x", 0, 0]], "ring"),
    ("not a list", "shape"),
])
def test_array_descriptors_fail_as_wire_errors(desc, kind):
    with pytest.raises(WireError) as err:
        array_spec(desc)
    assert err.value.kind == kind


def test_error_text_does_not_echo_a_huge_value():
    with pytest.raises(WireError) as err:
        array_spec(["a", "x" * 100_000, [1], None])
    assert len(str(err.value)) < 400


# --------------------------------------------------------------------------- inputs
class _Sink:
    """The actor side an Inputs needs: a stopping event and one handler."""

    def __init__(self, fail_on: set[int]):
        self.stopping = asyncio.Event()
        self.seen: list[int] = []
        self.fail_on = fail_on

    async def on_frames(self, msg):
        if msg.seq in self.fail_on:
            raise RuntimeError(f"handler bug on {msg.seq}")
        self.seen.append(msg.seq)


def _fifo_in_run() -> Path:
    path = shm.SHM_DIR / f"sebvs-{RUN}-planted-fifo"
    path.unlink(missing_ok=True)
    os.mkfifo(path)
    return path


async def _feed(messages: list[list[bytes]], fail_on: set[int] = frozenset()):
    with tempfile.TemporaryDirectory(prefix="sebvs-hard-") as tmp:
        endpoint = f"ipc://{tmp}/frames"
        ctx = zmq.Context()
        pub = ctx.socket(zmq.XPUB)
        pub.bind(endpoint)
        actor = _Sink(fail_on)
        inputs = Inputs()
        inputs.connect({"frames": {"endpoint": endpoint, "topic": "src/frames",
                                   "queue": 10_000, "hwm": 10_000}}, ctx, actor, RUN)
        assert pub.poll(5000), "the input never subscribed"
        pub.recv()
        inputs.start()
        for frames in messages:
            pub.send_multipart(frames)
        deadline = asyncio.get_running_loop().time() + 10
        inp = inputs.ports["frames"]
        while inp.stats.received < len(messages):
            assert asyncio.get_running_loop().time() < deadline, vars(inp.stats)
            await asyncio.sleep(0.01)
        await asyncio.sleep(0.05)
        stats = inputs.stats()["frames"]
        inputs.stop_reading()
        inputs.close()
        pub.close(linger=0)
        ctx.term()
        return actor, stats


def test_an_input_survives_every_kind_of_bad_message_and_reads_on():
    fifo = _fifo_in_run()
    topic = b"src/frames"
    f4 = np.zeros(2, np.float32).tobytes()
    bad = [
        [topic],                                                   # no header
        [topic, b"\xc1\xc1"],                                      # not msgpack
        [topic, raw_header(ts=...)],                               # KeyError before
        [topic, raw_header(st=[["x"]])],
        [topic, raw_header(a=[["a", [[["x"]], 4], [1], None]])],   # IndexError before
        [topic, raw_header(a=[["a", "<f4", [2 ** 64 - 1, 0], None]])],
        [topic, raw_header(a=[["a", "<f4", [2], None]])],          # buffer missing
        [topic, raw_header(a=[["a", "<f4", [3], None]]), f4],      # wrong length
        [topic, raw_header(a=[["a", "<f4", [2], ["sebvs-other-run-x", 0, 0, 2]]])],
        [topic, raw_header(a=[["a", "<f4", [2], [fifo.name, 0, 0, 2]]])],   # must not hang
        [b"src/frames2", header(seq=0)],                           # a prefix-matched topic
        [topic, header(seq=0), b"extra"],
    ]
    good = [[topic, header(seq=k)] for k in range(5)]
    forged = [[topic, header(seq=2 ** 63 - 1)], [topic, header(seq=0)],
              [topic, header(seq=1, arrays=[["a", "<f4", [2], None]]), f4]]
    try:
        actor, stats = asyncio.run(_feed(bad + good + forged, fail_on={3}))
    finally:
        fifo.unlink(missing_ok=True)
    assert stats["received"] == len(bad) + len(good) + len(forged)
    assert stats["malformed"] == len(bad)
    assert set(stats["malformed_kinds"]) >= {"frames", "header", "field", "stamps", "dtype",
                                             "shape", "ring", "topic"}
    assert stats["errors"] == 1 and stats["error_kinds"] == {"RuntimeError": 1}
    assert actor.seen == [0, 1, 2, 4, 2 ** 63 - 1, 0, 1]   # reads on after each one
    # a forged seq is a jump, going back is a producer restart: neither is a loss
    assert stats["seq_jumps"] == 1 and stats["seq_resets"] == 1
    assert stats["dropped_gap"] == 0


def test_seq_gaps_within_reason_count_as_losses():
    topic = b"src/frames"
    msgs = [[topic, header(seq=s)] for s in (0, 5, 5 + MAX_SEQ_GAP + 2)]
    _, stats = asyncio.run(_feed(msgs))
    assert stats["dropped_gap"] == 4 and stats["seq_jumps"] == 1


# --------------------------------------------------------------------------- rings
def test_ring_names_carry_a_random_part_and_squatting_is_refused(monkeypatch):
    a = RingWriter(f"sebvs-{RUN}-cam-rgb", 4, 4096)
    b = RingWriter(f"sebvs-{RUN}-cam-rgb", 4, 4096)
    try:
        assert a.name != b.name and a.name.startswith(f"sebvs-{RUN}-cam-rgb-{os.getpid()}-1-")
    finally:
        a.close()
        b.close()
    monkeypatch.setattr(shm.secrets, "token_hex", lambda n: "0" * (2 * n))
    squat = shm.SHM_DIR / f"sebvs-{RUN}-cam-rgb-{os.getpid()}-1-00000000"
    squat.write_bytes(b"")
    try:
        with pytest.raises(FileExistsError, match="refusing to share"):
            RingWriter(f"sebvs-{RUN}-cam-rgb", 4, 4096)
    finally:
        squat.unlink()


@pytest.mark.parametrize("plant", ["fifo", "symlink", "short", "bad_header", "dir"])
def test_reader_opens_only_plain_ring_files(plant):
    name = f"sebvs-{RUN}-planted-{plant}"
    path = shm.SHM_DIR / name
    real = RingWriter(f"sebvs-{RUN}-real", 2, 4096)
    real.reserve(8)
    try:
        if plant == "fifo":
            os.mkfifo(path)
        elif plant == "symlink":
            path.symlink_to(shm.SHM_DIR / real.name)
        elif plant == "short":
            path.write_bytes(b"\0" * 100)
        elif plant == "bad_header":
            data = bytearray((shm.SHM_DIR / real.name).read_bytes())
            data[8:16] = (10 ** 6).to_bytes(8, "little")     # claims a million slots
            path.write_bytes(bytes(data))
        else:
            path.mkdir()
        with pytest.raises((OSError, ValueError)):
            RingReader().view(name, 0, 0, 8, 0)
    finally:
        real.close()
        if path.is_dir() and not path.is_symlink():
            path.rmdir()
        else:
            path.unlink(missing_ok=True)


@pytest.mark.parametrize("name", ["sebvs-../../etc/passwd", "other-name", "sebvs-a b",
                                  "sebvs-" + "x" * 300])
def test_reader_refuses_names_outside_the_pattern(name):
    with pytest.raises(ValueError, match="refusing"):
        RingReader().view(name, 0, 0, 8, 0)


def source_sink_topology(tmp_path, name: str, *, sink_run: str = "actors.synthetic:Sink",
                         sink_input: str = '"source/frames"', source: str = "",
                         topology: str = ""):
    """A PatternSource feeding one sink, with extra TOML lines where a test needs them."""
    path = tmp_path / f"{name}.toml"
    path.write_text(f"""
[topology]
name = "{name}"
{topology}
[actors.source]
run = "actors.synthetic:PatternSource"
{source}
[actors.sink]
run = "{sink_run}"
inputs = {{ frames = {sink_input} }}
""")
    return path


# --------------------------------------------------------------------------- stalls
def test_stall_watch_reports_once_and_again_after_recovery():
    from sebvs.runtime.stalls import StallWatch
    w = StallWatch({("sink", "frames"): ("source", "frames")}, rounds=2)

    def rnd(sent, received):
        return w.update({"source": {"outputs": {"frames": {"sent": sent}}},
                         "sink": {"inputs": {"frames": {"received": received}}}})

    assert rnd(10, 10) == [] and rnd(20, 20) == []       # flowing
    assert rnd(30, 20) == []                             # one quiet round: not yet
    (text,) = rnd(40, 20)
    assert "sink.frames is stalled" in text and "source/frames sent 40" in text
    assert rnd(50, 20) == []                             # reported once
    assert rnd(50, 20) == []                             # producer idle too: no stall
    assert rnd(60, 30) == [] and not w.stalled          # recovered
    assert w.update({"sink": {}}) == []                  # a side that did not answer


def test_supervisor_reports_an_input_that_stops_receiving(tmp_path, monkeypatch):
    from sebvs.runtime import supervisor
    from sebvs.runtime.topology import load_topology
    monkeypatch.setattr(supervisor, "STALL_PERIOD_S", 0.3)
    topo = source_sink_topology(tmp_path, "stuck", sink_run="tests.runtime_actors:StuckSink",
                                source="width = 16\nheight = 16\nrate_hz = 200.0")
    messages = []
    sup = supervisor.Supervisor(load_topology(topo), runs_dir=tmp_path, echo=messages.append)
    sup.start()
    try:
        sup.wait(4.0)
    finally:
        sup.stop()
    stalled = [m for m in messages if "stalled" in m]
    assert len(stalled) == 1, messages
    assert "input sink.frames is stalled: source/frames sent" in stalled[0]


# --------------------------------------------------------------------------- control
def test_control_needs_the_runs_token_and_run_json_is_private(tmp_path):
    import json
    import stat

    import zmq

    from sebvs.runtime.supervisor import Supervisor, control_request
    from sebvs.runtime.topology import load_topology
    root = Path(__file__).resolve().parents[1]
    sup = Supervisor(load_topology(root / "topologies" / "synthetic.toml",
                                   ["source.width=32", "source.height=32"]),
                     runs_dir=tmp_path, echo=lambda s: None)
    sup.start()
    try:
        endpoint = sup.specs["relay"]["control"]
        ctx = zmq.Context.instance()
        for token in (None, "0" * 32, sup.token[:-1]):
            reply = control_request(ctx, endpoint, {"cmd": "set", "key": "mode", "value": "copy"},
                                    2.0, token=token)
            assert reply["ok"] is False and "token" in reply["error"]
        assert sup.request("relay", {"cmd": "get", "key": "mode"})["result"]["mode"] != "copy"
        run_json = sup.rundir / "run.json"
        assert json.loads(run_json.read_text())["token"] == sup.token
        assert stat.S_IMODE(run_json.stat().st_mode) == 0o600
        # a forged control request of 50 MB is never read in full, and the actor lives on
        control_request(ctx, endpoint, {"cmd": "get", "pad": "x" * (50 << 20)}, 1.0)
        assert sup.request("relay", {"cmd": "ping"})["ok"]
    finally:
        sup.stop()


@pytest.mark.parametrize("max_bytes, delivered", [(4096, False), (1 << 20, True)])
def test_an_input_refuses_messages_over_its_max_bytes(tmp_path, max_bytes, delivered):
    import time

    from sebvs.runtime.supervisor import Supervisor
    from sebvs.runtime.topology import TopologyError, load_topology
    # over tcp every array travels inline: 64 x 48 RGB is a 9,216-byte frame
    topo = source_sink_topology(
        tmp_path, "big", topology='transport = "tcp"',
        source="width = 64\nheight = 48\nrate_hz = 100.0",
        sink_input=f'{{ from = "source/frames", max_bytes = {max_bytes} }}')
    if not delivered:
        # the source's parameters say its frames' size: refused before any process starts
        with pytest.raises(TopologyError, match="9,216-byte arrays"):
            load_topology(topo)
        return
    sup = Supervisor(load_topology(topo), runs_dir=tmp_path, echo=lambda s: None)
    sup.start()
    try:
        time.sleep(1.0)
        handled = sup.request("sink", {"cmd": "stats"})["result"]["inputs"]["frames"]["handled"]
        assert sup.procs["sink"].popen.poll() is None
    finally:
        sup.stop()
    assert (handled > 10) if delivered else handled == 0


def test_max_bytes_is_validated_with_the_topology(tmp_path):
    from sebvs.runtime.topology import TopologyError, load_topology
    topo = source_sink_topology(tmp_path, "bad",
                                sink_input='{ from = "source/frames", max_bytes = 10 }')
    with pytest.raises(TopologyError, match="max_bytes"):
        load_topology(topo)


def test_a_ring_that_does_not_fit_shm_fails_at_creation_naming_the_budget(monkeypatch):
    """A full /dev/shm used to kill the writer with SIGBUS at its first write past the
    free pages; every page is now allocated when the ring is made, and a refusal there
    names the sizes and leaves no file behind."""
    import errno
    import os

    def no_space(fd, offset, length):
        raise OSError(errno.ENOSPC, "No space left on device")

    prefix = f"sebvs-test-full-{os.getpid()}"
    monkeypatch.setattr(shm.os, "posix_fallocate", no_space)
    ring = shm.RingWriter(prefix, 4)
    with pytest.raises(shm.ShmFull, match=r"needs [\d,]+ bytes .* bytes free of"):
        ring.reserve(1 << 20)
    assert not [p for p in os.listdir("/dev/shm") if p.startswith(prefix)]
    monkeypatch.undo()
    slot, view = ring.reserve(1 << 20)          # with room, the same ring works
    view[:4] = b"abcd"
    ring.commit(slot)
    ring.close()
    assert not [p for p in os.listdir("/dev/shm") if p.startswith(prefix)]


def test_ring_pages_are_allocated_up_front():
    import os
    ring = shm.RingWriter(f"sebvs-test-alloc-{os.getpid()}", 2, 1 << 20)
    try:
        st = os.stat(shm.SHM_DIR / ring.name)
        assert st.st_blocks * 512 >= st.st_size      # not a sparse file
    finally:
        ring.close()


async def _oversize_then_more(max_bytes: int):
    """Small messages, one over max_bytes, small ones again: what the input receives."""
    with tempfile.TemporaryDirectory(prefix="sebvs-hard-") as tmp:
        endpoint = f"ipc://{tmp}/frames"
        ctx = zmq.Context()
        pub = ctx.socket(zmq.XPUB)
        pub.bind(endpoint)
        actor = _Sink(set())
        inputs = Inputs()
        inputs.connect({"frames": {"endpoint": endpoint, "topic": "src/frames", "queue": 100,
                                   "hwm": 100, "max_bytes": max_bytes}}, ctx, actor, RUN)
        assert pub.poll(5000), "the input never subscribed"
        pub.recv()
        inputs.start()
        inp = inputs.ports["frames"]
        loop = asyncio.get_running_loop()

        async def until(cond, what):
            deadline = loop.time() + 10
            while not cond():
                assert loop.time() < deadline, f"{what}: {vars(inp.stats)}"
                await asyncio.sleep(0.01)

        topic = b"src/frames"
        for k in range(3):
            pub.send_multipart([topic, header(seq=k)])
        await until(lambda: inp.stats.received == 3, "before")
        pub.send_multipart([topic, header(seq=3), b"x" * (2 * max_bytes)])   # too big
        await until(lambda: inp.stats.oversize == 1, "the drop was not seen")
        # the subscription comes back with the new connection: send until it is there
        deadline = loop.time() + 10
        seq = 4
        while inp.stats.received < 4:
            assert loop.time() < deadline, f"never reconnected: {vars(inp.stats)}"
            pub.send_multipart([topic, header(seq=seq)])
            seq += 1
            await asyncio.sleep(0.02)
        base = inp.stats.received
        for k in range(3):
            pub.send_multipart([topic, header(seq=seq + k)])
        await until(lambda: inp.stats.received == base + 3, "after")
        stats = inputs.stats()["frames"]
        inputs.stop_reading()
        inputs.close()
        pub.close(linger=0)
        ctx.term()
        return stats


def test_one_oversized_frame_costs_that_frame_not_the_input():
    """ZeroMQ drops a peer that sends more than MAXMSGSIZE and does not reconnect: the
    input then received nothing for the rest of the run, and said nothing."""
    stats = asyncio.run(_oversize_then_more(4096))
    assert stats["oversize"] == 1
    assert stats["received"] >= 7 and stats["malformed"] == 0


def test_a_producer_that_goes_away_is_not_counted_as_oversize():
    async def scenario():
        with tempfile.TemporaryDirectory(prefix="sebvs-hard-") as tmp:
            endpoint = f"ipc://{tmp}/frames"
            ctx = zmq.Context()
            pub = ctx.socket(zmq.XPUB)
            pub.bind(endpoint)
            inputs = Inputs()
            inputs.connect({"frames": {"endpoint": endpoint, "topic": "src/frames",
                                       "queue": 100, "hwm": 100}}, ctx, _Sink(set()), RUN)
            assert pub.poll(5000)
            inputs.start()
            await asyncio.sleep(0.05)
            pub.close(linger=0)                       # the producer exits
            await asyncio.sleep(0.6)                  # beyond RETRY_WAIT_S: ZeroMQ retries
            stats = inputs.stats()["frames"]
            inputs.stop_reading()
            inputs.close()
            ctx.term()
            return stats
    assert asyncio.run(scenario())["oversize"] == 0


def test_the_profiler_counts_malformed_telemetry_instead_of_trusting_it():
    """Telemetry batches go through the data plane's bounded decoder: garbage, msgpack
    bombs (a huge array claimed in a few bytes) and oversized batches are counted."""
    import msgpack as mp

    from sebvs.runtime.profiler import MAX_TELEMETRY_BYTES, ProfileCollector

    with tempfile.TemporaryDirectory(prefix="sebvs-hard-") as tmp:
        endpoint = f"ipc://{tmp}/telemetry"
        ctx = zmq.Context()
        pub = ctx.socket(zmq.PUB)
        pub.bind(endpoint)
        prof = ProfileCollector({"actors": {"a": {"telemetry": endpoint, "consumed": True}}}, ctx)
        time.sleep(0.2)                                  # the SUB joins
        # 100,000 nils: 100 kB that unpack into a list past any batch's record limit
        bomb = b"\xdd" + (100_000).to_bytes(4, "big") + b"\xc0" * 100_000
        good = mp.packb({"actor": "a", "t_ns": 1, "records": [], "events": [],
                         "skipped": 0, "drops": {}})
        for body in (b"\xc1garbage", bomb, b"\0" * (MAX_TELEMETRY_BYTES + 1), good):
            pub.send_multipart([b"telemetry", body])
        deadline = time.monotonic() + 5
        while prof.skipped["batches"] < 3 and time.monotonic() < deadline:
            prof.poll(0.1)
        prof.poll(0.2)
        assert prof.skipped["batches"] == 3
        assert prof.t_first is not None                  # the good batch was taken
        prof.socket.close(linger=0)
        pub.close(linger=0)
        ctx.term()


def test_a_subscriber_without_the_runs_keys_reads_nothing_from_its_tcp_endpoints(tmp_path):
    """Every tcp socket of a run is a CURVE server keyed by the run's token: a local
    process without it used to read a source's frames and any actor's telemetry."""
    import time

    from sebvs.runtime.curve import client
    from sebvs.runtime.supervisor import Supervisor
    from sebvs.runtime.topology import load_topology
    topo = source_sink_topology(tmp_path, "curve", topology='transport = "tcp"',
                                source="width = 32\nheight = 32\nrate_hz = 100.0",
                                sink_input='"source/frames"')
    sup = Supervisor(load_topology(topo), runs_dir=tmp_path, echo=lambda s: None)
    sup.start()
    ctx = zmq.Context()
    try:
        data = sup.specs["source"]["outputs"]["frames"]["endpoint"]
        telemetry = sup.specs["sink"]["telemetry"]
        assert data.startswith("tcp://") and telemetry.startswith("tcp://")
        got = {}
        for who, keyed in (("stranger", False), ("member", True)):
            s = ctx.socket(zmq.SUB)
            s.setsockopt(zmq.LINGER, 0)
            s.setsockopt(zmq.SUBSCRIBE, b"")
            if keyed:
                client(s, data, sup.token)
            s.connect(data)
            s.connect(telemetry)
            deadline, n = time.monotonic() + 1.5, 0
            while time.monotonic() < deadline:
                if s.poll(100):
                    n += len(b"".join(s.recv_multipart()))
            got[who] = n
            s.close()
        assert got["stranger"] == 0
        assert got["member"] > 0          # the endpoints were live all along
    finally:
        ctx.term()
        sup.stop()


def test_curve_off_is_said_recorded_and_followed_by_the_profiler(tmp_path, monkeypatch):
    """SEBVS_CURVE=off (for measuring CURVE's cost): the supervisor says the tcp endpoints
    are open, run.json records it, a stranger reads frames, and the profiler, whose own
    environment still says on, attaches by what run.json says."""
    import json
    import time

    from sebvs.runtime import curve
    from sebvs.runtime.profiler import ProfileCollector
    from sebvs.runtime.supervisor import Supervisor
    from sebvs.runtime.topology import load_topology
    monkeypatch.setenv("SEBVS_CURVE", "off")
    topo = source_sink_topology(tmp_path, "plain", topology='transport = "tcp"',
                                source="width = 32\nheight = 32\nrate_hz = 100.0")
    messages = []
    sup = Supervisor(load_topology(topo), runs_dir=tmp_path, echo=messages.append)
    sup.start()
    ctx = zmq.Context()
    try:
        info = json.loads((sup.rundir / "run.json").read_text())
        assert info["curve"] is False
        assert any("SEBVS_CURVE=off" in m and "unencrypted" in m for m in messages), messages
        monkeypatch.setenv("SEBVS_CURVE", "on")
        collector = ProfileCollector(info, ctx)
        s = ctx.socket(zmq.SUB)
        s.setsockopt(zmq.LINGER, 0)
        s.setsockopt(zmq.SUBSCRIBE, b"")
        s.connect(sup.specs["source"]["outputs"]["frames"]["endpoint"])
        deadline, n = time.monotonic() + 1.5, 0
        while time.monotonic() < deadline:
            collector.poll(0.05)
            if s.poll(10):
                n += len(b"".join(s.recv_multipart()))
        s.close()
        rep = collector.report()
        collector.close()
        assert n > 0
        assert any(e["count"] > 0 for e in rep["edges"]), rep["edges"]
    finally:
        ctx.term()
        sup.stop()
    monkeypatch.setenv("SEBVS_CURVE", "maybe")
    with pytest.raises(ValueError, match="SEBVS_CURVE='maybe': expected 'on' or 'off'"):
        curve.enabled()


def test_a_consumer_whose_limit_refuses_every_frame_is_reported_stalled(tmp_path, monkeypatch):
    """The case the load-time size check cannot see (an actor whose frame size is not known
    from its parameters): every frame is over the input's max_bytes, so the input reconnects
    after each one and receives nothing. The input counts each drop as `oversize` and the
    supervisor's stall report names the input."""
    import time

    from sebvs.runtime import supervisor, topology
    from sebvs.runtime.topology import load_topology
    monkeypatch.setattr(supervisor, "STALL_PERIOD_S", 0.3)
    monkeypatch.setattr(topology, "_check_inline_sizes", lambda *a, **k: None)
    topo = source_sink_topology(
        tmp_path, "small", topology='transport = "tcp"',
        source="width = 64\nheight = 48\nrate_hz = 100.0",
        sink_input='{ from = "source/frames", max_bytes = 4096 }')
    messages, frames = [], {}
    sup = supervisor.Supervisor(load_topology(topo), runs_dir=tmp_path, echo=messages.append)

    def poll(dt: float) -> None:          # the sink's counters, taken once while it runs
        time.sleep(dt)
        if not frames and time.monotonic() > t_stats:
            frames.update(sup.request("sink", {"cmd": "stats"})["result"]["inputs"]["frames"])
            assert sup.procs["sink"].popen.poll() is None
    sup.start()
    t_stats = time.monotonic() + 3.0
    try:
        sup.wait(3.5, on_poll=poll)
    finally:
        sup.stop()
    assert frames["received"] == 0 and frames["oversize"] >= 2, frames
    stalled = [m for m in messages if "stalled" in m]
    assert len(stalled) == 1 and "input sink.frames is stalled" in stalled[0], messages
    assert "frames over its max_bytes dropped by ZeroMQ" in stalled[0]


def test_rings_that_do_not_fit_dev_shm_are_refused_before_any_process_starts(tmp_path,
                                                                            monkeypatch):
    """A 640 x 480 source's ring (12 slots of 900 KiB) against 1 MiB free: one line naming
    the budget and the ring, and no actor process started."""
    from sebvs.runtime import shm
    from sebvs.runtime.supervisor import RunFailed, Supervisor
    from sebvs.runtime.topology import load_topology
    monkeypatch.setattr(shm, "free_bytes", lambda directory=shm.SHM_DIR: 1 << 20)
    topo = source_sink_topology(tmp_path, "wide", source="width = 640\nheight = 480")
    sup = Supervisor(load_topology(topo), runs_dir=tmp_path, echo=lambda s: None)
    try:
        with pytest.raises(RunFailed, match=r"rings need [\d.,]+ MiB and /dev/shm has 1.0 MiB "
                                            r"free \(largest: source/frames "):
            sup.start()
        assert not any(p.popen for p in sup.procs.values())
    finally:
        sup.stop()
    assert shm.ring_bytes(12, 640 * 480 * 3) == 4096 + 12 * 921_600


def test_losses_are_said_at_the_end_of_a_run():
    """An input that lost data (here: ring slots overwritten before it read them, and a
    malformed message) gets one line at the end, naming how; a `latest` input's skips and
    clean inputs get none."""
    from sebvs.runtime.stalls import format_losses, losses
    stats = {"emulator": {"inputs": {"luma": {"received": 90, "dropped_overwritten": 7,
                                              "malformed": 1, "dropped_latest": 3}}},
             "policy": {"inputs": {"rgb": {"received": 50, "dropped_latest": 12}}},
             "sink": "not a dict"}
    found = losses(stats)
    assert found == {"emulator.luma": {"dropped_overwritten": 7, "malformed": 1}}
    assert format_losses(found) == [
        "input emulator.luma lost messages: 7 overwritten in the ring before it was read, "
        "1 malformed"]


def test_a_run_whose_input_lost_messages_says_so_when_it_stops(tmp_path):
    """Garbage to the sink for a second: `sebvs run` ends with the loss line."""
    import json
    import time

    from sebvs.runtime.supervisor import Supervisor
    from sebvs.runtime.topology import load_topology
    topo = source_sink_topology(tmp_path, "lossy")
    text = topo.read_text().replace('run = "actors.synthetic:PatternSource"',
                                    'run = "tests.runtime_actors:GarbageSource"')
    topo.write_text(text)
    said = []
    sup = Supervisor(load_topology(topo), runs_dir=tmp_path, echo=said.append)
    sup.start()
    try:
        time.sleep(1.0)
    finally:
        sup.stop()
    lines = [m for m in said if "lost messages" in m]
    assert len(lines) == 1 and lines[0].startswith("sebvs: input sink.frames lost messages: ")
    assert "malformed" in lines[0], lines
    info = json.loads((sup.rundir / "run.json").read_text())
    assert info["losses"]["sink.frames"]["malformed"] > 0


def test_no_spec_holding_the_token_outlives_a_workers_start_and_a_restart_writes_it_again(
        tmp_path):
    """A worker's spec holds the run's token; a pool worker killed with SIGKILL used to leave
    it in the socket directory until `sebvs ps` cleaned up. Each worker now removes its spec
    once read, and the supervisor writes it again for a restart."""
    import signal
    import time

    from sebvs.runtime.supervisor import Supervisor
    from sebvs.runtime.topology import load_topology
    topo = source_sink_topology(tmp_path, "spec", topology='restart = "restart"',
                                source="width = 32\nheight = 32\nrate_hz = 100.0")
    sup = Supervisor(load_topology(topo), runs_dir=tmp_path, echo=lambda s: None)
    sup.start()

    def holding_token() -> list[str]:
        return sorted(f.name for f in sup.sockdir.iterdir()
                      if f.is_file() and sup.token.encode() in f.read_bytes())

    seen = {}

    def watch(dt: float) -> None:
        time.sleep(dt)
        sink = sup.procs["sink"]
        if "killed" not in seen:
            seen["killed"] = sink.popen.pid
            os.kill(sink.popen.pid, signal.SIGKILL)
        elif sink.restarts == 1 and sink.ready and "after" not in seen:
            seen["after"] = holding_token()
            seen["stats"] = sup.request("sink", {"cmd": "stats"})
            sup.interrupt("checked")
        if time.monotonic() > deadline:
            sup.interrupt("no restart in time")

    try:
        assert holding_token() == []
        assert sorted(p.name for p in sup.sockdir.glob("*.json")) == []
        deadline = time.monotonic() + 15
        code = sup.wait(None, on_poll=watch)
    finally:
        sup.stop()
    assert code == 0 and sup.procs["sink"].restarts == 1, seen
    assert sup.procs["sink"].popen.pid != seen["killed"]
    assert seen["after"] == []                 # the restarted worker read and removed its own
    assert seen["stats"]["ok"] and seen["stats"]["result"]["started"]
