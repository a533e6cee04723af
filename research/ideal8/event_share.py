"""Where a nav dataset's events come from: the target, or everything else?

An event camera on a moving robot sees edges everywhere: the floor's checker, the walls,
the horizon. A policy that steers by events alone has to find the cube's share among them.
For every labelled frame with the target visible, this counts the events inside the
target's true bounding box (from the episode's truth, grown by `--margin` px) against all
the frame's events, and the box's share of the image. The ratio of the two shares is the
target's event density over the image's: 1 means the target stands out no more than a
random patch of the same size; the event input carries the target only where it is well
above 1.

It also measures why a target makes few events: its edge contrast in the RGB frame, in the
emulator's lin-log units (sebvs.dvs.emulator.linlog of the frame's 601 luma, which is what
the camera hands the emulator): the mean inside the box (less a 1 px rim) against the mean
of a 2 px band beyond each side edge, 1 px out, the larger of the two sides (a target
crossing the image horizontally fires on its side edges). A pixel fires only when its
level moves by the threshold (the episode's emulator pos_thres / neg_thres), so an edge
of lower contrast makes no events however fast it moves. (The emulator sees sharp luma;
in motion-blurred episodes the recorded RGB frame is smeared and understates it.) An
episode recorded through the physical camera (its topology's camera.sensor "physical")
fed the emulator the scene's linear luminance, which a dataset does not keep, not its
frame's luma: its contrast is not measured, and the contrast columns show "-" for it.

    python research/ideal8/event_share.py datasets/nav_rand [--json out.json]
                                          [--by variant,lighting] [--figure shares.png]

Printed: one row per group of episodes (by the scene settings named in --by, from each
file's `conditions`), medians over frames: events per frame, the target's share of the
events, its share of the pixels, and the density ratio; frames where the target holds no
event at all.
"""
from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from sebvs.data.episode import open_episode  # noqa: E402
from sebvs.dvs.emulator import linlog  # noqa: E402
from sebvs.data.stats import episode_files  # noqa: E402


