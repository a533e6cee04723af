"""`sebvs eval`: closed-loop evaluation of policy variants (the paper's Tables 4 and 5)."""
from __future__ import annotations

import argparse
import importlib.util
import sys
from pathlib import Path

from sebvs.sensor_pairs import DEFAULT_CONDITION


def conditions_of(text: str | None, task: str, sensor: str = "physical") -> list[str]:
    """--conditions as a list: comma-separated names and groups; "all" for every condition
    of the sensor pair (physical: light in physical units; ideal8: the 8-bit benchmark's
    six), "physical" and "ideal8" for either pair's; None: the pair's nominal one. A name
    given twice runs once. ValueError for a condition of the other pair (each condition
    sets its own camera sensor: one evaluation, one pair, one set of checkpoints); unknown
    names are left to EvalPlan.validate."""
    from sebvs.conditions import TASKS
    spec = TASKS[task]
    groups = {pair: spec.names(pair) for pair in ("physical", "ideal8")}
    groups["all"] = groups[sensor]
    out: list[str] = []
    for name in (c.strip() for c in (text or DEFAULT_CONDITION[sensor]).split(",")):
        for c in groups.get(name, [name] if name else []):
            if c not in out:
                out.append(c)
    other = [c for c in out if c in spec.conditions and spec.conditions[c].sensor != sensor]
    if other:
        pair = spec.conditions[other[0]].sensor
        raise ValueError(f"condition {other[0]!r} is the {pair} sensor pair's, this "
                         f"evaluation runs --sensor {sensor} (its conditions: "
                         f"{', '.join(groups[sensor])}); give --sensor {pair} to run it with "
                         f"the checkpoints trained on that pair")
    return out


def _cmd_eval(args) -> int:
    from sebvs.output_guard import check_output_dir
    from sebvs.sensor_pairs import checkpoint_dir
    from .plan import EvalPlan
    from .report import never_acted, output_files
    from .run import evaluate
    if args.out is None:
        print("sebvs eval: --out is required (the evaluation's output directory); "
              "`sebvs eval compare` and `sebvs eval table` read evaluations", file=sys.stderr)
        return 2
    scenarios = [s for s in args.scenarios.split(",") if s] if args.scenarios else None
    try:
        conditions = conditions_of(args.conditions, args.task, args.sensor)
    except ValueError as exc:
        print(f"sebvs eval: {exc}", file=sys.stderr)
        return 2
    plan = EvalPlan(task=args.task, modalities=[m for m in args.modalities.split(",") if m],
                    conditions=conditions, scenarios=scenarios,
                    episodes=args.episodes, out=Path(args.out), clock=args.clock,
                    split=args.split, seed=args.seed,
                    checkpoints=args.checkpoints or checkpoint_dir(args.sensor),
                    expert=not args.no_expert,
                    baseline=not args.no_baseline,
                    extra=args.set, control_hz=args.control_hz,
                    video=args.video, video_episodes=args.video_episodes,
                    workers=args.workers, ray=args.ray, max_attempts=args.max_attempts)
    try:
        check_output_dir(plan.out, inputs=[plan.checkpoints], force=args.force,
                         owns=is_evaluation, what="evaluation")
        plan.validate()
        if plan.ray is not None and importlib.util.find_spec("ray") is None:
            raise ValueError("--ray needs Ray, which is not installed: pip install -e .[ray]")
        _check_checkpoints(plan)
    except (ValueError, OSError) as exc:
        if getattr(args, "debug", False):
            raise
        print(f"sebvs eval: {exc}", file=sys.stderr)
        return 2
    results = evaluate(plan)
    print((plan.out / "report.md").read_text())
    print(f"wrote {plan.out}/: {output_files(plan.task)}"
          + (f", videos/ ({len(results.get('videos', []))} files)" if plan.video else ""))
    # after the outputs are written: the marked rows and Run health are the evidence
    idle = never_acted(results)
    for line in idle:
        print(f"sebvs eval: {line}", file=sys.stderr)
    return 1 if idle else 0


def is_evaluation(path: Path) -> bool:
    """A folder `sebvs eval` wrote: it resumes there (its episode lines, results, runs)."""
    return (path / "episodes").is_dir() or (path / "results.json").is_file()


def _check_checkpoints(plan) -> None:
    """Load every policy's checkpoint once before any run: a missing, damaged or refused
    file then stops the evaluation with its name, not a policy actor minutes into it."""
    from sebvs.policy.checkpoint import checkpoint_paths, load_checkpoint
    for modality in plan.modalities:
        pt = checkpoint_paths(plan.checkpoints, plan.task, modality)[0]
        if not pt.is_file():
            raise FileNotFoundError(f"checkpoint for modality {modality!r} not found: {pt}")
        load_checkpoint(pt, expect={"task": plan.task, "modality": modality})


