"""Command-line registration for the data tools: `sebvs record`, `sebvs data check|stats`."""
from __future__ import annotations

from ..shipped import topology_argument


def _check(args) -> int:
    from .check import cmd_check
    return cmd_check(args)


def _stats(args) -> int:
    from .stats import cmd_stats
    return cmd_stats(args)


def _compare(args) -> int:
    from .compare import cmd_compare
    return cmd_compare(args)


def _export(args) -> int:
    import json
    import sys

    from ..extras import MissingExtra
    try:
        if args.format == "lerobot":
            from .export_lerobot import export_lerobot
            info = export_lerobot(args.dataset, args.out, progress=not args.quiet,
                                  force=args.force, compression=args.compression)
            for note in info["notes"]:
                print(f"sebvs data export: note: {note}", file=sys.stderr)
        else:
            from .export_mcap import export_mcap
            info = export_mcap(args.dataset, args.out, progress=not args.quiet,
                               compression=args.compression, force=args.force)
    except (ValueError, OSError, MissingExtra) as exc:
        print(f"sebvs data export: {exc}", file=sys.stderr)
        return 2
    print(json.dumps(info))
    return 0


def _record(args) -> int:
    from .record import cmd_record
    return cmd_record(args)


def workers_arg(text: str) -> int:
    """--workers: a positive count, or "auto" (the CPUs this process may use)."""
    import argparse
    if text == "auto":
        from sebvs.runtime.topology import run_cpus
        return run_cpus()
    if text.isdigit() and int(text) >= 1:
        return int(text)
    raise argparse.ArgumentTypeError(f"{text!r}: expected a number of workers (1 or more) "
                                     f"or auto")


def seed_arg(text: str) -> int:
    """--seed: a seed of the project's one range, 0 <= seed < 2**31 (topology seeds are
    one-to-one with their episodes there, sebvs/runtime/topology.py; training seeds keep
    the same rule)."""
    import argparse

    from sebvs.runtime.topology import check_seed
    try:
        return check_seed(int(text), "seed")
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc) if text.strip().lstrip("-").isdigit()
                                         else f"{text!r}: expected an integer") from None


def add_fanout_arguments(parser, what: str) -> None:
    """--workers, --ray and --max-attempts of `sebvs record` and `sebvs eval` (docs/scale.md)."""
    parser.add_argument(
        "--workers", type=workers_arg, default=None, metavar="N|auto",
        help=f"run the {what} on N worker processes at once, each its own topology run "
             f"(own run directory and sockets) playing a contiguous range of episodes; "
             f"episode k is seeded from (topology seed, k) whatever the split, so any N "
             f"gives the same results; auto: one per CPU this process may use (default "
             f"1: one run, as without the flag; with --ray: tasks in flight, default one "
             f"per CPU of this machine)")
    parser.add_argument(
        "--ray", nargs="?", const="", default=None, metavar="ADDRESS",
        help="run the workers as Ray tasks: on the cluster at ADDRESS (e.g. "
             "ray://head:10001 or auto), or on a local Ray started for this command when "
             "no ADDRESS is given; needs pip install -e .[ray], and on a cluster the "
             "checkout and the output directory at the same paths on every node")
    parser.add_argument(
        "--max-attempts", type=int, default=3, metavar="K",
        help="with --workers/--ray: run a failed or lost worker's missing episodes again, "
             "up to K attempts in all, then stop with an error naming them (default 3)")


