"""`sebvs v2e` (offline conversion), `sebvs events show` (a look at an event file) and
`sebvs events export` (to AEDAT4 or the common HDF5 layout)."""
from __future__ import annotations

import argparse
import json
import sys

from .params import PRESET_VERSION, PRESET_VERSIONS, PRESETS


FORCE_HELP = "replace OUT if it exists (never an input, an episode or a dataset's index)"


def _cmd_v2e(args) -> int:
    from ..output_guard import check_output_file
    from .convert import convert
    from .params import preset
    try:
        check_output_file(args.out, inputs=[args.input], force=args.force)
        overrides = {k: v for k, v in (("seed", args.seed), ("max_gap_s", args.max_gap_s))
                     if v is not None}
        overrides["preset_version"] = args.preset_version
        params = preset(args.preset, **overrides)
        info = convert(args.input, args.out, params, fps=args.fps, progress=not args.quiet)
    except (ValueError, OSError) as exc:
        print(f"sebvs v2e: {exc}", file=sys.stderr)
        return 2
    print(json.dumps(info))
    return 0


def _cmd_events_show(args) -> int:
    from ..output_guard import check_output_file
    from .render import render_file
    try:
        check_output_file(args.out, inputs=[args.file], force=args.force)
        render_file(args.file, args.out, n=args.frames, window_ms=args.window_ms)
    except (ValueError, OSError, ImportError) as exc:      # ImportError: a missing extra
        print(f"sebvs events show: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {args.out}")
    return 0


def _cmd_events_export(args) -> int:
    from ..extras import MissingExtra
    from ..output_guard import check_output_file
    from .export import export_events
    try:
        check_output_file(args.out, inputs=[args.file], force=args.force)
        info = export_events(args.file, args.out, args.format, progress=not args.quiet)
    except (ValueError, OSError, MissingExtra) as exc:
        print(f"sebvs events export: {exc}", file=sys.stderr)
        return 2
    print(json.dumps(info))
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    v = sub.add_parser("v2e", help="convert a video or image folder to events (HDF5)",
                       description="Emulate a DVS on every frame of a video file or an image "
                                   "folder and write events/x, y, t (us), p and ms_to_idx.")
    v.add_argument("input", help="video file, or folder of images (sorted by name)")
    v.add_argument("--out", required=True, help="output .h5 file")
    v.add_argument("--preset", default="paper", choices=sorted(PRESETS))
    v.add_argument("--preset-version", type=int, default=PRESET_VERSION,
                   choices=PRESET_VERSIONS,
                   help=f"the presets' noise model (default {PRESET_VERSION}; 1: as before "
                        "issue 67, docs/dvs.md)")
    v.add_argument("--fps", type=float, default=None,
                   help="frame rate (required for image folders; overrides a video's)")
    v.add_argument("--seed", type=int, default=None)
    v.add_argument("--max-gap-s", type=float, default=None,
                   help="frames further apart restart the sensor (default 10; raise it for "
                        "slow time-lapse folders)")
    v.add_argument("--quiet", action="store_true", help="no progress bar")
    v.add_argument("--force", action="store_true", help=FORCE_HELP)
    v.set_defaults(func=_cmd_v2e)

    e = sub.add_parser("events", help="event file tools: show, export",
                       description="Event files of every layout the project reads: our "
                                   "HDF5 (sebvs v2e), the common DSEC-style HDF5, AEDAT4 "
                                   "and episode files with raw events (docs/formats.md).")
    esub = e.add_subparsers(dest="events_cmd", metavar="COMMAND", required=True)
    s = esub.add_parser("show", help="render a few accumulated frames to a PNG",
                        description="Render a few accumulated event frames (ON blue, OFF "
                                    "red) of an event file to a PNG; the file's layout is "
                                    "read from its content.")
    s.add_argument("file", help="event file: .h5 (ours or DSEC-style), .aedat4, or an "
                                "episode .h5 with raw events")
    s.add_argument("--out", required=True, help="PNG file")
    s.add_argument("--frames", type=int, default=6)
    s.add_argument("--window-ms", type=float, default=33.0)
    s.add_argument("--force", action="store_true", help=FORCE_HELP)
    s.set_defaults(func=_cmd_events_show)
    x = esub.add_parser("export", help="write an event file as AEDAT4 or common HDF5",
                        description="Write the events of FILE (any layout `events show` "
                                    "reads) as AEDAT4 through dv-processing, for DV and "
                                    "the iniVation tools, or as HDF5 in the common "
                                    "DSEC-style layout: events/x, y (uint16), t (uint32 us "
                                    "from the dataset t_offset), p (uint8 1 = ON, 0 = OFF) "
                                    "and ms_to_idx, gzip-compressed. Both keep "
                                    "microseconds: nanosecond timestamps (episodes) are "
                                    "floored. Prints a JSON summary; exit 2 on an "
                                    "unreadable input or an unwritable output. AEDAT4 "
                                    "needs pip install 'sebvs[formats]'.")
    x.add_argument("file", help="event file or episode with raw events")
    x.add_argument("--out", required=True, help="output file (.aedat4 or .h5)")
    x.add_argument("--format", choices=("aedat4", "h5"), default=None,
                   help="output format (default: from the --out suffix)")
    x.add_argument("--quiet", action="store_true", help="no progress bar")
    x.add_argument("--force", action="store_true", help=FORCE_HELP)
    x.set_defaults(func=_cmd_events_export)
