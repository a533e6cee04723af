"""Behaviour cloning of the ERP variants (paper section 4.2), seeded and reproducible on CPU.

    train("datasets/nav", "ck", "nav", ["rgb", "rgb+event"], epochs=2,
          norm=Normalisation(size=64))    # the paper's settings, these ones overridden

nav: Adam lr 2e-4, weight decay 1e-4, MSE, 10 epochs, batch 32, early stopping patience 2.
arm: Adam lr 1e-4, ReduceLROnPlateau(factor 0.5, patience 2, threshold 1e-4 absolute),
Smooth L1, 10 epochs, batch 32, early stopping (patience 4 here: with 2, training would
stop before the scheduler's first halving could ever act).

The split is by episode; the weights of the best validation epoch are saved. A loss
(every batch, training and validation) or a weight (after every epoch) gone NaN or
infinite stops the training at once with one line (TrainingDiverged), nothing written.
Outputs in ``out``: ``<task>-<modality>.pt`` + ``.json`` and ``<task>-<modality>-losses.csv``
per variant, and ``<task>-losses.png``, every variant trained into ``out`` on one plot
(the paper's Fig. 6). One variant is four steps: `load_training_data`,
`deterministic_torch`, `fit`, `finish`.
"""
from __future__ import annotations

import contextlib
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
                      content_digest, dataset_hash, emulator_of, event_frames_of,
                      load_datasets, load_index, split_episodes)
from .inputs import Modality, Normalisation, event_clip_for
from .resume import (NonFiniteState, first_non_finite, fingerprint, load_state, resume_path,
                     save_state)
from .steps import NonFiniteLoss, optimise
from .subnormal import ZeroSubnormals


# the TrainSettings fields of the recipe options: what `sebvs train` takes as flags, a sweep
# as settings, and a config records as training.recipe
RECIPE_FIELDS = ("memory", "aux_weight", "modality_dropout", "seq_len", "lanes", "burn_in")


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
    # the recipe options of issue 65, item 2 (docs/policy.md, "Memory, target head,
    # modality dropout"); any of them trains on sequences (sequence.py) instead of
    # shuffled frames. memory: "none" | "gru" (a recurrent state across ticks)
    memory: str = "none"
    aux_weight: float = 0.0       # > 0: the target head, its loss weighted so
    modality_dropout: float = 0.0  # fused modalities: the share of windows losing a stream
    # windows of seq_len ticks, lanes of them a batch, each after burn_in ticks without
    # gradient. Defaults measured on the nav dev data (docs/policy.md): 4 windows of 8 did
    # not train (a batch of 4 places); 32 windows of 2 with 6 ticks of burn-in did
    seq_len: int = 2              # ticks per window, backpropagated through
    lanes: int = 32               # windows per batch (the batch's B)
    burn_in: int = 6              # ticks before a window that set its state, no gradient
    norm: Normalisation = field(default_factory=Normalisation)

    @property
    def on_sequences(self) -> bool:
        """Whether these settings train on windows of ticks (any recipe option is on)."""
        return self.memory != "none" or self.aux_weight > 0 or self.modality_dropout > 0


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
                optimise(loss, optimizer, after_step)
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


def train_variant(data: str | Path | list[str | Path], out: str | Path,
                  modality: Modality | str, s: TrainSettings, progress: bool = True,
                  log=print) -> dict:
    """Train one modality; writes its checkpoint, config and loss CSV.

    Parameters:
        data: the dataset directory, or several (trained together, `load_training_data`);
            out: where the outputs go.
        modality: the modality, or its name; s: the settings (the recording decides the
            event bins, see `load_training_data`).
        progress: tqdm bars; log: takes each line (the epochs, the resume, the cache).

    Returns:
        The config written beside the checkpoint (less its version).
    """
    modality = Modality.parse(modality)
    check_stem(s.stem, modality)
    out = Path(out)
    td = load_training_data(data, modality, s, progress, log)
    try:
        with deterministic_torch(td.settings):
            fitted = fit(td, out, progress, log)
    finally:
        td.close()
    return finish(td, fitted, out)