def register(sub) -> None:
    from ..sensor_pairs import SENSORS
    d = sub.add_parser("data", help="dataset tools: check, stats, compare, export",
                       description="Inspect recorded datasets (one HDF5 file per episode "
                                   "plus index.json).")
    dsub = d.add_subparsers(dest="data_cmd", metavar="SUBCOMMAND", required=True)
    c = dsub.add_parser("check", help="verify every episode against the index",
                        description="Verify each indexed episode (exists, sha256, frame "
                                    "counts, shapes, attributes); report .partial leftovers "
                                    "(lost in-progress episodes) and unindexed files. Exit "
                                    "code 1 on any problem.")
    c.add_argument("dir", help="dataset directory")
    c.set_defaults(func=_check)
    s = dsub.add_parser("stats", help="summary and the paper's Fig. 3 views",
                        description="Print episodes, frames, minutes simulated and labelled "
                                    "commands; --plot writes control-vector / workspace "
                                    "scatter, per-episode speed and events as PNG. An "
                                    "episode that differs from the index (size, sha256) or "
                                    "cannot be read is named and left out: exit code 1.")
    s.add_argument("dir", help="dataset directory")
    s.add_argument("--plot", metavar="FILE", help="write the figure (PNG)")
    s.add_argument("--force", action="store_true", help="replace the --plot file if it exists")
    s.set_defaults(func=_stats)
    m = dsub.add_parser("compare", help="are two datasets the same recording?",
                        description="Pair the episodes of two datasets by file name and "
                                    "compare every array and attribute, except the hop "
                                    "latencies (wall clock) and tick / t_sim (compared from "
                                    "each episode's first frame: they count from the start "
                                    "of the run that recorded it). Two lockstep recordings "
                                    "of one topology and seed are the same whatever the "
                                    "worker count or placement. Exit code 0 when every "
                                    "episode is the same, 1 when any differs or is missing "
                                    "on one side, 2 when a directory is not a dataset.")
    m.add_argument("a", help="dataset directory")
    m.add_argument("b", help="dataset directory")
    m.add_argument("--max-lines", type=int, default=10, metavar="N",
                   help="differences shown per episode (default 10)")
    m.add_argument("--quiet", action="store_true", help="no progress bar")
    m.set_defaults(func=_compare)
    x = dsub.add_parser("export", help="write episodes as ROS 2 bags (MCAP) or a LeRobot "
                                       "dataset",
                        description="Write each episode as one MCAP file of ROS 2 messages "
                                    "that Foxglove and `ros2 bag` open: the RGB frames "
                                    "(sensor_msgs/Image on /camera/image_raw), the raw "
                                    "events (event_camera_msgs/EventPacket, mono encoding, "
                                    "on /events) and event frames (/events/frame, "
                                    "/events/image) where the episode has them, the "
                                    "commands (nav: geometry_msgs/Twist on /cmd_vel in m/s "
                                    "and rad/s; arm: geometry_msgs/PoseStamped on "
                                    "/cmd_pose) and the true poses on /tf. Messages are "
                                    "stamped with the simulation time. Prints a JSON "
                                    "summary; exit 2 when DATASET is not a dataset or an "
                                    "episode, or OUT cannot be written. Needs pip install "
                                    "'sebvs[formats]' (docs/formats.md). --format lerobot "
                                    "writes a LeRobotDataset v3.0 folder instead: parquet "
                                    "frames, one mp4 per camera, meta/info.json, stats.json, "
                                    "episodes and tasks (pip install 'sebvs[lerobot]').")
    x.add_argument("dataset", metavar="DATASET",
                   help="dataset directory (index.json) or one episode .h5 file")
    x.add_argument("--format", choices=("mcap", "lerobot"), default="mcap",
                   help="output format (default mcap: ROS 2 messages, CDR; lerobot: a "
                        "LeRobotDataset v3.0 folder)")
    x.add_argument("--out", metavar="FILE_OR_DIR", default=None,
                   help="a dataset exports into this folder (default DATASET/mcap/, one "
                        "episode_NNNN.mcap per episode); one episode into this file, or "
                        "into this folder as <episode>.mcap (default: beside it). lerobot: "
                        "the dataset folder to make, which must not exist (default "
                        "DATASET/lerobot/, or EPISODE_lerobot/ beside one episode)")
    x.add_argument("--compression", choices=("zstd", "lz4", "none"), default="zstd",
                   help="MCAP chunk compression, or lerobot's parquet compression (default "
                        "zstd; every MCAP and parquet reader has it)")
    x.add_argument("--quiet", action="store_true", help="no progress bar")
    x.add_argument("--force", action="store_true",
                   help="replace .mcap files that exist (never an episode, the index or "
                        "the source); lerobot: replace an earlier LeRobot export of sebvs "
                        "at --out (nothing else)")
    x.set_defaults(func=_export)

    r = sub.add_parser("record", help="record expert demonstrations into a dataset",
                       description="Run a recording topology until its recorder has "
                                   "finished N episodes; numbering resumes in an existing "
                                   "dataset. Shows episodes, frames and speed (simulated "
                                   "s per wall s). --workers / --ray play the episodes on "
                                   "several topology runs at once, with the same episode "
                                   "files as one (docs/scale.md). --hard-share F records "
                                   "a chosen share of the episodes under hard conditions "
                                   "(hdr, dusk, mains flicker) beside the randomised mix "
                                   "(docs/data.md).")
    r.add_argument("topology", type=topology_argument,
                   help="topology TOML file with a recorder actor")
    r.add_argument("--episodes", type=int, required=True, metavar="N")
    r.add_argument("--out", required=True, metavar="DIR", help="dataset directory")
    r.add_argument("--sensor", choices=SENSORS, default=None,
                   help="record through this sensor pair: physical (the shipped topologies' "
                        "own) or ideal8 (the 8-bit benchmark: camera.sensor=\"ideal8\" and "
                        "the emulator's \"paper\" preset); --set lines come after it")
    r.add_argument("--condition", default=None, metavar="NAME",
                   help="record one named condition of the task (sebvs eval's, docs/sim.md) "
                        "instead of the topology's randomised mix")
    r.add_argument("--scenario", default=None, metavar="NAME",
                   help="with --condition or --hard-share: the scene of the named "
                        "condition's episodes (nav indoor | outdoor, arm single | multi; "
                        "default: the topology's)")
    r.add_argument("--set", action="append", default=[], metavar="ACTOR.KEY=VALUE",
                   help="override a parameter (value read as TOML; repeatable; after "
                        "--sensor and --condition)")
    r.add_argument("--timeout", type=float, default=None, metavar="SECONDS",
                   help="give up after this long (default: none; with --workers or --ray: "
                        "each worker's run)")
    r.add_argument("--runs-dir", default=None)
    r.add_argument("--quiet", action="store_true", help="no progress bar")
    r.add_argument("--force", action="store_true",
                   help="record into a folder that holds other files (never over them: "
                        "episodes are numbered after the highest there)")
    r.add_argument("--fill", action="store_true",
                   help="make the dataset hold episodes 0..N-1: record only the numbers "
                        "below N it lacks (the holes a stopped --workers run leaves, then "
                        "the tail), each the same episode it would have been, instead of "
                        "N more after its highest")
    r.add_argument("--hard-share", default=None, metavar="F",
                   help="make the dataset hold episodes 0..N-1 (as --fill), round(F*N) of "
                        "them under hard conditions and the rest under the topology's "
                        "randomised mix; F between 0 and 1, a decimal or a fraction (1/6). "
                        "By episode number alone: the hard ones are spread evenly (any "
                        "first n episodes hold round(F*n)) and take the conditions in "
                        "turn, each recorded under the condition as --condition NAME sets "
                        "it (with --scenario: in that scene) but drawing from the "
                        "topology's randomised mix what the condition leaves open (nav hdr: "
                        "the variant, target speed and blur), its name in the episode's "
                        "condition attribute (\"randomised\" for the rest). The plan is "
                        "kept in the dataset: a "
                        "rerun records only the missing numbers, each under the condition "
                        "the plan gives it, and a recording with another share, other "
                        "conditions or none is refused (docs/data.md)")
    r.add_argument("--hard-conditions", default=None, metavar="A,B,...",
                   help="with --hard-share: the hard conditions, comma-separated, taken in "
                        "turn (a name given twice gets twice the turns); default nav "
                        "hdr,dusk_fast,flicker_120, arm hdr,dusk_moving,fast_hdr "
                        "(sebvs/data/condition_mix.py says why)")
    add_fanout_arguments(r, "episodes")
    r.set_defaults(func=_record)
