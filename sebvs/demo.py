"""`sebvs demo`: one closed-loop run with the profiler attached, an optional live modality
swap half-way through, and the tracking metrics per modality at the end.

It is `sebvs run` plus two things a person wants to see at once: what each hop costs,
and how well the robot tracked the target before and after the swap.
"""
from __future__ import annotations

import argparse
import json
import signal
import sys
import time
from pathlib import Path

from .runtime.overrides import Overrides, as_mapping, lookup
from .runtime.profiler import ProfileCollector, format_loop_latency, format_report
from .runtime.supervisor import RunFailed, Supervisor
from .runtime.topology import load_topology
from .sensor_pairs import SENSORS, topology_overrides
from .shipped import topology_argument


def _format_metrics(records: list[dict]) -> str:
    """The tracker's finished episodes as a table: nav's per modality that acted (a swap
    can fall inside an episode), the arm's per episode (21 ticks, then the grasp)."""
    if not records:
        return "tracking: no finished episode"
    if all("by_modality" in r for r in records):
        return _format_nav(records)
    return _format_arm(records)


def _format_nav(records: list[dict]) -> str:
    rows = [(r["episode"], mod, m) for r in records for mod, m in r["by_modality"].items()]
    lines = ["tracking (Table 4 metrics, privileged truth; success = target within 200 px "
             "of the centre at 640 px, scaled)",
             f"{'episode':>7}  {'modality':<10} {'frames':>6} {'centroid err px':>16} "
             f"{'bbox w px':>9} {'success %':>9} {'visible %':>9}"]
    for ep, mod, m in rows:
        lines.append(f"{ep:>7}  {mod:<10} {m['frames']:>6} "
                     f"{m['centroid_error_px']:>8.1f} ± {m['centroid_error_std_px']:<5.1f} "
                     f"{m['bbox_width_px']:>9.1f} {100 * m['success']:>9.1f} "
                     f"{100 * m['visible']:>9.1f}")
    return "\n".join(lines)


def _format_arm(records: list[dict]) -> str:
    lines = ["tracking (Table 5 metrics against the task's pose, privileged truth; the arm "
             "tracker scores whole episodes, whichever modality acted)",
             f"{'episode':>7}  {'ticks':>5} {'position err mm':>16} {'yaw err deg':>11} "
             f"{'accuracy %':>10}  outcome"]
    for r in records:
        m = r.get("metrics") or {}
        if "position_error_mm" not in m:
            lines.append(f"{r.get('episode', '?'):>7}  no scored tick ({r.get('reason', '')})")
            continue
        lines.append(f"{r['episode']:>7}  {r['ticks']:>5} "
                     f"{m['position_error_mm']:>8.1f} ± {m['position_error_std_mm']:<5.1f} "
                     f"{m['yaw_error_deg']:>11.1f} {100 * m['accuracy']:>10.1f}  "
                     f"{m.get('outcome') or '-'}")
    return "\n".join(lines)


