"""The profiler's chain split (queueing, wake-up, transport, handler per hop) and its trace
export: exact on hand-built telemetry, robust to bad telemetry, non-empty on a live run."""
import json
import subprocess
import sys
from pathlib import Path

import pytest

from sebvs.runtime.chainsplit import COMPONENTS, split_hops
from sebvs.runtime.profiler import ProfileCollector, format_report
from sebvs.runtime.supervisor import Supervisor
from sebvs.runtime.topology import load_topology
from sebvs.runtime.trace import build_trace, select_records

ROOT = Path(__file__).resolve().parents[1]
SYNTHETIC = ROOT / "topologies" / "synthetic.toml"
LOOP = "sim > camera > policy > sim"


def collector(tmp_path, actors=("sim", "camera", "policy")) -> ProfileCollector:
    """A collector over a run.json with no live actor (batches are fed by hand)."""
    info = {"name": "hand", "run_id": "x", "actors": {
        a: {"telemetry": f"ipc://{tmp_path}/{a}.tel", "consumed": ["out"]} for a in actors}}
    return ProfileCollector(info)


def batch(actor, records):
    return {"actor": actor, "t_ns": 0, "records": records, "events": [], "skipped": 0,
            "drops": {}}


US = 1000  # ns


def loop_tick(t0: int, tick: int, camera_busy: bool = False) -> dict[str, list]:
    """One tick of sim > camera > policy > sim, times in ns from t0, every stamp chosen.

    camera: asleep from before the send until it woke 40 us later (wake-up 40), 5 us of
    loop before the take (queueing 5), 10 us receive (transport), 700 us to its emit.
    With camera_busy, its loop woke before the send: no wake-up, all waiting is queueing.
    policy: asleep since 3 us after the send, woke 60 us after it (wake-up 57, queueing
    3 + 2), 20 us receive, 1200 us to its emit. sim: 30 us wake-up, 8 us receive, 50 us
    handler.
    """
    s0 = t0
    cam_woke = s0 - 100 * US if camera_busy else s0 + 40 * US
    cam_taken = s0 + 45 * US
    cam_start, cam_send = cam_taken + 10 * US, cam_taken + 710 * US
    pol_woke = cam_send + 60 * US
    pol_taken = pol_woke + 2 * US
    pol_start, pol_send = pol_taken + 20 * US, pol_taken + 1220 * US
    sim_woke = pol_send + 30 * US
    sim_start, sim_end = sim_woke + 8 * US, sim_woke + 58 * US
    chain = [["sim", 0, s0], ["camera", cam_start, cam_send], ["policy", pol_start, pol_send]]
    return {
        "camera": ["state", "sim/state", tick, tick, 0.1 * tick, chain[:1], cam_start,
                   cam_start + 900 * US, s0 - 5000 * US, cam_woke, cam_taken],
        "policy": ["rgb", "camera/rgb", tick, tick, 0.1 * tick, chain[:2], pol_start,
                   pol_send + 40 * US, cam_send + 3 * US, pol_woke, pol_taken],
        "sim": ["action", "policy/action", tick, tick, 0.1 * tick, chain, sim_start, sim_end,
                pol_send - 10 * US, sim_woke, sim_woke],
    }


def test_split_hops_telescopes_to_the_chain():
    rec = loop_tick(1_000_000, 0)
    stamps, end = rec["sim"][5], rec["sim"][7]
    arrivals = [tuple(rec[a][8:11]) + (rec[a][6],) for a in ("camera", "policy", "sim")]
    hops = split_hops(stamps, end, arrivals)
    assert hops == [
        {"queueing": 5 * US, "wakeup": 40 * US, "transport": 10 * US, "handler": 700 * US},
        {"queueing": 5 * US, "wakeup": 57 * US, "transport": 20 * US, "handler": 1200 * US},
        {"queueing": 0, "wakeup": 30 * US, "transport": 8 * US, "handler": 50 * US}]
    assert sum(sum(h.values()) for h in hops) == end - stamps[0][2]
    # a missing record or a stamp out of order: no split rather than a wrong one
    assert split_hops(stamps, end, arrivals[:2] + [None]) is None
    bad = list(arrivals)
    bad[1] = (arrivals[1][0], arrivals[1][1], stamps[1][2] - 1, arrivals[1][3])
    assert split_hops(stamps, end, bad) is None


