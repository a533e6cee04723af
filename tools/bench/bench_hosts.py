#!/usr/bin/env python3
"""Hop latency across hosts, offset-corrected, beside the same hop on one host (issue 17).

Three placements of the synthetic chain source > relay > sink (160 x 160 RGB at 100 Hz,
arrays inline over tcp in all three), each run for `--for` seconds with the profiler:

same_host     topologies/synthetic.toml with `transport = "tcp"`: one supervisor
plain         the same with SEBVS_CURVE=off: what CURVE (on by default) costs per hop
two_hosts     topologies/synthetic_hosts.toml: the relay on host b, a second supervisor
              on 127.0.0.1, both hops cross between the two
skewed        the same, b's clock 50 ms ahead (SEBVS_CLOCK_SKEW_NS): the profiler
              corrects b's stamps with the offset the primary estimated

Reported per placement and hop: p50 and p90 of the hop latency (median over repeats);
for the skewed runs the estimated offset, its stated uncertainty and its error against
the injected skew (both "hosts" share one physical clock, so the skew is the true
offset). The placements alternate within each repeat so a slow phase of a shared machine
hits all. The figure the issue names: |skewed p50 - same_host p50| per hop <= 0.5 ms;
beside it, `curve_cost`: same_host - plain per hop (p50, p90), and the CPU time of the
whole one-host run (supervisor and actors) per frame with and without it.

    tools/bench/bench_hosts.py [--quick] [--repeats N] [--for S] [--json FILE]
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from sebvs.runtime.ports import TcpPorts  # noqa: E402
from tools.benchio import print_report  # noqa: E402

SKEW_NS = 50_000_000
TARGET_MS = 0.5
HOPS = ("source/frames -> relay.frames", "relay/frames -> sink.frames")
FRAMES = ["--set", "source.width=160", "--set", "source.height=160",
          "--set", "source.rate_hz=100"]


def sebvs(args: list[str], env: dict) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "sebvs.cli", *args], cwd=ROOT,
                            env=dict(os.environ, **env), stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)


def run_placement(kind: str, seconds: float, tmp: Path) -> dict:
    """One run; its profile's hops (p50, p90 in us) and, two-host, b's clock entry."""
    profile = tmp / f"{kind}.json"
    runs = ["--runs-dir", str(tmp / "runs")]
    common = [*FRAMES, *runs, "--for", str(seconds), "--profile-json", str(profile)]
    token = {"SEBVS_RUN_TOKEN": os.urandom(16).hex()}
    if kind in ("same_host", "plain"):
        env = dict(token, SEBVS_CURVE="off" if kind == "plain" else "on")
        cpu0 = _children_cpu_s()
        proc = sebvs(["run", "topologies/synthetic.toml", "--set", "topology.transport=tcp",
                      *common], env)
        out, _ = proc.communicate(timeout=seconds + 60)
        cpu_s = _children_cpu_s() - cpu0       # the run and every actor it waited for
        if proc.returncode:
            raise RuntimeError(f"{kind}: exit {proc.returncode}\n{out[-2000:]}")
        clock = None
    else:
        cpu_s = None
        picker = TcpPorts()     # one picker: the two hosts' blocks cannot overlap
        ports = ["--set", f"hosts.a.port={picker.block(8)}", "--set", f"hosts.b.port={picker.block(8)}"]
        skew = {"SEBVS_CLOCK_SKEW_NS": str(SKEW_NS)} if kind == "skewed" else {}
        b = sebvs(["run", "topologies/synthetic_hosts.toml", "--host", "b", *ports, *FRAMES,
                   *runs], dict(token, **skew))
        a = sebvs(["run", "topologies/synthetic_hosts.toml", "--host", "a", *ports, *common],
                  token)
        out, _ = a.communicate(timeout=seconds + 90)
        out_b, _ = b.communicate(timeout=30)
        if a.returncode or b.returncode:
            raise RuntimeError(f"{kind}: exit {a.returncode}/{b.returncode}\n{out[-2000:]}\n"
                               f"{out_b[-2000:]}")
        infos = [json.loads(p.read_text()) for p in (tmp / "runs").glob("*/run.json")]
        primary = max((i for i in infos if i.get("host") == "a"), key=lambda i: i["started_at"])
        clock = primary["hosts"]["b"]["clock"]
    rep = json.loads(profile.read_text())
    edges = {e["edge"]: e for e in rep["edges"]}
    hops = {h: {"p50_us": edges[h]["p50"], "p90_us": edges[h]["p90"],
                "count": edges[h]["count"],
                "clock_uncertainty_us": edges[h].get("clock_uncertainty_us")} for h in HOPS}
    frames = hops[HOPS[0]]["count"]
    return {"hops": hops, "clock": clock,
            "cpu_us_per_frame": 1e6 * cpu_s / frames if cpu_s is not None and frames else None}


def _children_cpu_s() -> float:
    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return ru.ru_utime + ru.ru_stime


def median(values):
    values = [v for v in values if v is not None]
    return statistics.median(values) if values else None


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog="\n\n".join(__doc__.split("\n\n")[1:]))
    ap.add_argument("--quick", action="store_true", help="one repeat of 3 s per placement")
    ap.add_argument("--repeats", type=int, default=None, help="default 1 quick, else 3")
    ap.add_argument("--for", dest="seconds", type=float, default=None,
                    help="seconds per run (default 3 quick, else 8)")
    ap.add_argument("--json", metavar="FILE")
    args = ap.parse_args()
    repeats = args.repeats or (1 if args.quick else 3)
    seconds = args.seconds or (3.0 if args.quick else 8.0)
    kinds = ["same_host", "plain", "two_hosts", "skewed"]
    results = {k: [] for k in kinds}
    load_before = os.getloadavg()[0]
    with tempfile.TemporaryDirectory(prefix="bench-hosts-") as tmp:
        for r in range(repeats):
            order = kinds[r % len(kinds):] + kinds[:r % len(kinds)]
            for kind in order:
                results[kind].append(run_placement(kind, seconds, Path(tmp)))
                print(f"repeat {r + 1}/{repeats} {kind}: " + ", ".join(
                    f"{h.split(' -> ')[1]} p50 {v['p50_us']:.0f} us"
                    for h, v in results[kind][-1]["hops"].items()), file=sys.stderr)
    report = {"config": {"repeats": repeats, "seconds": seconds, "frames": "160x160x3 @ 100 Hz",
                         "skew_ns": SKEW_NS, "statistic": "median over repeats",
                         "load_before": round(load_before, 2),
                         "load_after": round(os.getloadavg()[0], 2)},
              "placements": {}, "skew": {}, "targets": {}}
    for kind in kinds:
        report["placements"][kind] = {
            h: {"p50_us": median(r["hops"][h]["p50_us"] for r in results[kind]),
                "p90_us": median(r["hops"][h]["p90_us"] for r in results[kind]),
                "per_repeat_p50_us": [r["hops"][h]["p50_us"] for r in results[kind]],
                "clock_uncertainty_us": median(r["hops"][h]["clock_uncertainty_us"]
                                               for r in results[kind])}
            for h in HOPS}
    clocks = [r["clock"] for r in results["skewed"]]
    report["skew"] = {
        "estimated_offset_ns": [c["offset_ns"] for c in clocks],
        "uncertainty_ns": [c["uncertainty_ns"] for c in clocks],
        "error_ns": [c["offset_ns"] - SKEW_NS for c in clocks],
        "within_uncertainty": all(abs(c["offset_ns"] - SKEW_NS) <= c["uncertainty_ns"]
                                  for c in clocks)}
    plain, keyed = report["placements"]["plain"], report["placements"]["same_host"]
    cpu = {k: median(r["cpu_us_per_frame"] for r in results[k]) for k in ("same_host", "plain")}
    report["curve_cost"] = {
        **{h: {"p50_us": round(keyed[h]["p50_us"] - plain[h]["p50_us"], 1),
               "p90_us": round(keyed[h]["p90_us"] - plain[h]["p90_us"], 1)} for h in HOPS},
        "cpu_us_per_frame": {"curve": round(cpu["same_host"], 1),
                             "plain": round(cpu["plain"], 1),
                             "ratio": round(cpu["same_host"] / cpu["plain"], 3)}}
    for h in HOPS:
        diff = abs(report["placements"]["skewed"][h]["p50_us"]
                   - report["placements"]["same_host"][h]["p50_us"]) / 1e3
        report["targets"][f"{h}: |skewed - same_host| p50 ms"] = {
            "target": TARGET_MS, "got": round(diff, 3), "met": diff <= TARGET_MS}
    print_report(report, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
