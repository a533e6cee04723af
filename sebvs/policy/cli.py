"""`sebvs train` and `sebvs train-sweep`: registered by sebvs/cli.py. torch is imported only
when a command runs.

    sebvs train --task nav --modality all --data datasets/nav --out checkpoints/nav
    sebvs train --task nav --modality rgb --data datasets/nav --data datasets/nav_dagger1 ...
    sebvs train-sweep nav_sweep.toml --out out/sweep_nav --workers 8 --threads 2
    sebvs train-dagger --task nav --modality rgb --data datasets/nav --out out/dagger \
        --rounds 3 --episodes 10 --workers 4
"""
from __future__ import annotations

import argparse
import sys

from sebvs.data.cli import seed_arg


def _size(text: str) -> int:
    from .inputs import parse_size
    try:
        return parse_size(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _workers(text: str) -> int | str:
    """--workers: a count of 0 or more, or "auto"."""
    if text == "auto":
        return text
    if text.isdigit():
        return int(text)
    raise argparse.ArgumentTypeError(f"{text!r}: expected a number of workers (0 or more) "
                                     f"or auto")


def _cmd_train(args) -> int:
    from .inputs import MODALITIES
    from .train import train
    modalities = list(MODALITIES) if args.modality == "all" else [args.modality]
    try:
        check_train_outputs(args.out, args.data, args.task, modalities, args.force)
    except ValueError as exc:
        print(f"sebvs train: {exc}", file=sys.stderr)
        return 2
    if args.size >= 640 and args.device == "cpu":
        print(f"sebvs train: note: {args.size} px is the paper's GPU preset; on a 2-core CPU "
              f"one batch of 32 takes ~8 s (tools/bench/bench_policy.py). Use --device cuda, or "
              f"--size 160.", file=sys.stderr)
    try:
        train(args.data if len(args.data) > 1 else args.data[0], args.out, args.task,
              modalities, progress=not args.no_progress,
              **train_overrides(args, args.workers))
    except (FileNotFoundError, ValueError) as exc:   # bad data or settings: say so, no trace
        print(f"sebvs train: {exc}", file=sys.stderr)
        return 2
    return 0


def train_overrides(args, workers: int | str) -> dict:
    """The TrainSettings fields `sebvs train`'s options set (train.train's keywords):
    what `sebvs train` and `sebvs train-dagger` train with.

    Parameters:
        args: the parsed options of `add_train_arguments`.
        workers: the DataLoader workers option, a count or "auto".

    Returns:
        The overrides (None: the paper's default).
    """
    from .inputs import Normalisation
    from .train import loader_workers
    return dict(epochs=args.epochs, batch=args.batch, seed=args.seed,
                max_frames=args.max_frames,
                num_workers=loader_workers(args.device) if workers == "auto" else workers,
                cache=args.cache, threads=args.threads, val_fraction=args.val_fraction,
                patience=args.patience, lr=args.lr, device=args.device, stem=args.stem,
                zero_subnormals=args.zero_subnormals, **recipe_settings(args),
                norm=Normalisation(size=args.size, event_clip=args.event_clip))


def recipe_settings(args) -> dict:
    """The recipe options of `sebvs train` (memory, target head, modality dropout,
    sequences) as TrainSettings fields; an option not given keeps its default."""
    from .train import RECIPE_FIELDS
    return {k: getattr(args, k) for k in RECIPE_FIELDS if getattr(args, k, None) is not None}


def _add_recipe_options(t) -> None:
    """The recipe options (issue 65, item 2; docs/policy.md, "Memory, target head and
    modality dropout"). Any of them trains on windows of consecutive ticks."""
    g = t.add_argument_group(
        "recipe options", "off by default (the paper's per-tick behaviour cloning); any of "
        "them trains on batches of B windows of L consecutive ticks, shuffled across "
        "episodes, each window's state set by the W ticks before it (a burn-in without "
        "gradient: truncated backpropagation through time)")
    g.add_argument("--memory", choices=["none", "gru"], default=None,
                   help="a recurrent state across control ticks: gru (a GRU cell over the "
                        "encoded class token); the policy actor resets it per episode and at "
                        "a modality swap (default none)")
    g.add_argument("--aux-weight", type=float, default=None, metavar="W",
                   help="> 0: the target head, trained to predict the target's image "
                        "position and visibility from the sim's truth (truth/centroid, "
                        "truth/visible), its loss weighted by W; training only (default 0)")
    g.add_argument("--modality-dropout", type=float, default=None, metavar="P",
                   help="fused modalities: the share of lane batches whose RGB or event "
                        "planes (one, as likely) are zeroed, so that neither stream can be "
                        "ignored (default 0)")
    g.add_argument("--seq-len", type=int, default=None, metavar="L",
                   help="ticks per window, backpropagated through (default 2)")
    g.add_argument("--lanes", type=int, default=None, metavar="B",
                   help="windows per batch (default 32: each batch 32 places of the "
                        "episodes; 4 windows of 8 ticks did not train on nav, docs/policy.md)")
    g.add_argument("--burn-in", type=int, default=None, metavar="W",
                   help="ticks before each window, run without gradient, that set its "
                        "state (default 6; 0: every window starts from the initial state)")


def check_train_outputs(out, data, task: str, modalities: list[str], force: bool) -> None:
    """OutputRefused (one line) for a training whose outputs `sebvs train` must not write:
    into the dataset it reads, or over a finished checkpoint (its weights, config or loss
    CSV) unless ``force``. A stopped training's resume state is its own to go on from."""
    from pathlib import Path

    from sebvs.output_guard import check_output_dir, check_output_file
    from .checkpoint import checkpoint_paths
    check_output_dir(out, inputs=data if isinstance(data, list) else [data],
                     owns=lambda p: True, what="checkpoints")
    for modality in modalities:
        pt, js = checkpoint_paths(out, task, modality)
        for path in (pt, js, Path(out) / f"{task}-{modality}-losses.csv"):
            check_output_file(path, force=force)


def _cmd_train_sweep(args) -> int:
    import importlib.util
    from pathlib import Path

    from .sweep import plan_sweep, run_sweep
    from .sweep_grid import load_grid
    from .sweep_table import SUMMARY_JSON, SUMMARY_MD, format_markdown
    from sebvs.output_guard import check_output_dir
    try:
        grid = load_grid(args.grid)
        # its own folder, resumed point by point; never the dataset the points read
        check_output_dir(args.out, inputs=[grid.data], owns=lambda p: True, what="sweep")
        if args.dry_run:
            points, records = plan_sweep(grid, args.out)
            width = max(len(p.name) for p in points)
            for p in points:
                r = records[p.name]
                done = (f"trained before (best val loss {r['best_val_loss']:.5g})"
                        if r["status"] == "skipped" and r["best_val_loss"] is not None
                        else "trained before" if r["status"] == "skipped" else "to train")
                print(f"{p.name:<{width}}  {done}")
            return 0
        if args.ray is not None and importlib.util.find_spec("ray") is None:
            raise ValueError("--ray needs Ray, which is not installed: pip install -e .[ray]")
        summary = run_sweep(grid, args.out, workers=args.workers, ray=args.ray,
                            threads=args.threads, device=args.device,
                            gpus_per_task=args.gpus_per_task, progress=not args.no_progress)
    except (FileNotFoundError, ValueError) as exc:   # bad grid, data or options: one line
        print(f"sebvs train-sweep: {exc}", file=sys.stderr)
        return 2
    print(format_markdown(summary), end="")
    out = Path(args.out)
    print(f"\nsummary: {out / SUMMARY_MD}, {out / SUMMARY_JSON}")
    return 1 if any(p["status"] == "failed" for p in summary["points"]) else 0


def register(subparsers) -> None:
    """Add `sebvs train`, `sebvs train-sweep` and `sebvs train-dagger` to sebvs's
    subcommands.

    Parameters:
        subparsers: what ``argparse.ArgumentParser.add_subparsers`` returned.
    """
    _register_train(subparsers)
    _register_train_sweep(subparsers)
    _register_train_dagger(subparsers)


def _register_train(subparsers) -> None:
    """`sebvs train`: its parser, run by `_cmd_train`."""
    t = subparsers.add_parser(
        "train", help="behaviour-clone ERP policies from a recorded dataset",
        description="Train the ERP transformer on recorded episodes with the paper's settings "
                    "(nav: Adam 2e-4, wd 1e-4, MSE, early stopping 2; arm: Adam 1e-4, "
                    "ReduceLROnPlateau, Smooth L1). Writes <out>/<task>-<modality>.pt and "
                    ".json, loss CSVs and <out>/<task>-losses.png. A stopped training "
                    "goes on after its last finished epoch when the same command runs again "
                    "(<out>/<task>-<modality>.resume.pt), to the same weights.")
    add_train_arguments(t)
    t.set_defaults(func=_cmd_train)


def add_train_arguments(t) -> None:
    """`sebvs train`'s options, on parser ``t``: `sebvs train-dagger` takes them too
    (`train_overrides` turns them into TrainSettings fields)."""
    t.add_argument("--task", required=True, choices=["nav", "arm"])
    t.add_argument("--modality", required=True,
                   choices=["rgb", "event", "rgb+event", "all", "rgb+diff"],
                   help="'all' trains the three variants one after another; rgb+diff is a "
                        "control, not one of them: the RGB frame and its change since the "
                        "previous tick's, as a frame camera would give (docs/policy.md)")
    t.add_argument("--data", required=True, action="append", metavar="DIR",
                   help="dataset directory (index.json + episodes); repeat it to train on "
                        "several together (their episodes split as one, by episode; one "
                        "task and one event representation)")
    t.add_argument("--out", required=True, help="where checkpoints and curves go")
    t.add_argument("--size", type=_size, default=160,
                   help="input side in px, or a preset: cpu=160 (100 tokens), "
                        "paper=640 (1600 tokens, for GPUs) (default 160)")
    t.add_argument("--stem", choices=["patch", "conv", "dual", "gated"], default="patch",
                   help="token embedding: patch, the paper's linear 16x16 patchify; conv, "
                        "four 3x3 stride-2 convolutions giving the same tokens; for rgb+event "
                        "only, gated, a conv stem per modality and a learned gate that adds "
                        "the event tokens to the rgb ones, or dual, the same two stems summed "
                        "without a gate (docs/policy.md; default patch)")
    t.add_argument("--epochs", type=int, default=None, help="default 10")
    t.add_argument("--batch", type=int, default=None, help="default 32")
    t.add_argument("--seed", type=seed_arg, default=0,
                   help="seeds the weights, the shuffle and the train/validation split of "
                        "episodes (0 <= seed < 2**31; default 0)")
    t.add_argument("--max-frames", type=int, default=0,
                   help="cap on training frames, strided over all episodes (0: all)")
    t.add_argument("--lr", type=float, default=None, help="default: the paper's per task")
    t.add_argument("--patience", type=int, default=None,
                   help="early stopping patience in epochs (default nav 2, arm 4)")
    t.add_argument("--val-fraction", type=float, default=None,
                   help="share of episodes held out (default 0.2)")
    t.add_argument("--event-clip", type=int, default=8,
                   help="event counts saturate here before scaling to [0, 1] (default 8)")
    t.add_argument("--workers", type=_workers, default="auto", metavar="N|auto",
                   help="DataLoader workers (default auto: up to 8 on a GPU, where the CPUs "
                        "only feed it; 0 on the CPU, where the model wants the cores)")
    t.add_argument("--cache", choices=["auto", "memory", "none"], default="auto",
                   help="frames read whole into memory before training (auto: when they "
                        "fit half the available memory), or from the files item by item")
    t.add_argument("--threads", type=int, default=0, help="torch threads (default: torch's)")
    t.add_argument("--force", action="store_true",
                   help="train again over finished checkpoints of these variants in --out "
                        "(default: refused; a stopped training goes on without it)")
    t.add_argument("--device", default="cpu",
                   help="torch device, e.g. cuda for the paper preset (default cpu; "
                        "bit-reproducible on cpu only)")
    t.add_argument("--zero-subnormals", action="store_true",
                   help="zero the weights' and Adam's subnormal floats (below 1.2e-38) after "
                        "every step: weight decay drives dead units' weights there, where a "
                        "CPU computes several times slower (sebvs/policy/subnormal.py); "
                        "changes the weights, so a recipe says whether it is on")
    t.add_argument("--no-progress", action="store_true", help="no tqdm bars")
    _add_recipe_options(t)


def _register_train_sweep(subparsers) -> None:
    """`sebvs train-sweep`: its parser, run by `_cmd_train_sweep`."""
    w = subparsers.add_parser(
        "train-sweep", help="run `sebvs train` over a grid of settings, seeds and modalities",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Train one policy per point of a grid, each exactly as `sebvs train`\n"
                    "would with the point's settings, into OUT/<point name>/, and write\n"
                    "OUT/sweep.json (every point: settings, status, best validation loss,\n"
                    "epochs run, seconds, parameters) and OUT/sweep.md (the points and their\n"
                    "seed groups, sorted by best validation loss).",
        epilog="""grid file (TOML):
  task = "nav"                      # nav | arm
  data = "datasets/nav"             # from the current directory
  [train]                           # settings shared by every point
  epochs = 10
  size = 160                        # or "cpu" / "paper", as sebvs train --size
  [axes]                            # a list per setting; the grid is their product
  modality = ["rgb", "event", "rgb+event"]
  seed = [0, 1, 2]
  lr = [2e-4, 5e-4]

settings: modality, seed, lr, stem, epochs, batch, size, event_clip, max_frames,
memory, aux_weight, modality_dropout, seq_len, lanes, burn_in (the recipe options),
patience, val_fraction (sebvs train's options; one not given keeps its default).
A point's directory is named by its modality, seed and other axes, e.g.
modality=event__seed=1__lr=0.0005. A rerun into the same OUT skips points whose
checkpoint and config exist (refusing ones trained with other settings) and trains
failed or unfinished ones again. A failed point is recorded with its error
(and the traceback in its train.log); the others go on, and the exit status is 1.
docs/scale.md, "Sweeps".""")
    w.add_argument("grid", help="grid file (TOML)")
    w.add_argument("--out", required=True, help="sweep directory: one subdirectory per point")
    w.add_argument("--workers", type=int, default=1, metavar="N",
                   help="points trained at once on this machine (default 1: one after another "
                        "in this process). Each worker is a process of its own with --threads "
                        "torch threads, pinned to its own CPUs (os.sched_setaffinity) when the "
                        "machine has N x threads CPUs, else placed by the kernel. With --ray: "
                        "tasks in flight (default 1 means as many as the cluster has CPUs)")
    w.add_argument("--ray", nargs="?", const="", default=None, metavar="ADDRESS",
                   help="train the points as Ray tasks, one per point: on the cluster at "
                        "ADDRESS, or on a local Ray started for this command when no ADDRESS "
                        "is given (pip install -e .[ray]; a cluster needs the checkout, the "
                        "data and OUT at the same paths on every node)")
    w.add_argument("--threads", type=int, default=None, metavar="T",
                   help="torch threads per point (default: this machine's CPUs divided among "
                        "the workers; with --ray 1); a Ray task asks for T CPUs. On the CPU, "
                        "the same threads give the same weights for any --workers")
    w.add_argument("--device", default="cpu",
                   help="torch device of every point, e.g. cuda (default cpu; bit-reproducible "
                        "on cpu only). Local workers share this machine's device; with --ray "
                        "each task gets its own GPUs")
    w.add_argument("--gpus-per-task", type=float, default=None, metavar="G",
                   help="with --ray and --device cuda: GPUs each task asks Ray for (default 1; "
                        "0.5 trains two points per GPU)")
    w.add_argument("--no-progress", action="store_true",
                   help="no per-point tqdm bars (off anyway when points train at once)")
    w.add_argument("--dry-run", action="store_true",
                   help="list the points and which are trained already; train nothing")
    w.set_defaults(func=_cmd_train_sweep)


def _cmd_train_dagger(args) -> int:
    from .dagger import DaggerSettings, run_dagger
    try:
        settings = DaggerSettings(
            task=args.task, modality=args.modality, base=tuple(args.data),
            episodes=args.episodes, episode_s=args.episode_s, first_seed=args.first_seed,
            topology=args.topology, sets=tuple(args.set), init=args.init,
            train=train_overrides(args, args.loader_workers))
        run_dagger(settings, args.out, args.rounds, workers=args.workers,
                   progress=not args.no_progress, force=args.force)
    except (FileNotFoundError, ValueError) as exc:   # bad data or settings: one line
        print(f"sebvs train-dagger: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    return 0


def _register_train_dagger(subparsers) -> None:
    """`sebvs train-dagger`: `sebvs train`'s options (add_train_arguments) and the rounds'
    own, run by `_cmd_train_dagger`. A command of its own beside train-sweep rather than
    flags of `sebvs train`: a round records as well as trains, and its --workers are the
    recording's fan-out, not DataLoader workers."""
    d = subparsers.add_parser(
        "train-dagger", conflict_handler="resolve",
        help="DAgger rounds: the policy drives, the expert labels, retrain on all of it",
        description="DAgger (Ross et al. 2011) for one modality. Round 0 trains it on the "
                    "base data (or --init drives round 1); each round r then records "
                    "--episodes episodes of topologies/nav_dagger.toml with round r-1's "
                    "checkpoint driving and the expert labelling every tick, on topology "
                    "seed --first-seed + r - 1 (train split only), into "
                    "<out>/round-<r>/data, checks it as `sebvs data check` does, and trains "
                    "on the base data plus every round's into <out>/round-<r>/checkpoints. "
                    "<out>/dagger.json is the ledger: run the command again to go on at "
                    "the first unfinished round (docs/policy.md, \"DAgger rounds\"). "
                    "Training options are `sebvs train`'s.")
    add_train_arguments(d)
    # redefined for the rounds (conflict_handler "resolve" replaces train's)
    d.add_argument("--task", required=True, choices=["nav", "arm"],
                   help="nav (topologies/nav_dagger.toml); arm needs a --topology of your "
                        "own: its scene holds HOME, so a policy's poses change no frame")
    d.add_argument("--modality", required=True,
                   choices=["rgb", "event", "rgb+event", "rgb+diff"],
                   help="the one modality that drives and is trained")
    d.add_argument("--data", required=True, action="append", metavar="DIR",
                   help="base dataset, the expert's recording (repeatable)")
    d.add_argument("--out", required=True, metavar="DIR",
                   help="the run's folder: dagger.json and round-<r>/{data,checkpoints}")
    d.add_argument("--loader-workers", type=_workers, default="auto", metavar="N|auto",
                   help="DataLoader workers of each training (sebvs train --workers; "
                        "default auto)")
    d.add_argument("--force", action="store_true",
                   help="write into a non-empty folder that holds no dagger.json (a run of "
                        "other settings is refused either way: give another --out)")
    g = d.add_argument_group("rounds")
    g.add_argument("--rounds", type=int, required=True, metavar="R",
                   help="finish rounds up to R (a later call with a larger R goes on)")
    g.add_argument("--episodes", type=int, required=True, metavar="E",
                   help="episodes recorded per round (at least 2)")
    g.add_argument("--workers", type=int, default=None, metavar="N",
                   help="processes each round's recording fans out over (sebvs record "
                        "--workers; default one)")
    g.add_argument("--episode-s", type=float, default=None, metavar="SECONDS",
                   help="episode length of the rounds' recordings (default the topology's)")
    g.add_argument("--first-seed", type=seed_arg, default=500, metavar="S",
                   help="round 1's topology seed; round r records on S + r - 1, which must "
                        "stay in the train split (0-999) and off the base data's seeds "
                        "(default 500)")
    g.add_argument("--init", default=None, metavar="DIR",
                   help="a folder with <task>-<modality>.pt to drive round 1 (default: "
                        "round 0 trains one on the base data)")
    g.add_argument("--topology", default=None, metavar="FILE",
                   help="the recording topology, its recorder's drive wired to a policy "
                        "(default topologies/nav_dagger.toml)")
    g.add_argument("--set", action="append", default=[], metavar="ACTOR.KEY=VALUE",
                   help="override the recording topology in every round, as sebvs record "
                        "--set (repeatable)")
    d.set_defaults(func=_cmd_train_dagger)
