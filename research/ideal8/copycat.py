"""Does a nav policy steer by the target, or by reading its own motion off the input?

Causal confusion in imitation learning (de Haan et al. 2019; the "copycat" problem of
Wen et al. 2020): the expert's command changes little from one control tick to the next,
so anything in the observation that shows the command being executed predicts the label
well. An event camera on a turning robot shows exactly that: ego-motion events of the floor
and walls. A policy that learns to read them fits its validation set and, in closed loop,
keeps doing whatever it was doing.

For each checkpoint and group of episodes (by the scene settings in --by), over every
labelled tick after the first of an episode, per command channel ([v, w] for nav):

    r2_label    R^2 of the policy's output against the expert's label at this tick
    r2_prev     R^2 of the output against the label of the tick before (what the robot
                was executing while the input was recorded)
    innovation  correlation of (output - previous label) with (label - previous label):
                does the output know where the command is going, beyond where it was?
                A copycat scores about 0, a policy that sees the target well above 0.

plus the copy-the-previous-label baseline's MSE beside the policy's. r2_prev above r2_label
with an innovation near 0 is the copycat's signature.

    python research/ideal8/copycat.py datasets/nav_rand_fr checkpoints/nav-event.pt \\
        checkpoints/nav-rgb.pt [--episodes val|all] [--by variant] [--json out.json]

--episodes val (default) uses each checkpoint's own validation episodes, and needs the
checkpoint to have been trained on this dataset; all uses every episode (held out only for
a checkpoint trained on another dataset).
"""
from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from sebvs.data.episode import open_episode  # noqa: E402
from sebvs.data.stats import episode_files  # noqa: E402
from sebvs.policy.checkpoint import load_checkpoint  # noqa: E402
from sebvs.policy.inputs import model_input  # noqa: E402

BATCH = 64


def copy_scores(labels: list[np.ndarray], outputs: list[np.ndarray]) -> dict:
    """Scores over episodes: labels[i], outputs[i] [T_i, C] (tick t's label and output).

    Ticks 1..T-1 of each episode are scored against tick t-1's label. Returns per-channel
    lists (r2_label, r2_prev, innovation) and scalars (mse, copy_mse, label_var, ticks).
    """
    a = np.concatenate([x[1:] for x in labels]).astype(np.float64)
    p = np.concatenate([x[:-1] for x in labels]).astype(np.float64)
    o = np.concatenate([y[1:] for y in outputs]).astype(np.float64)
    if not len(a):
        raise ValueError("no episode has two or more labelled ticks")

    def r2(target: np.ndarray) -> list[float]:
        var = target.var(axis=0)
        return [float(1 - ((o[:, k] - target[:, k]) ** 2).mean() / var[k]) if var[k] > 0
                else float("nan") for k in range(a.shape[1])]

    def corr(x: np.ndarray, y: np.ndarray) -> float:
        if x.std() == 0 or y.std() == 0:
            return float("nan")
        return float(np.corrcoef(x, y)[0, 1])

    return {"ticks": int(len(a)), "r2_label": r2(a), "r2_prev": r2(p),
            "innovation": [corr(o[:, k] - p[:, k], a[:, k] - p[:, k])
                           for k in range(a.shape[1])],
            "mse": float(((o - a) ** 2).mean()), "copy_mse": float(((p - a) ** 2).mean()),
            "label_var": float(a.var(axis=0).mean())}


def run_policy(model, modality: str, norm, ep) -> np.ndarray:
    """The checkpoint's output for every tick of an open episode -> [T, C]; a recurrent
    checkpoint's tick by tick from the initial state, its state carried on as the policy
    actor carries it."""
    import torch

    out = []
    n = len(ep)
    state = model.initial_state(1)
    for s in range(0, n, BATCH):
        rgb = ep.rgb[s:s + BATCH] if "rgb" in modality else [None] * min(BATCH, n - s)
        ev = ep.event_frame[s:s + BATCH] if "event" in modality else [None] * len(rgb)
        x = torch.from_numpy(np.stack([model_input(modality, norm, rgb=r, events=e)
                                       for r, e in zip(rgb, ev)]))
        with torch.no_grad():
            if model.state_size:
                for tick in x:
                    y, state = model.step(tick[None], state)
                    out.append(y.numpy())
            else:
                out.append(model(x).numpy())
    return np.concatenate(out)


