#!/usr/bin/env python3
"""The sensor models measured against their fields' standards (docs/sensors.md).

Top-level keys (issue 34's targets):
  dynamic_range_db        the radiance render: red's clip over blue's quantisation noise
                          (EMVA 1288's saturation over dark noise), every patch between
                          decoded within `radiance.max_error_lsb` of the truth   (>= 100)
  ptc_gain_error          EMVA photon transfer on simulated flat fields: conversion gain
  ptc_read_noise_error    and read noise recovered, relative error, worst of 0 and 12 dB
                                                                                 (<= 0.05)
  blur_length_error       a bar at v px/s through the whole rig (poses between states,
                          sub-frames every 0.5 ms, integration) smears v * T px  (<= 0.10)
                          (and _camera_defaults: the camera actor's 4 ms, at most 8)
  hdr_target_lost_fraction   HDR nav cells, worst of indoor and outdoor: the share of the
                          target's pixels the auto-exposed frame lost (top code or
                          SNR < 1)                                               (>= 0.30)
  hdr_event_edge_coverage    the same cells: the share of the target's edge pixels the
                          event sensor fired on per 0.1 s, worst cell            (>= 0.80)
cells: per nav cell (nominal, hdr, dusk, dusk_fast; indoor and outdoor; without --quick
  also mains flicker at 100 and 120 Hz indoors, sampled at 1 kHz, one seed), arm cell
  (nominal, moving, hdr, dusk_moving, fast_hdr; the wrist camera at home) and seed:
  detector_hit_rate (the colour detector on the modelled frames), event_edge_coverage
  (and event_edge_coverage_ideal: the ideal pixel on the same light, what the scene's
  motion allows), target_lost_fraction, the privileged expert's paper rate, exposure and gain.
  `cell_means` averages seeds. Targets: detector >= 0.95 in nominal cells and < 0.70 in
  hdr and dusk_fast; expert >= 0.95 everywhere.
Also: snr (the preset's SNR against illuminance, lux at SNR 1 at 10 and 33 ms), step (a
10^4 : 1 step: lost frame pixels and event edge coverage per side), radiance details.
event_noise: the event sensor's noise on a still uniform field of linear light, events per
  pixel per second, per emulator preset, preset version (the current one, and 1, which the
  shipped topologies pin) and light level (0.01, 1, 100 cd/m^2), measured on the emulator
  (sebvs/dvs/noise.py: 128 x 128, 5 s at 100 frames a second, seed 0) beside the rate the
  model states (docs/dvs.md, "Noise and preset versions"); event_noise_worst_ratio is the
  measured over the stated rate furthest from 1 (tests/test_dvs_noise.py: within 10 %).
frame_light (issue 64): the frame camera on the event sensor's light samples (camera
  frame_light "shared", the default) against its own sub-frames. blur_length_error_shared:
  the blur bar through the shared path with light at 200 Hz (<= 0.10, as the sub-frames'
  figure); frame_light_agreement: nav episodes turning at full rate, every tick, the
  noise-free frames' mean |difference| in DN (shared - subframes) against two noisy
  cameras' (the frame's own noise), and the light renders each path made
  (frame_light_ratio_max: the largest light/noise ratio of the cells, < 1 the target).

    tools/bench/bench_sensors.py [--quick] [--json FILE] [--plot FILE.png] [--seeds N]
    tools/bench/bench_sensors.py --noise-only [--json FILE]
    tools/bench/bench_sensors.py --light-only [--quick] [--json FILE]
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from sebvs.dvs import noise  # noqa: E402
from sebvs.sensors import validate  # noqa: E402  (sets MUJOCO_GL before mujoco)
from sebvs.sensors.framecam import preset  # noqa: E402

NAV_CELLS = {"nominal": {"lighting": "nominal"}, "hdr": {"lighting": "hdr"},
             "dusk": {"lighting": "dusk"},
             "dusk_fast": {"lighting": "dusk", "target_speed": "fast"}}
# mains flicker (indoor: daylight does not flicker) needs 1 kHz samples: costly, one seed
FLICKER_CELLS = {"flicker_100": {"lighting": "flicker", "flicker_hz": 100.0},
                 "flicker_120": {"lighting": "flicker", "flicker_hz": 120.0}}
# the arm's wrist camera at home over the belt (docs/sim.md: the physical conditions)
ARM_CELLS = {"nominal": {"lighting": "nominal"},
             "moving": {"lighting": "nominal", "conveyor": "moving", "belt_speed": 0.08},
             "hdr": {"lighting": "hdr"},
             "dusk_moving": {"lighting": "dusk", "conveyor": "moving", "belt_speed": 0.08},
             "fast_hdr": {"lighting": "hdr", "conveyor": "moving", "belt_speed": 0.25}}


def run_cells(variants, seeds, episode_s: float, progress, flicker: bool) -> list[dict]:
    jobs = [("nav", v, name, {**config, "variant": v}, seeds, {}) for v in variants
            for name, config in NAV_CELLS.items()]
    if flicker:
        jobs += [("nav", "indoor", name, config, seeds[:1], {"dvs_hz": 1000.0})
                 for name, config in FLICKER_CELLS.items()]
    jobs += [("arm", "arm", name, config, seeds, {}) for name, config in ARM_CELLS.items()]
    rows = []
    for task, variant, name, config, cell_seeds, kw in jobs:
        for seed in cell_seeds:
            t0 = time.perf_counter()
            r = validate.sensor_cell(task, config, seed=seed, episode_s=episode_s, **kw)
            r.update(cell=name, variant=variant, seconds=round(time.perf_counter() - t0, 1))
            rows.append(r)
            progress(f"cell {variant:7s} {name:11s} seed {seed}: detector "
                     f"{r['detector_hit_rate']:.2f}, events {r['event_edge_coverage']:.2f} "
                     f"(ideal pixel {r['event_edge_coverage_ideal']:.2f}, noise alone "
                     f"{r['event_background_coverage']:.2f}), "
                     f"lost {r['target_lost_fraction']:.2f}, expert "
                     f"{r['expert_reference']:.2f}, exposure "
                     f"{r['exposure_s_median'] * 1e3:.2f} ms at {r['gain_db_median']:.1f} dB")
    return rows


def cell_means(rows: list[dict]) -> list[dict]:
    keys = ("detector_hit_rate", "event_edge_coverage", "event_edge_coverage_ideal",
            "event_background_coverage",
            "target_lost_fraction", "expert_reference")
    groups: dict = {}
    for r in rows:
        groups.setdefault((r["variant"], r["cell"]), []).append(r)
    # a seed whose episode never showed the target long enough has no scores (NaN)
    out = []
    for (v, c), g in groups.items():
        scored = [x for x in g if x["scored_ticks"] > 0]
        out.append({"variant": v, "cell": c, "seeds": len(scored),
                    **{k: round(statistics.fmean(x[k] for x in scored), 4) if scored
                       else float("nan") for k in keys}})
    return out


def plot(out: dict, path: str) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(1, 3, figsize=(15, 4.2))
    for curve in out["snr"]["curves"]:
        ax[0].loglog(curve["lux"], [max(s, 1e-3) for s in curve["snr"]],
                     label=f"{curve['exposure_s'] * 1e3:.3g} ms, lux at SNR 1: "
                           f"{curve['lux_at_snr1']:.2g}")
    ax[0].axhline(1, color="grey", lw=0.8)
    ax[0].set(xlabel="scene illuminance (lux), albedo 0.5", ylabel="SNR (0 dB gain)",
              title="frame camera preset: SNR", ylim=(1e-2, 300))
    ax[0].legend(fontsize=8)
    p = out["radiance"]["patches"]
    ax[1].loglog(p["truth_cd_m2"], p["measured_cd_m2"], ".", ms=4)
    ax[1].loglog(p["truth_cd_m2"], p["truth_cd_m2"], color="grey", lw=0.8)
    ax[1].axvline(out["radiance"]["floor_cd_m2"], color="red", lw=0.8, ls=":")
    ax[1].axvline(out["radiance"]["top_cd_m2"], color="red", lw=0.8, ls=":")
    ax[1].set(xlabel="true luminance (cd/m^2)", ylabel="decoded (cd/m^2)",
              title=f"radiance render, one image: {out['dynamic_range_db']:.0f} dB")
    means = out["cell_means"]
    labels = [f"{m['variant'][:3]} {m['cell']}" for m in means]
    ax[2].tick_params(axis="x", labelsize=7)
    x = range(len(means))
    ax[2].bar([i - 0.27 for i in x], [m["detector_hit_rate"] for m in means], 0.27,
              label="detector on modelled frames")
    ax[2].bar(list(x), [m["event_edge_coverage"] for m in means], 0.27,
              label="event edge coverage / 0.1 s, beyond noise")
    ax[2].bar([i + 0.27 for i in x], [m["event_edge_coverage_ideal"] for m in means], 0.27,
              label="... of the ideal pixel (the motion's limit)")
    ax[2].set_xticks(list(x), labels, rotation=45, ha="right", fontsize=8)
    ax[2].set(ylim=(0, 1.45), yticks=[0, 0.2, 0.4, 0.6, 0.8, 1.0],
              title="nav cells, at the sensor (3 seeds)")
    ax[2].legend(fontsize=8)
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)


def measure_event_noise(progress) -> dict:
    """The event sensor's static-scene noise per preset, version and light level, measured
    beside the stated rate (sebvs/dvs/noise.py); one progress line per noisy cell.

    Parameters:
        progress: takes one line of text.
    Returns:
        {"rows": noise.noise_table()'s rows, "worst_ratio": the measured over the stated
        rate furthest from 1, "config": how it was measured}.
    """
    rows = noise.noise_table()
    for r in rows:
        if r["stated_hz"]:
            progress(f"event noise {r['preset']:8s} version {r['preset_version']} at "
                     f"{r['luminance_cd_m2']:g} cd/m^2: {r['measured_hz']:.4g} events/px/s "
                     f"(stated {r['stated_hz']:.4g}, ratio {r['ratio']:.3f})")
    silent = [r["measured_hz"] for r in rows if not r["stated_hz"]]
    progress(f"event noise where none is stated (paper, clean): at most {max(silent)} "
             "events/px/s")
    ratios = [r["ratio"] for r in rows if r["ratio"] is not None]
    return {"rows": rows, "worst_ratio": max(ratios, key=lambda q: abs(q - 1)),
            "config": {"side": noise.SIDE, "seconds": noise.SECONDS, "fps": noise.FPS,
                       "seed": 0, "levels_cd_m2": list(noise.LEVELS_CD_M2)}}


def measure_frame_light(progress, quick: bool) -> dict:
    """The shared light stream's figures (module docstring, frame_light)."""
    blur = validate.blur_length(light_hz=200.0)
    progress(f"blur, shared light at 200 Hz: {blur['smear_px']:.2f} px against "
             f"{blur['expected_px']:.1f}")
    cells = [{}, {"lighting": "dusk", "target_speed": "fast"}]
    rows = []
    for config in cells[:1] if quick else cells:
        for hz in (200.0,) if quick else (200.0, 100.0):
            r = validate.frame_light_agreement("nav", config, seconds=3.0, dvs_hz=hz)
            progress(f"frame light {config or 'nominal'} at {hz:g} Hz: shared - subframes "
                     f"{r['light_dn_median']:.2f} DN against the noise's "
                     f"{r['noise_dn_median']:.2f} DN; light renders "
                     f"{r['renders']['shared']['light']} against "
                     f"{r['renders']['subframes']['light']} + "
                     f"{2 * r['renders']['subframes']['subframes']} (sub-frames x2)")
            rows.append(r)
    return {"blur_length_error_shared": round(blur["blur_length_error"], 4),
            "frame_light_ratio_max": round(max(r["ratio_median"] for r in rows), 4),
            "blur_shared": blur, "frame_light_agreement": rows}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--quick", action="store_true",
                    help="indoor nav and arm cells, one seed, 4 s episodes (under two minutes)")
    ap.add_argument("--seeds", type=int, default=0, help="seeds per cell (default 1 quick, 3)")
    ap.add_argument("--json", metavar="FILE", help="write the results here")
    ap.add_argument("--plot", metavar="FILE", help="SNR curve, radiance decode, cells (PNG)")
    ap.add_argument("--noise-only", action="store_true",
                    help="only the event sensor's noise (event_noise; a few seconds)")
    ap.add_argument("--light-only", action="store_true",
                    help="only the shared light stream's figures (frame_light; minutes)")
    args = ap.parse_args()
    seeds = list(range(args.seeds or (1 if args.quick else 3)))
    variants = ("indoor",) if args.quick else ("indoor", "outdoor")
    episode_s = 4.0 if args.quick else 8.0

    def progress(line: str) -> None:
        print(line, file=sys.stderr, flush=True)

    t0 = time.perf_counter()
    if args.noise_only:
        event_noise = measure_event_noise(progress)
        out = {"event_noise_worst_ratio": event_noise["worst_ratio"],
               "event_noise": event_noise}
        print(json.dumps(out, indent=1))
        if args.json:
            Path(args.json).parent.mkdir(parents=True, exist_ok=True)
            Path(args.json).write_text(json.dumps(out, indent=1))
        return 0
    if args.light_only:
        out = measure_frame_light(progress, args.quick)
        print(json.dumps({k: v for k, v in out.items() if k != "frame_light_agreement"},
                         indent=1))
        if args.json:
            Path(args.json).parent.mkdir(parents=True, exist_ok=True)
            Path(args.json).write_text(json.dumps(out, indent=1))
        return 0
    camera = preset("mv_global_shutter")
    radiance = validate.radiance_range()
    progress(f"radiance: {radiance['dynamic_range_db']:.1f} dB, max error "
             f"{radiance['max_error_lsb']:.2f} LSB, 5 % range {radiance['range_5pct_db']:.1f} dB")
    ptc = [validate.photon_transfer_errors(camera, g) for g in (0.0, 12.0)]
    progress("ptc: " + ", ".join(f"{p['gain_db']:g} dB: K {p['gain_error']:.4f}, read "
                                 f"{p['read_noise_error']:.4f}" for p in ptc))
    blur = validate.blur_length()
    # the camera actor's defaults: one sub-frame per 4 ms, at most 8
    blur_default = validate.blur_length(subframe_s=0.004, max_subframes=8)
    progress(f"blur: {blur['smear_px']:.2f} px against {blur['expected_px']:.1f} "
             f"({blur_default['smear_px']:.2f} px at the camera's sub-frame defaults)")
    snr = {"curves": [validate.snr_curve(camera, t) for t in (0.01, 1 / 30)]}
    step = validate.step_range()
    progress(f"step 1e4:1: {json.dumps({k: step[k] for k in ('dim', 'bright')})}")
    event_noise = measure_event_noise(progress)
    frame_light = measure_frame_light(progress, args.quick)
    rows = run_cells(variants, seeds, episode_s, progress, flicker=not args.quick)
    means = cell_means(rows)
    hdr = [m for m in means if m["cell"] == "hdr" and m["variant"] != "arm"]
    out = {
        "dynamic_range_db": round(radiance["dynamic_range_db"], 2),
        "ptc_gain_error": round(max(p["gain_error"] for p in ptc), 5),
        "ptc_read_noise_error": round(max(p["read_noise_error"] for p in ptc), 5),
        "blur_length_error": round(blur["blur_length_error"], 4),
        "blur_length_error_camera_defaults": round(blur_default["blur_length_error"], 4),
        "hdr_target_lost_fraction": min(m["target_lost_fraction"] for m in hdr),
        "hdr_event_edge_coverage": min(m["event_edge_coverage"] for m in hdr),
        "event_noise_worst_ratio": event_noise["worst_ratio"],
        **frame_light,
        "detector_hit_rate": {f"{m['variant']}/{m['cell']}": m["detector_hit_rate"]
                              for m in means},
        "event_edge_coverage": {f"{m['variant']}/{m['cell']}": m["event_edge_coverage"]
                                for m in means},
        "cell_means": means, "cells": rows, "radiance": radiance, "ptc": ptc, "blur": blur,
        "blur_camera_defaults": blur_default,
        "snr": snr, "step": step,
        "event_noise": event_noise,
        "config": {"quick": args.quick, "seeds": seeds, "episode_s": episode_s,
                   "variants": list(variants), "frame_camera": "mv_global_shutter",
                   "event_preset": "physical", "event_preset_version": 1,
                   "control_hz": 10.0,
                   "frame_rate_hz": "the control rate",
                   "seconds": round(time.perf_counter() - t0, 1)}}
    summary = {k: out[k] for k in ("dynamic_range_db", "ptc_gain_error", "ptc_read_noise_error",
                                   "blur_length_error", "blur_length_error_camera_defaults",
                                   "hdr_target_lost_fraction",
                                   "hdr_event_edge_coverage", "event_noise_worst_ratio",
                                   "blur_length_error_shared", "frame_light_ratio_max",
                                   "detector_hit_rate",
                                   "event_edge_coverage")}
    print(json.dumps(summary, indent=1))
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(out, indent=1))
    if args.plot:
        plot(out, args.plot)
    return 0


if __name__ == "__main__":
    sys.exit(main())
