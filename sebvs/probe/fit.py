"""Train the probe on some episodes of a recording and measure it on the others.

    frames = load_frames("datasets/probe/expert/hdr__outdoor")
    result = probe(frames, "event", Recipe(), seed=0)
    result["error_px"]["median"], result["baseline_px"]["median"], result["auc"]

The recipe (`Recipe`) is fixed: the same for every sensor and cell. Episodes are split by
their position in the index, the first `train_episodes` for training and the next
`test_episodes` for the test; the test frames are never trained on and choose nothing (the
model is the one after the last epoch). The figures: the localisation error on the test's
visible frames (the Euclidean distance between the predicted and the true centroid, in px
of a 160 px wide image, median and 90th percentile, and the same as a fraction of the
image's width), beside the no-information baseline that predicts the training frames' mean
centroid; the visibility head's ROC AUC on every test frame, beside 0.5 (None where the
test holds one class only).
"""
from __future__ import annotations

import time
from dataclasses import asdict, dataclass

import numpy as np

from sebvs.policy.inputs import Normalisation

from .data import SENSORS, Frames

REPORT_WIDTH_PX = 160          # errors are given in px of an image this wide


@dataclass(frozen=True)
class Recipe:
    """The probe's training, fixed before any result (docs/probe.md, "Method")."""
    train_episodes: int = 8
    test_episodes: int = 2
    epochs: int = 8              # 15 gave the same within noise (rgb 2.9 / event 28 px
                                 #   against 2.8 / 24 px at 8, still nominal_physical/indoor)
    batch: int = 32
    lr: float = 1e-3
    loc_weight: float = 10.0     # loss = loc_weight * L1(centre fraction) on visible frames
                                 #        + BCE(visibility logit) on every frame
    width: int = 32              # ProbeNet channels
    size: int = 160              # the input side: the policies' Normalisation (160 px)
    batchnorm: bool = False      # BatchNorm after each convolution
    cell_weight: float = 1.0     # + this x the cross-entropy of the cells' scores against
                                 #   the cell holding the true centroid (visible frames):
                                 #   without it the soft arg-max barely learnt (rgb, still
                                 #   nominal_physical/indoor: 39 px against 2.8 px with it)
    flip: bool = True            # mirror a random half of every batch left-right (u -> 1 - u)
    weight_decay: float = 0.0    # Adam's

    def to_dict(self) -> dict:
        return asdict(self)


def split(frames: Frames, recipe: Recipe) -> tuple[np.ndarray, np.ndarray, list, list]:
    """(train frame indices, test frame indices, train episodes, test episodes). ValueError
    (one line) when the dataset holds fewer episodes than the recipe splits."""
    n = len(frames.files)
    need = recipe.train_episodes + recipe.test_episodes
    if n < need:
        raise ValueError(f"{frames.root}: {n} episode(s), the recipe splits {need} "
                         f"({recipe.train_episodes} train + {recipe.test_episodes} test)")
    train = list(range(recipe.train_episodes))
    test = list(range(recipe.train_episodes, need))
    return frames.frames_of(train), frames.frames_of(test), train, test


def roc_auc(scores: np.ndarray, labels: np.ndarray) -> float | None:
    """ROC AUC of `scores` for boolean `labels` (the Mann-Whitney statistic, ties counted
    half); None when the labels hold one class."""
    scores, labels = np.asarray(scores, np.float64), np.asarray(labels, bool)
    pos, neg = int(labels.sum()), int((~labels).sum())
    if pos == 0 or neg == 0:
        return None
    order = np.argsort(scores, kind="mergesort")
    ranks = np.empty(len(scores), np.float64)
    sorted_scores = scores[order]
    # average ranks over ties
    i = 0
    while i < len(scores):
        j = i
        while j + 1 < len(scores) and sorted_scores[j + 1] == sorted_scores[i]:
            j += 1
        ranks[order[i:j + 1]] = (i + j) / 2.0 + 1.0
        i = j + 1
    return float((ranks[labels].sum() - pos * (pos + 1) / 2.0) / (pos * neg))


def _errors_px(pred_fraction: np.ndarray, true_fraction: np.ndarray, image) -> np.ndarray:
    """Euclidean error in px of a REPORT_WIDTH_PX wide image."""
    w, h = image
    d = (pred_fraction - true_fraction) * np.array([w, h], np.float64)
    return np.hypot(d[:, 0], d[:, 1]) * (REPORT_WIDTH_PX / w)


def _summary(err: np.ndarray) -> dict:
    if len(err) == 0:
        return {"median": None, "p90": None, "mean": None,
                "median_fraction": None, "p90_fraction": None}
    med, p90 = float(np.median(err)), float(np.percentile(err, 90))
    return {"median": med, "p90": p90, "mean": float(err.mean()),
            "median_fraction": med / REPORT_WIDTH_PX, "p90_fraction": p90 / REPORT_WIDTH_PX}


