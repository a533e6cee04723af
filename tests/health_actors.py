"""Actors used only by the run-health tests (importable by a worker as tests.health_actors)."""
from __future__ import annotations

import numpy as np

from sebvs_actors.policy import Policy


class NaNPolicy(Policy):
    """The policy actor, its checkpoint loaded and run as ever, whose every output is NaN:
    a diverged training however the checkpoint checks evolve."""

    async def setup(self) -> None:
        await super().setup()
        act = self.policies.act

        def nan_act(modality, **inputs):
            y, prep_ms, inf_ms = act(modality, **inputs)
            return np.full_like(y, np.nan), prep_ms, inf_ms

        self.policies.act = nan_act


class FlakyPolicy(Policy):
    """The policy actor whose rgb handler raises on control ticks FAIL_TICKS: no action
    for those ticks (a lockstep sim times out on them), an error counted by the input."""
    FAIL_TICKS = (3, 7)

    async def on_rgb(self, msg) -> None:
        if msg.meta.get("control") is not False and msg.tick in self.FAIL_TICKS:
            raise RuntimeError(f"flaky on tick {msg.tick}")
        await super().on_rgb(msg)
