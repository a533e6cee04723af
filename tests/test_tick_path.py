"""Nothing but the readout on the tick path (issue 64, item 2): the physical frame camera
makes the frame a tick gets on the states before it (camera frame_ready "ahead", what the
default "auto" is on the realtime clock), and the tick only publishes it. Where a state falls between the exposure's end
(readout_s before the tick) and the tick, the frames are those of making them at the tick,
bit for bit; where none does, the exposure ends at the last state before the tick."""
import numpy as np
import pytest

from sebvs_actors.camera import Camera
from sebvs.sensors.camera import CameraCore
from sebvs.sensors.framecam import FrameCamera
from sebvs.sensors.rig import SensorRig
from sebvs.sim.render import FrameRenderer
from tests.test_camera_output import sim_states

SMALL = {"variant": "indoor", "width": 64, "height": 64}


@pytest.fixture(scope="module")
def states_100():
    """The shipped rate: a state every 10 ms, sparser than the 5 ms readout."""
    return sim_states(SMALL, dvs_hz=100.0)


def frames(states, wanted=("rgb", "luma"), **params):
    """The frames a camera makes of `states`: [(image, meta)], and its counts."""
    params.setdefault("frame_ready", "ahead")
    core = CameraCore(Camera.Params(sensor="physical", **params), set(wanted))
    try:
        out = [(a["rgb"].copy(), m) for arrays, meta, *_ in states
               for o, a, m in core.sample(arrays, meta) if o == "rgb"]
        return out, dict(core.counts)
    finally:
        core.close()


def all_at_the_tick(monkeypatch):
    """Nothing made ahead: the rig's rendering and exposing before a tick do nothing, so
    each frame is made whole by the tick's own call."""
    monkeypatch.setattr(SensorRig, "ahead", lambda self, *a, **k: 0)
    monkeypatch.setattr(SensorRig, "ahead_shared", lambda self, *a, **k: False)


@pytest.mark.parametrize("states_hz, light", [(200.0, "shared"), (1000.0, "subframes")],
                         ids=["shared-light-200Hz", "subframes-1kHz"])
def test_frames_made_ahead_are_the_frames_of_the_tick(states_hz, light, monkeypatch):
    # dusk: the auto exposure ramps over the run, so each frame has its own exposure
    states = sim_states({**SMALL, "lighting": "dusk"}, dvs_hz=states_hz)
    ahead, counts = frames(states, dvs_hz=states_hz, frame_light=light)
    all_at_the_tick(monkeypatch)
    at_tick, counts_at_tick = frames(states, dvs_hz=states_hz, frame_light=light,
                                     frame_ready="tick")
    assert len(ahead) == len(at_tick) == 4
    for (a, m), (b, n) in zip(ahead, at_tick):
        assert np.array_equal(a, b) and m == n
    assert len({m["exposure_s"] for _, m in ahead}) > 1
    # the first tick is the episode's first state: nothing comes before it
    assert counts["frames_ahead"] == 3 and counts_at_tick["frames_ahead"] == 0
    assert counts["exposure_end_moved"] == 0
    assert counts["subframes"] == counts_at_tick["subframes"]


class Calls:
    """Counts the renders and exposures made while a state is handled."""

    def __init__(self, monkeypatch) -> None:
        self.n = {"light": 0, "albedo": 0, "expose": 0, "rgb": 0}
        for cls, name, key in ((SensorRig, "luminance", "light"),
                               (FrameRenderer, "albedo", "albedo"),
                               (FrameRenderer, "rgb", "rgb"),
                               (FrameCamera, "expose", "expose")):
            monkeypatch.setattr(cls, name, self._counting(getattr(cls, name), key))

    def _counting(self, fn, key):
        def counted(*a, **k):
            self.n[key] += 1
            return fn(*a, **k)
        return counted

    def per_tick(self, core, states) -> list[dict]:
        """The calls made while each tick's state was handled, after the first tick."""
        ticks = []
        for arrays, meta, *_ in states:
            before = dict(self.n)
            outputs = [o for o, a, m in core.sample(arrays, meta)]
            if meta["control"]:
                assert "rgb" in outputs
                ticks.append({k: self.n[k] - before[k] for k in self.n})
        return ticks[1:]


@pytest.mark.parametrize("light, wanted", [("shared", {"rgb", "luma"}),
                                           ("subframes", {"rgb"})],
                         ids=["shared-light", "rgb-only-subframes"])
