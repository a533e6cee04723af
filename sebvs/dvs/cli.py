"""`sebvs v2e` (offline conversion) and `sebvs events show` (a look at an event file)."""
from __future__ import annotations

import argparse
import json
import sys

from .params import PRESETS


def _cmd_v2e(args) -> int:
    from .convert import convert
    from .params import preset
    try:
        overrides = {k: v for k, v in (("seed", args.seed), ("max_gap_s", args.max_gap_s))
                     if v is not None}
        params = preset(args.preset, **overrides)
        info = convert(args.input, args.out, params, fps=args.fps, progress=not args.quiet)
    except ValueError as exc:
        print(f"sebvs v2e: {exc}", file=sys.stderr)
        return 2
    print(json.dumps(info))
    return 0


def _cmd_events_show(args) -> int:
    from .render import render_file
    try:
        render_file(args.file, args.out, n=args.frames, window_ms=args.window_ms)
    except (ValueError, OSError) as exc:
        print(f"sebvs events show: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {args.out}")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    v = sub.add_parser("v2e", help="convert a video or image folder to events (HDF5)",
                       description="Emulate a DVS on every frame of a video file or an image "
                                   "folder and write events/x, y, t (us), p and ms_to_idx.")
    v.add_argument("input", help="video file, or folder of images (sorted by name)")
    v.add_argument("--out", required=True, help="output .h5 file")
    v.add_argument("--preset", default="paper", choices=sorted(PRESETS))
    v.add_argument("--fps", type=float, default=None,
                   help="frame rate (required for image folders; overrides a video's)")
    v.add_argument("--seed", type=int, default=None)
    v.add_argument("--max-gap-s", type=float, default=None,
                   help="frames further apart restart the sensor (default 10; raise it for "
                        "slow time-lapse folders)")
    v.add_argument("--quiet", action="store_true", help="no progress bar")
    v.set_defaults(func=_cmd_v2e)

    e = sub.add_parser("events", help="event file tools")
    esub = e.add_subparsers(dest="events_cmd", metavar="COMMAND", required=True)
    s = esub.add_parser("show", help="render a few accumulated frames to a PNG")
    s.add_argument("file")
    s.add_argument("--out", required=True, help="PNG file")
    s.add_argument("--frames", type=int, default=6)
    s.add_argument("--window-ms", type=float, default=33.0)
    s.set_defaults(func=_cmd_events_show)
