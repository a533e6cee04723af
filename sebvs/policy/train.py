"""Behaviour cloning of the ERP variants (paper section 4.2), seeded and reproducible on CPU.

    nav: Adam lr 2e-4, weight decay 1e-4, MSE, 10 epochs, batch 32, early stopping patience 2
    arm: Adam lr 1e-4, ReduceLROnPlateau(factor 0.5, patience 2, threshold 1e-4 absolute),
         Smooth L1, 10 epochs, batch 32, early stopping (patience 4 here: with 2, training
         would stop before the scheduler's first halving could ever act)

The split is by episode. The weights of the best validation epoch are saved. A loss
(every batch, training and validation) or a weight (after every epoch) gone NaN or
infinite stops the training at once with one line (TrainingDiverged), nothing written.
Outputs in ``out``: ``<task>-<modality>.pt`` + ``.json`` per variant,
``<task>-<modality>-losses.csv`` per variant and ``<task>-losses.png`` with every variant
trained into that directory on one plot (the paper's Fig. 6).
"""
from __future__ import annotations

import csv
import json
import math
import os
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

from .checkpoint import model_config, save_checkpoint
# defined beside the checkpoint schema, which checks a config's stem the same way
from .checkpoint_schema import FUSION_STEMS, check_stem  # noqa: F401
from .dataset import (OPEN_EPISODES, EpisodeBlockSampler, EpisodeFrames, available_memory,
                      content_digest, dataset_hash, event_frames_of, load_index,
                      split_episodes)
from .inputs import CONTROL_MODALITIES, MODALITIES, MODALITY_INPUTS, Normalisation, channels
from .resume import (NonFiniteState, first_non_finite, fingerprint, load_state, resume_path,
                     save_state)
from .subnormal import ZeroSubnormals


@dataclass
class TrainSettings:
    task: str
    lr: float
    weight_decay: float
    loss: str                     # "mse" | "smooth_l1"
    epochs: int = 10
    batch: int = 32
    patience: int = 2             # early stopping, epochs without a better validation loss
    plateau: dict | None = None   # ReduceLROnPlateau arguments, or None
    val_fraction: float = 0.2
    seed: int = 0
    max_frames: int = 0
    num_workers: int = 0
    # "auto": the frames in memory when they fit CACHE_SHARE of the available memory;
    # "memory" always, "none" never (dataset.py, EpisodeFrames.preload)
    cache: str = "auto"
    threads: int = 0              # torch.set_num_threads; 0 leaves torch's default
    device: str = "cpu"           # "cuda" for the paper preset; bit-reproducible on CPU only
    stem: str = "patch"           # "patch" (the paper's), "conv", "dual", "gated" (model.STEMS)
    # zero the weights' and Adam's subnormal floats after every step (subnormal.py), which
    # a CPU computes with through a slow path; it changes the weights, so a recipe names it
    zero_subnormals: bool = False
    norm: Normalisation = field(default_factory=Normalisation)


def paper_settings(task: str) -> TrainSettings:
    if task == "nav":
        return TrainSettings("nav", lr=2e-4, weight_decay=1e-4, loss="mse")
    if task == "arm":
        return TrainSettings("arm", lr=1e-4, weight_decay=0.0, loss="smooth_l1", patience=4,
                             plateau={"factor": 0.5, "patience": 2, "threshold": 1e-4,
                                      "threshold_mode": "abs"})
    raise ValueError(f"unknown task {task!r} (nav, arm)")


class TrainingDiverged(ValueError):
    """A training whose loss or weights went NaN or infinite: stopped there, no checkpoint
    written (an earlier one of that name is left as it was). A ValueError, so that
    `sebvs train` says it in one line with exit status 2."""


class NonFiniteLoss(ValueError):
    """Raised by `_epoch` at the first batch (counted from 1) whose loss is not finite."""

    def __init__(self, batch: int, value: float):
        super().__init__(f"loss is {value} at batch {batch}")
        self.batch, self.value = batch, value