def episodes_for(cfg: dict, dataset: Path, which: str, pt: Path) -> list[str]:
    if which == "all":
        return episode_files(dataset)
    trained_on = Path(cfg.get("dataset", {}).get("path", ""))
    if trained_on.resolve() != dataset.resolve():
        raise SystemExit(f"{pt}: trained on {trained_on or 'an unrecorded dataset'}, not "
                         f"{dataset}; its validation episodes are not this dataset's "
                         f"(use --episodes all: every episode is held out for it)")
    return list(cfg["dataset"]["val_episodes"])


def score_checkpoint(pt: Path, dataset: Path, which: str, by: list[str]) -> list[dict]:
    model, cfg, norm = load_checkpoint(pt)
    if cfg.get("task") != "nav":
        raise SystemExit(f"{pt}: a {cfg.get('task')} checkpoint; this tool reads nav commands")
    groups: dict[str, tuple[list, list]] = defaultdict(lambda: ([], []))
    for name in episodes_for(cfg, dataset, which, pt):
        with open_episode(dataset / name) as ep:
            if "event" in cfg["modality"] and ep.event_frame is None:
                raise SystemExit(f"{dataset / name}: no event frames for {pt}")
            cond = ep.attrs.get("conditions") or {}
            key = ", ".join(f"{k}={cond.get(k, '?')}" for k in by) or "all"
            labels, outputs = groups[key]
            labels.append(np.asarray(ep.target[:]))
            outputs.append(run_policy(model, cfg["modality"], norm, ep))
    return [{"checkpoint": str(pt), "modality": cfg["modality"], "group": key,
             "episodes": len(groups[key][0]), **copy_scores(*groups[key])}
            for key in sorted(groups)]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("dataset", type=Path, help="a nav dataset directory")
    ap.add_argument("checkpoints", type=Path, nargs="+", help="nav checkpoints (.pt)")
    ap.add_argument("--episodes", choices=("val", "all"), default="val",
                    help="each checkpoint's validation episodes (default) or every episode")
    ap.add_argument("--by", default="variant",
                    help="comma-separated scene settings to group by (default variant)")
    ap.add_argument("--threads", type=int, default=2, help="torch CPU threads (default 2)")
    ap.add_argument("--json", type=Path, help="also write the rows as JSON here")
    args = ap.parse_args(argv)
    if not args.dataset.is_dir():
        ap.error(f"{args.dataset}: not a directory")
    for pt in args.checkpoints:
        if not pt.is_file():
            ap.error(f"{pt}: no such checkpoint")
    import torch
    torch.set_num_threads(max(1, args.threads))
    by = [k for k in args.by.split(",") if k]
    rows = [r for pt in args.checkpoints
            for r in score_checkpoint(pt, args.dataset, args.episodes, by)]
    print(f"{'checkpoint':<28} {'group':<18} {'ticks':>6} {'mse':>8} {'copy mse':>8} "
          f"{'r2 label v/w':>13} {'r2 prev v/w':>13} {'innov v/w':>11}")
    for r in rows:
        pair = lambda xs: "/".join(f"{x:.2f}" for x in xs)   # noqa: E731
        print(f"{Path(r['checkpoint']).name:<28} {r['group']:<18} {r['ticks']:>6} "
              f"{r['mse']:>8.4f} {r['copy_mse']:>8.4f} {pair(r['r2_label']):>13} "
              f"{pair(r['r2_prev']):>13} {pair(r['innovation']):>11}")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"dataset": str(args.dataset), "episodes": args.episodes,
                                         "by": by, "rows": rows}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
