"""A test source like tests.data_actors.DataSource that also sends the sim's `proprio`.

Importable by the runtime's worker as ``tests.proprio_actors``. Tick k's proprioception is
[k, -k, k / 1000] (float32), named as the nav scene's, so a test can check that each row
got its own tick's.
"""
from __future__ import annotations

import numpy as np

from tests.data_actors import DataSource

NAMES = ["v_forward", "v_lateral", "yaw_rate"]


def expected_proprio(tick: int) -> np.ndarray:
    return np.array([tick, -tick, tick / 1000], np.float32)


class ProprioSource(DataSource):
    outputs = (*DataSource.outputs, "proprio")

    async def _tick(self) -> None:
        t = self.tick
        # before the other streams of the tick, as the sim sends it before the camera renders
        await self.emit("proprio", {"proprio": expected_proprio(t)}, tick=t,
                        t_sim=t / self.params.rate_hz,
                        meta={"names": NAMES, "episode": self.episode, "control": True})
        await super()._tick()
