"""Per-episode scene randomisation: the data covers the world the policy is evaluated in.

A spec maps scene config keys to what each episode draws for them:

    [ ... ]          a list of choices, one drawn uniformly (repeat a value to weight it)
    {uniform = [lo, hi]}   a float drawn uniformly in [lo, hi]

e.g. in a topology's sim table:

    randomise = { variant = ["indoor", "outdoor"], lighting = ["nominal", "low", "flicker"],
                  target_speed = ["slow", "nominal", "fast"], rgb_blur = [0, 0, 0, 8] }

Keys are drawn in sorted order from a generator seeded by the episode seed and a fixed
stream tag, so the scene's own reset stream (seeded by the episode seed alone) is the same
with or without randomisation, and an episode's draw depends on its seed only: the same
episode seed gives the same config whichever process or worker plays it.

Every choice is checked against the scene when the spec is built (a bad value is an error
before the first episode, naming the key and the value); integrator and timestep are sim
settings, not randomisable.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from . import make_scene

STREAM_TAG = 0x52414E44             # "RAND": the randomiser's stream, apart from reset()'s
NOT_RANDOMISABLE = ("integrator", "timestep")


class SceneRandomiser:
    """Draws one scene config per episode from ``base`` (the topology's config) and ``spec``."""

    def __init__(self, scene: str, base: dict[str, Any], spec: dict[str, Any]):
        self.scene = scene
        self.base = dict(base)
        self.spec: dict[str, list | tuple[float, float]] = {}
        for key in sorted(spec):
            self.spec[key] = self._parse(key, spec[key])

    def _parse(self, key: str, rule: Any) -> list | tuple[float, float]:
        where = f"randomise.{key}"
        if key in NOT_RANDOMISABLE:
            raise ValueError(f"{where}: {key} is a sim setting, not a scene config key")
        if isinstance(rule, dict):
            if set(rule) != {"uniform"}:
                raise ValueError(f"{where}: a table must be {{uniform = [lo, hi]}}, "
                                 f"got keys {sorted(rule)}")
            bounds = rule["uniform"]
            ok = isinstance(bounds, (list, tuple)) and len(bounds) == 2 and all(
                isinstance(b, (int, float)) and not isinstance(b, bool) and math.isfinite(b)
                for b in bounds)
            if not ok or bounds[0] > bounds[1]:
                raise ValueError(f"{where}: uniform needs [lo, hi] with finite lo <= hi, "
                                 f"got {bounds!r}")
            lo, hi = float(bounds[0]), float(bounds[1])
            for value in (lo, hi):
                self._check(key, value)
            return (lo, hi)
        if not isinstance(rule, (list, tuple)) or not rule:
            raise ValueError(f"{where}: expected a non-empty list of choices or "
                             f"{{uniform = [lo, hi]}}, got {rule!r}")
        for value in rule:
            self._check(key, value)
        return list(rule)

    def _check(self, key: str, value: Any) -> None:
        try:
            make_scene(self.scene, **{**self.base, key: value})
        except ValueError as exc:
            raise ValueError(f"randomise.{key}: {value!r} is refused by the {self.scene} "
                             f"scene: {exc}") from None

    def draw(self, episode_seed: int) -> dict[str, Any]:
        """The scene config of the episode seeded ``episode_seed``."""
        rng = np.random.default_rng(np.random.SeedSequence([episode_seed, STREAM_TAG]))
        config = dict(self.base)
        for key, rule in self.spec.items():
            if isinstance(rule, tuple):
                config[key] = float(rng.uniform(rule[0], rule[1]))
            else:
                config[key] = rule[int(rng.integers(len(rule)))]
        return config

    def describe(self) -> str:
        parts = [f"{k} in [{r[0]:g}, {r[1]:g}]" if isinstance(r, tuple)
                 else f"{k} from {r}" for k, r in self.spec.items()]
        return ", ".join(parts) or "nothing"