def register(sub: argparse._SubParsersAction) -> None:
    from sebvs.data.cli import add_fanout_arguments, seed_arg
    from sebvs.data.splits import DEFAULT_EVAL_SPLIT, EVAL_SPLITS, SPLITS
    from sebvs.conditions import TASKS
    from sebvs.sensor_pairs import DEFAULT_SENSOR, SENSORS
    nav, arm = TASKS["nav"], TASKS["arm"]
    e = sub.add_parser(
        "eval", help="closed-loop evaluation of policies against the expert",
        description="Run every modality (the expert as the reference row and a no-action "
                    "baseline beside it) through the real topology on the same seeded "
                    "episodes, per condition and scenario (nav: indoor and outdoor scene; "
                    "arm: single- or multi-object), and write report.md (the paper's Table 4 "
                    "or 5), results.json and plots. The arm's episodes end with the sim "
                    "grasping the last predicted pose. An interrupted evaluation resumes: "
                    "finished runs are kept. --workers / --ray play the runs and episodes "
                    "on several topology runs at once, with the same results.json "
                    "(docs/scale.md). Exits 1, after writing the reports, when a run "
                    "never acted (the sim applied none of its commands: all rejected as "
                    "NaN or the wrong shape, or none came); report.md marks rows with "
                    "rejected or non-finite commands and lists them under Run health.")
    e.add_argument("--task", choices=["nav", "arm"], default="nav")
    e.add_argument("--modalities", default="rgb,event,rgb+event",
                   help="comma-separated: rgb, event, rgb+event; or rgb+diff, the control "
                        "that gives the RGB policy the change since the previous frame "
                        "(needs <task>-rgb+diff.pt)")
    e.add_argument("--episodes", type=int, default=10,
                   help="episodes per modality, condition and scenario")
    e.add_argument("--sensor", choices=SENSORS, default=DEFAULT_SENSOR,
                   help="the sensor pair: physical (default; the frame camera and the event "
                        "sensor on the scene's linear light, docs/sensors.md) or ideal8 (the "
                        "8-bit benchmark before it, the pair of research/ideal8/'s pages); it "
                        "picks the conditions and the default checkpoints (checkpoints/ or "
                        "checkpoints/ideal8/)")
    e.add_argument("--conditions", default=None,
                   help=f"comma-separated names or groups of the --sensor pair (default: its "
                        f"nominal); all = every one of the pair's. physical: light in physical "
                        f"units (nav: {', '.join(nav.names('physical'))}; arm: "
                        f"{', '.join(arm.names('physical'))}; docs/sim.md); ideal8: the "
                        f"8-bit benchmark's (nav: {', '.join(nav.names('ideal8'))}; arm: "
                        f"{', '.join(arm.names('ideal8'))})")
    e.add_argument("--scenarios", default="",
                   help=f"comma-separated; nav: {', '.join(nav.scenarios)} (the scene "
                        f"variant); arm: {', '.join(arm.scenarios)} (default: all of the task's)")
    e.add_argument("--clock", choices=["lockstep", "realtime"], default="lockstep",
                   help="realtime: the policy's latency affects control, as on a robot")
    e.add_argument("--checkpoints", default=None,
                   help="directory with <task>-<modality>.pt checkpoints (default: the "
                        "shipped ones of the --sensor pair)")
    e.add_argument("--split", choices=EVAL_SPLITS, default=None,
                   help=f"topology seeds of the episodes: dev ({SPLITS['dev']}, the default, "
                        f"to evaluate and iterate on) or test ({SPLITS['test']}, held out: no "
                        f"recording may use them); the split's first seed unless --seed")
    e.add_argument("--seed", type=seed_arg, default=None,
                   help=f"topology seed (episode seeds follow); alone, the split is 'custom'; "
                        f"default: the first of the split ({DEFAULT_EVAL_SPLIT}: "
                        f"{SPLITS[DEFAULT_EVAL_SPLIT].first})")
    e.add_argument("--no-expert", action="store_true", help="leave out the expert reference row")
    e.add_argument("--no-baseline", action="store_true",
                   help="leave out the no-action row (the robot holds still, the arm stays "
                        "home, on the same seeds): what each metric gives for free")
    e.add_argument("--video", action="store_true",
                   help="also write episode videos to OUT/videos/<condition>[__<scenario>]__"
                        "<modality>__ep<k>.mp4 (rgb+event as rgb_event): per control tick the "
                        "RGB frame the policy saw, that tick's event frame overlaid (ON blue, "
                        "OFF red; event modalities only), the target marked from the sim's "
                        "truth, and a caption (modality, tick, centre error or the arm's mode)")
    e.add_argument("--video-episodes", type=int, default=1, metavar="K",
                   help="with --video: the first K episodes of each run (default 1)")
    e.add_argument("--control-hz", type=float, default=None, metavar="HZ",
                   help="the control rate (default: the topologies', 10 Hz as the paper): "
                        "sim and tracker ticks, the event frames' window (one tick, unless "
                        "the checkpoint names the one it learned from) and a "
                        "render rate that is a whole multiple of it; the physical frame "
                        "camera runs at it too, capped at its sensor's top rate")
    e.add_argument("--set", action="append", default=[], metavar="ACTOR.KEY=VALUE",
                   help="extra topology overrides for every run (results.json keeps them)")
    e.add_argument("--out", default=None,
                   help="output directory (required to evaluate): new, empty, or an earlier evaluation's (it "
                        "resumes); never a dataset or the checkpoint folder")
    e.add_argument("--force", action="store_true",
                   help="write into a folder that holds other files and no evaluation")
    add_fanout_arguments(e, "evaluation's runs and episodes")
    e.set_defaults(func=_cmd_eval)
    readers = e.add_subparsers(dest="eval_cmd", metavar="[compare | table]", required=False,
                               help="read evaluations instead of running one")
    _register_compare(readers)
    _register_table(readers)


