"""Control deadlines on the realtime clock: what a robot feels as late commands.

The clock (the sim) publishes control tick k at wall time s_k; the action for tick k is
due before tick k + 1 is published. An action that has not arrived by then is a **miss**
(the robot drove the whole next period on an older command); it is still timed if it
arrives later, so the latency figures include the tail. Latency is measured on the
clock's own host and clock: from its publish of the tick to its receipt of the action.
"""
from __future__ import annotations

import collections

import numpy as np

LATENCY_WINDOW = 4096      # latencies kept for the percentiles
LATE_KEPT = 64             # missed ticks still timed if their action comes late


class DeadlineMonitor:
    def __init__(self, period_ns: int) -> None:
        if period_ns <= 0:
            raise ValueError(f"period_ns must be positive, got {period_ns}")
        self.period_ns = int(period_ns)
        self.ticks = 0
        self.misses = 0
        self.answered = 0
        self._open: dict[int, int] = {}                    # tick -> publish ns, in time
        self._late: collections.OrderedDict = collections.OrderedDict()   # missed ones
        self.latency_ns: collections.deque = collections.deque(maxlen=LATENCY_WINDOW)

    def published(self, tick: int, now_ns: int) -> int:
        """Control tick ``tick`` went out at ``now_ns``: the open ticks' deadline passed.
        Returns how many ticks missed it just now."""
        missed = len(self._open)
        for t, sent in self._open.items():
            self._late[t] = sent
        self._open = {tick: now_ns}
        while len(self._late) > LATE_KEPT:
            self._late.popitem(last=False)
        self.misses += missed
        self.ticks += 1
        return missed

    def action(self, tick: int, now_ns: int) -> None:
        """The action for ``tick`` arrived at ``now_ns`` (a repeat, or one for a tick
        never published or long gone, is ignored)."""
        sent = self._open.pop(tick, None)
        if sent is None:
            sent = self._late.pop(tick, None)
        if sent is None:
            return
        self.answered += 1
        self.latency_ns.append(now_ns - sent)

    def close_episode(self) -> None:
        """The episode ended: its last tick has no next tick to be due before."""
        for t, sent in self._open.items():
            self._late[t] = sent        # a late action is still timed, never a miss
        self.ticks -= len(self._open)
        self._open = {}

    def summary(self) -> dict:
        """Counts, and action latency percentiles in ms over the last LATENCY_WINDOW."""
        # the tick still open has not reached its deadline: neither a miss nor a hit yet
        decided = self.ticks - len(self._open)
        out = {"period_ms": self.period_ns / 1e6, "ticks": self.ticks, "misses": self.misses,
               "miss_rate": self.misses / decided if decided else None,
               "answered": self.answered}
        if self.latency_ns:
            lat = np.asarray(self.latency_ns, dtype=np.float64) / 1e6
            out.update(latency_p50_ms=float(np.percentile(lat, 50)),
                       latency_p99_ms=float(np.percentile(lat, 99)),
                       latency_max_ms=float(lat.max()))
        return out
