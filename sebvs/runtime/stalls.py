"""Stalled inputs: an input that receives nothing while its producer keeps sending.

The inputs themselves survive bad messages (inputs.py); this is the supervisor's second
line, for whatever else could leave an input deaf (a broken connection, a handler that
never returns). Every `period_s` the supervisor asks all actors for their stats at once;
an input is stalled when, over `rounds` consecutive periods, its producer's output count
rose and the input's received count did not. Each stall is reported once, and again only
after the input has recovered.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import msgpack
import zmq

from . import curve

STALL_PERIOD_S = 2.0
STALL_ROUNDS = 2
QUERY_TIMEOUT_S = 0.3


def query_all(ctx: zmq.Context, endpoints: dict[str, str], request: dict,
              timeout_s: float = QUERY_TIMEOUT_S) -> dict[str, dict]:
    """One request to many control sockets in parallel: {actor: reply} for those that
    answered within ``timeout_s`` (a busy actor is skipped, not waited for)."""
    body = msgpack.packb(request, use_bin_type=True)
    socks = {}
    poller = zmq.Poller()
    try:
        for name, endpoint in endpoints.items():
            s = ctx.socket(zmq.DEALER)
            s.setsockopt(zmq.LINGER, 0)
            curve.client(s, endpoint, request.get("token"))
            s.connect(endpoint)
            s.send(body)
            socks[s] = name
            poller.register(s, zmq.POLLIN)
        replies = {}
        deadline = time.monotonic() + timeout_s
        while len(replies) < len(socks):
            left = deadline - time.monotonic()
            if left <= 0:
                break
            for s, _ in poller.poll(int(left * 1000) + 1):
                try:
                    replies[socks[s]] = msgpack.unpackb(s.recv(zmq.NOBLOCK), raw=False)
                except (zmq.Again, ValueError):
                    pass
                poller.unregister(s)
        return replies
    finally:
        for s in socks:
            s.close()


@dataclass
class StallWatch:
    """Counters of the last rounds, per input: (producer's sent, input's received)."""
    producers: dict[tuple[str, str], tuple[str, str]]   # (actor, input) -> (actor, output)
    rounds: int = STALL_ROUNDS
    _last: dict = field(default_factory=dict)
    _quiet: dict = field(default_factory=dict)          # rounds in a row without receiving
    stalled: set = field(default_factory=set)

    def update(self, stats: dict[str, dict]) -> list[str]:
        """Feed one round of `stats` replies ({actor: result}); the new stalls, as text."""
        found = []
        for (actor, inp), (src, out) in self.producers.items():
            try:
                sent = stats[src]["outputs"][out]["sent"]
                received = stats[actor]["inputs"][inp]["received"]
            except (KeyError, TypeError):
                continue   # one side did not answer this round
            key = (actor, inp)
            last = self._last.get(key)
            self._last[key] = (sent, received)
            if last is None:
                continue
            if sent > last[0] and received == last[1]:
                self._quiet[key] = self._quiet.get(key, 0) + 1
            elif received > last[1]:
                self._quiet[key] = 0
                self.stalled.discard(key)
            if self._quiet.get(key, 0) >= self.rounds and key not in self.stalled:
                self.stalled.add(key)
                found.append(f"input {actor}.{inp} is stalled: {src}/{out} sent {sent} "
                             f"(+{sent - last[0]} in the last round) while it received "
                             f"nothing for {self._quiet[key]} rounds (still at {received})"
                             + _why(stats[actor]["inputs"][inp]))
        return found


def _why(counters: dict) -> str:
    """What the input itself counted instead of receiving, when it counted anything."""
    parts = []
    if counters.get("oversize"):
        parts.append(f"{counters['oversize']} frames over its max_bytes dropped by ZeroMQ")
    if counters.get("malformed"):
        parts.append(f"{counters['malformed']} malformed messages")
    return f"; it counted {', '.join(parts)}" if parts else ""


# counters of data an input lost (dropped_latest is a `latest` input's choice, not a loss)
LOSSES = ("dropped_gap", "dropped_overwritten", "torn", "malformed", "oversize", "errors",
          "seq_jumps")
LOSS_WORDS = {"dropped_gap": "lost upstream (sequence gaps: a full queue)",
              "dropped_overwritten": "overwritten in the ring before it was read",
              "torn": "overwritten while its handler read it",
              "malformed": "malformed", "oversize": "over its max_bytes",
              "errors": "raised in its handler", "seq_jumps": "after a sequence leap"}


def losses(stats: dict[str, dict]) -> dict[str, dict[str, int]]:
    """{"actor.input": {counter: n}} of every input that lost data, from stats replies."""
    found = {}
    for actor, result in stats.items():
        inputs = result.get("inputs") if isinstance(result, dict) else None
        for inp, counters in (inputs.items() if isinstance(inputs, dict) else ()):
            lost = {k: int(counters.get(k) or 0) for k in LOSSES
                    if isinstance(counters, dict) and counters.get(k)}
            if lost:
                found[f"{actor}.{inp}"] = lost
    return found


def format_losses(found: dict[str, dict[str, int]]) -> list[str]:
    """One line per input that lost data, naming how."""
    return [f"input {name} lost messages: " + ", ".join(f"{n} {LOSS_WORDS[k]}"
                                                        for k, n in lost.items())
            for name, lost in sorted(found.items())]
