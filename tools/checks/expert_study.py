#!/usr/bin/env python3
"""The navigation expert's tracking and the detector's accuracy per condition, in process
(scene + render + detector + expert; no actors), on seeded episodes.

Per condition: the paper's success metric (share of frames with the target within 200 px of
the image centre at 640 px, scaled with the width) per episode, its mean and minimum, the
Table 4 centroid error and bbox width, and the detector's error against the scene's
projected truth (centroid px, largest bbox edge px: mean and p90; misses, false alarms).

    tools/checks/expert_study.py [--episodes 10] [--seconds 15] [--size 160] [--control-hz 10]
                          [--conditions nominal,fast,low,flicker,outdoor,blur] [--json FILE]
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from sebvs.experts.rollout import detection_errors, run_nav_episode  # noqa: E402

CONDITIONS = {
    "nominal": {},
    "fast": {"target_speed": "fast"},
    "low": {"lighting": "low"},
    "flicker": {"lighting": "flicker"},
    "outdoor": {"variant": "outdoor"},
}


def study(name: str, cfg: dict, episodes: int, seconds: float, size: int,
          control_hz: float) -> dict:
    t0 = time.perf_counter()
    rates, errs, widths, cerr, berr, miss, false = [], [], [], [], [], 0, 0
    for seed in range(episodes):
        ep = run_nav_episode(seed, episode_s=seconds, control_hz=control_hz,
                             config={**cfg, "width": size, "height": size})
        rates.append(ep.metrics["success"])
        errs.append(ep.metrics["centroid_error_px"])
        widths.append(ep.metrics["bbox_width_px"])
        e = detection_errors(ep.truth, ep.detections)
        cerr.extend(e["centroid"])
        berr.extend(e["bbox"])
        miss += e["misses"]
        false += e["false_alarms"]
    cerr, berr = np.array(cerr), np.array(berr)
    return {"condition": name, "episodes": episodes, "seconds": seconds, "size": size,
            "control_hz": control_hz, "success": rates,
            "success_mean": float(np.mean(rates)), "success_min": float(np.min(rates)),
            "centroid_error_px": float(np.nanmean(errs)), "bbox_width_px": float(np.nanmean(widths)),
            "detector_centroid_px": {"mean": float(cerr.mean()), "p90": float(np.percentile(cerr, 90)),
                                     "n": int(len(cerr))} if len(cerr) else None,
            "detector_bbox_edge_px": {"mean": float(berr.mean()), "p90": float(np.percentile(berr, 90))}
            if len(berr) else None,
            "misses": miss, "false_alarms": false, "wall_s": time.perf_counter() - t0}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=10)
    ap.add_argument("--seconds", type=float, default=15.0)
    ap.add_argument("--size", type=int, default=160)
    ap.add_argument("--control-hz", type=float, default=10.0)
    ap.add_argument("--conditions", default="nominal,fast,low,flicker,outdoor")
    ap.add_argument("--json", type=Path)
    a = ap.parse_args()
    out = []
    for name in a.conditions.split(","):
        if name not in CONDITIONS:
            ap.error(f"unknown condition {name!r} (one of {', '.join(CONDITIONS)})")
        r = study(name, CONDITIONS[name], a.episodes, a.seconds, a.size, a.control_hz)
        out.append(r)
        d, b = r["detector_centroid_px"] or {}, r["detector_bbox_edge_px"] or {}
        print(f"{name:8s} success mean {r['success_mean']:.3f} min {r['success_min']:.3f} | "
              f"centre err {r['centroid_error_px']:.1f} px, bbox w {r['bbox_width_px']:.1f} px | "
              f"detector centroid {d.get('mean', float('nan')):.2f}/{d.get('p90', float('nan')):.2f} px "
              f"(mean/p90), bbox edge {b.get('mean', float('nan')):.2f}/{b.get('p90', float('nan')):.2f}, "
              f"miss {r['misses']}, false {r['false_alarms']} | {r['wall_s']:.1f} s", flush=True)
    if a.json:
        a.json.parent.mkdir(parents=True, exist_ok=True)
        a.json.write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