def _seed_everything(seed: int) -> None:
    import random

    import numpy as np
    import torch
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


def _collate(batch):
    import numpy as np
    import torch
    xs, ys = zip(*batch)
    return torch.from_numpy(np.stack(xs)), torch.from_numpy(np.stack(ys))


def _epoch(model, loader, criterion, optimizer=None, desc: str = "", progress: bool = True,
           device: str = "cpu", after_step=None):
    """One pass; trains if an optimizer is given, calling ``after_step()`` (if given) after
    each of its steps. Returns the mean loss per sample; raises NonFiniteLoss at the first
    batch whose loss is NaN or infinite (the value is read for the mean anyway, so the
    check costs nothing; once one is, every later step only spreads it)."""
    import torch
    from tqdm import tqdm
    training = optimizer is not None
    model.train(training)
    total, n = 0.0, 0
    bar = tqdm(loader, desc=desc, unit="batch", leave=False, disable=not progress,
               dynamic_ncols=True)
    with torch.set_grad_enabled(training):
        for batch, (x, y) in enumerate(bar, 1):
            x, y = x.to(device, non_blocking=True), y.to(device, non_blocking=True)
            loss = criterion(model.predict_loss_space(x), model.loss_space(y))
            if training:
                optimizer.zero_grad(set_to_none=True)
                loss.backward()
                optimizer.step()
                if after_step is not None:
                    after_step()
            value = loss.item()
            if not math.isfinite(value):
                bar.close()
                raise NonFiniteLoss(batch, value)
            total += value * len(x)
            n += len(x)
            bar.set_postfix(loss=f"{total / n:.4g}")
    bar.close()
    return total / max(n, 1)


CACHES = ("auto", "memory", "none")
CACHE_SHARE = 0.5     # of the available memory that "auto" gives the frames


def _use_cache(cache: str, train_set: EpisodeFrames, val_set: EpisodeFrames, log) -> bool:
    if cache not in CACHES:
        raise ValueError(f"unknown cache {cache!r} ({', '.join(CACHES)})")
    if cache != "auto":
        return cache == "memory"
    need, free = train_set.frame_bytes() + val_set.frame_bytes(), available_memory()
    if need <= CACHE_SHARE * free:
        return True
    log(f"  frames read from the files: {need / 2**20:,.0f} MiB would take more than "
        f"{CACHE_SHARE:.0%} of the {free / 2**20:,.0f} MiB available (--cache memory "
        f"to insist)")
    return False


def loader_workers(device: str, cpus: int | None = None) -> int:
    """DataLoader workers for "auto": on a GPU the CPUs only feed it, so up to 8 of them
    (one input-bound GPU epoch halved with 8, docs/scale.md); on the CPU the model's own
    threads want the cores and frames in memory cost little, so none."""
    cpus = cpus if cpus is not None else len(os.sched_getaffinity(0))
    return 0 if device == "cpu" else max(0, min(8, cpus - 1))


