"""ZeroMQ CURVE on every tcp socket of a run: data, telemetry, control and ready reports.

ipc endpoints live in the run's private socket directory (mode 0700), so only this user
reaches them; tcp ports are open to any local process (and to the network where a host
address says so), so every tcp socket of a run is a CURVE server or client. The keys come
from the run's token (run.json "token", or SEBVS_RUN_TOKEN shared by the hosts of a
multi-host run): one server and one client key pair, derived so that every process that
holds the token, and only those, can connect. They are never in argv or in a file of
their own; the token travels as it always has (spec files in the 0700 socket directory,
each removed by its worker once read; run.json written 0600).

Clients are authenticated by their key. CURVE alone only proves a client knows the
server's public key, and libzmq lets any client key in unless a ZAP handler (RFC 27, on
``inproc://zeromq.zap.01``) is bound on the server's context. So ``serve`` starts one per
libzmq context, before the first server socket binds: a thread that accepts, on each
server endpoint (the socket's ZAP domain), only the client key derived from the token that
endpoint was served with, and refuses every other. A refusal is logged (the endpoint, the
peer address and the key's first characters; once a minute per endpoint at most) and
counted (``refused``, in an actor's stats as "refused_clients"). The thread ends with its
context: ``term()`` interrupts its wait and waits for it to close its socket.

A process without the token (a stray subscriber) completes no handshake and reads 0
bytes; nor does one that has the server's public key but not the run's client key pair.
A libzmq built without CURVE (no libsodium) makes a tcp run fail at its first socket with
a line that says so.

SEBVS_CURVE=off in the environment of every process of a run turns it off (no keys, no
ZAP handler): for measuring what it costs (tools/bench/bench_hosts.py) and for a network
nobody else can reach. The supervisor says so when it starts and writes it in run.json
("curve"), which the tools that attach (profile, view) follow.
"""
from __future__ import annotations

import functools
import hashlib
import hmac
import logging
import os
import threading
import time
from dataclasses import dataclass

import zmq
from zmq.utils import z85

ZAP_ENDPOINT = "inproc://zeromq.zap.01"     # RFC 27: where libzmq asks, per context
REFUSAL_LOG_S = 60.0    # a refused client retries: one line per endpoint per minute
MAX_DOMAIN_BYTES = 255  # libzmq's limit on ZMQ_ZAP_DOMAIN

log = logging.getLogger("sebvs.curve")


@dataclass(frozen=True)
class CurveKeys:
    server_public: bytes
    server_secret: bytes
    client_public: bytes
    client_secret: bytes


@functools.lru_cache(maxsize=8)
def keys_from_token(token: str) -> CurveKeys:
    """The run's key pairs, the same in every process that holds ``token`` (derived once
    per process: every tcp socket asks, the supervisor's stats rounds every 2 s among
    them)."""
    def secret(role: str) -> bytes:
        seed = hashlib.sha256(f"sebvs-curve-{role}\0{token}".encode()).digest()
        return z85.encode(seed)
    server_secret, client_secret = secret("server"), secret("client")
    return CurveKeys(zmq.curve_public(server_secret), server_secret,
                     zmq.curve_public(client_secret), client_secret)


def enabled() -> bool:
    """SEBVS_CURVE: "on" (the default) or "off"."""
    value = os.environ.get("SEBVS_CURVE", "on").strip().lower()
    if value not in ("on", "off"):
        raise ValueError(f"SEBVS_CURVE={value!r}: expected 'on' or 'off'")
    return value == "on"


def token_of(run_info: dict) -> str | None:
    """The token a tool attaching to a run (run.json) keys its tcp sockets with: none when
    the run went without CURVE."""
    return run_info.get("token") if run_info.get("curve", True) else None


def _needed(endpoint: str, token: str | None) -> bool:
    if not (enabled() and token and isinstance(endpoint, str) and endpoint.startswith("tcp://")):
        return False
    if not zmq.has("curve"):
        raise RuntimeError(f"{endpoint}: tcp endpoints of a run are encrypted with ZeroMQ "
                           f"CURVE, which this libzmq ({zmq.zmq_version()}) was built "
                           f"without (libsodium): install a pyzmq wheel (they bundle it) "
                           f"or keep the run on one host (ipc)")
    return True


def serve(sock: zmq.Socket, endpoint: str, token: str | None) -> None:
    """Make ``sock`` a CURVE server before it binds ``endpoint`` (tcp only), accepting
    only clients with the key pair derived from ``token``."""
    if _needed(endpoint, token):
        k = keys_from_token(token)
        domain = _domain(endpoint)
        _authenticator(sock.context).allow(domain, z85.decode(k.client_public))
        sock.zap_domain = domain
        sock.curve_secretkey = k.server_secret
        sock.curve_publickey = k.server_public
        sock.curve_server = True


def client(sock: zmq.Socket, endpoint: str, token: str | None) -> None:
    """Make ``sock`` a CURVE client of the run's servers before it connects (tcp only)."""
    if _needed(endpoint, token):
        k = keys_from_token(token)
        sock.curve_serverkey = k.server_public
        sock.curve_publickey = k.client_public
        sock.curve_secretkey = k.client_secret


def refused(ctx: zmq.Context) -> dict[str, int]:
    """Clients refused so far on ``ctx``'s server endpoints, by endpoint (none: {})."""
    with _registry_lock:
        auth = _authenticators.get(ctx.underlying)
    live = auth is not None and not auth.ended and auth.pid == os.getpid()
    return auth.refusals() if live else {}


