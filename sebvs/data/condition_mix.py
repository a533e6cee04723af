"""A dataset's share of hard conditions: which episode numbers ``sebvs record --hard-share``
records under a named condition of sebvs/conditions.py, and which under the topology's
randomised mix.

    from fractions import Fraction
    from sebvs.data.condition_mix import ConditionMix
    mix = ConditionMix(Fraction(1, 6), ("hdr", "dusk_fast", "flicker_120"))
    [mix.condition_of(k) for k in range(9)]
    # ['randomised', 'randomised', 'hdr', 'randomised', 'randomised', 'randomised',
    #  'randomised', 'randomised', 'dusk_fast']
    mix.counts(70)      # {'hdr': 4, 'dusk_fast': 4, 'flicker_120': 4, 'randomised': 58}

The rule (interleaved, by episode number alone): with H(n) = floor(n * F + 1/2), the number
of hard episodes among the first n (n * F rounded half up), episode k is hard when
H(k + 1) > H(k), and the j-th hard episode (j = H(k), counting from 0) gets the j-th
condition of the list, cycling. So:

- any prefix 0..n-1 of the dataset holds exactly round(F * n) hard episodes, spread evenly
  (not bunched at the start), and the conditions take turns among them;
- an episode's condition depends on its number, the share and the list only, never on
  --episodes N: a resumed, filled or extended recording assigns every number as the first
  run did, and the plan a dataset stores is (share, conditions, scenario), without N.

The share is exact (a Fraction: "1/6" is one in six, not 0.1666...), so the rule needs no
floating-point tie-breaking. A condition named twice in the list gets twice the turns.

A hard episode's scene (`mix_left`): the condition fixes what it names, and the episode
draws the rest from the topology's randomised mix, so hard hdr episodes still come
indoors and outdoors, at every target speed, blurred or not:

    mix_left({"variant": ["indoor", "outdoor"], "lighting": ["nominal", "low"],
              "flicker_hz": {"uniform": [5.0, 20.0]}, "rgb_blur": [0, 8]}, {"lighting"})
    # {"variant": ["indoor", "outdoor"], "rgb_blur": [0, 8]}

The stored plan says so (MIX_KEPT): a dataset whose hard episodes were recorded by an
earlier version, in the topology's one scene, is refused rather than extended in two
recipes.
"""
from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from fractions import Fraction

RANDOMISED = "randomised"       # the condition name of an episode of the randomised mix
PLAN_KEY = "condition_mix"      # where index.json keeps a dataset's plan
RULE = "interleaved-1"          # the rule above; a dataset of another rule is refused
# a plan's field saying its hard episodes draw from the mix what their condition leaves
# open (mix_left); a plan without it is an earlier version's, whose hard episodes drew
# nothing (the topology's default scene), and is refused
MIX_KEPT = "mix_kept"

# scene config keys that only mean something through another key's value: flicker_hz is
# the rate of lighting "flicker", belt_speed the speed of conveyor "moving"
# (sebvs/sim/nav.py, arm.py)
QUALIFIED_BY: dict[str, str] = {"flicker_hz": "lighting", "belt_speed": "conveyor"}

# The hard conditions a task records by default: the physical sensor pair's conditions
# under which a frame camera is expected to fail or struggle (research/sensors/plan.md,
# "What the physics predicts"), one per kind of hard light.
# nav: hdr (the target in shade, below SNR 1 for the frame camera), dusk_fast (3 lux with
#   the target at 1 m/s: long exposures and motion at once) and flicker_120 (60 Hz mains:
#   the light itself changes faster than any frame).
# arm: sebvs/conditions.py gives the arm no mains-flicker condition, so its hard light is
#   hdr (a lamp beside the belt) and dusk (3 lux): hdr, dusk_moving (dusk on the moving
#   belt) and fast_hdr (the lamp with the fastest belt, as dusk_fast pairs nav's dusk
#   with its fastest target). fast_physical is left out: its light is nominal.
DEFAULT_HARD: dict[str, tuple[str, ...]] = {
    "nav": ("hdr", "dusk_fast", "flicker_120"),
    "arm": ("hdr", "dusk_moving", "fast_hdr"),
}


