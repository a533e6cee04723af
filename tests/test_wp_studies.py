"""Study helpers of tools/checks/work_precision.py: event metrics on hand-made streams, physics
runs against a reference, the synthetic policy data, all in a few seconds."""
import numpy as np
import pytest

from sebvs.numerics import wp_events as ev
from sebvs.numerics import wp_physics as ph
from sebvs.numerics import wp_policy as pol


def stream(*events):
    """(t ns, x, y, p) tuples -> the four arrays."""
    t, x, y, p = (np.array(c) for c in zip(*events)) if events else ([], [], [], [])
    return (np.asarray(t, np.int64), np.asarray(x), np.asarray(y), np.asarray(p))


# ------------------------------------------------------------------ event metrics
def test_count_frames_bins_by_tick_and_polarity():
    s = stream((0, 1, 0, 1), (10, 1, 0, 1), (49, 0, 1, -1), (50, 1, 1, 1), (200, 0, 0, 1))
    c = ev.count_frames(*s, shape=(2, 2), t0_ns=0, period_ns=50, ticks=2)
    assert c.shape == (2, 2, 2, 2) and c.dtype == np.int32
    assert c[0, 0, 0, 1] == 2 and c[0, 1, 1, 0] == 1 and c[1, 0, 1, 1] == 1
    assert c.sum() == 4                                 # t=200 is past the 2 ticks


def test_relative_l1():
    a, b = np.array([[1, 0], [2, 0]]), np.array([[1, 1], [0, 0]])
    assert ev.relative_l1(a, b) == pytest.approx(3 / 2)
    assert ev.relative_l1(b, b) == 0.0
    assert ev.relative_l1(np.zeros(2), np.zeros(2)) == 0.0
    assert ev.relative_l1(np.ones(2), np.zeros(2)) == float("inf")


def test_timestamp_errors_match_nearest_same_pixel_and_polarity():
    ref = stream((1000, 0, 0, 1), (5000, 0, 0, 1), (2000, 1, 0, -1), (7000, 1, 1, 1))
    test = stream((1300, 0, 0, 1),      # nearest: 1000 -> 300
                  (4000, 0, 0, 1),      # nearest: 5000 -> 1000
                  (2600, 1, 0, -1),     # OFF at (1, 0): 600
                  (2600, 1, 0, 1),      # ON at (1, 0): the reference has none
                  (9000, 1, 1, 1))      # 2000
    err, unmatched = ev.timestamp_errors(test, ref, (2, 2))
    assert sorted(err.tolist()) == [300, 600, 1000, 2000] and unmatched == 1


def test_timestamp_errors_with_test_pixels_beyond_every_reference_pixel():
    # The reference fires only at the first pixel; test events at the last pixel sort after
    # all of it (the case that once indexed past the reference's end).
    ref = stream((1000, 0, 0, 1), (3000, 0, 0, 1))
    test = stream((1100, 0, 0, 1), (500, 1, 1, -1), (900, 1, 1, 1))
    err, unmatched = ev.timestamp_errors(test, ref, (2, 2))
    assert err.tolist() == [100] and unmatched == 2


def test_event_errors_of_identical_streams():
    s = stream((10, 0, 0, 1), (20, 1, 1, -1), (70, 1, 0, 1))
    m = ev.event_errors(s, s, (2, 2), 0, 50, 2)
    assert m["rel_l1"] == 0 and m["ts_median_us"] == 0 and m["count_ratio"] == 1
    assert m["unmatched"] == 0


# ------------------------------------------------------------------ physics
def test_physics_study_points_and_convergence():
    case = ph.nav_case(seed=1, seconds=0.5)
    pts = ph.physics_study(case, 0.5, integrators=("euler",), timesteps=(0.01, 0.001),
                           reference=("rk4", 0.0005))
    assert [p["setting"] for p in pts] == [0.01, 0.001]
    assert all(set(p) >= {"method", "setting", "error", "seconds", "diverged"} for p in pts)
    assert not any(p["diverged"] for p in pts)
    assert 0 < pts[1]["error"] < pts[0]["error"]          # first order: smaller step, better


def test_diverged_run_is_marked(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)          # MuJoCo writes MUJOCO_LOG.TXT on the warning
    case = ph.nav_case(seconds=0.2)

    def drive(scene, model, data, t):
        if t > 0.05 and model.opt.integrator == 0:      # euler only, not the reference
            data.qvel[0] = np.nan                        # a blow-up the monitor must name
    case.drive = drive
    p = ph.physics_study(case, 0.2, integrators=("euler",), timesteps=(0.01,),
                         reference=("rk4", 0.002))[0]
    assert p["diverged"] and p["error"] is None and p["reason"].startswith("diverged")


def test_belt_case_carries_the_box():
    r = ph.run_case(ph.belt_case(speed=0.5), "implicitfast", 0.002, 1.0)
    assert r["reason"] is None and 0.3 < r["pos"][0] < 0.5      # ~0.5 m/s once it sticks


# ------------------------------------------------------------------ policy
def test_synthetic_dataset_layout_and_baseline(tmp_path):
    from sebvs.policy.dataset import EpisodeFrames, load_index
    from sebvs.policy.inputs import Normalisation
    root = pol.make_synthetic(tmp_path / "d", episodes=2, frames=5, size=32, seed=0)
    eps = load_index(root)
    assert [e["frames"] for e in eps] == [5, 5]
    x, y = EpisodeFrames(root, eps, "nav", "rgb+event", Normalisation(size=32))[3]
    assert x.shape == (5, 32, 32) and y.shape == (2,) and (np.abs(y) <= 1).all()
    assert pol.mean_baseline(root, root) > 0


