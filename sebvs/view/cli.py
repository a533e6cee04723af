"""`sebvs view [RUN | EPISODE.h5]`: a live run or a recorded episode in the rerun viewer.

rerun is imported when the command runs (the optional extra `[view]`), so `sebvs` and its
other commands work without it.
"""
from __future__ import annotations

import argparse
import asyncio
import json
import signal
import sys
import time
from pathlib import Path

# what sebvs.extras.require says when rerun is missing
MISSING_RERUN = "sebvs view needs rerun-sdk: pip install 'sebvs[view]'"
EPISODE_SUFFIXES = (".h5", ".hdf5")
FLUSH_TIMEOUT_S = 60.0     # the last rows into the file or the web viewer's server


def _seconds(text: str) -> float:
    from sebvs.cli import _seconds as seconds     # the other commands' --for parser
    return seconds(text)


def _port(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a port number") from None
    if not 1 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"{text!r}: a port is 1..65535")
    return value


def register(sub) -> None:
    v = sub.add_parser(
        "view", help="show a live run or a recorded episode in the rerun viewer",
        description="Attach read-only to a live run (as `sebvs profile` does) or replay an "
                    "episode file, and show RGB frames, event frames (ON blue, OFF red), "
                    "the target's truth over them, the commands and each hop's latency "
                    "on the tick and sim_time timelines (docs/view.md). Needs the extra "
                    "[view] (rerun-sdk).")
    v.add_argument("source", nargs="?", default=None, metavar="RUN | EPISODE.h5",
                   help="run name, id or directory (default: the newest live run), or an "
                        "episode file from `sebvs record`")
    where = v.add_mutually_exclusive_group()
    where.add_argument("--save", metavar="FILE.rrd",
                       help="write a recording file instead of opening a viewer")
    where.add_argument("--serve", action="store_true",
                       help="serve the web viewer on 127.0.0.1 (for a headless machine; "
                            "forward the ports over ssh) until Ctrl-C")
    v.add_argument("--for", dest="duration", type=_seconds, default=None, metavar="SECONDS",
                   help="live: detach after this long (default: when the run ends, or "
                        "Ctrl-C)")
    v.add_argument("--grpc-port", type=_port, default=9876,
                   help="--serve: the port the recording streams to (default 9876)")
    v.add_argument("--web-port", type=_port, default=9090,
                   help="--serve: the web viewer's page (default 9090)")
    v.add_argument("--json", metavar="FILE", help="also write the summary as JSON")
    v.add_argument("--force", action="store_true",
                   help="replace the --save or --json file if it exists (never the episode "
                        "or a dataset's files)")
    v.set_defaults(func=_cmd_view)


def _is_episode(source: str | None) -> bool:
    return source is not None and (Path(source).suffix.lower() in EPISODE_SUFFIXES
                                   or Path(source).is_file())


def _raise_interrupt(signum, frame):
    raise KeyboardInterrupt


def _cmd_view(args) -> int:
    from sebvs.extras import MissingExtra, require
    try:
        rr = require("rerun", "rerun-sdk", "view", "sebvs view")
    except MissingExtra as exc:
        print(exc, file=sys.stderr)           # MISSING_RERUN
        return 2
    from sebvs.runtime.runs import RunInfoError
    from .replay import NotAnEpisode
    from .sink import ViewerError

    from sebvs.output_guard import OutputRefused, check_output_file
    episode = info = server = None
    try:
        sources = [args.source] if _is_episode(args.source) else []
        for out in (args.save, args.json):
            if out:
                check_output_file(out, inputs=sources, force=args.force)
        episode, info, name = _open_source(args.source)
        rec = rr.RecordingStream("sebvs")
        rec.send_recording_name(name)
        server = _open_sink(rec, args)
    except (NotAnEpisode, RunInfoError, LookupError, ViewerError, OutputRefused) as exc:
        if episode is not None:
            episode.close()
        print(f"sebvs view: {exc}", file=sys.stderr)
        return 2
    old_term = signal.signal(signal.SIGTERM, _raise_interrupt)   # stop as on Ctrl-C
    try:
        return _show(rr, rec, episode, info, server, args)
    except KeyboardInterrupt:
        return 0
    finally:
        signal.signal(signal.SIGTERM, old_term)
        rec.disconnect()
        if server is not None:
            server.stop()
        if episode is not None:
            episode.close()


def _open_source(source: str | None):
    """(episode, None, name) for an episode file, (None, run.json, name) for a run."""
    from sebvs.runtime.runs import resolve_run
    from .replay import open_for_replay
    if _is_episode(source):
        return open_for_replay(source), None, Path(source).name
    info = resolve_run(source)
    return None, info, f"{info['name']} ({info['run_id']})"


def _open_sink(rec, args):
    """Connect the recording to its sink; the WebViewer with --serve, else None."""
    from .sink import WebViewer, save_to, spawn_native
    if args.save:
        save_to(rec, args.save)
        return None
    if args.serve:
        server = WebViewer(args.grpc_port, args.web_port).start()
        rec.connect_grpc(server.grpc_url)
        print(f"sebvs view: web viewer at {server.page_url}", flush=True)
        return server
    spawn_native(rec)
    return None


def _show(rr, rec, episode, info, server, args) -> int:
    """Replay the episode or attach to the run, print the summary; with --serve, serve on
    until Ctrl-C."""
    from .entities import ViewLog, layout
    view = ViewLog(rr, rec)
    interrupted = False
    if episode is not None:
        from .replay import image_entities, replay_episode
        rec.send_blueprint(layout(rr.blueprint, image_entities(episode)))
        t0 = time.monotonic()
        rows = replay_episode(episode, view)
        summary = {"episode": str(args.source), "rows": rows,
                   "seconds": round(time.monotonic() - t0, 3), "entities": dict(view.rows)}
    else:
        from .live import LiveView
        live = LiveView(info, view)
        rec.send_blueprint(layout(rr.blueprint, live.image_sources()))
        try:
            asyncio.run(live.run(args.duration))
        except KeyboardInterrupt:
            interrupted = True      # Ctrl-C ends the attach: the summary still follows
        summary = live.summary()
    try:
        rec.flush(timeout_sec=FLUSH_TIMEOUT_S)
    except Exception as exc:        # rerun raises its own types when a sink is gone
        print(f"sebvs view: the last rows did not reach the viewer: "
              f"{str(exc).splitlines()[0] if str(exc) else type(exc).__name__}",
              file=sys.stderr)
        return 1
    print(format_summary(summary, args), flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(summary, indent=2))
    if server is not None and not interrupted:
        print("sebvs view: serving; Ctrl-C to stop", flush=True)
        while True:
            time.sleep(3600)
    return 0


def format_summary(summary: dict, args) -> str:
    where = (f"written to {args.save}" if args.save else
             "served" if args.serve else "sent to the viewer")
    if "episode" in summary:
        head = f"view: {summary['episode']}, {summary['rows']} rows replayed, {where}"
    else:
        head = (f"view: run {summary['run']} ({summary['run_id']}), "
                f"{summary['seconds']:.1f} s attached, {where}")
    lines = [head]
    if summary.get("outputs"):
        lines.append(f"{'output':<28} {'received':>9} {'dropped':>8}")
        for src, st in sorted(summary["outputs"].items()):
            dropped = sum(v for k, v in st.items() if k != "received")
            lines.append(f"{src:<28} {st['received']:>9} {dropped:>8}")
    lines.append(f"{'entity':<40} {'rows':>6}")
    for entity, n in sorted(summary["entities"].items()):
        lines.append(f"{entity:<40} {n:>6}")
    return "\n".join(lines)