def _domain(endpoint: str) -> bytes:
    # the endpoint itself, so that a ZAP request says which server it is for
    raw = endpoint.encode()
    return raw if len(raw) <= MAX_DOMAIN_BYTES else hashlib.sha256(raw).hexdigest().encode()


class _Authenticator:
    """The ZAP handler of one libzmq context: per server endpoint (its ZAP domain), the
    one client key it accepts."""

    def __init__(self, ctx: zmq.Context) -> None:
        self.pid = os.getpid()
        self.ended = False
        self._allowed: dict[bytes, bytes] = {}      # domain -> client public key (32 bytes)
        self._refused: dict[str, int] = {}
        self._logged_at: dict[str, float] = {}
        self._lock = threading.Lock()
        # a context object of our own over the same libzmq context: the caller's may be
        # asyncio's (futures, unusable from a thread), and its destroy() closes the
        # sockets it made, which must not include this one (owned by another thread)
        self._ctx = zmq.Context.shadow(ctx.underlying)
        self._sock = self._ctx.socket(zmq.REP)
        self._sock.linger = 0
        try:
            self._sock.bind(ZAP_ENDPOINT)
        except zmq.ZMQError as exc:
            self._sock.close()
            raise RuntimeError(f"{ZAP_ENDPOINT}: cannot bind this run's ZAP handler ({exc}): "
                               f"another authenticator already serves this zmq context"
                               ) from None
        # daemon: a process that exits without term() is not held by it
        self._thread = threading.Thread(target=self._serve, name="sebvs-zap", daemon=True)
        self._thread.start()

    def allow(self, domain: bytes, client_public: bytes) -> None:
        # the latest token served on an endpoint wins: a socket bound there before has
        # been closed (or its endpoint would not bind again)
        with self._lock:
            self._allowed[domain] = client_public

    def refusals(self) -> dict[str, int]:
        with self._lock:
            return dict(self._refused)

    def _serve(self) -> None:
        try:
            while True:
                try:
                    request = self._sock.recv_multipart()
                except zmq.ZMQError as exc:
                    if exc.errno == zmq.ETERM:
                        return
                    # closing the socket would unbind the handler, and libzmq would then
                    # accept every client: go on instead
                    log.error("%s: receiving a ZAP request failed: %s", ZAP_ENDPOINT, exc)
                    time.sleep(0.1)
                    continue
                try:
                    reply = self._answer(request)
                except Exception as exc:
                    reply = [b"1.0", request[1] if len(request) > 1 else b"", b"500",
                             f"{type(exc).__name__}".encode(), b"", b""]
                try:
                    self._sock.send_multipart(reply)
                except zmq.ZMQError as exc:
                    if exc.errno == zmq.ETERM:
                        return
                    log.error("%s: answering a ZAP request failed: %s", ZAP_ENDPOINT, exc)
        finally:
            # before the close: term() returns once it is done, and a context made
            # after that may have this one's address
            self.ended = True
            self._sock.close(linger=0)

    def _answer(self, frames: list[bytes]) -> list[bytes]:
        """RFC 27: [version, request id, domain, address, identity, mechanism, *credentials]
        -> [version, request id, status, text, user id, metadata]."""
        if len(frames) < 6 or frames[0] != b"1.0":
            return [b"1.0", frames[1] if len(frames) > 1 else b"", b"500",
                    b"malformed ZAP request", b"", b""]
        request_id, domain, address, mechanism = frames[1], frames[2], frames[3], frames[5]
        key = frames[6] if mechanism == b"CURVE" and len(frames) == 7 else None
        with self._lock:
            allowed = self._allowed.get(domain)
        if key is not None and allowed is not None and hmac.compare_digest(key, allowed):
            return [b"1.0", request_id, b"200", b"OK", b"sebvs", b""]
        self._note_refusal(domain, address, mechanism, key)
        return [b"1.0", request_id, b"400", b"client key not of this run", b"", b""]

    def _note_refusal(self, domain: bytes, address: bytes, mechanism: bytes,
                      key: bytes | None) -> None:
        where = domain.decode(errors="replace")
        now = time.monotonic()
        with self._lock:
            count = self._refused[where] = self._refused.get(where, 0) + 1
            last = self._logged_at.get(where)
            if last is not None and now - last < REFUSAL_LOG_S:
                return
            self._logged_at[where] = now
        who = f"key {z85.encode(key)[:8].decode()}..." if key is not None and len(key) == 32 \
            else f"mechanism {mechanism.decode(errors='replace')}"
        log.warning("%s: refused a client from %s with %s, not this run's (%d refused on this "
                    "endpoint so far)", where, address.decode(errors="replace") or "?", who,
                    count)


_authenticators: dict[int, _Authenticator] = {}     # by libzmq context address
_registry_lock = threading.Lock()


def _authenticator(ctx: zmq.Context) -> _Authenticator:
    """``ctx``'s ZAP handler, started on first use (ZAP is per libzmq context, and the
    asyncio context of a Node and its sync shadow share one)."""
    with _registry_lock:
        for address in [a for a, auth in _authenticators.items()
                        if auth.ended or auth.pid != os.getpid()]:
            del _authenticators[address]    # terminated contexts; a fork's parent's
        auth = _authenticators.get(ctx.underlying)
        if auth is None:
            auth = _authenticators[ctx.underlying] = _Authenticator(ctx)
        return auth
