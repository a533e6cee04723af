"""The `sebvs` command line. Each subcommand's work lives in the library; this only parses."""
from __future__ import annotations

import argparse
import importlib
import json
import math
import os
import signal
import sys
import tomllib

from .shipped import topology_argument

# subcommand modules with a `register(subparsers)`; each adds its own commands
PLUGINS = ("sebvs.demo", "sebvs.dvs.cli", "sebvs.data.cli", "sebvs.policy.cli", "sebvs.eval.cli",
           "sebvs.view.cli", "sebvs.probe.cli")


def _seconds(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of seconds") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"{text!r}: expected a positive, finite number "
                                         f"of seconds")
    return value


def _cmd_run(args) -> int:
    from .runtime.profiler import ProfileCollector, format_report, write_json
    from .runtime.supervisor import RunFailed, Supervisor
    from .runtime.topology import load_topology

    topo = load_topology(args.topology, args.set)
    sup = Supervisor(topo, runs_dir=args.runs_dir, log_level=args.log_level, host=args.host)
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda s, f: sup.interrupt(signal.Signals(s).name))
    collector = None
    try:
        sup.start()
        print(f"sebvs: run {topo.name} ({sup.run_id}) in {sup.rundir}", file=sys.stderr)
        if sup.host is not None and sup.primary and len(sup.info["hosts"]) > 1:
            print(f"sebvs: clock offsets of the other hosts in {sup.rundir / 'run.json'} "
                  f"('hosts'); `sebvs profile {sup.rundir}` corrects hop latencies with them",
                  file=sys.stderr)
        pruned = [n for n, a in topo.actors.items() if a.pruned]
        if pruned:
            print(f"sebvs: pruned (outputs not consumed): {', '.join(pruned)}", file=sys.stderr)
        on_poll = None
        if args.profile or args.profile_json:
            collector = ProfileCollector(sup.info)
            on_poll = collector.poll
        code = sup.wait(args.duration, on_poll)
    except RunFailed as exc:
        print(f"sebvs: {exc}", file=sys.stderr)
        sup.stop()
        return 1
    except BaseException:
        sup.stop()
        raise
    if sup.failure:
        print(f"sebvs: run stopped: {sup.failure.splitlines()[0]}", file=sys.stderr)
    if collector is not None:
        rep = collector.report()
        collector.close()
        print(format_report(rep))
        if args.profile_json:
            write_json(rep, args.profile_json)
    return code


def _cmd_graph(args) -> int:
    from .runtime.graph import describe, to_dot
    from .runtime.topology import load_topology
    topo = load_topology(args.topology, args.set)
    print(to_dot(topo) if args.dot else describe(topo))
    return 0


def _cmd_ps(args) -> int:
    from .runtime.runs import live_runs
    runs = live_runs()
    if args.json:
        print(json.dumps(runs, indent=2))
        return 0
    if not runs:
        print("no live runs")
        return 0
    print(f"{'name':<16} {'id':<9} {'clock':<9} {'actors':>6}  {'started':<20} rundir")
    for r in runs:
        print(f"{r['name']:<16} {r['run_id']:<9} {r.get('clock', ''):<9} "
              f"{len(r['actors']):>6}  {r['started_at']:<20} {r['rundir']}")
    return 0


def _cmd_ctl(args) -> int:
    import zmq
    from .runtime.runs import resolve_run
    from .runtime.supervisor import control_request
    from .runtime.overrides import parse_key_value

    info = resolve_run(args.run)
    if args.actor not in info["actors"]:
        print(f"sebvs ctl: run {info['name']} has no actor {args.actor!r} "
              f"(actors: {', '.join(info['actors'])})", file=sys.stderr)
        return 2
    if args.command == "set":
        if not args.args:
            print("sebvs ctl: set needs key=value", file=sys.stderr)
            return 2
        requests = []
        for text in args.args:
            parts, value = parse_key_value(text) if "=" in text else ([""], None)
            if not all(parts):          # no "=", or an empty key: "=3", "a..b=3"
                print(f"sebvs ctl: set expects key=value, got {text!r}", file=sys.stderr)
                return 2
            requests.append({"cmd": "set", "key": ".".join(parts), "value": value})
    elif args.command == "get":
        requests = [{"cmd": "get", "key": k} for k in args.args] or [{"cmd": "get"}]
    else:
        requests = [{"cmd": args.command}]
    ctx = zmq.Context.instance()
    code = 0
    for req in requests:
        try:
            reply = control_request(ctx, info["actors"][args.actor]["control"], req,
                                    args.timeout, token=info.get("token"))
        except ValueError:      # msgpack's errors: not an actor's control socket answering
            reply = "unreadable"
        if reply is None:
            print(f"sebvs ctl: {args.actor} did not answer within {args.timeout} s",
                  file=sys.stderr)
            return 1
        if not isinstance(reply, dict):
            print(f"sebvs ctl: {args.actor} sent an unreadable reply", file=sys.stderr)
            return 1
        print(json.dumps(reply.get("result") if reply.get("ok") else reply, indent=2))
        if not reply.get("ok"):
            code = 1
    return code


