#!/usr/bin/env python3
"""Event emulator speed: ms per frame at 160, 320 and 640 px, presets paper and noisy;
and the accumulator's counts frame at a control tick, kept running against recounted.

Content: a textured pattern drifting sideways with a bright square moving across it,
100 frames at 1 kHz (quick: 30). The size is the emulated size (downsample 1). One thread:
the emulator is meant to run beside the other actors on a 2-core machine.

accumulator: the same content's events at 200 Hz into two counts accumulators side by
side, one keeping running counts (the default) and one recounting the 0.1 s window at
every frame (`incremental=False`, the code before), a frame every 20 packets (a 10 Hz
control tick): ms per frame (on the sensor-to-action chain) and ms per packet added (off
it, between ticks), medians over the frames; the frames are checked to be equal.

flicker: the same content in linear light (the physical preset, step_luminance), an office
at up to 100 cd/m^2, with all of it modulated by 100 Hz mains flicker (30-100 %), sampled at
1 kHz, as the study's
flicker cells run it: every pixel crosses several thresholds per sample, so the refractory
filter and the time sort carry the load. Beside it, on that row's events, the packed-key
orders against numpy's lexsort and stable argsort they replace (checked equal).

    tools/bench/bench_emulator.py [--quick] --json out/bench_emulator.json
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

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from sebvs.dvs.accumulator import EventAccumulator, EventGeometry  # noqa: E402
from sebvs.dvs.emulator import EventEmulator, pixel_time_order, time_order  # noqa: E402
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


def bench_flicker(size: int, n: int, mains_hz: float = 100.0) -> dict:
    emu = EventEmulator(preset("physical", downsample=1.0))
    cd_per_dn = 100.0 / 255.0                  # white paper under office light
    times, counts, raw = [], [], []
    refractory = emu._refractory

    def keep_input(events):                  # the events before the filter, for the orders
        raw.append(events.copy())
        return refractory(events)
    emu._refractory = keep_input
    for i, f in enumerate(frames(size, n)):
        t_ns = i * 1_000_000
        light = 0.65 + 0.35 * np.cos(2 * np.pi * mains_hz * t_ns * 1e-9)
        luminance = f.astype(np.float32) * np.float32(cd_per_dn * light)
        t = time.perf_counter()
        ev = emu.step_luminance(luminance, t_ns)
        times.append(time.perf_counter() - t)
        counts.append(ev.size)
    orders = {"time_order": [], "argsort_stable": [], "pixel_time_order": [], "lexsort": []}
    for ev in raw:
        pix = ev["y"].astype(np.int64) * size + ev["x"]
        for name, fn in (("time_order", lambda: time_order(ev["t"])),
                         ("argsort_stable", lambda: np.argsort(ev["t"], kind="stable")),
                         ("pixel_time_order", lambda: pixel_time_order(pix, ev["t"])),
                         ("lexsort", lambda: np.lexsort((ev["t"], pix)))):
            t = time.perf_counter()
            out = fn()
            orders[name].append(time.perf_counter() - t)
            if name == "argsort_stable" and not np.array_equal(out, time_order(ev["t"])):
                raise AssertionError("time_order differs from the stable argsort")
            if name == "lexsort" and not np.array_equal(out, pixel_time_order(pix, ev["t"])):
                raise AssertionError("pixel_time_order differs from lexsort")

    def ms(xs):
        return round(float(np.median(xs)) * 1e3, 3)
    return {"size": size, "preset": "physical", "mains_hz": mains_hz, "sample_hz": 1000,
            "frames": n, "ms_per_frame_p50": ms(times[1:]),
            "ms_per_frame_p90": round(float(np.percentile(times[1:], 90)) * 1e3, 3),
            "events_per_frame": int(np.mean(counts[1:])),
            "events_before_refractory": int(np.mean([e.size for e in raw])),
            "orders_ms_p50": {k: ms(v) for k, v in orders.items()},
            "time_sort_speedup": round(ms(orders["argsort_stable"]) / ms(orders["time_order"]), 1),
            "pixel_sort_speedup": round(ms(orders["lexsort"]) / ms(orders["pixel_time_order"]), 1)}


def bench_accumulator(size: int, name: str, ticks: int) -> dict:
    emu = EventEmulator(preset(name, downsample=1.0))
    geometry = EventGeometry((size, size), (size, size))
    accs = {"running": EventAccumulator(geometry, "counts", window_s=0.1),
            "recount": EventAccumulator(geometry, "counts", window_s=0.1, incremental=False)}
    frame_s = {k: [] for k in accs}
    add_s = {k: [] for k in accs}
    window_events = []
    per_tick = 20                                    # 200 Hz packets, 10 Hz frames
    for i, f in enumerate(frames(size, ticks * per_tick)):
        t_ns = i * 5_000_000
        ev = emu.step(f, t_ns)
        for k, acc in accs.items():
            t = time.perf_counter()
            acc.add(ev)
            add_s[k].append(time.perf_counter() - t)
        if i % per_tick == per_tick - 1:
            out = {}
            for k, acc in accs.items():
                t = time.perf_counter()
                out[k] = acc.frame(t_ns)
                frame_s[k].append(time.perf_counter() - t)
            if not np.array_equal(out["running"], out["recount"]):
                raise AssertionError(f"running and recounted frames differ at packet {i}")
            window_events.append(int(out["recount"].astype(np.int64).sum()))

    def ms(xs):
        return round(float(np.median(xs[1:])) * 1e3, 4)
    row = {"size": size, "preset": name, "frames": ticks,
           "events_per_window": int(np.median(window_events))}
    for k in accs:
        row[f"{k}_frame_ms_p50"] = ms(frame_s[k])
        row[f"{k}_add_ms_p50"] = ms(add_s[k])
    row["frame_speedup"] = round(row["recount_frame_ms_p50"] / row["running_frame_ms_p50"], 1)
    return row


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--json", metavar="FILE")
    args = ap.parse_args()
    n = 30 if args.quick else 100
    results = [bench(size, name, n) for name in ("paper", "noisy") for size in (160, 320, 640)]
    p640 = next(r for r in results if r["size"] == 640 and r["preset"] == "paper")
    accumulator = [bench_accumulator(size, name, 10 if args.quick else 30)
                   for name in ("paper", "noisy") for size in (160, 320)]
    flicker = [bench_flicker(160, n)]
    report = {"results": results, "accumulator": accumulator, "flicker": flicker, "threads": 1,
              "target": {"paper_640_ms_le_4": p640["ms_per_frame_p50"] <= 4.0},
              "reference": "v2e EventEmulator, DESIGN.md: 18-36 ms per 640x640 frame"}
    print_report(report, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
