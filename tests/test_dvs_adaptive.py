"""Adaptive luma sampling (sebvs/dvs/adaptive.py), the fidelity figures that judge it
(sebvs/dvs/fidelity.py) and the emulator's linear hold that spaced-out samples need."""
import math

import numpy as np
import pytest

from sebvs.dvs import adaptive
from sebvs.dvs.adaptive import LumaSampler, SamplerParams, largest_log_change, \
    sample_interval
from sebvs.dvs.emulator import EVENT_DTYPE, EventEmulator
from sebvs.dvs.fidelity import compare_streams, count_maps, nearest_time_errors, pearson
from sebvs.dvs.params import preset

PARAMS = SamplerParams(fraction=0.5, threshold=0.3, floor_hz=20.0, ceiling_hz=1000.0)


def edge(t: float, speed_px_s: float, width_px: float = 6.0, shape=(8, 96),
         contrast: float = 2.0) -> np.ndarray:
    """Log brightness of a soft vertical edge at x = 10 + speed t (float32 (h, w))."""
    x = np.arange(shape[1], dtype=np.float64)
    row = 3.0 + contrast / (1.0 + np.exp(-(x - 10.0 - speed_px_s * t) / width_px))
    return np.broadcast_to(row, shape).astype(np.float32)


def sampled(sampler: LumaSampler, frame_at, duration: float, period: float = 0.001):
    """Run a sampler over candidates every `period` s; the sample times."""
    times = []
    for i in range(round(duration / period) + 1):
        t = i * period
        if sampler.due(t, period):
            sampler.observe(t, frame_at(t))
            times.append(t)
    return np.array(times)


# ---------------------------------------------------------------------------- the rule
def test_interval_is_the_bound_over_the_rate_clamped():
    assert sample_interval(15.0, PARAMS) == pytest.approx(0.15 / 15.0)      # 10 ms
    assert sample_interval(1e9, PARAMS) == pytest.approx(1 / 1000)         # ceiling
    assert sample_interval(0.0, PARAMS) == pytest.approx(1 / 20)           # floor
    assert sample_interval(1e-6, PARAMS) == pytest.approx(1 / 20)
    assert sample_interval(math.inf, PARAMS) == pytest.approx(1 / 1000)    # unknown: soon
    assert sample_interval(float("nan"), PARAMS) == pytest.approx(1 / 20)


def test_largest_change():
    a = np.zeros((2, 2), np.float32)
    b = a.copy()
    b[0, 0] = -0.2
    assert largest_log_change(a, b) == pytest.approx(0.2)
    assert largest_log_change(a[:0], b[:0]) == 0.0


@pytest.mark.parametrize("bad", [dict(fraction=0), dict(threshold=-1), dict(floor_hz=0),
                                 dict(floor_hz=2000.0), dict(ceiling_hz=float("inf")),
                                 dict(fraction=True)])
def test_bad_options_are_refused(bad):
    with pytest.raises(ValueError, match="luma sampler"):
        SamplerParams(**bad).validate()


# ---------------------------------------------------------------------------- the sampler
def test_still_scene_asks_for_the_floor_rate():
    frame = np.full((16, 16), 90, np.uint8)
    times = sampled(LumaSampler(PARAMS), lambda t: frame, 1.0)
    gaps = np.diff(times)
    # the first interval is the ceiling's (no rate known yet), then the floor's
    assert gaps[0] == pytest.approx(0.001)
    assert np.allclose(gaps[1:], 1 / 20)
    assert len(times) == 21                 # 0, 0.001, then every 50 ms to 0.951


def hard_edge(t: float, speed_px_s: float, shape=(4, 128)) -> np.ndarray:
    """8-bit luma of an aliased edge (as MuJoCo renders without MSAA): a pixel is dark or
    bright, and flips when the edge passes its centre."""
    x = np.arange(shape[1])
    row = np.where(x + 0.5 < 10.0 + speed_px_s * t, 200, 30).astype(np.uint8)
    return np.broadcast_to(row, shape).copy()


def test_step_changes_do_not_make_the_rate_swing(monkeypatch):
    """An aliased edge at 40 px/s flips a pixel every 25 ms: an interval between flips
    shows no change at all. Read alone, that sends the next sample to the floor, and the
    one after (full of flips) to the ceiling; the rate's memory (it falls by at most half
    per sample) keeps the sampling on the motion."""
    frame_at = lambda t: hard_edge(t, 40.0)   # noqa: E731
    kept = sampled(LumaSampler(PARAMS), frame_at, 1.0)
    monkeypatch.setattr(adaptive, "RATE_FALL_PER_SAMPLE", 0.0)
    swinging = sampled(LumaSampler(PARAMS), frame_at, 1.0)
    assert np.diff(swinging).max() == pytest.approx(1 / 20)       # back at the floor
    assert np.diff(kept[2:]).max() < 0.6 / 20   # after the start (nothing known, 1 ms, still)
    assert len(kept) > 3 * len(swinging)


