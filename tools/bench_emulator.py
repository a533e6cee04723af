#!/usr/bin/env python3
"""Event emulator speed: ms per frame at 160, 320 and 640 px, presets paper and noisy.

Content: a textured pattern drifting sideways with a bright square moving across it,
100 frames at 1 kHz (quick: 30). The size is the emulated size (downsample 1). One thread:
the emulator is meant to run beside the other actors on a 2-core machine.

    tools/bench_emulator.py [--quick] --json out/bench_emulator.json
"""
import os

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[var] = "1"

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from sebvs.dvs.emulator import EventEmulator  # noqa: E402
from sebvs.dvs.params import preset  # noqa: E402
from tools.benchio import print_report  # noqa: E402

cv2.setNumThreads(1)


def frames(size: int, n: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    tex = cv2.GaussianBlur((rng.random((size, 3 * size)) * 255).astype(np.uint8), (0, 0), 2.0)
    side = size // 6
    for i in range(n):
        f = np.ascontiguousarray(tex[:, i * 2 % (2 * size):][:, :size])
        x = int((i / n) * (size - side))
        f[size // 3:size // 3 + side, x:x + side] = 250
        yield f


def bench(size: int, name: str, n: int) -> dict:
    emu = EventEmulator(preset(name, downsample=1.0))
    times, counts = [], []
    for i, f in enumerate(frames(size, n)):
        t = time.perf_counter()
        ev = emu.step(f, i * 1_000_000)
        times.append(time.perf_counter() - t)
        counts.append(ev.size)
    return {"size": size, "preset": name,
            "ms_per_frame_p50": round(float(np.median(times[1:])) * 1e3, 3),
            "ms_per_frame_p90": round(float(np.percentile(times[1:], 90)) * 1e3, 3),
            "events_per_frame": int(np.mean(counts[1:])), "frames": n}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--json", metavar="FILE")
    args = ap.parse_args()
    n = 30 if args.quick else 100
    results = [bench(size, name, n) for name in ("paper", "noisy") for size in (160, 320, 640)]
    p640 = next(r for r in results if r["size"] == 640 and r["preset"] == "paper")
    report = {"results": results, "threads": 1,
              "target": {"paper_640_ms_le_4": p640["ms_per_frame_p50"] <= 4.0},
              "reference": "v2e EventEmulator, DESIGN.md: 18-36 ms per 640x640 frame"}
    print_report(report, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
