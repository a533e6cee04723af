"""CURVE servers authenticate clients by their key: the server's public key is not enough
to read a run's tcp endpoints; only the client key pair derived from the run's token is."""
import asyncio
import threading
import time

import msgpack
import pytest
import zmq
import zmq.asyncio

from sebvs.runtime import curve
from tests.test_runtime_hardening import source_sink_topology


def _keys(server_public: bytes, client: tuple[bytes, bytes]):
    def key(sock):
        sock.curve_serverkey = server_public
        sock.curve_publickey, sock.curve_secretkey = client
    return key


def _subscribed_bytes(ctx, endpoints, key, seconds: float = 1.5) -> int:
    s = ctx.socket(zmq.SUB)
    s.setsockopt(zmq.LINGER, 0)
    s.setsockopt(zmq.SUBSCRIBE, b"")
    key(s)
    for endpoint in endpoints:
        s.connect(endpoint)
    deadline, n = time.monotonic() + seconds, 0
    while time.monotonic() < deadline:
        if s.poll(100):
            n += len(b"".join(s.recv_multipart()))
    s.close()
    return n


def _control_bytes(ctx, endpoint, key, request: dict, seconds: float = 1.5) -> int:
    s = ctx.socket(zmq.DEALER)
    s.setsockopt(zmq.LINGER, 0)
    key(s)
    s.connect(endpoint)
    s.send(msgpack.packb(request))
    n = len(s.recv()) if s.poll(int(seconds * 1000)) else 0
    s.close()
    return n


def test_a_client_with_the_server_key_but_a_key_pair_of_its_own_reads_nothing(tmp_path):
    """Who knows the run's server public key (derived from the token, or leaked) and makes
    a client key pair of their own used to complete the handshake and read frames,
    telemetry and control replies; now the actors' ZAP handlers refuse that key, count it
    and say so once in the actor's log."""
    from sebvs.runtime.supervisor import Supervisor
    from sebvs.runtime.topology import load_topology
    topo = source_sink_topology(tmp_path, "zap", topology='transport = "tcp"',
                                source="width = 32\nheight = 32\nrate_hz = 100.0",
                                sink_input='"source/frames"')
    sup = Supervisor(load_topology(topo), runs_dir=tmp_path, echo=lambda s: None)
    sup.start()
    ctx = zmq.Context()
    try:
        k = curve.keys_from_token(sup.token)
        data = sup.specs["source"]["outputs"]["frames"]["endpoint"]
        telemetry = sup.specs["sink"]["telemetry"]
        control = sup.specs["source"]["control"]
        assert all(e.startswith("tcp://") for e in (data, telemetry, control))
        stranger = _keys(k.server_public, zmq.curve_keypair())
        member = _keys(k.server_public, (k.client_public, k.client_secret))
        ping = {"cmd": "ping", "token": sup.token}
        assert _subscribed_bytes(ctx, [data, telemetry], stranger) == 0
        assert _control_bytes(ctx, control, stranger, ping) == 0
        assert _subscribed_bytes(ctx, [data], member) > 0
        assert _subscribed_bytes(ctx, [telemetry], member) > 0
        assert _control_bytes(ctx, control, member, ping) > 0
        # another run's derived client key is refused too
        other = curve.keys_from_token("another-run-token-0123456789")
        assert _subscribed_bytes(ctx, [data], _keys(k.server_public, (
            other.client_public, other.client_secret)), 0.5) == 0
        stats = sup.request("source", {"cmd": "stats"})["result"]
        assert stats["refused_clients"][data] >= 2 and stats["refused_clients"][control] >= 1
        sink = sup.request("sink", {"cmd": "stats"})["result"]
        assert list(sink["refused_clients"]) == [telemetry]   # each actor counts its own
        log = (sup.rundir / "logs" / "source.log").read_text()
        lines = [ln for ln in log.splitlines() if "refused a client" in ln]
        assert len(lines) == 2, lines             # one per endpoint, not one per attempt
        assert any(data in ln and "key " in ln for ln in lines), lines
        assert sup.request("source", {"cmd": "ping"}) is not None   # the run is unharmed
    finally:
        ctx.term()
        sup.stop()


def _pub(ctx, endpoint: str, token: str):
    s = ctx.socket(zmq.PUB)
    s.setsockopt(zmq.LINGER, 0)
    curve.serve(s, endpoint, token)
    s.bind(endpoint)
    return s


def _received(ctx, pub, endpoint: str, key, seconds: float = 0.7) -> int:
    s = ctx.socket(zmq.SUB)
    s.setsockopt(zmq.LINGER, 0)
    s.setsockopt(zmq.SUBSCRIBE, b"")
    key(s)
    s.connect(endpoint)
    n, deadline = 0, time.monotonic() + seconds
    while time.monotonic() < deadline:
        pub.send(b"x" * 10)
        if s.poll(10):
            n += len(s.recv())
    s.close()
    return n