def test_fast_pan_asks_more_samples_than_a_slow_one():
    slow = sampled(LumaSampler(PARAMS), lambda t: edge(t, 50.0), 0.5)
    fast = sampled(LumaSampler(PARAMS), lambda t: edge(t, 400.0), 0.5)
    assert len(fast) > 3 * len(slow)
    assert len(slow) > 0.5 * 20          # and more than a still scene's floor
    assert np.diff(fast).min() >= 0.001 - 1e-12     # never above the ceiling


def test_bound_holds_on_a_moving_edge():
    """Between consecutive samples no pixel changes by more than lambda C (on the 1 ms
    candidates' grid), while the sampler takes far fewer samples than the candidates."""
    frame_at = lambda t: edge(t, 150.0)   # noqa: E731
    times = sampled(LumaSampler(PARAMS), frame_at, 0.4)
    changes = [largest_log_change(frame_at(a), frame_at(b)) for a, b in zip(times, times[1:])]
    assert max(changes) <= PARAMS.bound * 1.02
    assert max(changes) >= PARAMS.bound * 0.6       # and it does not oversample
    assert len(times) < 0.4 * 400


def test_fast_motion_is_clamped_to_the_ceiling():
    # 5 px per ms: the edge crosses the 96 px image in under 17 ms
    times = sampled(LumaSampler(PARAMS), lambda t: edge(t, 5000.0, width_px=1.0), 0.015)
    assert np.allclose(np.diff(times), 0.001)


def test_samples_taken_anyway_count_and_reset_restarts():
    s = LumaSampler(PARAMS)
    still = np.full((4, 4), 100, np.uint8)
    s.observe(0.0, still)
    s.observe(0.001, still)                  # a control tick's sample
    assert s.next_t == pytest.approx(0.001 + 1 / 20)
    assert not s.due(0.02, 0.001) and s.due(0.0505, 0.001)
    s.reset()
    assert s.due(0.0, 0.001) and s.samples == 0


def test_samples_between_candidates_follow_the_rule_exactly():
    """Rendering between 10 ms candidates (pending_before) gives the intervals the rule
    asks for, not the candidates' grid, and no sample twice."""
    frame_at = lambda t: edge(t, 400.0, shape=(4, 256))   # noqa: E731
    s = LumaSampler(PARAMS)
    times = []
    for i in range(41):
        t = i * 0.01
        while (ts := s.pending_before(t)) is not None:
            s.observe(ts, frame_at(ts))
            times.append(ts)
        if s.due(t):
            s.observe(t, frame_at(t))
            times.append(t)
    gaps = np.diff(times)
    assert (gaps > 0).all() and len(times) > 2 * 41      # ~4.5 ms intervals
    changes = [largest_log_change(frame_at(a), frame_at(b)) for a, b in zip(times, times[1:])]
    assert max(changes[2:]) == pytest.approx(PARAMS.bound, rel=0.05)   # after the start
    assert LumaSampler(PARAMS).pending_before(1.0) is None    # nothing before a first sample


# ---------------------------------------------------------------------------- fidelity
def _events(rows):
    ev = np.zeros(len(rows), EVENT_DTYPE)
    for i, (x, y, t, p) in enumerate(rows):
        ev[i] = (x, y, t, p)
    return ev


def test_fidelity_of_a_stream_against_itself_and_a_shifted_copy():
    ref = _events([(1, 0, 1_000_000, 1), (1, 0, 5_000_000, 1), (2, 1, 2_000_000, -1),
                   (0, 2, 3_000_000, 1)])
    same = compare_streams(ref, ref, (3, 3))
    assert (same.count_ratio, same.median_time_error_ms, same.matched_fraction) == (1, 0, 1)
    assert same.count_correlation == pytest.approx(1.0)
    late = ref.copy()
    late["t"] += 500_000
    assert compare_streams(late, ref, (3, 3)).median_time_error_ms == pytest.approx(0.5)
    half = compare_streams(ref[:2], ref, (3, 3))
    assert half.count_ratio == 0.5 and half.count_correlation < 0.9


def test_time_errors_pair_only_the_same_pixel_and_polarity():
    ref = _events([(1, 1, 1_000_000, 1), (1, 1, 9_000_000, 1), (1, 1, 4_000_000, -1)])
    test = _events([(1, 1, 7_000_000, 1), (1, 1, 3_000_000, 1), (0, 0, 1_000_000, 1),
                    (1, 1, 1_000_000, -1)])
    err = nearest_time_errors(test, ref, (2, 2))
    assert err.tolist() == [2e6, 2e6, math.inf, 3e6]
    f = compare_streams(test, ref, (2, 2), max_match_ms=2.5)
    assert f.matched_fraction == 0.5 and f.median_time_error_ms == pytest.approx(2.0)


