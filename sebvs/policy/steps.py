"""What every training pass does per batch: one optimizer step, and the stop at a loss
that is not finite. train.py's shuffled frames and sequence.py's windows share it."""
from __future__ import annotations


class NonFiniteLoss(ValueError):
    """Raised by a pass at the first batch (counted from 1) whose loss is not finite."""

    def __init__(self, batch: int, value: float):
        super().__init__(f"loss is {value} at batch {batch}")
        self.batch, self.value = batch, value


def optimise(loss, optimizer, after_step=None) -> None:
    """One optimizer step on ``loss``, then ``after_step()`` if given (the subnormal
    zeroing)."""
    optimizer.zero_grad(set_to_none=True)
    loss.backward()
    optimizer.step()
    if after_step is not None:
        after_step()
