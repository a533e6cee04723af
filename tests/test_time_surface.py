"""The time surface representation (issue 65, item 2): per polarity, 255 exp(-age / tau)
of each pixel's newest event, tau the accumulator's window_s, memory beyond the window;
and the event frames' path to a policy's input."""
import math

import numpy as np
import pytest

from actors.accumulator import Accumulator
from sebvs.conditions import checkpoint_event_frames, event_frame_overrides
from sebvs.dvs.accumulator import REPRESENTATIONS, EventAccumulator, EventGeometry
from sebvs.dvs.emulator import EVENT_DTYPE
from sebvs.dvs.stream import FrameStream
from sebvs.dvs.time_surface import TimeSurface
from sebvs.policy.inputs import Normalisation, event_clip_for, model_input
from sebvs.runtime.params import build_params

S = 1_000_000_000          # ns per s
TAU = 0.1                  # s: the accumulator's window_s, the surface's decay constant


def events(*rows) -> np.ndarray:
    """EVENT_DTYPE events from (x, y, t ns, p) rows."""
    ev = np.zeros(len(rows), EVENT_DTYPE)
    for i, (x, y, t, p) in enumerate(rows):
        ev[i] = (x, y, t, p)
    return ev


def surface_acc(sensor=(4, 4), output=None) -> EventAccumulator:
    return EventAccumulator(EventGeometry(sensor, output or sensor), "time_surface",
                            window_s=TAU)


def expected(age_s: float) -> int:
    return round(255 * math.exp(-age_s / TAU))