def frame_shares(event_frame: np.ndarray, bbox: np.ndarray, image: np.ndarray,
                 margin: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per frame: (events, target's share of them, box's share of the pixels).

    event_frame [T, 2, H, W] counts; bbox [T, 4] (u0, v0, u1, v1) px in the truth's image
    of size image [T, 2] (w, h), which may differ from the event frame's H x W.
    """
    t, _, h, w = event_frame.shape
    total = event_frame.reshape(t, -1).sum(axis=1, dtype=np.int64)
    inside = np.zeros(t, np.int64)
    area = np.zeros(t)
    for k in range(t):
        sx, sy = w / image[k, 0], h / image[k, 1]
        u0 = int(np.clip(np.floor(bbox[k, 0] * sx - margin), 0, w))
        u1 = int(np.clip(np.ceil(bbox[k, 2] * sx + margin), 0, w))
        v0 = int(np.clip(np.floor(bbox[k, 1] * sy - margin), 0, h))
        v1 = int(np.clip(np.ceil(bbox[k, 3] * sy + margin), 0, h))
        inside[k] = event_frame[k, :, v0:v1, u0:u1].sum(dtype=np.int64)
        area[k] = (u1 - u0) * (v1 - v0) / (w * h)
    share = np.where(total > 0, inside / np.maximum(total, 1), np.nan)
    return total, share, area


def edge_contrast(rgb: np.ndarray, bbox: np.ndarray, image: np.ndarray) -> float:
    """The target's side-edge contrast in lin-log units (module docstring), or NaN where
    the box is narrower than 4 px or its side bands leave the frame.

    rgb [H, W, 3] uint8; bbox (u0, v0, u1, v1) px in the truth's image of size (w, h).
    """
    h, w = rgb.shape[:2]
    sx, sy = w / image[0], h / image[1]
    u0, u1 = int(round(bbox[0] * sx)), int(round(bbox[2] * sx))
    v0, v1 = int(round(bbox[1] * sy)), int(round(bbox[3] * sy))
    if u1 - u0 < 4 or v1 - v0 < 3 or u0 < 3 or u1 > w - 3 or v0 < 0 or v1 > h:
        return float("nan")
    level = linlog(cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY))
    rows = slice(v0 + 1, v1 - 1)
    inside = float(level[rows, u0 + 1:u1 - 1].mean())
    left = float(level[rows, u0 - 3:u0 - 1].mean())
    right = float(level[rows, u1 + 1:u1 + 3].mean())
    return max(abs(inside - left), abs(inside - right))


def _camera_sensor(attrs) -> str:
    """The camera sensor an episode was recorded through: its resolved topology's camera
    actor (the one that runs actors.camera, whatever its name; else the one named
    "camera"), and the camera's default, "ideal8", where the topology does not say."""
    topology = attrs.get("topology") or {}
    actors = (topology.get("content") or {}).get("actors", {})
    cameras = [a for a in actors.values()
               if isinstance(a, dict) and str(a.get("run", "")).startswith("actors.camera:")]
    camera = cameras[0] if cameras else actors.get("camera", {})
    return camera.get("sensor", "ideal8") if isinstance(camera, dict) else "ideal8"


def collect(root: Path, by: list[str], margin: float) -> dict[str, dict[str, list]]:
    groups: dict[str, dict[str, list]] = defaultdict(lambda: defaultdict(list))
    for name in episode_files(root):
        with open_episode(root / name) as ep:
            if ep.event_frame is None or "bbox" not in ep.truth:
                raise SystemExit(f"{root / name}: no event frames or no target bbox in its "
                                 f"truth (a nav dataset is needed)")
            cond = ep.attrs.get("conditions") or {}
            key = ", ".join(f"{k}={cond.get(k, '?')}" for k in by) or "all"
            vis = np.asarray(ep.truth["visible"][:]) > 0
            bbox = np.asarray(ep.truth["bbox"][:])
            ok = vis & np.isfinite(bbox).all(axis=1)
            if not ok.any():
                continue
            idx = np.flatnonzero(ok)
            image = np.asarray(ep.truth["image"][:])
            total, share, area = frame_shares(np.asarray(ep.event_frame[:])[idx], bbox[idx],
                                              image[idx], margin)
            emulator = (ep.attrs.get("emulator") or {}).get("resolved", {})
            thresholds = [float(emulator.get(k, "nan")) for k in ("pos_thres", "neg_thres")]
            g = groups[key]
            if _camera_sensor(ep.attrs) == "physical":   # not what its emulator saw
                g["contrast"] += [float("nan")] * idx.size
            else:
                g["contrast"] += [edge_contrast(np.asarray(ep.rgb[k]), bbox[k], image[k])
                                  for k in idx]
            g["threshold"].append(min(thresholds))
            g["events"] += total.tolist()
            g["share"] += share.tolist()
            g["area"] += area.tolist()
            g["episodes"].append(name)
    return groups


def example_frames(root: Path, by: list[str], margin: float) -> list[tuple[str, np.ndarray,
                                                                            np.ndarray, np.ndarray]]:
    """One frame per group (the middle labelled frame of its first episode with the target
    in view): (group, rgb [H, W, 3], event frame [2, h, w], box in event px)."""
    out, seen = [], set()
    for name in episode_files(root):
        with open_episode(root / name) as ep:
            cond = ep.attrs.get("conditions") or {}
            key = ", ".join(f"{k}={cond.get(k, '?')}" for k in by) or "all"
            if key in seen or ep.event_frame is None:
                continue
            vis = np.flatnonzero(np.asarray(ep.truth["visible"][:]) > 0)
            if not len(vis):
                continue
            k = int(vis[len(vis) // 2])
            ev = np.asarray(ep.event_frame[k])
            sx = ev.shape[2] / ep.truth["image"][k][0]
            sy = ev.shape[1] / ep.truth["image"][k][1]
            b = np.asarray(ep.truth["bbox"][k]) * [sx, sy, sx, sy] + [-margin, -margin,
                                                                      margin, margin]
            out.append((key, np.asarray(ep.rgb[k]), ev, b))
            seen.add(key)
    return sorted(out, key=lambda x: x[0])


def plot_examples(examples, rows: list[dict], path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Rectangle

    by_group = {r["group"]: r for r in rows}
    fig, axes = plt.subplots(2, len(examples), figsize=(2.6 * len(examples), 5.6),
                             squeeze=False)
    for j, (key, rgb, ev, box) in enumerate(examples):
        axes[0, j].imshow(rgb)
        on, off = ev[0].astype(float), ev[1].astype(float)
        img = np.stack([np.minimum(off / 4, 1), np.zeros_like(on), np.minimum(on / 4, 1)], -1)
        axes[1, j].imshow(1 - 0.8 * img.max(axis=-1, keepdims=True) + 0.8 * img)
        for ax, scale in ((axes[0, j], rgb.shape[1] / ev.shape[2]), (axes[1, j], 1.0)):
            u0, v0, u1, v1 = box * scale
            ax.add_patch(Rectangle((u0, v0), u1 - u0, v1 - v0, fill=False, ec="lime", lw=1.2))
            ax.set_xticks([])
            ax.set_yticks([])
        r = by_group.get(key, {})
        share = r.get("target_event_share_p50")
        axes[0, j].set_title(key.replace(", ", "\n"), fontsize=8)
        axes[1, j].set_xlabel(f"{int(ev.sum())} events here; median\ntarget share "
                              f"{'-' if share is None else f'{100 * share:.1f} %'}", fontsize=8)
    fig.suptitle("RGB (top) and the event frame the policy sees (bottom; ON blue, OFF red); "
                 "green: the target's true box", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def summarise(groups: dict) -> list[dict]:
    rows = []
    for key in sorted(groups):
        g = groups[key]
        share, area = np.asarray(g["share"], float), np.asarray(g["area"], float)
        ratio = share / np.maximum(area, 1e-9)
        has = np.isfinite(share)
        contrast = np.asarray(g["contrast"], float)
        measured = np.isfinite(contrast)
        threshold = float(np.nanmin(g["threshold"])) if np.isfinite(g["threshold"]).any() \
            else None
        rows.append({"group": key, "episodes": len(g["episodes"]), "frames": len(share),
                     "events_per_frame_p50": float(np.median(g["events"])),
                     "target_event_share_p50": float(np.nanmedian(share)) if has.any() else None,
                     "target_area_share_p50": float(np.median(area)),
                     "density_ratio_p50": float(np.nanmedian(ratio)) if has.any() else None,
                     "frames_without_target_events": float(np.mean(share[has] == 0))
                     if has.any() else None,
                     "edge_contrast_p50": float(np.median(contrast[measured]))
                     if measured.any() else None,
                     "emulator_threshold": threshold,
                     "frames_under_threshold": float(np.mean(contrast[measured] < threshold))
                     if measured.any() and threshold is not None else None})
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("dataset", type=Path, help="a nav dataset directory (index.json + episodes)")
    ap.add_argument("--by", default="variant,lighting",
                    help="comma-separated scene settings to group by (default variant,lighting; "
                         "'' for one group)")
    ap.add_argument("--margin", type=float, default=2.0,
                    help="px the target's box grows by on every side (event frames are "
                         "accumulated over a window the target moves in)")
    ap.add_argument("--json", type=Path, help="also write the rows as JSON here")
    ap.add_argument("--figure", type=Path,
                    help="also draw one example frame per group (RGB and events, the "
                         "target's box) to this PNG")
    args = ap.parse_args(argv)
    if not args.dataset.is_dir():
        ap.error(f"{args.dataset}: not a directory")
    by = [k for k in args.by.split(",") if k]
    rows = summarise(collect(args.dataset, by, args.margin))
    print(f"{'group':<38} {'eps':>4} {'frames':>7} {'events/frame':>12} "
          f"{'target share':>12} {'box area':>9} {'density x':>9} {'no target ev':>12} "
          f"{'contrast':>8} {'< thres':>7}")
    for r in rows:
        f = lambda x, fmt: "-" if x is None else format(x, fmt)   # noqa: E731
        print(f"{r['group']:<38} {r['episodes']:>4} {r['frames']:>7} "
              f"{r['events_per_frame_p50']:>12.0f} {f(r['target_event_share_p50'], '.3f'):>12} "
              f"{r['target_area_share_p50']:>9.3f} {f(r['density_ratio_p50'], '.1f'):>9} "
              f"{f(r['frames_without_target_events'], '.2f'):>12} "
              f"{f(r['edge_contrast_p50'], '.2f'):>8} {f(r['frames_under_threshold'], '.2f'):>7}")
    if args.figure:
        args.figure.parent.mkdir(parents=True, exist_ok=True)
        plot_examples(example_frames(args.dataset, by, args.margin), rows, args.figure)
        print(f"figure: {args.figure}")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"dataset": str(args.dataset), "margin_px": args.margin,
                                         "by": by, "rows": rows}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