def test_the_tick_handler_only_publishes_the_frame(states_100, light, wanted, monkeypatch):
    calls = Calls(monkeypatch)
    core = CameraCore(Camera.Params(sensor="physical", dvs_hz=100.0, frame_light=light,
                                    frame_ready="ahead"),
                      wanted)
    try:
        ticks = calls.per_tick(core, states_100)
        counts = dict(core.counts)
    finally:
        core.close()
    assert len(ticks) == 3
    # the event sensor's own luma sample (one radiance render, drawn by FrameRenderer.rgb)
    # is the one render left on a tick
    own_luma = int("luma" in wanted)
    assert ticks == [{"light": own_luma, "albedo": 0, "expose": 0, "rgb": own_luma}] * 3
    assert counts["frames_ahead"] == 3

    # the same camera at the tick renders and exposes there
    calls.n = dict.fromkeys(calls.n, 0)
    core = CameraCore(Camera.Params(sensor="physical", dvs_hz=100.0, frame_light=light,
                                    frame_ready="tick"), wanted)
    try:
        ticks = calls.per_tick(core, states_100)
    finally:
        core.close()
    assert all(t["expose"] == 1 and t["albedo"] >= 1 for t in ticks), ticks


def test_sparse_states_end_the_exposure_at_the_last_state_before_the_tick(states_100):
    """No state between the exposure's end (5 ms before the tick) and the tick: it ends at
    the state 10 ms before the tick instead; the first frame (no state before its tick)
    keeps the 5 ms."""
    got, counts = frames(states_100, dvs_hz=100.0)
    ends = [round(m["t_ep"] - m["t_exposure_end"], 9) for _, m in got]
    assert ends == [0.005, 0.01, 0.01, 0.01]
    assert counts["exposure_end_moved"] == 3 and counts["frames_ahead"] == 3
    tick, _ = frames(states_100, dvs_hz=100.0, frame_ready="tick")
    assert [round(m["t_ep"] - m["t_exposure_end"], 9) for _, m in tick] == [0.005] * 4


def test_the_moved_exposure_differs_from_the_tick_s_by_less_than_the_noise(states_100):
    """What moving the exposure's end 5 ms earlier changes in a noise-free frame, against
    what the noise changes between two cameras (docs/sensors.md measures it at 160 px)."""
    clean = dict(dvs_hz=100.0, frame_camera="ideal")
    ahead, _ = frames(states_100, **clean)
    tick, _ = frames(states_100, frame_ready="tick", **clean)
    moved = [np.abs(a.astype(int) - b.astype(int)).mean() for (a, _), (b, _) in
             zip(ahead[1:], tick[1:])]
    noisy = [frames(states_100, dvs_hz=100.0, frame_overrides={})[0]]
    core = CameraCore(Camera.Params(sensor="physical", dvs_hz=100.0, frame_ready="ahead"),
                      {"rgb", "luma"}, seed=1)
    try:
        noisy.append([(a["rgb"].copy(), m) for arrays, meta, *_ in states_100
                      for o, a, m in core.sample(arrays, meta) if o == "rgb"])
    finally:
        core.close()
    noise = [np.abs(a.astype(int) - b.astype(int)).mean() for (a, _), (b, _) in
             zip(noisy[0][1:], noisy[1][1:])]
    assert max(moved) > 0                    # the robot moves: the frames do change
    assert np.median(moved) < np.median(noise), (moved, noise)


def test_luma_sparser_than_the_states_gets_the_frame_a_light_sample_of_its_own():
    """States every 5 ms, luma every 10 ms: the state at the exposure's end has no luma
    sample, so the frame renders one there for itself, ahead of the tick, and keeps the
    5 ms readout."""
    states = sim_states(SMALL, dvs_hz=200.0)
    got, counts = frames(states, dvs_hz=100.0)
    assert [round(m["t_ep"] - m["t_exposure_end"], 9) for _, m in got] == [0.005] * 4
    assert counts["exposure_end_moved"] == 0 and counts["frames_ahead"] == 3
    assert counts["light_extra"] >= 3


def test_a_tick_that_does_not_come_when_announced_gets_its_frame_at_the_tick(states_100):
    """The sim announces the next tick (t_next_control); where that is wrong the frame
    made ahead is dropped and the tick makes its own, exposed readout_s before it."""
    late = [(a, {**m, "t_next_control": m["t_next_control"] + 0.05}
             if "t_next_control" in m else m, *rest) for a, m, *rest in states_100]
    got, counts = frames(late, dvs_hz=100.0)
    tick, _ = frames(late, dvs_hz=100.0, frame_ready="tick")
    assert [round(m["t_ep"] - m["t_exposure_end"], 9) for _, m in got] == [0.005] * 4
    for (a, m), (b, n) in zip(got, tick):
        assert np.array_equal(a, b) and m == n


def test_frame_ready_is_checked():
    with pytest.raises(ValueError, match="frame_ready must be one of auto, ahead, tick"):
        CameraCore(Camera.Params(sensor="physical", frame_ready="soon"), {"rgb"})


@pytest.mark.parametrize("clock, ahead", [("realtime", True), ("lockstep", False)])
def test_auto_makes_frames_ahead_on_the_realtime_clock_only(clock, ahead):
    """Lockstep runs (eval, record, the envs) keep the frames the checkpoints were made on."""
    core = CameraCore(Camera.Params(sensor="physical"), {"rgb"}, clock=clock)
    try:
        assert core.frame_ahead is ahead
    finally:
        core.close()
    assert Camera.Params().frame_ready == "auto"