def mix_left(randomise: Mapping, fixed: Iterable[str]) -> dict:
    """What a hard episode still draws from the topology's randomised mix: the table
    without the keys its condition (and scenario) fix, and without the keys that qualify
    a fixed one (QUALIFIED_BY: flicker_hz when the lighting is fixed, belt_speed when the
    conveyor is). The rule goes one way: a qualifier drawn beside a fixed lighting would
    change the condition (ideal8 "flicker" is 10 Hz, hdr has no flicker rate at all),
    while a fixed qualifier (flicker_120's 120 Hz) comes with its key in every shipped
    condition.

    Parameters:
        randomise: the topology's sim `randomise` table (sebvs/sim/randomise.py).
        fixed: the sim config keys the condition's and the scenario's overrides set.

    Returns:
        The rest of the table, its rules as given, in its order.
    """
    fixed = set(fixed)
    return {key: rule for key, rule in randomise.items()
            if key not in fixed and QUALIFIED_BY.get(key) not in fixed}


def parse_share(text: str) -> Fraction:
    """--hard-share: a share 0 <= F <= 1, as a decimal ("0.25") or a fraction ("1/6").

    Parameters:
        text: what the user typed.

    Returns:
        The exact share. ValueError, in one line, for anything else.
    """
    try:
        share = Fraction(text.strip())
    except (ValueError, ZeroDivisionError):
        raise ValueError(f"--hard-share {text!r}: expected a share between 0 and 1, as a "
                         f"decimal (0.25) or a fraction (1/6)") from None
    if not 0 <= share <= 1:
        raise ValueError(f"--hard-share {text!r}: a share is between 0 and 1")
    return share


def parse_conditions(text: str) -> tuple[str, ...]:
    """--hard-conditions: comma-separated condition names ("hdr,dusk_fast"), in order.

    Returns:
        The names. ValueError, in one line, for an empty list or an empty name.
    """
    names = tuple(n.strip() for n in text.split(","))
    if not text.strip() or any(not n for n in names):
        raise ValueError(f"--hard-conditions {text!r}: expected condition names separated "
                         f"by commas, e.g. hdr,dusk_fast")
    return names


def default_conditions(task_name: str) -> tuple[str, ...]:
    """The hard conditions a task records when --hard-conditions is not given.

    Returns:
        DEFAULT_HARD's list. ValueError, in one line, for a task without one.
    """
    if task_name not in DEFAULT_HARD:
        raise ValueError(f"--hard-share: task {task_name!r} has no named hard conditions "
                         f"(tasks with them: {', '.join(DEFAULT_HARD)})")
    return DEFAULT_HARD[task_name]


