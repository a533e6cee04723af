#!/usr/bin/env python3
"""A time surface frame against a counts frame (docs/dvs.md, "Time surface").

160 x 160 sensor and output, 200 Hz packets of 1,000 events (uniform positions and
polarities, time-sorted): about 20k events per 0.1 s window. Two accumulators take the
same packets, `counts` (its running counts, the default) and `time_surface` (tau = 0.1 s);
a frame every 20 packets (a 10 Hz control tick). Prints the medians over the frames of
the ms per frame (on the sensor-to-action chain) and per packet added (between ticks).

    .venv/bin/python tools/bench/bench_time_surface.py [--frames 60]
"""
import os

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[var] = "1"

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from sebvs.dvs.accumulator import EventAccumulator, EventGeometry  # noqa: E402
from sebvs.dvs.emulator import EVENT_DTYPE  # noqa: E402

SIDE, PACKET_S, PER_PACKET, PACKETS_PER_FRAME = 160, 0.005, 1000, 20


def packets(rng: np.random.Generator, n: int) -> list[np.ndarray]:
    """``n`` packets of PER_PACKET events each, PACKET_S apart, time-sorted inside."""
    out = []
    for k in range(n):
        ev = np.zeros(PER_PACKET, EVENT_DTYPE)
        ev["x"], ev["y"] = rng.integers(0, SIDE, (2, PER_PACKET))
        start = round((1.0 + k * PACKET_S) * 1e9)
        ev["t"] = np.sort(rng.integers(start, start + round(PACKET_S * 1e9), PER_PACKET))
        ev["p"] = rng.choice(np.array([-1, 1], np.int8), PER_PACKET)
        out.append(ev)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=60)
    args = ap.parse_args()
    stream = packets(np.random.default_rng(0), args.frames * PACKETS_PER_FRAME)
    geometry = EventGeometry((SIDE, SIDE), (SIDE, SIDE))
    for name in ("counts", "time_surface"):
        acc = EventAccumulator(geometry, name, window_s=0.1)
        frame_ms, add_ms = [], []
        for i, p in enumerate(stream):
            start = time.perf_counter()
            acc.add(p)
            add_ms.append((time.perf_counter() - start) * 1e3)
            if i % PACKETS_PER_FRAME == PACKETS_PER_FRAME - 1:
                start = time.perf_counter()
                acc.frame(int(p["t"][-1]))
                frame_ms.append((time.perf_counter() - start) * 1e3)
        # the first window is still filling: leave its frame out
        print(f"{name:13s} frame {np.median(frame_ms[1:]):.3f} ms   "
              f"per packet added {np.median(add_ms):.3f} ms   "
              f"({PER_PACKET * PACKETS_PER_FRAME} events per window, "
              f"{len(frame_ms) - 1} frames)")


if __name__ == "__main__":
    main()
