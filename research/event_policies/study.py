#!/usr/bin/env python3
"""Steps 2-4 of docs/plan_event_policies.md (issue 65): the test's recordings, trainings,
evaluations and readings, on the sensor study's resumable driver.

    research/event_policies/study.py plan              # every command, nothing run
    research/event_policies/study.py run --commit      # what is not done yet, in order
    research/event_policies/study.py status            # what is done, what is left
    research/event_policies/study.py smoke --only nav10   # the commands shrunk to minutes

The driver is research/sensors/sensor_study.py's (its docstring says how `run` resumes,
commits each finished step with --commit, and keeps a stopped training's resume state);
this file holds only what the plan fixes, as its Plan. Nothing here chooses anything:
the recipe is the one step 1 chose on the dev split (CHOSEN, written into the plan
before step 2; research/event_policies/step1.py select printed it), and the test refuses
to run before it is set.

The plan, as data:
  data     nav: topology seed 40, 120 episodes of 20 s; arm: seed 42, 1,500 of 2 s; half
           of each under hard conditions (nav hdr, dusk_fast, flicker_120; arm hdr,
           dusk_moving, fast_physical), the rest the topology's randomised mix; the
           emulator's current noise (preset_version 2), events as the recipe reads them
  train    Event, RGB+Event and RGB+Diff with training seeds 0, 1, 2, RGB with seed 0;
           nav with the chosen recipe (fused rows with modality dropout 0.25 where it has
           memory), the arm with R0's (the plan's second amendment: no GPU lent, so the
           arm's rows train without memory on this machine, and the report says so)
  eval     the test split on seeds never evaluated: nav 100500, arm 100600; 20 episodes a
           cell; nav nominal_physical, hdr, dusk_fast (indoor, outdoor) and flicker_120
           (indoor), 10 s; arm nominal_physical, fast_physical, hdr, dusk_moving (single,
           multi); the expert and no-action rows with seed 0's
  read     the sensor study's rule: RGB+Event against RGB+Diff, --min-diff 10
           --min-ahead 3, nav strict rate, arm grasp success

Outputs under research/event_policies/outputs/test/ (tracked), datasets under
datasets/evtest_<task><rate> (not tracked).
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from research.event_policies import step1  # noqa: E402
from research.sensors import sensor_study as driver  # noqa: E402
from research.sensors.sensor_study import Plan, Recording  # noqa: E402

# step 1's choice (research/event_policies/outputs/step1/selection.json), written into
# docs/plan_event_policies.md before step 2; None until then, and the test does not run
CHOSEN: str | None = "R3"

SELECTION = step1.OUT / "selection.json"
# the dev data's sensors: the camera renders at the sensor size, the current noise model
NOISE = "emulator.overrides={downsample=1.0, preset_version=2}"
HARD = {"nav": "hdr,dusk_fast,flicker_120", "arm": "hdr,dusk_moving,fast_physical"}
BASE = {"nav": ("--epochs", "10", "--patience", "3", "--stem", "conv", "--lr", "5e-4"),
        "arm": ("--epochs", "16", "--stem", "conv", "--lr", "5e-4")}
FUSED = ("rgb+event", "rgb+diff")
SEEDS = {10: {"event": (0, 1, 2), "rgb+event": (0, 1, 2), "rgb+diff": (0, 1, 2),
              "rgb": (0,)}}


class NotChosen(RuntimeError):
    """Step 1 has not chosen the recipe yet, or a DAgger recipe was chosen (its rounds
    per training seed are not steps of this driver)."""


def recipe_of(chosen: str) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """The chosen candidate's (nav `sebvs train` options beyond the base, the --set lines
    of its events at recording); NotChosen for a candidate with DAgger rounds."""
    if chosen not in step1.CANDIDATES:
        raise NotChosen(f"{chosen!r} is not a step-1 candidate "
                        f"({', '.join(step1.CANDIDATES)})")
    kind, options, rounds = step1.CANDIDATES[chosen]
    if rounds:
        raise NotChosen(f"{chosen} has DAgger rounds: each training seed's rounds "
                        "(plan, step 2) are not steps of this driver yet")
    events = [a for a in step1.DATASETS[kind][1] if a != "--set"]
    return tuple(options), tuple(events)


def event_policy_plan(chosen: str) -> Plan:
    """The plan's steps 2-4 with step 1's ``chosen`` recipe (module docstring)."""
    options, events = recipe_of(chosen)
    nav_recipe = {m: (*BASE["nav"], *options,
                      *(step1.FUSED_DROPOUT if m in FUSED and options else ()))
                  for m in SEEDS[10]}
    return Plan(
        name="event-policy test", plan_file="docs/plan_event_policies.md",
        out=ROOT / "research" / "event_policies" / "outputs" / "test",
        smoke_out=ROOT / "out" / "study_event_policies" / "smoke",
        dataset_prefix="evtest_", topology=driver.TOPOLOGY,
        recordings={
            ("nav", 10): Recording(120, ("sim.episode_s=20.0", "topology.seed=40", NOISE,
                                         *events),
                                   ("--hard-share", "0.5", "--hard-conditions", HARD["nav"])),
            ("arm", 10): Recording(1500, ("topology.seed=42", NOISE),
                                   ("--hard-share", "0.5", "--hard-conditions", HARD["arm"]))},
        recipe={**{("nav", m): r for m, r in nav_recipe.items()},
                **{("arm", m): BASE["arm"] for m in SEEDS[10]}},
        seeds=SEEDS, test_seed={"nav": 100_500, "arm": 100_600}, episodes_per_cell=20,
        eval_groups={"nav": [("main", "nominal_physical,hdr,dusk_fast", "indoor,outdoor"),
                             ("flicker", "flicker_120", "indoor")],
                     "arm": [("main", "nominal_physical,fast_physical,hdr,dusk_moving",
                              "single,multi")]},
        eval_sets={"nav": ["sim.episode_s=10"], "arm": []},
        read_rule=driver.READ_RULE,
        read_metric={"nav": "strict_success", "arm": None})


def selection_chosen(path: Path = SELECTION) -> str | None:
    """What step 1's selection table chose, once every candidate was in; else None."""
    try:
        table = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return table.get("chosen") if table.get("complete") else None


def main(argv: list[str] | None = None) -> int:
    if CHOSEN is None:
        print(f"event-policy test: step 1 has not chosen its recipe yet (CHOSEN is unset; "
              f"{SELECTION.relative_to(ROOT)} says {selection_chosen()!r}): finish step 1 "
              "and write its choice into docs/plan_event_policies.md first",
              file=sys.stderr)
        return 2
    try:
        plan = event_policy_plan(CHOSEN)
    except NotChosen as exc:
        print(f"event-policy test: {exc}", file=sys.stderr)
        return 2
    return driver.main(argv, plan, __doc__)


if __name__ == "__main__":
    sys.exit(main())
