"""Clock offsets between hosts, NTP-style, over an actor's control socket.

One exchange: the supervisor reads its clock (t0), asks an actor on the other host for its
stamp clock (``{"cmd": "clock"}``, answered with ``now_ns()``: tr), and reads its clock
again when the reply arrives (t1). The remote reading happened between t0 and t1, so

    offset = tr - (t0 + t1) / 2,  known to within +-(t1 - t0) / 2

whatever the delays of the two directions. Of several exchanges, the intervals
[offset - rtt/2, offset + rtt/2] must all contain the true offset (clocks that do not
drift over the few milliseconds a measurement takes): their intersection is the estimate
and its half width the uncertainty. If they do not intersect (a clock stepped, or drifted
during the measurement), the exchange with the shortest round trip is taken, as NTP's
clock filter does. Offsets are remote minus local: a stamp t taken on the remote host is
t - offset on the local host's clock.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Callable, Sequence

import msgpack
import zmq

from . import curve
from .clock import now_ns

DEFAULT_EXCHANGES = 16
EXCHANGE_TIMEOUT_S = 0.5


@dataclass(frozen=True)
class ClockOffset:
    offset_ns: int          # remote clock - local clock
    uncertainty_ns: int     # the true offset lies within offset_ns +- this
    rtt_ns: int             # the shortest round trip of the exchanges
    exchanges: int          # exchanges that were answered
    intersected: bool       # False: the intervals disagreed, the shortest round trip was used

    def to_dict(self) -> dict:
        return asdict(self)


def estimate_offset(exchanges: Sequence[tuple[int, int, int]]) -> ClockOffset:
    """The offset from (t0, remote, t1) exchanges, t0 <= t1 on the local clock."""
    rows = [(int(t0), int(tr), int(t1)) for t0, tr, t1 in exchanges if t1 >= t0]
    if not rows:
        raise ValueError("no usable exchange (each needs t0 <= t1)")
    # doubled to stay in integers: 2 * offset = 2 * tr - t0 - t1, half width = t1 - t0
    lows = [2 * tr - t0 - t1 - (t1 - t0) for t0, tr, t1 in rows]
    highs = [2 * tr - t0 - t1 + (t1 - t0) for t0, tr, t1 in rows]
    low, high = max(lows), min(highs)
    best = min(rows, key=lambda r: r[2] - r[0])
    rtt = best[2] - best[0]
    if low <= high:
        return ClockOffset((low + high) // 4, (high - low + 3) // 4, rtt, len(rows), True)
    t0, tr, t1 = best
    return ClockOffset((2 * tr - t0 - t1) // 2, (rtt + 1) // 2, rtt, len(rows), False)


def measure_offset(ctx: zmq.Context, endpoint: str, token: str | None,
                   exchanges: int = DEFAULT_EXCHANGES,
                   clock: Callable[[], int] = now_ns,
                   timeout_s: float = EXCHANGE_TIMEOUT_S) -> ClockOffset | None:
    """Exchange ``exchanges`` times with the actor whose control socket is ``endpoint``;
    None when it answers none of them (it is gone, or refuses the token)."""
    sock = ctx.socket(zmq.DEALER)
    sock.setsockopt(zmq.LINGER, 0)
    curve.client(sock, endpoint, token)
    sock.connect(endpoint)
    request = msgpack.packb({"cmd": "clock", "token": token}, use_bin_type=True)
    rows = []
    try:
        for _ in range(exchanges):
            t0 = clock()
            sock.send(request)
            if not sock.poll(int(timeout_s * 1000)):
                break   # a late reply would pair with the next request: stop here
            t1 = clock()
            try:
                reply = msgpack.unpackb(sock.recv(), raw=False)
                remote = reply["result"]["t_ns"]
            except (ValueError, KeyError, TypeError):
                continue
            if type(remote) is int:
                rows.append((t0, remote, t1))
    finally:
        sock.close()
    return estimate_offset(rows) if rows else None
