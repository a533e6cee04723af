"""Float32 subnormals in a training's weights and optimizer state.

    zeroer = ZeroSubnormals(model, optimizer)
    optimizer.step(); zeroer()          # after every step; zeroer.total counts the zeroed
    count_subnormals(tensor)            # how many of a tensor's floats are subnormal

Weights that get no gradient from the data decay under weight decay until they are
subnormal (non-zero, below float32's smallest normal, 1.18e-38), which a CPU multiplies
through slow microcode. Zeroing them after every step (`sebvs train --zero-subnormals`)
is the software form of the CPU's flush-to-zero, the same on every machine and at any
thread count. The measurements, and why not the CPU's own mode: docs/policy.md,
"Subnormal weights".
"""
from __future__ import annotations


def subnormal_mask(t):
    """Where floating tensor ``t`` is subnormal: non-zero, below its dtype's smallest normal."""
    import torch
    return (t != 0) & (t.abs() < torch.finfo(t.dtype).tiny)


def count_subnormals(t) -> int:
    return int(subnormal_mask(t).sum())


def state_tensors(per_parameter_states):
    """The floating tensors of an optimizer's per-parameter states (``optimizer.state``'s
    values, or a state dict's ``["state"]`` values): Adam's moments, not its step count."""
    for state in per_parameter_states:
        yield from (v for v in state.values()
                    if hasattr(v, "is_floating_point") and v.is_floating_point()
                    and v.dim() > 0)


def _float_tensors(model, optimizer=None):
    yield from (t for t in model.state_dict().values() if t.is_floating_point())
    if optimizer is not None:
        yield from state_tensors(optimizer.state.values())


def zero_subnormals_(model, optimizer=None) -> int:
    """Set every subnormal entry of the model's floating parameters and buffers, and of the
    optimizer's per-parameter state (Adam's moments), to zero in place; how many were.
    One device sync per call (the count), not one per tensor."""
    import torch
    counts = []
    with torch.no_grad():
        for t in _float_tensors(model, optimizer):
            mask = subnormal_mask(t)
            counts.append(mask.sum())
            t.masked_fill_(mask, 0.0)
    return int(torch.stack(counts).sum()) if counts else 0


class ZeroSubnormals:
    """``zero_subnormals_(model, optimizer)`` as a callable for after each optimizer step;
    ``total`` counts the floats it zeroed."""

    def __init__(self, model, optimizer):
        self.model, self.optimizer, self.total = model, optimizer, 0

    def __call__(self) -> None:
        self.total += zero_subnormals_(self.model, self.optimizer)