def train_variant(data: str | Path, out: str | Path, modality: str, s: TrainSettings,
                  progress: bool = True, log=print) -> dict:
    """Train one modality; writes its checkpoint, config and loss CSV. Returns the config."""
    import numpy as np
    import torch
    from torch.utils.data import DataLoader

    from .model import ERP, count_parameters
    check_stem(s.stem, modality)
    data, out = Path(data), Path(out)
    episodes = load_index(data, s.task)
    event_frames = None
    if "events" in MODALITY_INPUTS[modality]:
        # the recording decides the event input (counts or K time bins); the model follows
        event_frames = event_frames_of(data, episodes)
        s = replace(s, norm=replace(s.norm, event_bins=event_frames["bins"]))
    train_eps, val_eps = split_episodes(episodes, s.val_fraction, s.seed)
    train_set = EpisodeFrames(data, train_eps, s.task, modality, s.norm, s.max_frames)
    val_cap = max(1, s.max_frames // 4) if s.max_frames else 0
    val_set = EpisodeFrames(data, val_eps, s.task, modality, s.norm, val_cap)

    if _use_cache(s.cache, train_set, val_set, log):
        held = train_set.preload(progress) + val_set.preload(progress)
        log(f"  frames in memory: {held / 2**20:,.0f} MiB")

    prev_threads = torch.get_num_threads()
    prev_det = torch.are_deterministic_algorithms_enabled()
    if s.threads:
        torch.set_num_threads(s.threads)
    # deterministic kernels; cuBLAS needs a fixed workspace for that, and warn_only keeps a
    # GPU run going where an op has no deterministic variant
    if s.device != "cpu":
        os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", ":4096:8")
    torch.use_deterministic_algorithms(True, warn_only=s.device != "cpu")
    try:
        _seed_everything(s.seed)
        model = ERP(s.task, channels(modality, s.norm.event_bins), s.norm.size, stem=s.stem)
        target_stats = None
        if s.task == "arm":
            target_stats = pose_stats(train_set.targets())
            model.head.set_target_stats(target_stats["mean"], target_stats["scale"])
        model = model.to(s.device)
        gen = torch.Generator().manual_seed(s.seed)
        # Up to OPEN_EPISODES training episodes, a plain shuffle (every file stays open);
        # beyond, shuffled blocks of episodes so that a file is opened once per epoch.
        order = ({"shuffle": True, "generator": gen} if len(train_eps) <= OPEN_EPISODES else
                 {"sampler": EpisodeBlockSampler(train_set.pairs[:, 0], OPEN_EPISODES, gen)})
        # Workers start afresh every epoch: a persistent loader draws its base seed from
        # the shuffle's generator once, where one without workers draws it every epoch,
        # and the second epoch's order would then depend on the worker count.
        train_loader = DataLoader(train_set, batch_size=s.batch, **order,
                                  num_workers=s.num_workers, collate_fn=_collate)
        val_loader = DataLoader(val_set, batch_size=s.batch, shuffle=False,
                                num_workers=s.num_workers, collate_fn=_collate)
        optimizer = torch.optim.Adam(model.parameters(), lr=s.lr, weight_decay=s.weight_decay)
        scheduler = (torch.optim.lr_scheduler.ReduceLROnPlateau(optimizer, mode="min",
                                                                **s.plateau)
                     if s.plateau else None)
        criterion = torch.nn.MSELoss() if s.loss == "mse" else torch.nn.SmoothL1Loss()
        zeroer = ZeroSubnormals(model, optimizer) if s.zero_subnormals else None
        log(f"train {s.task}-{modality}: {count_parameters(model)} parameters, "
            f"{len(train_set)} train frames ({len(train_eps)} episodes), "
            f"{len(val_set)} validation frames ({len(val_eps)} episodes), size {s.norm.size}")

        rows, best, best_state, bad = [], math.inf, None, 0
        data_hash = dataset_hash(data, episodes)
        state_file = resume_path(out, s.task, modality)
        key = fingerprint(s, modality, content_digest(data, episodes, modality))
        first, seconds_before, resumed = 1, 0.0, []
        state = load_state(state_file, key, log)
        if state is not None:
            model.load_state_dict(state["model"])
            optimizer.load_state_dict(state["optimizer"])
            if scheduler is not None:
                scheduler.load_state_dict(state["scheduler"])
            gen.set_state(state["generator"])
            torch.set_rng_state(state["torch_rng"])
            rows, best, best_state, bad = (state["rows"], state["best"], state["best_state"],
                                           state["bad"])
            first = state["epoch"] + 1 if bad < s.patience else s.epochs + 1
            seconds_before, resumed = state["seconds"], [*state["resumed"], state["epoch"]]
            log(f"  resuming after epoch {state['epoch']} ({state_file.name})")
        t0 = time.monotonic()
        name = f"{s.task}-{modality}"
        for epoch in range(first, s.epochs + 1):
            tag = f"{name} {epoch}/{s.epochs}"
            lr = optimizer.param_groups[0]["lr"]
            zeroed_before, epoch_t0 = (zeroer.total if zeroer else 0), time.monotonic()
            tr = _finite_epoch(name, "training", epoch, model, train_loader, criterion,
                               optimizer, f"{tag} train", progress, s.device, after_step=zeroer)
            # a last step can make a weight NaN with its batch's loss still finite; a
            # buffer (BatchNorm statistics) can go with no training loss seeing it at all
            broken = first_non_finite(model.state_dict())
            if broken is not None:
                raise TrainingDiverged(f"{name}: weight {broken} is not finite after epoch "
                                       f"{epoch}; stopped, no checkpoint written")
            va = _finite_epoch(name, "validation", epoch, model, val_loader, criterion, None,
                               f"{tag} val", progress, s.device)
            rows.append({"modality": modality, "epoch": epoch, "train_loss": tr,
                         "val_loss": va, "lr": lr})
            log(f"  epoch {epoch}: train {tr:.5f}  val {va:.5f}  lr {lr:.2e}  "
                f"{time.monotonic() - epoch_t0:,.0f} s"
                + (f"  subnormals zeroed {zeroer.total - zeroed_before:,}" if zeroer else ""))
            if va < best:
                best, bad = va, 0
                best_state = {k: v.detach().to("cpu", copy=True)
                              for k, v in model.state_dict().items()}
            else:
                bad += 1
            if scheduler is not None:
                scheduler.step(va)
            try:    # the weights are finite (above); Adam's moments need not be
                save_state(state_file, {
                    "fingerprint": key, "epoch": epoch, "model": model.state_dict(),
                    "optimizer": optimizer.state_dict(),
                    "scheduler": scheduler.state_dict() if scheduler is not None else None,
                    "generator": gen.get_state(), "torch_rng": torch.get_rng_state(),
                    "rows": rows, "best": best, "best_state": best_state, "bad": bad,
                    "seconds": seconds_before + time.monotonic() - t0, "resumed": resumed})
            except NonFiniteState as exc:
                raise TrainingDiverged(f"{name}: after epoch {epoch}, {exc}; stopped, no "
                                       f"checkpoint written") from None
            if bad >= s.patience:
                log(f"  early stop: no better validation loss for {bad} epochs")
                break
        model.cpu()
        if best_state is not None:     # else no epoch ran (resumed past the last)
            model.load_state_dict(best_state)
    finally:
        torch.use_deterministic_algorithms(prev_det)
        torch.set_num_threads(prev_threads)
        train_set.close()
        val_set.close()

    config = {**model_config(s.task, modality, s.norm, s.stem),
              "parameters": count_parameters(model),
              **({"target_stats": target_stats} if target_stats else {}),
              **({"event_frames": event_frames} if event_frames else {}),
              "dataset": {"path": str(data), "hash": data_hash,
                          "train_episodes": [e["file"] for e in train_eps],
                          "val_episodes": [e["file"] for e in val_eps],
                          "train_frames": len(train_set), "val_frames": len(val_set)},
              "training": {"lr": s.lr, "weight_decay": s.weight_decay, "loss": s.loss,
                           "batch": s.batch, "device": s.device, "epochs": s.epochs,
                           "epochs_run": len(rows),
                           "patience": s.patience, "plateau": s.plateau,
                           "best_val_loss": best, "seed": s.seed, "max_frames": s.max_frames,
                           **({"zero_subnormals": True} if s.zero_subnormals else {}),
                           "seconds": round(seconds_before + time.monotonic() - t0, 2),
                           **({"resumed_after_epochs": resumed} if resumed else {})},
              "torch": torch.__version__, "numpy": np.__version__}
    save_checkpoint(model, config, out)
    write_losses_csv(rows, out / f"{s.task}-{modality}-losses.csv")
    state_file.unlink(missing_ok=True)
    return config


def _finite_epoch(name: str, kind: str, epoch: int, *args, **kwargs) -> float:
    """`_epoch`, its mean loss checked too: TrainingDiverged, in one line, naming the
    variant, the pass ("training" or "validation"), the epoch and the batch, when a loss
    is not finite."""
    try:
        mean = _epoch(*args, **kwargs)
    except NonFiniteLoss as exc:
        raise TrainingDiverged(f"{name}: {kind} loss is {exc.value} at epoch {epoch}, batch "
                               f"{exc.batch}; stopped, no checkpoint written") from None
    if not math.isfinite(mean):     # finite batches whose sum overflowed
        raise TrainingDiverged(f"{name}: {kind} loss is {mean} at epoch {epoch} (the mean "
                               f"over its batches); stopped, no checkpoint written")
    return mean


# Floors of the arm pose's standardisation scale: a dimension that hardly varies (roll and
# pitch of a gripper that always points down) must not be blown up into noise.
POSE_SCALE_FLOOR = (0.01, 0.01, 0.01, 0.05, 0.05, 0.05)     # m, m, m, rad, rad, rad


def pose_stats(targets) -> dict:
    """Mean and scale (std, floored by POSE_SCALE_FLOOR) of arm targets [N, 6]."""
    import numpy as np
    t = np.asarray(targets, dtype=np.float64).reshape(-1, 6)
    if not len(t):
        raise ValueError("no training targets to standardise the arm pose with")
    return {"mean": t.mean(0).tolist(),
            "scale": np.maximum(t.std(0), POSE_SCALE_FLOOR).tolist()}


def write_losses_csv(rows: list[dict], path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=["modality", "epoch", "train_loss", "val_loss", "lr"])
        w.writeheader()
        w.writerows(rows)


def plot_losses(out: str | Path, task: str) -> Path | None:
    """Fig. 6: train (solid) and validation (dashed) loss per epoch, one colour per variant,
    from every ``<task>-*-losses.csv`` in ``out``."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    out = Path(out)
    curves = {}
    for m in MODALITIES + CONTROL_MODALITIES:
        p = out / f"{task}-{m}-losses.csv"
        if p.exists():
            with open(p) as f:
                curves[m] = list(csv.DictReader(f))
    if not curves:
        return None
    colours = {"rgb": "tab:blue", "event": "tab:orange", "rgb+event": "tab:green",
               "rgb+diff": "tab:purple"}
    fig, ax = plt.subplots(figsize=(6, 4))
    for m, rows in curves.items():
        ep = [int(r["epoch"]) for r in rows]
        ax.plot(ep, [float(r["train_loss"]) for r in rows], "-", color=colours[m],
                label=f"{m} train")
        ax.plot(ep, [float(r["val_loss"]) for r in rows], "--", color=colours[m],
                label=f"{m} val")
    ax.set_xlabel("epoch")
    ax.set_ylabel("MSE" if task == "nav" else "Smooth L1")
    ax.set_yscale("log")
    ax.set_title(f"ERP{task.capitalize()}: training and validation loss")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    path = out / f"{task}-losses.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def settings_for(task: str, **overrides) -> TrainSettings:
    """The paper's settings for ``task`` with ``overrides`` (TrainSettings fields; None
    keeps the default): what `train` trains with, and what a sweep records per point."""
    return replace(paper_settings(task), **{k: v for k, v in overrides.items() if v is not None})


def train(data: str | Path, out: str | Path, task: str, modalities: list[str],
          progress: bool = True, log=print, **overrides) -> dict[str, dict]:
    """Train each modality in turn with the paper's settings for ``task`` (``overrides``
    replace TrainSettings fields, e.g. epochs=2, norm=Normalisation(size=64))."""
    s = settings_for(task, **overrides)
    for m in modalities:             # refuse before the first modality trains, not after
        check_stem(s.stem, m)
    results = {}
    for m in modalities:
        results[m] = train_variant(data, out, m, s, progress=progress, log=log)
    png = plot_losses(out, task)
    summary = {m: {"best_val_loss": c["training"]["best_val_loss"],
                   "epochs_run": c["training"]["epochs_run"],
                   "parameters": c["parameters"]} for m, c in results.items()}
    log(json.dumps(summary, indent=2))
    if png:
        log(f"loss curves: {png}")
    return results