def test_collector_split_sums_to_chain_and_joins_out_of_order(tmp_path):
    col = collector(tmp_path)
    ticks = [loop_tick(10_000_000 * k, k, camera_busy=k % 2 == 1) for k in range(1, 41)]
    # the closing actor's batch first: its chains are joined at report time
    for actor in ("sim", "policy", "camera"):
        col.ingest(batch(actor, [t[actor] for t in ticks]))
    rep = col.report()
    col.close()
    (loop,) = [s for s in rep["split"] if s["chain"] == LOOP]
    assert loop["resolved"] == loop["instances"] == 40 and loop["unresolved"] == 0
    assert [h["hop"] for h in loop["hops"]] == ["sim > camera", "camera > policy",
                                                "policy > sim"]
    chain_mean = loop["chain_us"]["mean"]
    assert chain_mean == pytest.approx(45 + 10 + 700 + 62 + 20 + 1200 + 38 + 50, abs=1e-6)
    # every component's mean, summed over hops, is the chain's mean; shares add to 1
    total = sum(h[c]["mean"] for h in loop["hops"] for c in COMPONENTS)
    assert total == pytest.approx(chain_mean, rel=1e-12)
    assert sum(loop["components"][c]["share"] for c in COMPONENTS) == pytest.approx(1.0)
    cam = loop["hops"][0]
    # half the ticks the camera was asleep (40 us wake-up), half busy (45 us queueing)
    assert cam["wakeup"]["mean"] == pytest.approx(20) and cam["queueing"]["mean"] == \
        pytest.approx(25)
    assert loop["compute_us"]["p50"] == pytest.approx(700 + 1200 + 50)
    assert loop["chain_over_compute_p50"] == pytest.approx(chain_mean / 1950)
    text = format_report(rep)
    assert "chain split: " + LOOP in text and "wake-up" in text and "all hops" in text


def test_unjoined_instances_are_counted_not_split(tmp_path):
    col = collector(tmp_path)
    ticks = [loop_tick(10_000_000 * k, k) for k in range(1, 6)]
    col.ingest(batch("sim", [t["sim"] for t in ticks]))
    col.ingest(batch("camera", [t["camera"] for t in ticks]))
    col.ingest(batch("policy", [t["policy"] for t in ticks[:3]]))   # two lost
    old = [r[:8] for r in (t["policy"] for t in ticks[3:])]         # ... or unstamped
    col.ingest(batch("policy", old))
    (loop,) = [s for s in col.report()["split"] if s["chain"] == LOOP]
    col.close()
    assert (loop["instances"], loop["resolved"], loop["unresolved"]) == (5, 3, 2)


def test_bad_telemetry_is_counted_and_skipped(tmp_path):
    col = collector(tmp_path)
    good = loop_tick(50_000_000, 1)
    col.ingest("not a batch")
    col.ingest({"records": []})                                # no actor
    col.ingest(batch("camera", [
        good["camera"],
        ["state", "sim/state"],                                # too short
        ["state", "sim/state", 1, 1, 0.1, [["sim", "zero", 5]], 1, 2, 0, 0, 0],   # stamp
        ["state", "sim/state", 1, 1, 0.1, [], "start", 2, 0, 0, 0],               # type
        ["state", "sim/state", 1, 1, 0.1, [], 9, 2, 0, 0, 0],  # ends before it starts
        None]))
    col.ingest({"actor": "policy", "records": "x", "events": [1, [2]], "drops": {"a": 3}})
    rep = col.report()
    col.close()
    assert rep["skipped"]["profiler"] == {"batches": 2, "records": 5, "events": 2,
                                          "drops": 1}
    assert [h["count"] for h in rep["handlers"]] == [1]
    assert format_report(rep)