def test_count_maps_and_pearson():
    ev = _events([(0, 0, 1, 1), (0, 0, 2, 1), (1, 0, 3, -1)])
    maps = count_maps(ev, (1, 2))
    assert maps.tolist() == [[[2, 0]], [[0, 1]]]
    assert math.isnan(pearson(np.ones(4), np.arange(4)))


# ---------------------------------------------------------------------------- linear hold
def _ramp_stream(hz: float, hold: str) -> np.ndarray:
    """A uniform 8 x 8 patch whose log brightness ramps from ln 40 to ln 200 in 0.2 s, then
    holds, seen at `hz` through the paper's low-pass (no mismatch)."""
    em = EventEmulator(preset("paper", sigma_thres=0.0, downsample=1.0, blur=False,
                              lowpass_hold=hold))
    out = []
    for i in range(round(0.4 * hz) + 1):
        t = i / hz
        level = math.log(40) + (math.log(200) - math.log(40)) * min(t / 0.2, 1.0)
        out.append(em.step(np.full((8, 8), math.exp(level), np.float32), round(t * 1e9)))
    return np.concatenate(out)


def test_linear_hold_keeps_event_times_when_samples_space_out():
    """The step hold makes every event early by up to an interval; the linear hold, the
    exact low-pass of a ramp, comes within a tenth of an interval of the 1 kHz stream's
    times at 50 Hz (what is left: the crossings placed on a straight line between samples
    of a curved filtered level)."""
    figures = {}
    for hold in ("step", "linear"):
        ref = _ramp_stream(1000.0, hold)
        figures[hold] = compare_streams(_ramp_stream(50.0, hold), ref, (8, 8))
        assert figures[hold].count_ratio == 1.0
    assert figures["linear"].median_time_error_ms < 2.0     # measured 1.2 ms
    assert figures["step"].median_time_error_ms > 4 * figures["linear"].median_time_error_ms


def test_step_hold_is_the_default_and_unknown_holds_are_refused():
    assert preset("paper").lowpass_hold == "step"
    with pytest.raises(ValueError, match="lowpass_hold"):
        preset("paper", lowpass_hold="cubic")


# ---------------------------------------------------------------------------- the camera
def nav_state_messages(command, seconds: float, still: bool = False, hz: float = 100.0):
    """(arrays, meta, t_sim, tick) of nav states every 1 / hz s, the robot driven by
    `command` ([v, w]); `still`: the first state again and again (nothing moves)."""
    import mujoco

    from sebvs.sim import make_scene
    config = {"width": 64, "height": 64}
    scene = make_scene("nav", **config)
    model = scene.compile()
    data = mujoco.MjData(model)
    scene.reset(model, data, np.random.default_rng(0))
    scene.apply_command(model, data, np.asarray(command, np.float64))
    steps = round(1.0 / (hz * model.opt.timestep))
    first = scene.state(data)
    out = []
    for i in range(round(seconds * hz) + 1):
        t = i / hz
        meta = {"episode": 0, "control": i % 10 == 0, "t_ep": t}
        if i == 0:
            meta.update(scene="nav", config=config, control_hz=hz / 10)
        out.append((first if still else scene.state(data), meta, 5.0 + t, i // 10))
        for _ in range(steps):
            scene.scripted(model, data)
            mujoco.mj_step(model, data)
    return out


def test_camera_samples_luma_between_states_when_the_view_turns():
    from tests.test_camera_output import camera_outputs
    params = dict(luma_sampling="adaptive", luma_scale=0.5, luma_fraction=0.35,
                  luma_ceiling_hz=1000.0)
    turning = nav_state_messages([0.0, 1.0], 0.5)
    luma = [e for e in camera_outputs(turning, {"luma"}, **params) if e[0] == "luma"]
    still = [e for e in camera_outputs(nav_state_messages([0.0, 0.0], 0.5, still=True),
                                       {"luma"}, **params) if e[0] == "luma"]
    assert len(still) <= 6 + 11                # control ticks (6) and the floor (20 Hz)
    assert len(luma) > 3 * len(turning)        # far above the 100 Hz states
    times = np.array([e[3] for e in luma])
    assert (np.diff(times) > 0).all()
    state_t = {t_sim: tick for _, _, t_sim, tick in turning}
    between = [e for e in luma if e[3] not in state_t]
    assert len(between) > 0.5 * len(luma)
    for _, arrays, meta, t_sim, tick in between:
        assert meta["control"] is False and arrays["luma"].shape == (32, 32)
        assert meta["t_ep"] == pytest.approx(t_sim - 5.0)
        assert tick == int((t_sim - 5.0) * 10 + 1e-9)      # the earlier state's tick
    # every control state still gets its luma, flagged
    assert sum(e[2]["control"] for e in luma) == sum(m["control"] for _, m, _, _ in turning)
