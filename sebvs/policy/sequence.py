"""Training on sequences: lanes of consecutive ticks, the state carried across batches.

    truth = [target_truth(path) for path in episode_paths]         # [T, 3] each
    batches = LaneBatches(frames, lanes=8, length=8, generator=gen, truth=truth)
    for x, y, target, mask, reset in batches:   # x [B, L, C, S, S], y [B, L, 2 | 6], ...
        pred, aux, state = model.sequence(x, state, reset)

What the recipe options of issue 65, item 2 train with (a model with memory, the target
head, modality dropout); the paper's recipe keeps its shuffled frames (train.py `_epoch`).

Truncated backpropagation through time, with the state carried: each of B lanes plays its
share of the episodes in order, L ticks per batch. A batch's loss backpropagates through
its L ticks; the state it ends with starts the lane's next batch, detached, so a lane's
GRU has seen its episode from the first tick, as the policy actor's does in closed loop.
A lane starts a new episode with the state reset (``reset`` [B, L] marks the tick), and
a lane whose episode ends inside a batch is padded there (``mask`` False, no loss). The
episodes are shuffled into lanes every epoch (seeded), each to the lane with the fewest
ticks so far, so the lanes end together.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sebvs.data.episode import open_episode

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


@dataclass
class _Lane:
    """One lane's episodes for an epoch and where it is in them."""
    queue: list[np.ndarray]          # item indices of each episode still to play
    ticks: int = 0                   # ticks assigned (for balancing)
    current: np.ndarray | None = None
    at: int = 0


class LaneBatches:
    """An epoch of sequence batches over a dataset of frames (an EpisodeFrames).

    Each item is (x float32 [B, L, C, S, S], y float32 [B, L, 2 | 6], truth float32
    [B, L, 3] (zeros where no truth is given), mask bool [B, L] (False: padding),
    reset bool [B, L] (True: the lane's state starts afresh before this tick)), as torch
    tensors.

    Args:
        frames: an EpisodeFrames; its items run in episode order, tick by tick.
        lanes: B; length: L, the ticks backpropagated through per batch.
        generator: a torch.Generator to shuffle the episodes into lanes each epoch; None
            keeps the index order (validation).
        truth: per episode of ``frames`` (its position), float32 [T, 3] from
            `target_truth`, or None.
    """

    def __init__(self, frames, lanes: int, length: int, generator=None,
                 truth: list[np.ndarray] | None = None):
        if lanes < 1 or length < 1:
            raise ValueError(f"lanes and length must be >= 1, got {lanes} and {length}")
        self.frames, self.lanes, self.length = frames, lanes, length
        self.generator, self.truth = generator, truth
        ep = frames.pairs[:, 0]
        order = np.argsort(ep, kind="stable")
        starts = np.flatnonzero(np.r_[True, ep[order][1:] != ep[order][:-1]])
        self.episodes = np.split(order, starts[1:]) if len(order) else []

    def __len__(self) -> int:
        """Batches in an epoch: exact without shuffling; with it, the balanced share
        (the greedy assignment may need one more)."""
        chunks = [math.ceil(len(e) / self.length) for e in self.episodes]
        if self.generator is None:
            return max((lane.ticks for lane in self._assign(range(len(chunks)))), default=0)
        return math.ceil(sum(chunks) / self.lanes)

    def _assign(self, order) -> list[_Lane]:
        """Episodes (in ``order``) to lanes, each to the lane with the fewest batches so
        far; ``ticks`` counts a lane's batches (an episode's ceil(len / L))."""
        lanes = [_Lane([]) for _ in range(self.lanes)]
        for e in order:
            lane = min(lanes, key=lambda la: la.ticks)
            lane.queue.append(self.episodes[e])
            lane.ticks += math.ceil(len(self.episodes[e]) / self.length)
        return lanes

    def __iter__(self):
        import torch
        order = (torch.randperm(len(self.episodes), generator=self.generator).tolist()
                 if self.generator is not None else range(len(self.episodes)))
        lanes = self._assign(order)
        for lane in lanes:
            lane.queue.reverse()        # pop() from the end plays them in order
        while any(lane.queue or lane.current is not None for lane in lanes):
            yield self._batch(lanes, torch)

    def _batch(self, lanes: list[_Lane], torch):
        rows = [self._lane_rows(lane) for lane in lanes]
        b, n = len(lanes), self.length
        x = y = None        # allocated at the first item, whose shapes they take
        truth = np.zeros((b, n, TRUTH_WIDTH), np.float32)
        mask = np.zeros((b, n), bool)
        reset = np.stack([starts for _, starts in rows])
        for li, (index, _) in enumerate(rows):
            for t, item in enumerate(index):
                if item < 0:
                    continue
                xi, yi = self.frames[int(item)]
                if x is None:
                    x = np.zeros((b, n, *xi.shape), np.float32)
                    y = np.zeros((b, n, *yi.shape), np.float32)
                x[li, t], y[li, t] = xi, yi
                mask[li, t] = True
                if self.truth is not None:
                    ei, tick = (int(v) for v in self.frames.pairs[item])
                    truth[li, t] = self.truth[ei][tick]
        return tuple(torch.from_numpy(a) for a in (x, y, truth, mask, reset))

    def _lane_rows(self, lane: _Lane) -> tuple[np.ndarray, np.ndarray]:
        """The next L item indices of a lane (-1: padding) and where its state resets."""
        index = np.full(self.length, -1, np.int64)
        starts = np.zeros(self.length, bool)
        if lane.current is None:
            if not lane.queue:
                starts[0] = True        # an idle lane: nothing carried into its padding
                return index, starts
            lane.current, lane.at = lane.queue.pop(), 0
            starts[0] = True
        take = lane.current[lane.at:lane.at + self.length]
        index[:len(take)] = take
        lane.at += len(take)
        if lane.at >= len(lane.current):
            lane.current = None         # the next batch starts the lane's next episode
        return index, starts