@dataclass
class TrainingData:
    """What one variant trains on (`load_training_data`)."""
    root: Path                    # the dataset directory (of several: the first)
    modality: Modality
    settings: TrainSettings       # the settings asked for, the recording's event bins in
    episodes: list[dict]          # every episode of the index
    train_episodes: list[dict]
    val_episodes: list[dict]
    train_set: EpisodeFrames
    val_set: EpisodeFrames
    event_frames: dict | None     # dataset.event_frames_of: modalities with events only
    emulator: dict | None         # dataset.emulator_of: modalities with events only
    # every dataset, in the order given; the entries of several carry their own ("root")
    roots: list[Path] = field(default_factory=list)

    def close(self) -> None:
        self.train_set.close()
        self.val_set.close()


def dataset_roots(data: str | Path | list[str | Path]) -> list[Path]:
    """The dataset directories a training reads: one, or several in the order given."""
    roots = [Path(d) for d in data] if isinstance(data, (list, tuple)) else [Path(data)]
    if not roots:
        raise ValueError("no dataset given")
    return roots


def load_training_data(data: str | Path | list[str | Path], modality: Modality,
                       s: TrainSettings, progress: bool = True, log=print) -> TrainingData:
    """The data step: the datasets' episodes, what their event frames and emulator are
    (modalities with events), the seeded split by episode, and a reader of each side,
    its frames read into memory first when the cache says so (`_use_cache`).

    Several datasets train together (dataset.load_datasets): their episodes, the first
    dataset's first, are split as one list (by episode, seeded as for one dataset), each
    entry read from its own dataset. Datasets of different tasks, event frames or emulator
    preset versions are refused in one line naming both.

    Parameters:
        data: the dataset directory, or several; modality, s: the variant and its settings.
        progress: tqdm bars for the preload; log: takes the cache's line.

    Returns:
        The TrainingData; its settings' event_bins are the recording's.
    """
    roots = dataset_roots(data)
    root = roots[0]
    # one dataset's entries stay as its index lists them (its digest and records as before)
    episodes = load_index(root, s.task) if len(roots) == 1 else load_datasets(roots, s.task)
    event_frames = emulator = None
    if modality.has_events:
        # the recording decides the event input (counts or K time bins); the model follows
        event_frames = event_frames_of(root, episodes)
        emulator = emulator_of(root, episodes)
        # a time surface reaches the model as value / 255, not clipped as counts are
        s = replace(s, norm=replace(s.norm, event_bins=event_frames["bins"],
                                    event_clip=event_clip_for(event_frames["representation"],
                                                              s.norm.event_clip)))
    train_eps, val_eps = split_episodes(episodes, s.val_fraction, s.seed)
    train_set = EpisodeFrames(root, train_eps, s.task, modality, s.norm, s.max_frames)
    val_cap = max(1, s.max_frames // 4) if s.max_frames else 0
    val_set = EpisodeFrames(root, val_eps, s.task, modality, s.norm, val_cap)
    if _use_cache(s.cache, train_set, val_set, log):
        held = train_set.preload(progress) + val_set.preload(progress)
        log(f"  frames in memory: {held / 2**20:,.0f} MiB")
    return TrainingData(root, modality, s, episodes, train_eps, val_eps, train_set, val_set,
                        event_frames, emulator, roots)


@contextlib.contextmanager
def deterministic_torch(s: TrainSettings):
    """The torch settings step: ``s.threads`` threads (0 leaves torch's) and deterministic
    kernels for the block, torch's own settings restored after it.

    Parameters:
        s: the settings (threads, device).
    """
    import torch
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
        yield
    finally:
        torch.use_deterministic_algorithms(prev_det)
        torch.set_num_threads(prev_threads)


@dataclass
class Fitting:
    """A model and everything that trains it (`_start_fitting`)."""
    settings: TrainSettings
    modality: Modality
    name: str                     # <task>-<modality>, as the lines and errors say it
    model: object                 # ERP, on the settings' device
    optimizer: object
    scheduler: object | None      # ReduceLROnPlateau, where the settings name one
    criterion: object
    zeroer: ZeroSubnormals | None
    generator: object             # the shuffle's torch.Generator
    train_loader: object
    val_loader: object
    target_stats: dict | None     # the arm pose's standardisation (pose_stats)
    # one pass over a loader: _epoch (shuffled frames), or sequence_epoch with the
    # recipe's options bound (sequence.py)
    epoch_fn: object = None
    epoch_stats: dict = field(default_factory=dict)   # what the last pass reported


@dataclass
class FitProgress:
    """The epochs so far: what the resume state saves, and the early stopping's count."""
    rows: list[dict] = field(default_factory=list)    # one per epoch: the loss CSV's rows
    best: float = math.inf                             # the best validation loss
    best_state: dict | None = None                     # its weights (on the CPU)
    bad: int = 0                                       # epochs since it
    first: int = 1                                     # the epoch to run next
    seconds_before: float = 0.0                        # spent before a resume
    resumed: list[int] = field(default_factory=list)   # epochs a resume went on after


@dataclass
class Fitted:
    """What `fit` leaves for `finish`."""
    model: object                 # the best epoch's weights, on the CPU
    progress: FitProgress
    target_stats: dict | None
    data_hash: str                # dataset.dataset_hash
    state_file: Path              # the resume state, removed once the checkpoint is written
    seconds: float                # training time, resumed runs' included


def fit(td: TrainingData, out: Path, progress: bool = True, log=print) -> Fitted:
    """The fit step: seed, build the model and its optimizer, go on from a resume state
    of the same settings and data if there is one, and run the epochs to the last or to
    early stopping; the best validation epoch's weights are kept. Torch's settings are
    the caller's (`deterministic_torch`).

    Parameters:
        td: the data step's result; out: where the resume state is kept.
        progress: tqdm bars; log: takes the lines.

    Returns:
        The Fitted. TrainingDiverged when a loss or a weight goes NaN or infinite.
    """
    s, modality = td.settings, td.modality
    _seed_everything(s.seed)
    run = _start_fitting(td)
    from .model import count_parameters
    log(f"train {s.task}-{modality}: {count_parameters(run.model)} parameters, "
        f"{len(td.train_set)} train frames ({len(td.train_episodes)} episodes), "
        f"{len(td.val_set)} validation frames ({len(td.val_episodes)} episodes), "
        f"size {s.norm.size}")
    data_hash = dataset_hash(td.root, td.episodes)
    state_file = resume_path(out, s.task, modality)
    key = fingerprint(s, modality, content_digest(td.root, td.episodes, modality))
    done = _resume(run, state_file, key, s, log)
    t0 = time.monotonic()
    for epoch in range(done.first, s.epochs + 1):
        _run_epoch(run, done, epoch, progress, log)
        _save_epoch_state(run, done, epoch, state_file, key, t0)
        if done.bad >= s.patience:
            log(f"  early stop: no better validation loss for {done.bad} epochs")
            break
    run.model.cpu()
    if done.best_state is not None:     # else no epoch ran (resumed past the last)
        run.model.load_state_dict(done.best_state)
    return Fitted(run.model, done, run.target_stats, data_hash, state_file,
                  done.seconds_before + time.monotonic() - t0)


def _start_fitting(td: TrainingData) -> Fitting:
    """The model (its arm pose standardised from the training targets), optimizer,
    schedule, loss and the two loaders; after `_seed_everything`, which the weights'
    initialisation draws on."""
    import torch
    from torch.utils.data import DataLoader

    from .model import ERP
    s = td.settings
    check_recipe(s, td.modality)
    model = ERP(s.task, td.modality.channels(s.norm.event_bins), s.norm.size, stem=s.stem,
                memory=s.memory, aux=s.aux_weight > 0)
    target_stats = None
    if s.task == "arm":
        target_stats = pose_stats(td.train_set.targets())
        model.head.set_target_stats(target_stats["mean"], target_stats["scale"])
    model = model.to(s.device)
    gen = torch.Generator().manual_seed(s.seed)
    # Up to OPEN_EPISODES training episodes, a plain shuffle (every file stays open);
    # beyond, shuffled blocks of episodes so that a file is opened once per epoch.
    order = ({"shuffle": True, "generator": gen}
             if len(td.train_episodes) <= OPEN_EPISODES else
             {"sampler": EpisodeBlockSampler(td.train_set.pairs[:, 0], OPEN_EPISODES, gen)})
    # Workers start afresh every epoch: a persistent loader draws its base seed from
    # the shuffle's generator once, where one without workers draws it every epoch,
    # and the second epoch's order would then depend on the worker count.
    stats: dict = {}
    if s.on_sequences:
        train_loader, val_loader, epoch_fn = _sequence_loaders(td, gen, stats)
    else:
        train_loader = DataLoader(td.train_set, batch_size=s.batch, **order,
                                  num_workers=s.num_workers, collate_fn=_collate)
        val_loader = DataLoader(td.val_set, batch_size=s.batch, shuffle=False,
                                num_workers=s.num_workers, collate_fn=_collate)
        epoch_fn = _epoch
    optimizer = torch.optim.Adam(model.parameters(), lr=s.lr, weight_decay=s.weight_decay)
    scheduler = (torch.optim.lr_scheduler.ReduceLROnPlateau(optimizer, mode="min",
                                                            **s.plateau)
                 if s.plateau else None)
    criterion = torch.nn.MSELoss() if s.loss == "mse" else torch.nn.SmoothL1Loss()
    zeroer = ZeroSubnormals(model, optimizer) if s.zero_subnormals else None
    return Fitting(s, td.modality, f"{s.task}-{td.modality}", model, optimizer, scheduler,
                   criterion, zeroer, gen, train_loader, val_loader, target_stats,
                   epoch_fn, stats)


def check_recipe(s: TrainSettings, modality: Modality) -> None:
    """ValueError, one line, for recipe options out of range or that cannot apply."""
    from .model import MEMORIES
    if s.memory not in MEMORIES:
        raise ValueError(f"unknown memory {s.memory!r} ({', '.join(MEMORIES)})")
    if not (math.isfinite(s.aux_weight) and s.aux_weight >= 0):
        raise ValueError(f"aux_weight must be a finite number >= 0, got {s.aux_weight}")
    if not 0 <= s.modality_dropout <= 1:
        raise ValueError(f"modality_dropout must be in [0, 1], got {s.modality_dropout}")
    if s.modality_dropout > 0 and len(modality.streams) < 2:
        raise ValueError(f"modality dropout needs two streams to drop one of; modality "
                         f"{modality} has one")
    if s.seq_len < 1 or s.lanes < 1 or s.burn_in < 0:
        raise ValueError(f"seq_len and lanes must be >= 1 and burn_in >= 0, got "
                         f"{s.seq_len}, {s.lanes} and {s.burn_in}")


def _sequence_loaders(td: TrainingData, generator, stats: dict):
    """The recipe's loaders (WindowBatches) and its epoch (sequence_epoch, the options
    bound); the target head's truth read from the episodes when it is on."""
    import functools

    from .sequence import WindowBatches, ModalityDropout, sequence_epoch, target_truth
    s = td.settings

    def truth_of(frames):
        if s.aux_weight <= 0:
            return None
        return [target_truth(path) for path in frames.paths]
    train = WindowBatches(td.train_set, s.lanes, s.seq_len, generator, truth_of(td.train_set),
                        s.burn_in)
    val = WindowBatches(td.val_set, s.lanes, s.seq_len, None, truth_of(td.val_set), s.burn_in)
    dropout = ModalityDropout(s.modality_dropout) if s.modality_dropout > 0 else None
    epoch_fn = functools.partial(sequence_epoch, loss=s.loss, aux_weight=s.aux_weight,
                                 dropout=dropout, generator=generator, stats=stats)
    return train, val, epoch_fn


def _resume(run: Fitting, state_file: Path, key: str, s: TrainSettings, log) -> FitProgress:
    """The progress to go on from: a resume state's, loaded into ``run`` (model,
    optimizer, schedule, the shuffle's and torch's generators), when it was saved by the
    same settings on the same data (``key``); else a fresh start."""
    import torch
    state = load_state(state_file, key, log)
    if state is None:
        return FitProgress()
    run.model.load_state_dict(state["model"])
    run.optimizer.load_state_dict(state["optimizer"])
    if run.scheduler is not None:
        run.scheduler.load_state_dict(state["scheduler"])
    run.generator.set_state(state["generator"])
    torch.set_rng_state(state["torch_rng"])
    bad = state["bad"]
    log(f"  resuming after epoch {state['epoch']} ({state_file.name})")
    return FitProgress(rows=state["rows"], best=state["best"], best_state=state["best_state"],
                       bad=bad, first=state["epoch"] + 1 if bad < s.patience else s.epochs + 1,
                       seconds_before=state["seconds"],
                       resumed=[*state["resumed"], state["epoch"]])


def _run_epoch(run: Fitting, done: FitProgress, epoch: int, progress: bool, log) -> None:
    """One epoch: train, check the weights, validate, log its line, keep the weights if
    they are the best so far (else count the epoch for early stopping), step the
    schedule. TrainingDiverged when a loss or a weight is not finite."""
    s, name = run.settings, run.name
    tag = f"{name} {epoch}/{s.epochs}"
    lr = run.optimizer.param_groups[0]["lr"]
    zeroer = run.zeroer
    zeroed_before, epoch_t0 = (zeroer.total if zeroer else 0), time.monotonic()
    tr = _finite_epoch(name, "training", epoch, run.model, run.train_loader, run.criterion,
                       run.optimizer, f"{tag} train", progress, s.device, after_step=zeroer,
                       epoch_fn=run.epoch_fn)
    aux_train = run.epoch_stats.get("aux_loss")
    # a last step can make a weight NaN with its batch's loss still finite; a
    # buffer (BatchNorm statistics) can go with no training loss seeing it at all
    broken = first_non_finite(run.model.state_dict())
    if broken is not None:
        raise TrainingDiverged(f"{name}: weight {broken} is not finite after epoch "
                               f"{epoch}; stopped, no checkpoint written")
    va = _finite_epoch(name, "validation", epoch, run.model, run.val_loader, run.criterion,
                       None, f"{tag} val", progress, s.device, epoch_fn=run.epoch_fn)
    # the name, not the Modality: the rows go into the resume state, which torch reads
    # back with weights_only (plain values only)
    done.rows.append({"modality": run.modality.value, "epoch": epoch, "train_loss": tr,
                      "val_loss": va, "lr": lr})
    log(f"  epoch {epoch}: train {tr:.5f}  val {va:.5f}  lr {lr:.2e}  "
        f"{time.monotonic() - epoch_t0:,.0f} s"
        + (f"  target head train {aux_train:.4f} val {run.epoch_stats['aux_loss']:.4f}"
           if s.aux_weight > 0 and aux_train is not None else "")
        + (f"  subnormals zeroed {zeroer.total - zeroed_before:,}" if zeroer else ""))
    if va < done.best:
        done.best, done.bad = va, 0
        done.best_state = {k: v.detach().to("cpu", copy=True)
                           for k, v in run.model.state_dict().items()}
    else:
        done.bad += 1
    if run.scheduler is not None:
        run.scheduler.step(va)


def _save_epoch_state(run: Fitting, done: FitProgress, epoch: int, state_file: Path,
                      key: str, t0: float) -> None:
    """Write the resume state after ``epoch`` (resume.save_state: atomically, refused
    when a value is not finite, which stops the training)."""
    import torch
    try:    # the weights are finite (checked in the epoch); Adam's moments need not be
        save_state(state_file, {
            "fingerprint": key, "epoch": epoch, "model": run.model.state_dict(),
            "optimizer": run.optimizer.state_dict(),
            "scheduler": run.scheduler.state_dict() if run.scheduler is not None else None,
            "generator": run.generator.get_state(), "torch_rng": torch.get_rng_state(),
            "rows": done.rows, "best": done.best, "best_state": done.best_state,
            "bad": done.bad, "seconds": done.seconds_before + time.monotonic() - t0,
            "resumed": done.resumed})
    except NonFiniteState as exc:
        raise TrainingDiverged(f"{run.name}: after epoch {epoch}, {exc}; stopped, no "
                               f"checkpoint written") from None


def finish(td: TrainingData, fitted: Fitted, out: Path) -> dict:
    """The finish step: the config (the model's, and the records of the dataset, the
    training and the recording's events), the checkpoint and the loss CSV written, the
    resume state removed.

    Parameters:
        td: the data step's result; fitted: the fit step's; out: where the outputs go.

    Returns:
        The config (less the version save_checkpoint adds).
    """
    import numpy as np
    import torch

    from .model import count_parameters
    s, done = td.settings, fitted.progress
    config = {**model_config(s.task, td.modality, s.norm, s.stem, s.memory, s.aux_weight > 0),
              "parameters": count_parameters(fitted.model),
              **({"target_stats": fitted.target_stats} if fitted.target_stats else {}),
              **({"event_frames": td.event_frames} if td.event_frames else {}),
              **({"emulator": td.emulator} if td.emulator else {}),
              "dataset": dataset_record(td, fitted.data_hash),
              "training": {"lr": s.lr, "weight_decay": s.weight_decay, "loss": s.loss,
                           "batch": s.batch, "device": s.device, "epochs": s.epochs,
                           "epochs_run": len(done.rows),
                           "patience": s.patience, "plateau": s.plateau,
                           "best_val_loss": done.best, "seed": s.seed,
                           "max_frames": s.max_frames,
                           **({"zero_subnormals": True} if s.zero_subnormals else {}),
                           **({"recipe": {k: getattr(s, k) for k in RECIPE_FIELDS}}
                              if s.on_sequences else {}),
                           "seconds": round(fitted.seconds, 2),
                           **({"resumed_after_epochs": done.resumed} if done.resumed else {})},
              "torch": torch.__version__, "numpy": np.__version__}
    save_checkpoint(fitted.model, config, out)
    write_losses_csv(done.rows, out / f"{s.task}-{td.modality}-losses.csv")
    fitted.state_file.unlink(missing_ok=True)
    return config


def _finite_epoch(name: str, kind: str, epoch: int, *args, epoch_fn=None, **kwargs) -> float:
    """`_epoch` (or ``epoch_fn``, the same signature), its mean loss checked too:
    TrainingDiverged, in one line, naming the variant, the pass ("training" or
    "validation"), the epoch and the batch, when a loss is not finite."""
    try:
        mean = (epoch_fn or _epoch)(*args, **kwargs)
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
    for m in Modality:
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


def record_name(first: Path, entry: dict) -> str:
    """An episode's name in a checkpoint's record: its file name in the first dataset
    (``first``), its absolute path in another (dataset_record)."""
    own = Path(entry.get("root", first))
    return entry["file"] if own == first else str((own / entry["file"]).resolve())


def dataset_record(td: TrainingData, data_hash: str) -> dict:
    """The config's "dataset" record: "path" (the first dataset), "hash" (of all,
    dataset.dataset_hash), "train_episodes" and "val_episodes", "train_frames",
    "val_frames", and "datasets": every dataset's {"path", "hash", "episodes"}.

    An episode of the first dataset is named by its file name, as a record of one dataset
    always named them; one of another dataset by its absolute path, so that a reader
    joining the record's path and a name (``Path(path) / name``) finds either.

    Parameters:
        td: the data step's result; data_hash: the hash of all its episodes.

    Returns:
        The record.
    """
    roots = td.roots or [td.root]
    datasets = []
    for r in roots:
        mine = [e for e in td.episodes if Path(e.get("root", td.root)) == r]
        datasets.append({"path": str(r), "hash": dataset_hash(r, mine),
                         "episodes": len(mine)})
    return {"path": str(td.root), "hash": data_hash,
            "train_episodes": [record_name(td.root, e) for e in td.train_episodes],
            "val_episodes": [record_name(td.root, e) for e in td.val_episodes],
            "train_frames": len(td.train_set), "val_frames": len(td.val_set),
            "datasets": datasets}


def settings_for(task: str, **overrides) -> TrainSettings:
    """The paper's settings for ``task`` with ``overrides`` (TrainSettings fields; None
    keeps the default): what `train` trains with, and what a sweep records per point."""
    return replace(paper_settings(task), **{k: v for k, v in overrides.items() if v is not None})


def train(data: str | Path | list[str | Path], out: str | Path, task: str,
          modalities: list[Modality | str], progress: bool = True, log=print,
          **overrides) -> dict[Modality, dict]:
    """Train each modality in turn with the paper's settings for ``task`` (``overrides``
    replace TrainSettings fields, e.g. epochs=2, norm=Normalisation(size=64)); returns
    each one's config. ``data``: a dataset directory, or a list of several that train
    together (`load_training_data`; DAgger's rounds beside the expert's recording)."""
    s = settings_for(task, **overrides)
    modalities = [Modality.parse(m) for m in modalities]
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
