"""What a gated RGB+Event policy lets through: its fusion gate on the target and elsewhere.

A policy trained with `--stem gated` (model.GatedFusionStem) adds each patch's event token
to its RGB token through a gate in (0, 1), per token and feature. This reads the
validation frames of its own training data (the checkpoint's config names them), runs the
stem, and splits the tokens three ways with the episode's truth: the tokens over the
target's true box, background tokens with events in their patch (ego-motion: the floor,
the walls, the horizon sliding by), and background tokens without. Per token it takes the
gate's mean over features and the event share of the fused token, |gate * event| /
(|rgb| + |gate * event|) (norms over features: how much of what the transformer reads is
the event stem's).

Frames are grouped by scene variant and motion: "turning" when the expert's turn command
is at least --turn of its maximum, else "straight". Printed per group, medians over
frames: the gate on target, moving background and still background tokens, the event
share, and "gate~events", the rank correlation over a frame's background tokens between
their event mass and their gate (negative: the busier a patch, the less of its events
pass). A gate that holds ego-motion back reads lower on moving background tokens than on
the target's, and correlates negatively with event mass. The figure shows, per group, the
frame with the most events.

    python research/ideal8/fusion_gates.py \\
        out/study_fusion/train/gated/modality=rgb+event__seed=0/nav-rgb+event.pt \\
        [--data DIR] [--frames 2000] [--json FILE] [--figure FILE]
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from sebvs.data.episode import open_episode  # noqa: E402
from sebvs.policy.checkpoint import load_checkpoint  # noqa: E402
from sebvs.policy.dataset import load_index  # noqa: E402
from sebvs.policy.inputs import model_input  # noqa: E402
from sebvs.policy.model import RGB_PLANES  # noqa: E402

KINDS = ("target", "moving background", "still background")


def target_tokens(bbox: np.ndarray, image_wh: np.ndarray, size: int, patch: int) -> np.ndarray:
    """bool [G*G], row-major like the tokens: patches of the size x size model input that
    overlap the target's box (truth px of an image_wh image)."""
    g = size // patch
    sx, sy = size / float(image_wh[0]), size / float(image_wh[1])
    u0, v0, u1, v1 = bbox[0] * sx, bbox[1] * sy, bbox[2] * sx, bbox[3] * sy
    edges = np.arange(g) * patch
    cols = (edges < u1) & (edges + patch > u0)
    rows = (edges < v1) & (edges + patch > v0)
    return (rows[:, None] & cols[None, :]).reshape(-1)


def token_event_mass(events: np.ndarray, patch: int) -> np.ndarray:
    """events [E, S, S] (model input, in [0, 1]) -> their sum per patch, [G*G] row-major."""
    e, s, _ = events.shape
    g = s // patch
    return events.reshape(e, g, patch, g, patch).sum(axis=(0, 2, 4)).reshape(-1)


