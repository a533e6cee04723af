"""ZeroMQ CURVE on every tcp socket of a run: data, telemetry and control.

ipc endpoints live in the run's private socket directory (mode 0700), so only this user
reaches them; tcp ports are open to any local process (and to the network where a host
address says so), so every tcp socket of a run is a CURVE server or client. The keys come
from the run's token (run.json "token", or SEBVS_RUN_TOKEN shared by the hosts of a
multi-host run): one server and one client key pair, derived so that every process that
holds the token, and only those, can connect. They are never in argv or in a file of
their own; the token travels as it always has (spec files in the 0700 socket directory,
run.json written 0600).

A process without the token (a stray subscriber) completes no handshake and reads 0
bytes. A libzmq built without CURVE (no libsodium) makes a tcp run fail at its first
socket with a line that says so.

SEBVS_CURVE=off in the environment of every process of a run turns it off: for measuring
what it costs (tools/bench/bench_hosts.py) and for a network nobody else can reach. The
supervisor says so when it starts and writes it in run.json ("curve"), which the tools
that attach (profile, view) follow.
"""
from __future__ import annotations

import functools
import hashlib
import os
from dataclasses import dataclass

import zmq
from zmq.utils import z85


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
    """Make ``sock`` a CURVE server before it binds ``endpoint`` (tcp only)."""
    if _needed(endpoint, token):
        k = keys_from_token(token)
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
