"""The stamp clock: every hop stamp, handler time and telemetry event of a process.

It is ``time.monotonic_ns()``, one clock for all processes of a host. Different hosts'
monotonic clocks share no epoch; ``clocksync.py`` estimates their offsets so the
profiler can compare stamps across hosts.

``SEBVS_CLOCK_SKEW_NS`` (an integer, read once at import) shifts this process's stamps
by that many nanoseconds. It exists to test the offset estimation on one machine: a
supervisor started with it plays a host whose clock runs that far ahead, and the
processes it spawns inherit it. Scheduling (sleeps, deadlines) never reads this clock.
"""
from __future__ import annotations

import os
import time

SKEW_ENV = "SEBVS_CLOCK_SKEW_NS"


def _skew_from_env() -> int:
    text = os.environ.get(SKEW_ENV, "").strip()
    if not text:
        return 0
    try:
        return int(text)
    except ValueError:
        raise ValueError(f"{SKEW_ENV}={text!r}: expected an integer number of "
                         f"nanoseconds") from None


SKEW_NS = _skew_from_env()

if SKEW_NS:
    def now_ns() -> int:
        """This host's stamp clock (monotonic, shifted by the injected skew)."""
        return time.monotonic_ns() + SKEW_NS
else:
    now_ns = time.monotonic_ns     # no wrapper on the hot path when there is no skew