# ------------------------------------------------------------------ event study end to end
def test_event_study_converges_with_the_sampling_rate():
    from sebvs.numerics import wp_events_run
    cfg = {"ev_rates": (100, 1000), "ev_ref_hz": 2000, "ev_seconds": 0.3}
    l1, timing, note = wp_events_run.study(cfg, seed=0)
    assert [p["setting"] for p in l1] == [100, 1000] * len(wp_events_run.PRESETS)
    for method in wp_events_run.PRESETS:
        lo, hi = [p for p in l1 if p["method"] == method]
        assert hi["error"] < lo["error"] and hi["seconds"] > lo["seconds"]
        assert 0.5 < hi["count_ratio"] < 1.5
    assert all(p["error"] == p["ts_p90_us"] for p in timing)
    assert "2000 Hz" in note


def conveyor_frames(seed, seconds=0.1, ref_hz=1000, belt_speed=0.25):
    """(frames (N+1, 80, 80) uint8, the motion after its last frame) of the conveyor."""
    from sebvs.numerics import wp_events_run
    m = wp_events_run.conveyor_motion(seed, ref_hz, belt_speed)
    frames, _, _ = wp_events_run.luma_sequence(m, seconds, ref_hz)
    return frames, m


def test_conveyor_luma_sequence_is_seeded_and_moves():
    a, m = conveyor_frames(seed=3)
    b, _ = conveyor_frames(seed=3)
    assert a.shape == (101, 80, 80) and np.array_equal(a, b)           # seeded
    assert not np.array_equal(a[0], conveyor_frames(seed=4)[0][0])     # other cubes
    # The cubes move: around each visible cube (its final centre, wrist image at 160 px
    # halved) the first and last frames differ. The belt itself is a static geom whose
    # surfacevel moves only what lies on it: its texture does not move in the image.
    truth = m.scene.truth(m.model, m.data)
    changed = a[0] != a[-1]
    seen = [c for c in truth["cubes"] if c["visible"]]
    assert seen
    for c in seen:
        u, v = (int(round(x / 2)) for x in c["uv"])
        assert changed[max(v - 6, 0):v + 7, max(u - 6, 0):u + 7].any(), c


def test_conveyor_study_points_carry_the_documented_fields():
    from sebvs.numerics import wp_events_run
    cfg = {"ev_rates": (100, 1000), "ev_ref_hz": 2000, "ev_seconds": 0.2,
           "ev_belt_speeds": (0.25,)}
    l1, timing, note = wp_events_run.study(cfg, seed=0, motion="conveyor")
    assert [p["method"] for p in l1] == [f"{p} 0.25 m/s" for p in wp_events_run.PRESETS
                                         for _ in (100, 1000)]
    fields = {"method", "setting", "error", "seconds", "render_s_per_frame", "emulator_s",
              "reference_hz", "sim_seconds", "motion", "window_s", "belt_speed", "rel_l1",
              "ts_median_us", "ts_p90_us", "count_ratio", "unmatched", "events", "ref_events"}
    assert all(set(p) == fields for p in l1 + timing)
    assert all(p["motion"] == "conveyor" and p["window_s"] == 0.1 for p in l1)
    assert all(p["ref_events"] > 0 for p in l1)                      # the cubes fire events
    assert [p["error"] for p in l1] == [p["rel_l1"] for p in timing]
    assert all(p["error"] == p["ts_p90_us"] for p in timing)
    assert "conveyor" in note and "2000 Hz" in note


# ------------------------------------------------------------------ the tool's outputs
def test_work_precision_tool_writes_the_summary_format(tmp_path, monkeypatch):
    import importlib.util
    import json
    from pathlib import Path
    monkeypatch.chdir(tmp_path)          # main() moves into --out; monkeypatch restores
    path = Path(__file__).resolve().parents[1] / "tools" / "checks" / "work_precision.py"
    spec = importlib.util.spec_from_file_location("work_precision_tool", path)
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    quick = tool.settings(True)           # a shorter event study: ~1 s instead of ~4
    monkeypatch.setattr(tool, "settings", lambda q: {**quick, "ev_rates": (100, 1000),
                                                     "ev_ref_hz": 2000, "ev_seconds": 0.2})
    out = tmp_path / "wp"
    only = "physics_nav,physics_conveyor,events_conveyor_timing"
    assert tool.main(["--quick", "--out", str(out), "--only", only]) == 0
    summary = json.loads((out / "summary.json").read_text())
    names = [s["name"] for s in summary["studies"]]
    assert names == only.split(",") and summary["quick"] is True
    nav = summary["studies"][0]
    assert len(nav["points"]) == 20 and nav["pareto"]
    assert set(nav["points"][0]) >= {"method", "setting", "error", "seconds"}
    assert (out / "physics_nav.png").exists() and (out / "physics_nav.csv").exists()
    assert summary["studies"][1]["points"] or "not run" in summary["studies"][1]["note"]
    ev = summary["studies"][2]
    assert [p["method"] for p in ev["points"]] == ["paper 0.08 m/s"] * 2 + ["clean 0.08 m/s"] * 2
    assert ev["error_label"].startswith("p90") and (out / "events_conveyor_timing.png").exists()