def frame_tokens(stem, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """x [C, S, S] -> (gate mean over features [N], event share of the fused token [N])."""
    import torch
    with torch.inference_mode():
        rgb, events, gate = stem.gates(torch.from_numpy(x)[None])
        mixed = (gate * events).norm(dim=2)
        share = mixed / (rgb.norm(dim=2) + mixed)
    return gate.mean(dim=2)[0].numpy(), share[0].numpy()


def collect(pt: Path, data: Path | None, frames: int, turn: float) -> tuple[dict, list]:
    """{group: {kind: {"gate": [...], "share": [...]}, "gate_vs_events": [...]}} of
    per-frame values, and one example frame per group (the one with the most events)."""
    model, cfg, norm = load_checkpoint(pt)
    if cfg.get("stem") != "gated":
        raise SystemExit(f"{pt}: a {cfg.get('stem', 'patch')}-stem checkpoint; this reads the "
                         f"gate of one trained with --stem gated")
    data = Path(data or cfg["dataset"]["path"])
    val = set(cfg["dataset"]["val_episodes"])
    episodes = [e for e in load_index(data, "nav") if e["file"] in val]
    if not episodes:
        raise SystemExit(f"{data}: none of the checkpoint's validation episodes is here")
    total = sum(int(e["frames"]) for e in episodes)
    stride = max(1, total // frames)
    patch = cfg["size"] // int(round(model.tokens.pos.shape[1] ** 0.5))
    groups: dict = {}
    examples: dict = {}
    for e in episodes:
        variant = (e.get("conditions") or {}).get("variant", "?")
        with open_episode(data / e["file"]) as ep:
            visible = np.asarray(ep.truth["visible"][:]) > 0
            for t in range(0, int(e["frames"]), stride):
                if not visible[t]:
                    continue
                rgb, ev = np.asarray(ep.rgb[t]), np.asarray(ep.event_frame[t])
                x = model_input("rgb+event", norm, rgb=rgb, events=ev)
                gate, share = frame_tokens(model.embed, x)
                on_target = target_tokens(np.asarray(ep.truth["bbox"][t]),
                                          np.asarray(ep.truth["image"][t]), cfg["size"], patch)
                mass = token_event_mass(x[RGB_PLANES:], patch)
                moving = mass > 0
                motion = "turning" if abs(float(ep.target[t][1])) >= turn else "straight"
                key = f"{variant}, {motion}"
                group = groups.setdefault(key, {**{k: {"gate": [], "share": []} for k in KINDS},
                                                "gate_vs_events": []})
                for kind, mask in zip(KINDS, (on_target, ~on_target & moving,
                                              ~on_target & ~moving)):
                    if mask.any():
                        group[kind]["gate"].append(float(gate[mask].mean()))
                        group[kind]["share"].append(float(share[mask].mean()))
                back = ~on_target
                r = rank_correlation(mass[back], gate[back])
                if r is not None:
                    group["gate_vs_events"].append(r)
                busy = float(mass.sum())
                if key not in examples or busy > examples[key][0]:
                    examples[key] = (busy, (rgb, ev, gate, on_target))
    return groups, [(k, v[1]) for k, v in sorted(examples.items())]


def rank_correlation(a: np.ndarray, b: np.ndarray) -> float | None:
    """Spearman's rank correlation of a and b (average ranks for ties); None when either
    is constant."""
    def ranks(x):
        order = np.argsort(x, kind="stable")
        r = np.empty(len(x))
        r[order] = np.arange(len(x))
        for v in np.unique(x):                  # ties share their mean rank
            tie = x == v
            r[tie] = r[tie].mean()
        return r
    if len(a) < 3 or np.ptp(a) == 0 or np.ptp(b) == 0:
        return None
    return float(np.corrcoef(ranks(a), ranks(b))[0, 1])


def summarise(groups: dict) -> list[dict]:
    rows = []
    for name in sorted(groups):
        row = {"group": name, "frames": max(len(groups[name][k]["gate"]) for k in KINDS)}
        corr = groups[name]["gate_vs_events"]
        row["gate_vs_event_mass_rank_corr_p50"] = statistics.median(corr) if corr else None
        for kind in KINDS:
            vals = groups[name][kind]
            key = kind.replace(" ", "_")
            row[f"{key}_gate_p50"] = statistics.median(vals["gate"]) if vals["gate"] else None
            row[f"{key}_event_share_p50"] = (statistics.median(vals["share"])
                                            if vals["share"] else None)
        rows.append(row)
    return rows


def plot(examples: list, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(3, len(examples), figsize=(2.6 * len(examples), 7.6),
                             squeeze=False)
    for j, (name, (rgb, ev, gate, on_target)) in enumerate(examples):
        g = int(round(len(gate) ** 0.5))
        axes[0, j].imshow(rgb)
        axes[0, j].set_title(name, fontsize=8)
        k = ev.shape[0] // 2                  # ON planes first, then OFF (K time bins each)
        on, off = ev[:k].sum(0).astype(float), ev[k:].sum(0).astype(float)
        img = np.stack([np.minimum(off / 4, 1), np.zeros(on.shape), np.minimum(on / 4, 1)], -1)
        axes[1, j].imshow(1 - 0.8 * img.max(axis=-1, keepdims=True) + 0.8 * img)
        im = axes[2, j].imshow(gate.reshape(g, g), vmin=0, vmax=1, cmap="viridis")
        rows, cols = np.nonzero(on_target.reshape(g, g))
        axes[2, j].scatter(cols, rows, marker="s", s=60, facecolors="none", edgecolors="r")
        for ax in axes[:, j]:
            ax.set_xticks([])
            ax.set_yticks([])
    axes[1, 0].set_ylabel("events (ON blue, OFF red)", fontsize=8)
    axes[2, 0].set_ylabel("gate per token (red: target)", fontsize=8)
    fig.colorbar(im, ax=axes[2, :].tolist(), shrink=0.8, label="gate, mean over features")
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("checkpoint", type=Path, help="a --stem gated checkpoint (.pt)")
    ap.add_argument("--data", type=Path, default=None,
                    help="its dataset (default: the path its config names)")
    ap.add_argument("--frames", type=int, default=2000,
                    help="about this many validation frames, strided (default 2000)")
    ap.add_argument("--turn", type=float, default=0.15,
                    help="|turn command| (of its maximum) from which a frame is 'turning' "
                         "(default 0.15: about the upper quartile of the randomised nav "
                         "recordings' expert)")
    ap.add_argument("--json", type=Path, default=None, help="write the rows here")
    ap.add_argument("--figure", type=Path, default=None,
                    help="one example frame per group: RGB, events, the gate map")
    args = ap.parse_args(argv)
    groups, examples = collect(args.checkpoint, args.data, args.frames, args.turn)
    rows = summarise(groups)
    heads = [f"{k} gate" for k in KINDS] + [f"{k} share" for k in KINDS] + ["gate~events"]
    print(f"{'group':<20}{'frames':>7}" + "".join(f"{h:>25}" for h in heads))
    for r in rows:
        cells = [r[f"{k.replace(' ', '_')}_gate_p50"] for k in KINDS]
        cells += [r[f"{k.replace(' ', '_')}_event_share_p50"] for k in KINDS]
        cells.append(r["gate_vs_event_mass_rank_corr_p50"])
        print(f"{r['group']:<20}{r['frames']:>7}" + "".join(
            f"{'-' if v is None else f'{v:.3f}':>25}" for v in cells))
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"checkpoint": str(args.checkpoint), "turn": args.turn,
                                         "rows": rows}, indent=1))
    if args.figure:
        args.figure.parent.mkdir(parents=True, exist_ok=True)
        plot(examples, args.figure)
        print(f"figure: {args.figure}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