def _zap_threads() -> list[threading.Thread]:
    return [t for t in threading.enumerate() if t.name == "sebvs-zap"]


def _endpoint() -> str:
    from sebvs.runtime.ports import TcpPorts
    return f"tcp://127.0.0.1:{TcpPorts('127.0.0.1').one()}"


def test_each_endpoint_accepts_only_its_own_tokens_client_key_and_ends_with_its_context():
    """Two runs' servers in one context: one ZAP handler, each endpoint keyed to its own
    token; term() ends the handler's thread instead of waiting on it."""
    before = len(_zap_threads())
    ctx, peers = zmq.Context(), zmq.Context()
    a, b = "token-of-run-a-0123456789", "token-of-run-b-0123456789"
    ka, kb = curve.keys_from_token(a), curve.keys_from_token(b)
    ea, eb = _endpoint(), _endpoint()
    pa, pb = _pub(ctx, ea, a), _pub(ctx, eb, b)
    try:
        assert len(_zap_threads()) == before + 1      # one per context, not per socket
        def client_of(token):
            def key(sock):
                curve.client(sock, "tcp://", token)
            return key
        assert _received(peers, pa, ea, client_of(a)) > 0
        assert _received(peers, pb, eb, client_of(b)) > 0
        assert _received(peers, pa, ea, _keys(ka.server_public, (
            kb.client_public, kb.client_secret))) == 0
        assert _received(peers, pb, eb, _keys(kb.server_public, zmq.curve_keypair())) == 0
        refused = curve.refused(ctx)
        assert set(refused) == {ea, eb} and min(refused.values()) >= 1, refused
    finally:
        pa.close()
        pb.close()
        t0 = time.monotonic()
        ctx.term()
        assert time.monotonic() - t0 < 2
        peers.term()
    deadline = time.monotonic() + 2
    while len(_zap_threads()) > before and time.monotonic() < deadline:
        time.sleep(0.01)
    assert len(_zap_threads()) == before


def test_an_asyncio_context_and_its_shadow_share_one_handler_and_destroy_ends_it():
    """A Node binds control on its asyncio context and data on a sync shadow of it."""
    async def main():
        actx = zmq.asyncio.Context()
        shadow = zmq.Context.shadow(actx.underlying)
        peers = zmq.Context()
        token = "token-of-an-asyncio-run-0123"
        e1, e2 = _endpoint(), _endpoint()
        control = actx.socket(zmq.ROUTER)
        control.setsockopt(zmq.LINGER, 0)
        data = shadow.socket(zmq.PUB)
        data.setsockopt(zmq.LINGER, 0)
        try:
            curve.serve(control, e1, token)
            control.bind(e1)
            curve.serve(data, e2, token)
            data.bind(e2)
            threads = len(_zap_threads())
            got = _received(peers, data, e2, lambda s: curve.client(s, e2, token))
            refused = _received(peers, data, e2, _keys(
                curve.keys_from_token(token).server_public, zmq.curve_keypair()))
        finally:
            peers.term()
            data.close()        # the shadow's sockets first, as Node.close does
            actx.destroy(linger=0)
        return threads, got, refused

    before = len(_zap_threads())
    threads, got, refused = asyncio.run(main())
    assert threads == before + 1 and got > 0 and refused == 0
    deadline = time.monotonic() + 2
    while len(_zap_threads()) > before and time.monotonic() < deadline:
        time.sleep(0.01)
    assert len(_zap_threads()) == before


def test_curve_off_starts_no_handler(monkeypatch):
    monkeypatch.setenv("SEBVS_CURVE", "off")
    before = len(_zap_threads())
    ctx = zmq.Context()
    endpoint = _endpoint()
    pub = _pub(ctx, endpoint, "token-of-a-plain-run-0123456")
    try:
        assert len(_zap_threads()) == before and curve.refused(ctx) == {}
        assert _received(ctx, pub, endpoint, lambda s: None) > 0
    finally:
        pub.close()
        ctx.term()


@pytest.mark.parametrize("frames, status", [
    ([b"1.0", b"7", b"tcp://h:1", b"127.0.0.1", b"", b"NULL"], b"400"),
    ([b"1.0", b"7", b"tcp://h:1", b"127.0.0.1", b"", b"CURVE", b"x" * 32], b"400"),
    ([b"2.0", b"7"], b"500"),
    ([], b"500"),
])
def test_zap_requests_other_than_a_known_key_are_refused(frames, status):
    ctx = zmq.Context()
    try:
        auth = curve._authenticator(ctx)
        auth.allow(b"tcp://h:1", b"y" * 32)
        reply = auth._answer(frames)
        assert len(reply) == 6 and reply[0] == b"1.0" and reply[2] == status
        assert auth._answer([b"1.0", b"8", b"tcp://h:1", b"", b"", b"CURVE",
                             b"y" * 32])[2] == b"200"
    finally:
        ctx.term()