@dataclass(frozen=True)
class ConditionMix:
    """A share of a dataset's episodes under hard conditions, by episode number (the
    module's rule).

    Parameters:
        share: the hard share F, 0 <= F <= 1.
        conditions: the hard conditions the hard episodes take in turn (at least one).
        scenario: the scenario the hard episodes are recorded in (None: the topology's
            scene as written), as `sebvs record --scenario`.
    """
    share: Fraction
    conditions: tuple[str, ...]
    scenario: str | None = None

    def __post_init__(self) -> None:
        if not 0 <= self.share <= 1:
            raise ValueError(f"hard share {self.share}: a share is between 0 and 1")
        if not self.conditions or any(not c or c == RANDOMISED for c in self.conditions):
            raise ValueError(f"hard conditions {list(self.conditions)}: expected at least "
                             f"one condition name (not {RANDOMISED!r})")

    def hard_among_first(self, n: int) -> int:
        """H(n): how many of episodes 0..n-1 are hard, n * F rounded half up."""
        return int((n * self.share + Fraction(1, 2)) // 1)

    def condition_of(self, k: int) -> str:
        """The condition episode number k is recorded under: a hard condition's name, or
        RANDOMISED."""
        if k < 0:
            raise ValueError(f"episode number {k}: numbers start at 0")
        j = self.hard_among_first(k)
        if self.hard_among_first(k + 1) == j:
            return RANDOMISED
        return self.conditions[j % len(self.conditions)]

    def assign(self, numbers: Iterable[int]) -> dict[int, str]:
        """Each episode number's condition, in the order given."""
        return {k: self.condition_of(k) for k in numbers}

    def counts(self, n: int) -> dict[str, int]:
        """Episodes per condition among 0..n-1: the hard ones in list order (each name once),
        then RANDOMISED."""
        out = dict.fromkeys(self.conditions, 0)
        out[RANDOMISED] = 0
        for c in self.assign(range(n)).values():
            out[c] += 1
        return out

    def flags(self) -> str:
        """The command line that asks for this mix: "--hard-share 1/6 --hard-conditions
        hdr,dusk_fast,flicker_120" (and "--scenario S")."""
        text = f"--hard-share {self.share} --hard-conditions {','.join(self.conditions)}"
        return text + (f" --scenario {self.scenario}" if self.scenario else "")

    def to_json(self) -> dict:
        """The plan as index.json keeps it (PLAN_KEY), with MIX_KEPT: the hard episodes
        draw from the mix what their condition leaves open."""
        return {"rule": RULE, "share": str(self.share), "conditions": list(self.conditions),
                "scenario": self.scenario, MIX_KEPT: True}

    @classmethod
    def from_json(cls, data: Mapping, where: str) -> "ConditionMix":
        """The plan a dataset stored; ValueError, in one line naming `where`, for one this
        version cannot read (another rule, or not a plan)."""
        try:
            if data.get("rule") != RULE:
                raise ValueError(f"rule {data.get('rule')!r}")
            return cls(Fraction(str(data["share"])), tuple(str(c) for c in data["conditions"]),
                       data.get("scenario"))
        except (AttributeError, KeyError, TypeError, ValueError, ZeroDivisionError) as exc:
            raise ValueError(f"{where}: {PLAN_KEY} is not a hard-share plan this version "
                             f"reads ({exc}); record into another folder") from None


def condition_runs(assigned: Mapping[int, str]) -> list[tuple[str, int, int]]:
    """Maximal runs of consecutive episode numbers under one condition, each (condition,
    a, b) for numbers [a, b): what one topology run can record, since a condition's
    overrides hold for a whole run. {0: "x", 1: "x", 2: "y", 4: "y"} -> [("x", 0, 2),
    ("y", 2, 3), ("y", 4, 5)]."""
    runs: list[tuple[str, int, int]] = []
    for k in sorted(assigned):
        c = assigned[k]
        if runs and runs[-1][0] == c and runs[-1][2] == k:
            runs[-1] = (c, runs[-1][1], k + 1)
        else:
            runs.append((c, k, k + 1))
    return runs


def check_dataset_plan(stored: Mapping | None, asked: ConditionMix | None, *, episodes: int,
                       where: str) -> None:
    """Whether a recording asking for `asked` may add to a dataset: refused when the
    dataset holds episodes and was planned otherwise (another share, other conditions or
    scenario, or a plan where none is asked, or none where one is), or by an earlier
    version whose hard episodes drew nothing from the mix (a plan without MIX_KEPT).

    Parameters:
        stored: the dataset's plan (index.json's PLAN_KEY), None without one.
        asked: the mix this recording asks for, None for a plain recording.
        episodes: how many episodes the dataset holds (files on disk included): a dataset
            with none takes any plan.
        where: the dataset, for the message.

    Raises:
        ValueError: one line saying what the dataset was recorded with.
    """
    if not episodes:
        return
    have = ConditionMix.from_json(stored, where) if stored is not None else None
    if have is not None and stored.get(MIX_KEPT) is not True:
        raise ValueError(f"{where}: its {episodes} episode(s) were recorded with "
                         f"{have.flags()} by an earlier sebvs, whose hard episodes drew "
                         f"nothing from the randomised mix (the topology's one scene); this "
                         f"version draws what a condition leaves open, and the dataset would "
                         f"mix both: record into another folder")
    if have == asked:
        return
    if have is None:
        raise ValueError(f"{where}: holds {episodes} episode(s) recorded without "
                         f"--hard-share; a hard share is planned from episode 0: record "
                         f"{asked.flags()} into a new folder")
    if asked is None:
        raise ValueError(f"{where}: recorded with {have.flags()}; give them again (a rerun "
                         f"records only the missing numbers, each under the condition the "
                         f"plan assigns), or record into another folder")
    raise ValueError(f"{where}: recorded with {have.flags()}, not {asked.flags()}; give "
                     f"the dataset's, or record into another folder")
