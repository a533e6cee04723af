"""`sebvs probe` (and `python -m sebvs.probe`): what each recording's streams hold,
measured before any policy.

    sebvs probe datasets/probe/still/* --json docs/figures/probe_still.json
    sebvs probe --table docs/figures/probe_still.json

For every dataset and sensor (rgb: the frame camera, event: the event frames, both), train
the fixed probe (sebvs/probe/fit.py `Recipe`) on the first episodes and measure it on the
next ones; write every fit, the per-(dataset, sensor) summary and the recipe as JSON
(--json, resumed: a fit already there with the same recipe is kept), and print the
summary. Exit 2, one line on stderr, for a dataset the probe cannot use (no truth, too few
episodes, not a dataset) or an output it must not write.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

SENSOR_NAMES = ("rgb", "event", "both")      # sebvs.probe.data.SENSORS, without its imports
DESCRIPTION = (
    "Measure what a recording's streams hold before any policy: train one small fixed CNN "
    "per dataset and sensor (rgb: the frame camera; event: the event frames; both) on the "
    "sim's truth (the target's centroid and visibility) over the first episodes, and "
    "report on the next, held-out episodes the localisation error (median and 90th "
    "percentile, px of a 160 px image) beside the no-information baseline (the training "
    "frames' mean centroid), and the visibility ROC AUC beside 0.5. A stream the probe "
    "cannot localise from holds too little for a policy reading it alone; one it can, "
    "where a policy fails, points at the learner. The recipe is fixed (sebvs/probe/fit.py "
    "Recipe; docs/probe.md).")


def add_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("datasets", nargs="*", type=Path, metavar="DATASET",
                    help="dataset folders from `sebvs record` (index.json and episodes "
                         "with truth/centroid, truth/visible); a dataset is named by its "
                         "folder (CONDITION__SCENARIO) and its parent's (the driver)")
    ap.add_argument("--sensors", default=",".join(SENSOR_NAMES),
                    help=f"comma-separated of {', '.join(SENSOR_NAMES)} (default all)")
    ap.add_argument("--seeds", default="0",
                    help="comma-separated training seeds (default 0): the figures are the "
                         "mean over them, their range beside")
    ap.add_argument("--threads", type=int, default=1, help="torch CPU threads (default 1)")
    ap.add_argument("--json", type=Path, default=None, metavar="FILE",
                    help="write every fit and the summary here, and resume from it: a "
                         "fit it holds with the same recipe is not run again")
    ap.add_argument("--force", action="store_true",
                    help="replace a --json file that is not a probe's results")
    ap.add_argument("--table", type=Path, default=None, metavar="FILE",
                    help="print the Markdown table of a results file and exit")
    ap.add_argument("--quiet", action="store_true", help="no progress bar")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("probe", help="measure what each recording's streams hold (a fixed "
                                     "CNN on the sim's truth)", description=DESCRIPTION)
    add_arguments(p)
    p.set_defaults(func=run)


class _Refused(ValueError):
    """Bad input: one line, exit 2."""


def _ints(text: str, what: str) -> list[int]:
    try:
        values = [int(s) for s in text.split(",") if s.strip()]
    except ValueError:
        raise _Refused(f"{what} {text!r}: expected comma-separated integers") from None
    if not values:
        raise _Refused(f"{what} {text!r}: give at least one")
    return values


def _write(path: Path, data: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(json.dumps(data, indent=1) + "\n")
    os.replace(tmp, path)


def _previous(path: Path | None, force: bool, inputs) -> dict | None:
    """The probe results already at --json (to resume), None when there are none; refuses
    a file that is not a probe's (unless --force) and any path the guard protects."""
    from sebvs.output_guard import check_output_file
    if path is None:
        return None
    if path.exists() and not path.is_dir():
        try:
            old = json.loads(path.read_text())
        except (OSError, ValueError):
            old = None
        if isinstance(old, dict) and isinstance(old.get("fits"), list) and "recipe" in old:
            check_output_file(path, inputs=inputs, force=True)
            return old
    check_output_file(path, inputs=inputs, force=force)
    return None


def run(args) -> int:
    """The command (the parsed arguments of add_arguments); returns the exit status."""
    from sebvs.output_guard import OutputRefused
    from .data import SENSORS, ProbeDataError, load_frames
    from .fit import Recipe, probe, split
    from .report import markdown, summarise
    try:
        if args.table is not None:
            try:
                data = json.loads(args.table.read_text())
                rows = data.get("summary") or summarise(data["fits"])
            except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
                raise _Refused(f"{args.table}: not a probe results file ({exc})") from None
            print(markdown(rows))
            return 0
        if not args.datasets:
            raise _Refused("no dataset given (see --help)")
        sensors = [s.strip() for s in args.sensors.split(",") if s.strip()]
        for s in sensors or [""]:
            if s not in SENSORS:
                raise _Refused(f"--sensors: unknown sensor {s!r} (one of "
                               f"{', '.join(SENSORS)})")
        seeds = _ints(args.seeds, "--seeds")
        if args.threads < 1:
            raise _Refused(f"--threads must be at least 1, got {args.threads}")
        recipe = Recipe()
        old = _previous(args.json, args.force,
                        [p / "index.json" for p in args.datasets])
        fits = old["fits"] if old and old.get("recipe") == recipe.to_dict() else []
        # every dataset is read and checked before the first fit: a bad one stops at once
        loaded = {}
        for path in args.datasets:
            frames = load_frames(path, sensors)
            split(frames, recipe)
            loaded[path] = frames
    except (_Refused, ProbeDataError, OutputRefused, ValueError) as exc:
        print(f"sebvs probe: {exc}", file=sys.stderr)
        return 2
    done = {(f["dataset"], f["sensor"], f["seed"]) for f in fits}
    todo = [(p, s, k) for p in args.datasets for s in sensors for k in seeds
            if (str(p), s, k) not in done]
    from tqdm import tqdm
    steps = {p: recipe.epochs * -(-len(split(loaded[p], recipe)[0]) // recipe.batch)
             for p in args.datasets}
    bar = tqdm(total=sum(steps[p] for p, _, _ in todo), unit="step", desc="probe",
               disable=args.quiet)
    for path, sensor, seed in todo:
        driver, cell = path.resolve().parent.name, path.name.replace("__", "/")
        bar.set_postfix_str(f"{driver}/{cell} {sensor} seed {seed}")
        result = probe(loaded[path], sensor, recipe, seed=seed, threads=args.threads,
                       progress=bar.update)
        fits.append({"dataset": str(path), "driver": driver, "cell": cell, **result})
        if args.json is not None:
            _write(args.json, {"recipe": recipe.to_dict(), "fits": fits,
                               "summary": summarise(fits)})
    bar.close()
    asked = {str(p) for p in args.datasets}
    print(json.dumps({"recipe": recipe.to_dict(),
                      "summary": summarise([f for f in fits if f["dataset"] in asked])}))
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m sebvs.probe", description=DESCRIPTION)
    add_arguments(ap)
    return run(ap.parse_args(argv))