def run_demo(topology: str, overrides: list, swap_to: str | None, swap_after: int,
             profile_json: str | None = None, clock: str | None = None) -> int:
    """Run the topology to its end with the profiler; print the latency and the metrics.

    Parameters:
        topology: the closed-loop topology file.
        overrides: override layers (mappings, or --set lines as typed), after `clock`.
        swap_to, swap_after: the modality the policy is set to after that many actions.
        profile_json: where the profile is written as JSON, if anywhere.
        clock: "realtime" or "lockstep"; None: the topology's.

    Returns:
        The run's exit status.
    """
    clocked = [{"topology": {"clock": clock}}] if clock else []
    topo = load_topology(topology, [*clocked, *overrides])
    out = Path("runs") / "demo-tracking.jsonl"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.unlink(missing_ok=True)
    if "tracker" in topo.active:
        topo.actors["tracker"].params["path"] = str(out)
    sup = Supervisor(topo, echo=lambda text: print(text, file=sys.stderr))
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda s, f: sup.interrupt(signal.Signals(s).name))
    try:
        sup.start()
    except RunFailed as exc:
        print(f"sebvs demo: {exc}", file=sys.stderr)
        sup.stop()
        return 1
    print(f"sebvs demo: {topo.name} running ({sup.rundir})", file=sys.stderr)
    collector = ProfileCollector(sup.info)
    swapped = [swap_to is None]
    last_check = [0.0]

    def poll(dt: float) -> None:
        collector.poll(dt)
        if swapped[0] or time.monotonic() - last_check[0] < 0.1:
            return
        last_check[0] = time.monotonic()
        stats = sup.request("policy", {"cmd": "stats"}, 1.0)
        if not (stats and stats.get("ok")
                and stats["result"]["actor_stats"]["emitted"] >= swap_after):
            return
        swapped[0] = True
        reply = sup.request("policy", {"cmd": "set", "key": "modality", "value": swap_to}, 3.0)
        print(f"sebvs demo: after {swap_after} actions, policy set modality={swap_to}: "
              f"{json.dumps(reply.get('result') if reply and reply.get('ok') else reply)}",
              file=sys.stderr)

    try:
        code = sup.wait(None, poll)
    except BaseException:
        sup.stop()
        raise
    report = collector.report()
    report["loop"] = collector.loop_latency()
    collector.close()
    print(format_report(report))
    print()
    print(format_loop_latency(report["loop"], topo.clock))
    if profile_json:
        Path(profile_json).write_text(json.dumps(report, indent=2))
    records = [json.loads(x) for x in out.read_text().splitlines()] if out.exists() else []
    print()
    print(_format_metrics(records))
    if sup.failure:
        print(f"sebvs demo: {sup.failure}", file=sys.stderr)
    return code


def load_for_swap(swap_to: str | None, sets: Overrides) -> dict:
    """The override that loads the checkpoint of the modality swapped to where the policy
    would not load it (by default it loads the paper's three), unless the user's overrides
    list the policy's modalities themselves; else {}."""
    from .policy.inputs import MODALITIES
    if swap_to is None or swap_to in MODALITIES or \
            lookup(as_mapping(sets), "policy", "modalities") is not None:
        return {}
    return {"policy": {"modalities": [*MODALITIES, swap_to]}}


def _cmd_demo(args) -> int:
    if args.swap_to and args.swap_after is None:
        print("sebvs demo: --swap-to needs --swap-after TICKS", file=sys.stderr)
        return 2
    overrides = [*([] if args.sensor is None else [topology_overrides(args.sensor)]),
                 *args.set, load_for_swap(args.swap_to, args.set)]
    return run_demo(args.topology, overrides, args.swap_to, args.swap_after or 0,
                    args.profile_json, args.clock)


def register(sub: argparse._SubParsersAction) -> None:
    d = sub.add_parser("demo", help="closed loop with the profiler, a live modality swap, "
                                    "and tracking metrics",
                       description="Run a closed-loop topology to its end with the latency "
                                   "profiler attached; optionally swap the policy's modality "
                                   "after --swap-after control ticks; print per-hop latency "
                                   "and the tracker's metrics per episode and modality.")
    d.add_argument("topology", type=topology_argument)
    d.add_argument("--sensor", choices=SENSORS, default=None,
                   help="run this sensor pair with the checkpoints trained on it: physical "
                        "(the shipped topologies' own) or ideal8 (the 8-bit benchmark before "
                        "it: camera.sensor=\"ideal8\", the emulator's \"paper\" preset, "
                        "checkpoints/ideal8/); --set lines come after it")
    d.add_argument("--set", action="append", default=[], metavar="ACTOR.KEY=VALUE")
    d.add_argument("--swap-to", choices=["rgb", "event", "rgb+event", "rgb+diff"], default=None,
                   help="the modality to swap the policy to; its checkpoint is loaded "
                        "beside the paper's three (rgb+diff, the frame-difference control, "
                        "is not loaded otherwise)")
    d.add_argument("--swap-after", type=int, default=None, metavar="TICKS",
                   help="swap once the policy has acted this many control ticks")
    d.add_argument("--clock", choices=["realtime", "lockstep"], default="realtime",
                   help="realtime (default): the loop runs as fast as it is, its actors at "
                        "SCHED_FIFO where the process may, the policy on its frozen graph, "
                        "and the loop's latency is printed beside its target; lockstep: "
                        "every tick waits for every actor, results reproduce bit for bit")
    d.add_argument("--profile-json", metavar="FILE")
    d.set_defaults(func=_cmd_demo)