@dataclass(frozen=True)
class ModalityDropout:
    """Training-time removal of one stream of a fused input, so that neither is ignored.

    With probability ``rate``, a lane's batch (its L ticks) loses one of the two streams,
    each as likely: its RGB planes (the first ``rgb_planes``) or the rest (events, or
    rgb+diff's difference) set to zero, what a black frame or a still scene gives. Fused
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
    """One pass over LaneBatches; trains if an optimizer is given (train.py's `_epoch`,
    for sequences). ``criterion`` is unused (the losses are masked: `sequence_losses`).

    Parameters:
        model: an ERP; batches: LaneBatches; optimizer, desc, progress, device,
            after_step: as `_epoch`.
        loss: the action loss's name; aux_weight: the target head's weight in the
            trained loss; dropout: a ModalityDropout (training only) or None;
            generator: the torch.Generator dropout draws from.
        stats: a dict, if given, gets "aux_loss": the target head's mean loss.

    Returns:
        The mean action loss per tick (what early stopping compares). NonFiniteLoss
        (train.py) at the first batch whose trained loss is not finite.
    """
    import torch
    from tqdm import tqdm

    from .train import NonFiniteLoss, optimise
    training = optimizer is not None
    model.train(training)
    total = head_total = 0.0
    n = 0
    state = model.initial_state(batches.lanes).to(device)
    bar = tqdm(batches, desc=desc, unit="batch", leave=False, disable=not progress,
               dynamic_ncols=True)
    with torch.set_grad_enabled(training):
        for batch, (x, y, truth, mask, reset) in enumerate(bar, 1):
            if training and dropout is not None:
                x = dropout.apply(x, generator)
            x, y, truth, mask, reset = (a.to(device, non_blocking=True)
                                        for a in (x, y, truth, mask, reset))
            b, t = y.shape[:2]
            target = model.loss_space(y.reshape(b * t, -1)).reshape(b, t, -1)
            pred, aux, state = model.sequence(x, state, reset)
            action, head = sequence_losses(pred, target, aux, truth, mask, loss)
            total_loss = action if head is None else action + aux_weight * head
            if training:
                optimise(total_loss, optimizer, after_step)
            state = state.detach()
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