def _cmd_profile(args) -> int:
    from .runtime.profiler import ProfileCollector, format_report, plot_report, write_json
    from .runtime.runs import resolve_run
    info = resolve_run(args.run)
    collector = ProfileCollector(info)
    try:
        collector.poll(args.duration)
    except KeyboardInterrupt:
        pass
    rep = collector.report()
    print(format_report(rep))
    if args.json:
        write_json(rep, args.json)
    if args.plot:
        plot_report(rep, collector, args.plot)
    if args.trace:
        from .runtime.trace import build_trace, select_records, write_trace
        trace = build_trace(select_records(list(collector.kept.values()), args.trace_ticks),
                            run=str(info.get("name", "")))
        write_trace(trace, args.trace)
        print(f"trace: {args.trace} ({trace['otherData']['records']} handled messages; "
              f"open it in ui.perfetto.dev or chrome://tracing)")
    collector.close()
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="sebvs",
        description="Synthetic event-based visual servoing: MuJoCo robots seen through an "
                    "emulated event camera, run as a graph of ZeroMQ actors.")
    p.add_argument("--debug", action="store_true",
                   help="on an error, show the Python traceback instead of one line "
                        "(give it before the command: sebvs --debug run ...)")
    sub = p.add_subparsers(dest="cmd", metavar="COMMAND", required=True)

    r = sub.add_parser("run", help="start a topology: one process per actor",
                       description="Start every actor of a topology in its own process, "
                                   "wait until all are ready, start the clock, and supervise "
                                   "until --for elapses, Ctrl-C, or an actor ends the run.")
    r.add_argument("topology", type=topology_argument, help="topology TOML file")
    r.add_argument("--set", action="append", default=[], metavar="ACTOR.KEY=VALUE",
                   help="override a parameter (value read as TOML; repeatable)")
    r.add_argument("--for", dest="duration", type=_seconds, default=None, metavar="SECONDS",
                   help="stop after this many seconds (default: until Ctrl-C or the end)")
    r.add_argument("--profile", action="store_true",
                   help="attach the latency profiler and print its table at the end")
    r.add_argument("--profile-json", metavar="FILE", help="also write the profile as JSON")
    r.add_argument("--runs-dir", default=None,
                   help="where run directories go (default ./runs or $SEBVS_RUNS_DIR)")
    r.add_argument("--log-level", default="INFO", choices=["DEBUG", "INFO", "WARNING"])
    r.add_argument("--host", default=None, metavar="NAME",
                   help="a topology with [hosts.<name>] tables: run this host's actors "
                        "(one `sebvs run FILE --host NAME` per host, all with the same "
                        "SEBVS_RUN_TOKEN; the first listed host starts the clock; "
                        "docs/scale.md, 'Several hosts')")
    r.set_defaults(func=_cmd_run)

    g = sub.add_parser("graph", help="show a topology's graph, pruned actors marked")
    g.add_argument("topology", type=topology_argument)
    g.add_argument("--set", action="append", default=[], metavar="ACTOR.KEY=VALUE")
    g.add_argument("--dot", action="store_true", help="print Graphviz DOT instead of text")
    g.set_defaults(func=_cmd_graph)

    s = sub.add_parser("ps", help="list live runs")
    s.add_argument("--json", action="store_true")
    s.set_defaults(func=_cmd_ps)

    c = sub.add_parser("ctl", help="talk to an actor of a live run",
                       description="Send a control command to one actor: get [KEY...], "
                                   "set KEY=VALUE..., stats, stop. Replies are printed as JSON.")
    c.add_argument("run", nargs="?", default=None,
                   help="run name, id or directory (default: the newest live run)")
    c.add_argument("actor")
    c.add_argument("command", choices=["get", "set", "stats", "stop", "ping"])
    c.add_argument("args", nargs="*", metavar="KEY[=VALUE]")
    c.add_argument("--timeout", type=_seconds, default=3.0)
    c.set_defaults(func=_cmd_ctl)

    f = sub.add_parser("profile", help="attach the latency profiler to a live run",
                       description="Subscribe to every actor's telemetry for a while and "
                                   "print per-edge transport latency, per-actor handler time "
                                   "(p50/p90/p99/max, counts, drops), end-to-end chains and "
                                   "each chain split per hop into queueing, wake-up, "
                                   "transport and handler (docs/runtime.md).")
    f.add_argument("run", nargs="?", default=None,
                   help="run name, id or directory (default: the newest live run)")
    f.add_argument("--for", dest="duration", type=_seconds, default=5.0, metavar="SECONDS")
    f.add_argument("--json", metavar="FILE")
    f.add_argument("--plot", metavar="FILE", help="latency histograms as PNG")
    f.add_argument("--trace", metavar="FILE.json",
                   help="write a Chrome trace-event file of the last --trace-ticks ticks "
                        "(one track per actor; open in ui.perfetto.dev or chrome://tracing)")
    f.add_argument("--trace-ticks", type=int, default=300, metavar="N",
                   help="control ticks in the trace (default 300)")
    f.set_defaults(func=_cmd_profile)

    for name in PLUGINS:
        importlib.import_module(name).register(sub)
    return p


def main(argv: list[str] | None = None) -> int:
    if os.getcwd() not in sys.path:
        sys.path.insert(0, os.getcwd())  # users' actor modules, as `python -m` would see them
    args = build_parser().parse_args(argv)
    from .runtime.runs import RunInfoError
    from .runtime.supervisor import RunFailed
    from .runtime.topology import TopologyError
    # what a user can get wrong (a file, a value, a run name): one line and exit status 2;
    # anything else is a bug and keeps its traceback (a KeyError too, though a LookupError)
    user_errors = (TopologyError, RunInfoError, LookupError, tomllib.TOMLDecodeError, OSError)
    try:
        return args.func(args)
    except user_errors as exc:
        if args.debug or isinstance(exc, (KeyError, IndexError)):
            raise
        print(f"sebvs: {_one_line(exc)}", file=sys.stderr)
        return 2
    except RunFailed as exc:    # an actor died: its message carries the end of its log
        if args.debug:
            raise
        print(f"sebvs: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        if args.debug:
            raise
        print("sebvs: interrupted", file=sys.stderr)
        return 130


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).splitlines()).strip()
    return text or type(exc).__name__


if __name__ == "__main__":
    sys.exit(main())
