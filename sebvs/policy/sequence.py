"""Training on sequences: shuffled windows of consecutive ticks, each with a burn-in.

    truth = [target_truth(path) for path in episode_paths]         # [T, 3] each
    batches = WindowBatches(frames, lanes=4, length=8, generator=gen, truth=truth, burn_in=8)
    for burn, burn_valid, x, y, truth, mask in batches:    # x [B, L, C, S, S], ...
        _, _, state = model.sequence(burn, state0, valid=burn_valid)      # no gradient
        pred, aux, _ = model.sequence(x, state.detach())

What the recipe options of issue 65, item 2 train with (a model with memory, the target
head, modality dropout); the paper's recipe keeps its shuffled frames (train.py `_epoch`).

Truncated backpropagation through time with a burn-in: each episode is cut into windows of
L ticks, the windows of all episodes shuffled into batches of B. A window's state starts
from what the W ticks before it in its episode leave (run forward without gradient), the
loss backpropagates through its L ticks. The first window of an episode starts from the
initial state, as the actor's first tick does; the padding of a short window or burn-in
carries no loss and does not move the state.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sebvs.data.episode import open_episode

from .steps import NonFiniteLoss, optimise

# the target head's truth per tick: [centroid u / width, v / height, visible]
TRUTH_WIDTH = 3
# the centroid's loss unit, as a fraction of the image: an error of one 16 px patch at 160
# px (0.1) is two units, in Smooth L1's linear zone; a pixel (0.006), in its quadratic zone
CENTROID_UNIT = 0.05


def target_truth(path: str | Path) -> np.ndarray:
    """The target head's labels of one episode, from the sim's truth it recorded.

    Parameters:
        path: the episode file (truth/centroid [T, 2] px, truth/visible [T], and
            truth/image [T, 2] px or the rgb frames' size).

    Returns:
        float32 [T, 3]: centroid u / width, v / height (0 where not visible) and visible
        (1 or 0). ValueError, one line naming the file, when the episode has no such
        truth (the aux head needs a recording whose scene reports its target: nav's).
    """
    with open_episode(path) as ep:
        truth = ep.truth
        missing = [k for k in ("centroid", "visible") if k not in truth]
        if missing:
            raise ValueError(f"{path}: no truth/{' or truth/'.join(missing)}: the target "
                             f"head (aux_weight > 0) needs the sim's target truth per tick")
        centroid = np.asarray(truth["centroid"][:], np.float64)
        visible = np.asarray(truth["visible"][:], np.float64)
        if "image" in truth:
            image = np.asarray(truth["image"][:], np.float64)
        else:
            h, w = ep.rgb.shape[1:3]
            image = np.broadcast_to(np.array([w, h], np.float64), centroid.shape)
    seen = (visible > 0.5) & np.isfinite(centroid).all(axis=1) & (image > 0).all(axis=1)
    out = np.zeros((len(centroid), TRUTH_WIDTH), np.float32)
    out[seen, :2] = np.clip(centroid[seen] / image[seen], 0.0, 1.0)
    out[:, 2] = seen
    return out


class WindowBatches:
    """An epoch of sequence batches over a dataset of frames (an EpisodeFrames): every
    episode cut into windows of L consecutive ticks, the windows shuffled across episodes
    (seeded), B of them a batch, each with the W ticks before it as its burn-in.

    Each item is (burn float32 [B, W, C, S, S], burn_valid bool [B, W], x float32
    [B, L, C, S, S], y float32 [B, L, 2 | 6], truth float32 [B, L, 3] (zeros where no truth
    is given), mask bool [B, L] (False: padding)), as torch tensors. A window's burn-in is
    the W ticks of its episode before it, left-padded (burn_valid False) where the episode
    has fewer: the first window of an episode starts from the initial state, as the
    actor's first tick does. Every tick is in exactly one window per epoch.

    Why shuffled windows and not lanes that play their episodes through: lanes that march
    through 200-tick episodes in step feed the optimizer the same few episodes' next ticks
    batch after batch, a stream far from independent draws, and on the nav dev data their
    training loss stayed at a constant command's (0.033) for 7-10 epochs with or without
    the GRU, where shuffled frames fell to 0.014-0.028 (research/event_policies/log.md).
    Windows drawn across all episodes give every batch B independent places; the burn-in
    (R2D2's, Kapturowski et al. 2019) gives each window the state its episode's ticks before
    it would have left, without backpropagating through them.

    Args:
        frames: an EpisodeFrames; its items run in episode order, tick by tick.
        lanes: B, windows per batch; length: L, the ticks backpropagated through.
        generator: a torch.Generator to shuffle the windows each epoch; None keeps them
            in index order (validation).
        truth: per episode of ``frames`` (its position), float32 [T, 3] from
            `target_truth`, or None.
        burn_in: W, the ticks before a window that set its initial state (0: none).
    """

    def __init__(self, frames, lanes: int, length: int, generator=None,
                 truth: list[np.ndarray] | None = None, burn_in: int = 0):
        if lanes < 1 or length < 1 or burn_in < 0:
            raise ValueError(f"lanes and length must be >= 1 and burn_in >= 0, got {lanes}, "
                             f"{length} and {burn_in}")
        self.frames, self.lanes, self.length, self.burn_in = frames, lanes, length, burn_in
        self.generator, self.truth = generator, truth
        ep = frames.pairs[:, 0]
        order = np.argsort(ep, kind="stable")
        starts = np.flatnonzero(np.r_[True, ep[order][1:] != ep[order][:-1]])
        episodes = np.split(order, starts[1:]) if len(order) else []
        # (episode items, window start) of every window, in index order
        self.windows = [(items, s) for items in episodes for s in range(0, len(items), length)]

    def __len__(self) -> int:
        return math.ceil(len(self.windows) / self.lanes)

    def __iter__(self):
        import torch
        order = (torch.randperm(len(self.windows), generator=self.generator).tolist()
                 if self.generator is not None else list(range(len(self.windows))))
        for first in range(0, len(order), self.lanes):
            yield self._batch([self.windows[k] for k in order[first:first + self.lanes]], torch)

    def _batch(self, windows, torch):
        b, n, w = len(windows), self.length, self.burn_in
        x = y = burn = None        # allocated at the first item, whose shapes they take
        truth = np.zeros((b, n, TRUTH_WIDTH), np.float32)
        mask = np.zeros((b, n), bool)
        burn_valid = np.zeros((b, w), bool)
        for li, (items, start) in enumerate(windows):
            for t, item in enumerate(items[start:start + n]):
                xi, yi = self.frames[int(item)]
                if x is None:
                    x = np.zeros((b, n, *xi.shape), np.float32)
                    y = np.zeros((b, n, *yi.shape), np.float32)
                    burn = np.zeros((b, w, *xi.shape), np.float32)
                x[li, t], y[li, t] = xi, yi
                mask[li, t] = True
                if self.truth is not None:
                    ei, tick = (int(v) for v in self.frames.pairs[item])
                    truth[li, t] = self.truth[ei][tick]
            before = items[max(0, start - w):start]
            for t, item in enumerate(before, w - len(before)):
                burn[li, t] = self.frames[int(item)][0]
                burn_valid[li, t] = True
        return tuple(torch.from_numpy(a) for a in (burn, burn_valid, x, y, truth, mask))


@dataclass(frozen=True)
class ModalityDropout:
    """Training-time removal of one stream of a fused input, so that neither is ignored.

    With probability ``rate``, a window (its L ticks and burn-in) loses one of the two
    streams, each as likely: its RGB planes (the first ``rgb_planes``) or the rest (events,
    or rgb+diff's difference) set to zero, what a black frame or a still scene gives. Fused
    modalities only; the caller passes it for those.
    """
    rate: float
    rgb_planes: int = 3

    def __post_init__(self):
        if not 0.0 <= self.rate <= 1.0:
            raise ValueError(f"modality_dropout must be in [0, 1], got {self.rate}")

    def apply(self, x, generator):
        """x [B, L, C, S, S] (zeroed in place where dropped); returns x."""
        import torch
        if self.rate <= 0:
            return x
        b = x.shape[0]
        drop = torch.rand(b, generator=generator) < self.rate
        rgb = torch.rand(b, generator=generator) < 0.5
        for li in torch.nonzero(drop).flatten().tolist():
            if rgb[li]:
                x[li, :, :self.rgb_planes] = 0
            else:
                x[li, :, self.rgb_planes:] = 0
        return x


def sequence_losses(pred, target, aux, truth, mask, loss: str):
    """(action loss, target-head loss or None), each a mean over the unmasked ticks.

    Parameters:
        pred, target: [B, L, K] in the loss space (ERP.sequence, ERP.loss_space).
        aux: [B, L, 3] TargetHead output or None; truth: [B, L, 3] (`target_truth`).
        mask: [B, L] bool; loss: "mse" or "smooth_l1" (the action's).

    Returns:
        The action loss (mean over valid ticks and outputs) and the target head's: BCE of
        visibility over valid ticks plus Smooth L1 of the centroid in CENTROID_UNITs over
        the valid ticks where the target is visible.
    """
    import torch.nn.functional as F
    valid = mask.reshape(-1)
    k = pred.shape[-1]
    p, t = pred.reshape(-1, k)[valid], target.reshape(-1, k)[valid]
    action = F.mse_loss(p, t) if loss == "mse" else F.smooth_l1_loss(p, t)
    if aux is None:
        return action, None
    a, tr = aux.reshape(-1, TRUTH_WIDTH)[valid], truth.reshape(-1, TRUTH_WIDTH)[valid]
    head = F.binary_cross_entropy_with_logits(a[:, 2], tr[:, 2])
    seen = tr[:, 2] > 0.5
    if bool(seen.any()):
        head = head + F.smooth_l1_loss(a[seen, :2] / CENTROID_UNIT,
                                       tr[seen, :2] / CENTROID_UNIT)
    return action, head


def sequence_epoch(model, batches, criterion=None, optimizer=None, desc: str = "",
                   progress: bool = True, device: str = "cpu", after_step=None, *,
                   loss: str = "mse", aux_weight: float = 0.0,
                   dropout: ModalityDropout | None = None, generator=None,
                   stats: dict | None = None):
    """One pass over WindowBatches; trains if an optimizer is given (train.py's `_epoch`,
    for sequences). ``criterion`` is unused (the losses are masked: `sequence_losses`).

    Parameters:
        model: an ERP; batches: WindowBatches; optimizer, desc, progress, device,
            after_step: as `_epoch`.
        loss: the action loss's name; aux_weight: the target head's weight in the
            trained loss; dropout: a ModalityDropout (training only) or None;
            generator: the torch.Generator dropout draws from.
        stats: a dict, if given, gets "aux_loss": the target head's mean loss.

    Returns:
        The mean action loss per tick (what early stopping compares). NonFiniteLoss
        (steps.py) at the first batch whose trained loss is not finite.
    """
    import torch
    from tqdm import tqdm

    training = optimizer is not None
    model.train(training)
    total = head_total = 0.0
    n = 0
    bar = tqdm(batches, desc=desc, unit="batch", leave=False, disable=not progress,
               dynamic_ncols=True)
    with torch.set_grad_enabled(training):
        for batch, (burn, burn_valid, x, y, truth, mask) in enumerate(bar, 1):
            if training and dropout is not None:
                # the same stream dropped over a window's burn-in and its ticks
                keep = torch.cat([burn, x], dim=1)
                dropout.apply(keep, generator)
                burn, x = keep[:, :burn.shape[1]], keep[:, burn.shape[1]:]
            burn, burn_valid, x, y, truth, mask = (
                a.to(device, non_blocking=True) for a in (burn, burn_valid, x, y, truth, mask))
            b, t = y.shape[:2]
            state = model.initial_state(b).to(device)
            if model.state_size and burn.shape[1]:
                with torch.no_grad():
                    _, _, state = model.sequence(burn, state, valid=burn_valid)
            target = model.loss_space(y.reshape(b * t, -1)).reshape(b, t, -1)
            pred, aux, _ = model.sequence(x, state.detach(), valid=mask)
            action, head = sequence_losses(pred, target, aux, truth, mask, loss)
            total_loss = action if head is None else action + aux_weight * head
            if training:
                optimise(total_loss, optimizer, after_step)
            value = total_loss.item()
            if not math.isfinite(value):
                bar.close()
                raise NonFiniteLoss(batch, value)
            ticks = int(mask.sum())
            total += action.item() * ticks
            head_total += (head.item() if head is not None else 0.0) * ticks
            n += ticks
            bar.set_postfix(loss=f"{total / max(n, 1):.4g}")
    bar.close()
    if stats is not None:
        stats["aux_loss"] = head_total / max(n, 1)
    return total / max(n, 1)
