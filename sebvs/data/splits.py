"""Topology-seed ranges of the evaluation protocol: which seeds recordings use, which the
evaluations we tune against use, and which stay held out.

    train  0 - 999              `sebvs record` (the shipped datasets used 0-8)
    dev    1,000 - 99,999       `sebvs eval` by default (first seed 1000, the seed of every
                                figure in docs/results.md): evaluate and iterate here
    test   100,000 - 199,999    held out: `sebvs eval --split test` (first seed 100,000);
                                `sebvs record` refuses these seeds

Reserving topology seeds reserves episodes: the sim's seed is the topology seed through
Topology.actor_seed (one-to-one on the topology seeds 0 <= seed < 2**31, and every seed
outside that range is refused, by the topology loader, the env and `sebvs eval`: a larger
one would wrap around onto a smaller one's, a test seed's among them), and episode k's seed is
SeedSequence([sim seed, k]) (actors/sim.py episode_seed), so a topology seed that no
recording used gives episodes that no recording saw (up to a collision of the 32-bit
episode seed: about 2e-4 for 4,000 recorded against 200 evaluated episodes). Seeds at
200,000 and above belong to no split; `sebvs eval --seed N` runs them as "custom".
"""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class SeedRange:
    name: str
    first: int
    last: int       # inclusive

    def __contains__(self, seed: object) -> bool:
        return isinstance(seed, int) and self.first <= seed <= self.last

    def __str__(self) -> str:
        return f"{self.first}-{self.last}"


SPLITS = {r.name: r for r in (SeedRange("train", 0, 999), SeedRange("dev", 1_000, 99_999),
                              SeedRange("test", 100_000, 199_999))}
EVAL_SPLITS = ("dev", "test")      # what `sebvs eval --split` offers
DEFAULT_EVAL_SPLIT = "dev"


def split_of(seed: int) -> str | None:
    """The split whose range holds this topology seed (None: no split's)."""
    return next((r.name for r in SPLITS.values() if seed in r), None)


def check_recording_seed(seed: int) -> str | None:
    """Raise ValueError (one line) for a topology seed a recording must not use: the test
    range, which is held out only as long as nothing is ever recorded from it. Returns a
    warning for a dev seed (evaluations tuned on dev would then include training
    episodes), None otherwise."""
    test = SPLITS["test"]
    if seed in test:
        raise ValueError(f"topology seed {seed} is in the test split's reserved range "
                         f"({test}), which no recording may use; record with a train seed "
                         f"({SPLITS['train']})")
    if seed in SPLITS["dev"]:
        return (f"topology seed {seed} is in the dev split's range ({SPLITS['dev']}): "
                f"`sebvs eval` evaluates on these episodes by default")
    return None