def check_trace(trace: dict) -> list[dict]:
    """The trace-event structure the viewers need; returns the handler slices."""
    json.loads(json.dumps(trace))                 # plain JSON, nothing exotic
    assert isinstance(trace["traceEvents"], list) and trace["displayTimeUnit"] == "ms"
    names = {}
    for ev in trace["traceEvents"]:
        assert {"ph", "pid", "tid", "name"} <= set(ev)
        assert isinstance(ev["pid"], int) and isinstance(ev["tid"], int)
        if ev["ph"] == "M":
            names[(ev["pid"], ev["tid"], ev["name"])] = ev["args"]["name"]
        else:
            assert isinstance(ev["ts"], (int, float)) and ev["ts"] >= 0
    slices = [e for e in trace["traceEvents"] if e["ph"] == "X"]
    by_track: dict = {}
    for e in slices:
        assert e["dur"] >= 0
        assert (e["pid"], 0, "process_name") in names
        assert (e["pid"], e["tid"], "thread_name") in names
        by_track.setdefault((e["pid"], e["tid"]), []).append(e)
    for track in by_track.values():               # slices of a track never overlap
        track.sort(key=lambda e: e["ts"])
        for a, b in zip(track, track[1:]):
            assert b["ts"] >= a["ts"] + a["dur"] - 1e-6
    starts = {e["id"]: e for e in trace["traceEvents"] if e["ph"] == "s"}
    ends = {e["id"]: e for e in trace["traceEvents"] if e["ph"] == "f"}
    assert starts.keys() == ends.keys()
    assert all(ends[i]["ts"] >= starts[i]["ts"] for i in starts)
    return [e for e in slices if e["cat"] == "handler"]


def test_trace_of_synthetic_telemetry_is_valid(tmp_path):
    col = collector(tmp_path)
    ticks = [loop_tick(10_000_000 * k, k) for k in range(1, 21)]
    for actor in ("camera", "policy", "sim"):
        col.ingest(batch(actor, [t[actor] for t in ticks]))
    trace = build_trace(select_records(list(col.kept.values()), 10), run="hand")
    col.close()
    handlers = check_trace(trace)
    assert len(handlers) == 3 * 10                # the last 10 ticks, three handlers each
    processes = {e["args"]["name"] for e in trace["traceEvents"]
                 if e["ph"] == "M" and e["name"] == "process_name"}
    assert processes == {"sim", "camera", "policy"}
    cam = [e for e in handlers if e["name"] == "on_state"]
    # microseconds, as the format says: the camera's handler ran 900 us
    assert all(e["dur"] == pytest.approx(900) for e in cam)
    assert cam[0]["args"]["wakeup_us"] == pytest.approx(40)
    assert cam[1]["ts"] - cam[0]["ts"] == pytest.approx(10_000)   # ticks 10 ms apart
    assert len([e for e in trace["traceEvents"] if e["ph"] == "s"]) == 30