def _cmd_compare(args) -> int:
    from .compare import compare, markdown
    from .results import read_results
    names = tuple(n.strip() for n in args.names.split(","))
    if len(names) != 2 or not all(names):
        print(f"sebvs eval compare: --names takes two comma-separated labels, got "
              f"{args.names!r}", file=sys.stderr)
        return 2
    try:
        comparison = compare(read_results(args.a), read_results(args.b),
                             args.modalities.split(",") if args.modalities else None)
        _check_new(args.json, inputs=(args.a, args.b), force=args.force)
    except ValueError as exc:
        print(f"sebvs eval compare: {exc}", file=sys.stderr)
        return 2
    print(markdown(comparison, names), end="")
    if args.json:
        _write_json(args.json, {"a": str(args.a), "b": str(args.b), "names": names,
                                **comparison})
    return 0


def _cmd_table(args) -> int:
    from .table import load_runs, markdown, plot, seed_table
    try:
        table = seed_table(load_runs(args.runs), args.a, args.b, args.metric,
                           args.min_diff, args.min_ahead)
        _check_new(args.json, args.plot, force=args.force,
                   inputs=[spec.partition("=")[2] for spec in args.runs])
    except ValueError as exc:
        print(f"sebvs eval table: {exc}", file=sys.stderr)
        return 2
    print(markdown(table), end="")
    if args.json:
        _write_json(args.json, table)
    if args.plot:
        args.plot.parent.mkdir(parents=True, exist_ok=True)
        plot(table, args.plot)
    return 0


def _check_new(*paths: Path | None, inputs=(), force: bool = False) -> None:
    """The files a reader writes are new, or it was told to replace them (--force), and
    never one of the evaluations it reads (sebvs.output_guard.check_output_file)."""
    from sebvs.output_guard import check_output_file
    from .results import results_path
    for path in paths:
        if path is not None:
            check_output_file(path, inputs=[results_path(i) for i in inputs], force=force)


def _write_json(path: Path, data: dict) -> None:
    import json
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data, indent=1) + "\n")


def _register_compare(readers: argparse._SubParsersAction) -> None:
    from . import compare
    c = readers.add_parser("compare", help="two evaluations of the same episodes, paired",
                           description=compare.__doc__,
                           formatter_class=argparse.RawDescriptionHelpFormatter)
    c.add_argument("a", type=Path, help="evaluation A: an `sebvs eval --out` directory "
                                        "(or its results.json)")
    c.add_argument("b", type=Path, help="evaluation B, of the same task and topology seed")
    c.add_argument("--modalities", help="comma-separated (default: every modality both "
                                        "hold, expert and no_action included)")
    c.add_argument("--names", default="A,B", help="two labels for the tables (default A,B)")
    c.add_argument("--json", type=Path, help="also write the comparison here (a new file)")
    c.add_argument("--force", action="store_true", help="replace a --json file that exists")
    c.set_defaults(func=_cmd_compare)


def _register_table(readers: argparse._SubParsersAction) -> None:
    from . import table
    t = readers.add_parser("table", help="training seeds of two modalities, per cell, "
                                         "read by a rule given beforehand",
                           description=table.__doc__,
                           formatter_class=argparse.RawDescriptionHelpFormatter)
    t.add_argument("runs", nargs="+", metavar="NAME=DIR",
                   help="an `sebvs eval --out` directory per training seed (a NAME given "
                        "again adds a directory to that seed's run; NAME@TAG=DIR names its "
                        "modalities MODALITY@TAG)")
    t.add_argument("--a", required=True, help="modality A (e.g. rgb+event)")
    t.add_argument("--b", required=True, help="modality B (e.g. rgb)")
    t.add_argument("--metric", help="episode metric (default: the task's first)")
    t.add_argument("--min-diff", type=float, default=10.0,
                   help="points of mean difference for a reading (default 10)")
    t.add_argument("--min-ahead", type=int,
                   help="runs that must agree for a reading (default: all)")
    t.add_argument("--json", type=Path, help="also write the table here (a new file)")
    t.add_argument("--plot", type=Path, help="also draw the differences here (a new PNG)")
    t.add_argument("--force", action="store_true",
                   help="replace --json / --plot files that exist")
    t.set_defaults(func=_cmd_table)