def test_one_event_decays_with_tau_from_the_frames_end():
    acc = surface_acc()
    acc.add(events((1, 2, 1 * S, 1)))
    at = acc.frame(1 * S)
    assert at.shape == (2, 4, 4) and at.dtype == np.uint8
    assert at[0, 2, 1] == 255 and at.sum() == 255          # only that pixel, ON plane
    assert acc.frame(1 * S + S // 20)[0, 2, 1] == expected(0.05) == 155
    assert acc.frame(1 * S + S // 10)[0, 2, 1] == round(255 / math.e) == 94
    # about 6.2 tau on the value rounds to 0: gone
    assert acc.frame(1 * S + S)[0, 2, 1] == 0


def test_the_newest_event_of_each_polarity_counts_on_its_own_plane():
    acc = surface_acc()
    acc.add(events((0, 0, 900_000_000, 1), (0, 0, 950_000_000, -1), (3, 1, 960_000_000, -1),
                   (0, 0, 980_000_000, 1)))
    f = acc.frame(S)
    assert f[0, 0, 0] == expected(0.02)                     # ON: its newest, at 0.98 s
    assert f[1, 0, 0] == expected(0.05)                     # OFF at the same pixel
    assert f[1, 1, 3] == expected(0.04) and f[0, 1, 3] == 0
    assert np.count_nonzero(f) == 3


def test_matches_the_formula_on_a_random_stream():
    rng = np.random.default_rng(3)
    sensor, n = (16, 12), 4000
    ev = np.zeros(n, EVENT_DTYPE)
    ev["x"], ev["y"] = rng.integers(0, 16, n), rng.integers(0, 12, n)
    ev["t"] = np.sort(rng.integers(0, S, n))
    ev["p"] = rng.choice([-1, 1], n)
    acc = surface_acc(sensor)
    for packet in np.array_split(ev, 50):
        acc.add(packet)
    t_end = S + 37_000_000
    got = acc.frame(t_end).astype(int)
    want = np.zeros((2, 12, 16))
    for x, y, t, p in ev.tolist():                  # time order: the last one is the newest
        want[0 if p > 0 else 1, y, x] = 255 * math.exp(-(t_end - t) / (TAU * S))
    rounded = np.floor(want + 0.5)
    # float32 inside: only a value within a hair of a half may round the other way
    assert np.abs(got - rounded).max() <= 1
    clear_of_half = np.abs(want - np.floor(want) - 0.5) > 1e-3
    assert np.array_equal(got[clear_of_half], rounded[clear_of_half])
    assert np.count_nonzero(got) > 100


def test_the_memory_reaches_beyond_the_window():
    old = events((2, 2, 1 * S, 1))
    surface, counts = surface_acc(), EventAccumulator(EventGeometry((4, 4), (4, 4)),
                                                      "counts", window_s=TAU)
    for acc in (surface, counts):
        acc.add(old)
        acc.add(events((0, 3, 1 * S + 3 * S // 10, -1)))    # a packet 3 tau later
    t_end = 1 * S + 3 * S // 10
    assert counts.frame(t_end)[0].sum() == 0          # the window lost the still target
    assert surface.frame(t_end)[0, 2, 2] == expected(0.3) == 13


def test_events_off_the_sensor_and_of_polarity_zero_are_ignored():
    acc = surface_acc()
    acc.add(events((4, 0, S, 1), (0, 4, S, -1), (65535, 65535, S, 1), (1, 1, S, 0)))
    assert not acc.frame(S).any()
    acc.add(events((3, 3, S, -1)))
    f = acc.frame(S)
    assert f[1, 3, 3] == 255 and np.count_nonzero(f) == 1


def test_an_event_after_the_frames_time_does_not_count():
    acc = surface_acc()
    acc.add(events((1, 1, 1 * S, 1), (2, 2, 1 * S, 1)))
    acc.add(events((1, 1, 2 * S, 1)))
    early = acc.frame(1 * S + S // 10)
    # the newest time is all a pixel keeps: (1, 1) is hidden, not shown as of 1 s
    assert early[0, 1, 1] == 0 and early[0, 2, 2] == 94
    assert acc._surface.hidden_frames == 1
    assert acc.frame(2 * S)[0, 1, 1] == 255 and acc._surface.hidden_frames == 1


def test_a_late_packet_does_not_move_a_pixels_time_back():
    acc = surface_acc()
    acc.add(events((1, 1, 2 * S, 1)))
    acc.add(events((1, 1, 1 * S, 1)))
    assert acc.frame(2 * S)[0, 1, 1] == 255


def test_a_new_episode_clears_the_surface_through_the_frame_stream():
    stream = FrameStream("time_surface", window_s=TAU, out_width=8, out_height=8)
    geometry = {"event_sensor": [4, 4], "frame": [8, 8]}
    stream.add(events((0, 0, S, 1)), 0, geometry)
    assert stream.frame(1.0)[0, 0, 0] == 255
    assert stream.frame_meta()["representation"] == "time_surface"
    assert stream.frame_meta()["bins"] == 1 and stream.frame_meta()["window_s"] == TAU
    stream.add(events((3, 3, S + S // 100, -1)), 1, geometry)   # episode 1
    f = stream.frame(1.01)
    assert f[0].sum() == 0 and f[1, 6, 6] == 255 and np.count_nonzero(f) == 4
    stream.add(np.zeros(0, EVENT_DTYPE), 2, geometry)          # episode 2, no events yet
    assert not stream.frame(1.02).any()


def test_output_geometry_follows_the_nearest_mapping():
    small_sensor = surface_acc((4, 4), (8, 8))     # a half-size sensor: 2 x 2 blocks
    small_sensor.add(events((1, 2, S, 1)))
    f = small_sensor.frame(S)
    assert f.shape == (2, 8, 8) and f.flags.c_contiguous
    assert (f[0, 4:6, 2:4] == 255).all() and np.count_nonzero(f) == 4
    big_sensor = surface_acc((8, 6), (4, 3))       # output below the sensor: every 2nd
    big_sensor.add(events((2, 4, S, -1), (3, 4, S, -1)))
    g = big_sensor.frame(S)
    assert g.shape == (2, 3, 4)
    assert g[1, 2, 1] == 255 and np.count_nonzero(g) == 1   # (3, 4) falls between


def test_the_name_is_accepted_wherever_representations_are_named():
    assert "time_surface" in REPRESENTATIONS
    p = build_params(Accumulator.Params, {"representation": "time_surface", "window_s": 0.2},
                     where="accumulator")
    assert p.representation == "time_surface" and p.window_s == 0.2
    with pytest.raises(ValueError, match="representation"):
        build_params(Accumulator.Params, {"representation": "time_surfaces"},
                     where="accumulator")
    frames = {"representation": "time_surface", "bins": 1, "window_s": 0.2}
    assert checkpoint_event_frames({"event_frames": frames}) == frames
    assert event_frame_overrides(frames, {})["accumulator"] == {
        "representation": "time_surface", "bins": 1, "window_s": 0.2}
    with pytest.raises(ValueError, match="tau_s"):
        TimeSurface((4, 4), 0.0)


def test_a_recording_of_time_surfaces_is_taken_for_training(tmp_path):
    import h5py
    from sebvs.policy.dataset import event_frames_of, load_index
    from tests.policy_data import make_dataset, reindex
    data = make_dataset(tmp_path / "d", episodes=1, frames=2)
    with h5py.File(data / load_index(data)[0]["file"], "a") as f:
        f.attrs["event_representation"] = "time_surface"
    reindex(data)
    frames = event_frames_of(data, load_index(data))
    assert frames["representation"] == "time_surface" and frames["bins"] == 1


def test_a_time_surface_reaches_the_model_as_value_over_255():
    assert event_clip_for("time_surface", 8) == 255
    assert event_clip_for("counts", 8) == 8 and event_clip_for("histogram", 3) == 3
    acc = surface_acc((8, 8))
    acc.add(events((2, 3, S, 1)))
    frame = acc.frame(S + S // 10)                          # 94 at (2, 3)
    x = model_input("event", Normalisation(size=8, event_clip=event_clip_for(
        "time_surface", 8)), events=frame)
    assert x.shape == (2, 8, 8) and x[0, 3, 2] == pytest.approx(94 / 255)
    clipped = model_input("event", Normalisation(size=8), events=frame)
    assert clipped[0, 3, 2] == 1.0           # a count's clip at 8 loses the decay


def test_a_histogram_of_k_bins_passes_to_an_event_policys_input():
    k = 3
    acc = EventAccumulator(EventGeometry((8, 8), (16, 16)), "histogram", window_s=TAU,
                           bins=k)
    acc.add(events((1, 1, 10_000_000, 1), (1, 1, 20_000_000, 1), (6, 6, 95_000_000, -1)))
    frame = acc.frame(TAU * S)
    assert frame.shape == (2 * k, 16, 16)
    x = model_input("event", Normalisation(size=16, event_clip=4, event_bins=k),
                    events=frame)
    assert x.shape == (2 * k, 16, 16) and x.dtype == np.float32
    assert (x[0, 2:4, 2:4] == 0.5).all()          # ON, oldest bin: 2 of event_clip 4
    assert (x[2 * k - 1, 12:14, 12:14] == 0.25).all()   # OFF, newest bin
    assert x.sum() == pytest.approx(4 * 0.75)
    with pytest.raises(ValueError, match=r"\[6, H, W\]"):
        model_input("event", Normalisation(size=16, event_bins=k), events=frame[:2])


def test_an_env_wrapper_observes_time_surfaces_in_its_space():
    pytest.importorskip("gymnasium")
    pytest.importorskip("imageio")
    from sebvs.envs import EventCameraWrapper
    from tests.test_event_wrapper import BareArm
    env = EventCameraWrapper(BareArm(), "front", width=32, height=32, obs=("events",),
                             representation="time_surface", preset="paper", clip=8)
    space = env.observation_space["events"]
    assert space.shape == (2, 32, 32) and space.dtype == np.uint8 and space.high.max() == 255
    obs, _ = env.reset(seed=0)
    seen = []
    for _ in range(8):
        obs, *_ = env.step(np.ones(1, np.float32))
        assert space.contains(obs["events"])
        seen.append(int(obs["events"].max()))
    env.close()
    assert max(seen) > 8            # the arm swings: fresh pixels, above a count's clip


def test_the_task_env_checks_with_a_time_surface():
    gym = pytest.importorskip("gymnasium")
    from gymnasium.utils.env_checker import check_env
    from sebvs.envs import ENV_IDS
    env = gym.make(ENV_IDS["nav"], representation="time_surface", obs=("events",),
                   width=48, height=48, episode_s=0.5)
    space = env.observation_space["events"]
    assert space.shape == (2, 48, 48) and space.dtype == np.uint8 and space.high.max() == 255
    assert env.unwrapped.settings["accumulator"].representation == "time_surface"
    check_env(env.unwrapped)
    env.close()