def probe(frames: Frames, sensor: str, recipe: Recipe | None = None, seed: int = 0,
          threads: int = 1, progress=None) -> dict:
    """Train the probe on `sensor`'s input of the train episodes, measure it on the test's.

    Parameters:
        frames: load_frames() of the dataset (with the streams `sensor` needs).
        sensor: "rgb", "event" or "both" (SENSORS).
        recipe: the training (default Recipe()).
        seed: the model's initialisation and the batches' order.
        threads: torch's CPU threads.
        progress: called with the number of optimiser steps done since its last call.

    Returns:
        A JSON-able dict: sensor, seed, the split (episodes and frames), error_px and
        baseline_px (median, p90, mean, as fractions too), auc (None: one class in the
        test), the test's visible share, wall_s.
    """
    import torch

    from .model import ProbeNet
    recipe = recipe or Recipe()
    if sensor not in SENSORS:
        raise ValueError(f"unknown sensor {sensor!r} (one of {', '.join(SENSORS)})")
    t0 = time.perf_counter()
    torch.set_num_threads(max(1, threads))
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    train, test, train_eps, test_eps = split(frames, recipe)
    target = np.nan_to_num(frames.centroid_fraction, nan=0.0).astype(np.float32)
    visible = frames.visible.astype(np.float32)
    norm = Normalisation(size=recipe.size)
    x_test = frames.inputs(sensor, test, norm)
    net = ProbeNet(x_test.shape[1], recipe.width, batchnorm=recipe.batchnorm)
    opt = torch.optim.Adam(net.parameters(), lr=recipe.lr, weight_decay=recipe.weight_decay)
    bce = torch.nn.BCEWithLogitsLoss()
    losses = []
    for _ in range(recipe.epochs):
        order = rng.permutation(train)
        total, steps = 0.0, 0
        net.train()
        for start in range(0, len(order), recipe.batch):
            idx = np.sort(order[start:start + recipe.batch])
            xb = frames.inputs(sensor, idx, norm)
            tb = target[idx].copy()
            if recipe.flip:
                mirror = rng.uniform(size=len(idx)) < 0.5
                xb[mirror] = xb[mirror][..., ::-1]
                tb[mirror, 0] = 1.0 - tb[mirror, 0]
            centre, logit, scores = net.heads(torch.from_numpy(xb))
            vis = torch.from_numpy(visible[idx])
            loss = bce(logit, vis)
            mask = vis > 0.5
            if mask.any():
                truth = torch.from_numpy(tb)[mask]
                loss = loss + recipe.loc_weight * (centre[mask] - truth).abs().mean()
                if recipe.cell_weight > 0:
                    h, w = scores.shape[1:]
                    cell = (truth[:, 1] * h).long().clamp(0, h - 1) * w + \
                        (truth[:, 0] * w).long().clamp(0, w - 1)
                    loss = loss + recipe.cell_weight * torch.nn.functional.cross_entropy(
                        scores[mask].flatten(1), cell)
            opt.zero_grad()
            loss.backward()
            opt.step()
            total += float(loss.detach())
            steps += 1
            if progress is not None:
                progress(1)
        losses.append(total / max(1, steps))
    net.eval()
    with torch.no_grad():
        preds, logits = [], []
        for start in range(0, len(test), 64):
            c, lg = net(torch.from_numpy(x_test[start:start + 64]))
            preds.append(c.numpy())
            logits.append(lg.numpy())
    pred = np.concatenate(preds).astype(np.float64)
    logit = np.concatenate(logits).astype(np.float64)
    truth = frames.centroid_fraction
    seen_test = frames.visible[test]
    seen_train = frames.visible[train]
    err = _errors_px(pred[seen_test], truth[test][seen_test], frames.image)
    mean = truth[train][seen_train].mean(axis=0) if seen_train.any() else np.array([0.5, 0.5])
    base = _errors_px(np.broadcast_to(mean, (int(seen_test.sum()), 2)),
                      truth[test][seen_test], frames.image)
    return {"sensor": sensor, "modality": SENSORS[sensor], "seed": seed,
            "train_episodes": [frames.files[i] for i in train_eps],
            "test_episodes": [frames.files[i] for i in test_eps],
            "train_frames": int(len(train)), "test_frames": int(len(test)),
            "train_visible": int(seen_train.sum()), "test_visible": int(seen_test.sum()),
            "error_px": _summary(err), "baseline_px": _summary(base),
            "baseline_centroid_px": [float(mean[0] * frames.image[0]),
                                     float(mean[1] * frames.image[1])],
            "auc": roc_auc(logit, seen_test), "auc_baseline": 0.5,
            "train_loss": [round(v, 5) for v in losses],
            "wall_s": round(time.perf_counter() - t0, 2)}