def test_live_synthetic_run_splits_and_traces(tmp_path):
    sup = Supervisor(load_topology(SYNTHETIC, ["source.width=64", "source.height=48",
                                               "source.rate_hz=100"]),
                     runs_dir=tmp_path, echo=lambda s: None)
    sup.start()
    try:
        col = ProfileCollector(sup.info)
        col.poll(1.5)
        rep = col.report()
        trace = build_trace(select_records(list(col.kept.values()), 50))
        col.close()
        cli = subprocess.run(
            [sys.executable, "-m", "sebvs.cli", "profile", str(sup.rundir), "--for", "1",
             "--trace", str(tmp_path / "t.json")], cwd=ROOT, capture_output=True, text=True,
            timeout=60)
    finally:
        sup.stop()
    (split,) = rep["split"]
    assert split["chain"] == "source > relay > sink" and split["resolved"] > 20
    assert [h["hop"] for h in split["hops"]] == ["source > relay", "relay > sink"]
    for hop in split["hops"]:
        assert all(hop[c]["count"] == split["resolved"] for c in COMPONENTS)
        assert hop["transport"]["p50"] > 0 and hop["handler"]["p50"] > 0
    total = sum(h[c]["mean"] for h in split["hops"] for c in COMPONENTS)
    assert total == pytest.approx(split["chain_us"]["mean"], rel=1e-9)
    assert check_trace(trace)
    assert cli.returncode == 0, cli.stderr
    assert "chain split: source > relay > sink" in cli.stdout
    assert check_trace(json.loads((tmp_path / "t.json").read_text()))


def test_loop_latency_leaves_the_warm_up_out_and_reads_the_targets(tmp_path):
    from sebvs.runtime.profiler import format_loop_latency
    col = collector(tmp_path)
    assert col.loop_latency() is None
    ticks = [loop_tick(10_000_000 * k, k) for k in range(1, 41)]
    ticks[0]["sim"][7] += 50_000_000          # the first chain was slow: inside the warm-up
    for actor in ("sim", "policy", "camera"):
        col.ingest(batch(actor, [t[actor] for t in ticks]))
    loop = col.loop_latency(warmup_s=0.1)
    col.close()
    # chains that started 0.1 s after the first one: ticks 11..40, 2,125 us each
    assert (loop["chain"], loop["instances"]) == (LOOP, 30)
    assert loop["since_ns"] == ticks[10]["sim"][5][0][2]     # tick 11's chain, the first kept
    assert loop["p50_ms"] == pytest.approx(2.125, abs=0.006)
    assert loop["p99_ms"] == pytest.approx(2.125, abs=0.006)     # the slow one left out
    assert loop["met"] is True
    line = format_loop_latency(loop, "lockstep")
    assert line.startswith(f"loop latency ({LOOP}): p50 2.1") and "met" in line
    assert line.endswith("(the target is for the realtime clock; this run was lockstep)")
    assert "not met" in format_loop_latency(dict(loop, p99_ms=20.0, met=False), "realtime")


def test_loop_latency_counts_every_tick_whichever_input_completed_it(tmp_path):
    """rgb+event on the physical pair: a tick's action carries the stamps of the input
    that came last, the frame (camera > policy) or the events (through the accumulator),
    so the loop is two paths and each tick is on one of them."""
    from sebvs.runtime.profiler import format_loop_latency
    col = collector(tmp_path, ("sim", "camera", "accumulator", "policy"))
    ticks = [loop_tick(10_000_000 * k, k) for k in range(1, 41)]
    for k, t in enumerate(ticks):
        if k % 4 == 0:                      # a quarter completed by the events, 1 ms later
            stamps = t["sim"][5]
            via = ["accumulator", stamps[1][2] + 100 * US, stamps[1][2] + 200 * US]
            t["sim"][5] = [*stamps[:2], via, stamps[2]]
            t["sim"][6] += 1_000 * US
            t["sim"][7] += 1_000 * US
    for actor in ("sim", "policy", "camera"):
        col.ingest(batch(actor, [t[actor] for t in ticks]))
    loop = col.loop_latency(warmup_s=0.0)
    col.close()
    events = "sim > camera > accumulator > policy > sim"
    assert loop["instances"] == 40 and loop["paths"] == {LOOP: 30, events: 10}
    assert loop["chain"] == LOOP
    assert loop["p50_ms"] == pytest.approx(2.125, abs=0.006)
    assert loop["p99_ms"] == pytest.approx(3.125, abs=0.006)
    assert format_loop_latency(loop, "realtime").startswith(
        f"loop latency ({LOOP} and 1 more path): p50 2.1")
