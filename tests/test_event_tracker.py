"""The event-only tracker (sebvs/experts/event_tracker.py) and its look-and-move driver
(sebvs/experts/event_agent.py) on synthetic event frames, and the actor
(actors/event_tracker.py) in process and in a short lockstep run of
topologies/nav_event_tracker.toml."""
import asyncio
import json
import math
from dataclasses import fields
from pathlib import Path

import numpy as np
import pytest

from sebvs.experts.event_agent import EventAgentConfig, EventTrackerAgent
from sebvs.experts.event_tracker import EventTracker, EventTrackerConfig
from sebvs.runtime import Message

ROOT = Path(__file__).resolve().parents[1]
SIZE = 160
EMPTY = np.zeros((2, SIZE, SIZE), np.uint8)


def blob_frame(centre, prev=None, side=12, noise=0, rng=None):
    """ON events on a square's leading edge, OFF on its trailing edge (as a moving bright
    square fires), plus `noise` random single events."""
    ev = np.zeros((2, SIZE, SIZE), np.uint8)

    def mask(c):
        m = np.zeros((SIZE, SIZE), bool)
        u0, v0 = int(round(c[0] - side / 2)), int(round(c[1] - side / 2))
        m[max(0, v0):max(0, v0 + side), max(0, u0):max(0, u0 + side)] = True
        return m
    now = mask(centre)
    before = mask(prev) if prev is not None else np.zeros_like(now)
    ev[0][now & ~before] = 3
    ev[1][before & ~now] = 3
    if prev is None or not (now & ~before).any():
        ev[0][now] = 2
    if noise:
        rng = rng or np.random.default_rng(0)
        ev[rng.integers(0, 2, noise), rng.integers(0, SIZE, noise),
           rng.integers(0, SIZE, noise)] = 1
    return ev


def path(k, start=(40.0, 70.0), vel=(25.0, 6.0), dt=0.1):
    """The blob's centre at frame k: `vel` px/s from `start`."""
    return (start[0] + vel[0] * dt * k, start[1] + vel[1] * dt * k)


def test_follows_a_moving_blob_and_learns_its_velocity():
    tr = EventTracker(EventTrackerConfig())
    rng = np.random.default_rng(1)
    errors = []
    for k in range(30):
        ev = blob_frame(path(k), path(k - 1) if k else None, noise=150, rng=rng)
        det = tr.step(ev, 0.1)
        assert det is not None and tr.mode == "track"
        errors.append(np.hypot(det.centroid[0] - path(k)[0], det.centroid[1] - path(k)[1]))
    assert np.median(errors) < 3.0 and max(errors[5:]) < 5.0, errors
    # the velocity memory: 25, 6 px/s (2.5, 0.6 px per 0.1 s tick)
    assert abs(tr.vel[0] - 25.0) < 5.0 and abs(tr.vel[1] - 6.0) < 5.0, tr.vel


def test_the_velocity_is_learnt_from_sparse_measurements_too():
    # measured every fourth frame only (the driver looks between its moves): the residual
    # is over the whole gap, not one frame's dt
    tr = EventTracker(EventTrackerConfig())
    tr.step(blob_frame(path(0)), 0.1)
    for _ in range(3):
        tr.step(EMPTY, 0.1, measure=False)
    tr.step(blob_frame(path(4), path(3)), 0.1)
    # the first update: beta x the residual (10 px) over the 0.4 s since the last
    # measurement, 0.2 x 25 px/s (over one frame's 0.1 s it would be four times that)
    assert tr.vel[0] == pytest.approx(0.2 * 25.0, abs=1.0), tr.vel
    tr.reset()
    for k in range(0, 40):
        if k % 4 == 0:
            tr.step(blob_frame(path(k), path(k - 1) if k else None), 0.1)
        else:
            tr.step(EMPTY, 0.1, measure=False)
    assert abs(tr.vel[0] - 25.0) < 6.0, tr.vel
    assert tr.mode in ("track", "coast")


def test_coasts_through_empty_frames_then_reports_lost():
    cfg = EventTrackerConfig(coast_s=0.5)
    tr = EventTracker(cfg)
    for k in range(15):
        tr.step(blob_frame(path(k), path(k - 1) if k else None), 0.1)
    for k in range(15, 20):                       # 0.5 s without events: coasting
        det = tr.step(EMPTY, 0.1)
        assert det is not None and tr.mode == "coast"
        # on the constant-velocity prediction, where the blob would be
        assert np.hypot(det.centroid[0] - path(k)[0], det.centroid[1] - path(k)[1]) < 6.0
        assert det.confidence < 1.0
    # the blob reappears where the prediction says: it is measured again
    det = tr.step(blob_frame(path(20), path(19)), 0.1)
    assert tr.mode == "track" and det.confidence == 1.0
    for _ in range(5):
        det = tr.step(EMPTY, 0.1)
    assert det is not None and tr.mode == "coast"
    det = tr.step(EMPTY, 0.1)                     # past coast_s: lost, forgotten
    assert det is None and tr.mode == "lost" and tr.pos is None
    assert tr.counts["lost"] == 1


def test_a_whole_frame_flicker_burst_is_not_a_target():
    tr = EventTracker(EventTrackerConfig())
    for k in range(10):
        tr.step(blob_frame(path(k), path(k - 1) if k else None), 0.1)
    held = tr.pos.copy()
    rng = np.random.default_rng(2)
    burst = rng.integers(0, 4, (2, SIZE, SIZE)).astype(np.uint8)     # most pixels fire
    burst[0, 10:40, 120:150] = 20                                     # a bright patch too
    det = tr.step(burst, 0.1)
    assert tr.burst and tr.mode == "coast" and det is not None
    # coasted on the prediction, not pulled to the burst's brightest patch
    assert np.hypot(*(np.array(det.centroid) - held - tr.vel * 0.1)) < 1.0
    assert np.hypot(det.centroid[0] - 135, det.centroid[1] - 25) > 50
    assert tr.counts["bursts"] == 1
    # a tracker holding nothing does not acquire a burst either
    fresh = EventTracker(EventTrackerConfig())
    assert fresh.step(burst, 0.1) is None and fresh.burst


def test_scattered_noise_gives_no_target():
    rng = np.random.default_rng(3)
    tr = EventTracker(EventTrackerConfig())
    for _ in range(20):
        ev = np.zeros((2, SIZE, SIZE), np.uint8)
        ev[rng.integers(0, 2, 600), rng.integers(0, SIZE, 600), rng.integers(0, SIZE, 600)] = 1
        assert tr.step(ev, 0.1) is None
    assert tr.mode == "acquire"


def test_a_noisy_band_is_not_a_target_but_a_blob_beside_it_is():
    # the hdr cell's bright sky fires far more noise than the dark floor: against the
    # frame's mean density the band's densest spot passes for a cluster; against its own
    # surround it does not
    rng = np.random.default_rng(5)
    tr = EventTracker(EventTrackerConfig())
    band = np.zeros((2, SIZE, SIZE), np.uint8)
    n = 2500
    band[rng.integers(0, 2, n), rng.integers(0, 50, n), rng.integers(0, SIZE, n)] = 1
    for _ in range(10):
        assert tr.step(band, 0.1) is None
        band = np.roll(band, 7, axis=2)
    with_blob = np.maximum(band, blob_frame((100.0, 110.0)))
    det = tr.step(with_blob, 0.1)
    assert det is not None and np.hypot(det.centroid[0] - 100, det.centroid[1] - 110) < 3


def test_a_long_edge_is_not_a_target_but_a_blob_of_fewer_counts_is():
    # a floor edge sweeping by while the robot turns: a line, whose surround holds it too
    tr = EventTracker(EventTrackerConfig())
    line = np.zeros((2, SIZE, SIZE), np.uint8)
    line[0, 118:121, :] = 2                        # 960 counts along the whole width
    assert tr.step(line, 0.1) is None
    blob = np.maximum(line, blob_frame((60.0, 60.0)))   # 288 counts in a 12 px square
    det = tr.step(blob, 0.1)
    assert det is not None and np.hypot(det.centroid[0] - 60, det.centroid[1] - 60) < 3


def test_a_shift_moves_the_held_target():
    tr = EventTracker(EventTrackerConfig())
    tr.step(blob_frame((40.0, 80.0)), 0.1)
    before = tr.pos.copy()
    tr.shift(30.0, -2.0)
    assert np.allclose(tr.pos - before, [30.0, -2.0])
    tr.reset()
    tr.shift(5.0)                                  # nothing held: nothing to move
    assert tr.pos is None


def _looks_until_track(agent, frame):
    for k in range(10):
        cmd, det, mode = agent.act(frame, 0.1, episode=0)
        if mode.startswith("look/track"):
            return cmd, det, k
        assert not cmd.any(), (k, mode)          # still while settling and looking
    raise AssertionError("never tracked")


def test_the_driver_looks_still_then_turns_toward_the_blob_by_its_bearing():
    f = 0.5 * SIZE / math.tan(math.radians(35.0))
    for u in (120.0, 155.0):
        agent = EventTrackerAgent(EventTrackerConfig(), EventAgentConfig(lead_s=0.0))
        cmd, det, k = _looks_until_track(agent, blob_frame((u, 80.0)))
        bearing = math.atan((det.centroid[0] - 80.0) / f)
        # right of centre: turn right (w < 0), the bearing in move_s at w_max, clipped to 1
        w = max(-1.0, -bearing / (2.0 * 0.2))
        assert cmd[1] < 0 and cmd[1] == pytest.approx(w, abs=1e-5)
        # the efference copy: the held target now sits where the turn puts it (the centre,
        # unless the command was clipped)
        after = 80.0 + f * math.tan(bearing + w * 2.0 * 0.2)
        assert agent.tracker.pos[0] == pytest.approx(after, abs=1e-6)
        assert (after == pytest.approx(80.0)) == (u == 120.0)
        # the move lasts move_s (this tick and the next), then the robot stands still for
        # settle_s (a frame whose window still holds the turn) before it looks again
        cmd2, _, mode2 = agent.act(EMPTY, 0.1, episode=0)
        assert mode2.startswith("move") and np.array_equal(cmd2, cmd)
        modes = []
        for _ in range(2):
            cmd3, _, mode3 = agent.act(EMPTY, 0.1, episode=0)
            modes.append(mode3)
            assert not cmd3.any()
        assert modes[0].startswith("settle") and modes[1].startswith("look"), modes
        assert agent.counts["moves"] == 1


def test_the_driver_searches_toward_the_side_last_seen_and_resets_per_episode():
    cfg = EventAgentConfig(patience_s=0.5)
    agent = EventTrackerAgent(EventTrackerConfig(coast_s=0.2), cfg)
    _looks_until_track(agent, blob_frame((30.0, 80.0)))        # left of centre
    modes, cmds = [], []
    for _ in range(20):
        cmd, det, mode = agent.act(EMPTY, 0.1, episode=0)
        modes.append(mode)
        cmds.append(cmd)
    first = next(i for i, m in enumerate(modes) if m.startswith("search"))
    assert cmds[first][1] == pytest.approx(cfg.search_w) and cmds[first][0] == 0
    # search_angle at w_max * search_w: 0.3 s of turning, then still again
    turning = [i for i, c in enumerate(cmds) if c[1] > 0 and i >= first]
    assert turning[:3] == [first, first + 1, first + 2] and first + 3 not in turning
    agent.act(EMPTY, 0.1, episode=1)                              # a new episode resets
    assert agent.tracker.counts["frames"] == 1 and agent.phase == "settle"


def test_the_driver_holds_still_while_blinded_by_bursts():
    rng = np.random.default_rng(4)
    agent = EventTrackerAgent(EventTrackerConfig(), EventAgentConfig())
    for _ in range(10):
        burst = rng.integers(20, 90, (2, SIZE, SIZE)).astype(np.uint8)  # 120 Hz flicker
        cmd, det, mode = agent.act(burst, 0.1, episode=0)
        assert det is None and not cmd.any() and agent.tracker.counts["measured"] == 0


def test_the_driver_waits_for_a_quiet_frame_after_a_move():
    agent = EventTrackerAgent(EventTrackerConfig(), EventAgentConfig())
    rng = np.random.default_rng(6)

    def noise(n):
        ev = np.zeros((2, SIZE, SIZE), np.uint8)
        ev[rng.integers(0, 2, n), rng.integers(0, SIZE, n), rng.integers(0, SIZE, n)] = 1
        return ev
    quiet = np.maximum(noise(500), blob_frame((120.0, 80.0)))
    _looks_until_track(agent, quiet)
    agent.act(noise(500), 0.1, episode=0)                        # the move's second tick
    busy = noise(4000)                                           # the robot still turning
    modes = [agent.act(busy, 0.1, episode=0)[2] for _ in range(4)]
    assert all(m.startswith("settle") for m in modes), modes      # up to settle_max_s
    assert agent.act(busy, 0.1, episode=0)[2].startswith("look")
    # quiet at once: looks after settle_s. An episode's first frames hold no event at all:
    # they are not the noise floor the quiet test compares with
    agent2 = EventTrackerAgent(EventTrackerConfig(), EventAgentConfig())
    for _ in range(3):
        agent2.act(EMPTY, 0.1, episode=0)
    _looks_until_track(agent2, quiet)
    agent2.act(noise(500), 0.1, episode=0)
    modes = [agent2.act(noise(500), 0.1, episode=0)[2] for _ in range(2)]
    assert modes[0].startswith("settle") and modes[1].startswith("look"), modes


def test_bad_settings_are_refused():
    with pytest.raises(ValueError, match="burst_active"):
        EventTrackerConfig(burst_active=0.0)
    with pytest.raises(ValueError, match="alpha"):
        EventTrackerConfig(alpha=1.5)
    with pytest.raises(ValueError, match="surround"):
        EventTrackerConfig(surround=1.0)
    with pytest.raises(ValueError, match="move_s"):
        EventAgentConfig(move_s=0.0)
    with pytest.raises(ValueError, match="settle_max_s"):
        EventAgentConfig(settle_s=0.4, settle_max_s=0.3)


def test_the_actor_parameters_are_the_configs_fields_with_their_defaults():
    from sebvs_actors.event_tracker import EventTrackerDriver
    params = EventTrackerDriver.Params()
    for config in (EventTrackerConfig(), EventAgentConfig()):
        for f in fields(config):
            assert getattr(params, f.name) == getattr(config, f.name), f.name


class FakeNode:
    def __init__(self):
        self.emitted = []

    def emit(self, output, arrays, *, meta=None, t_sim=None, tick=None, parent=None):
        self.emitted.append((output, {k: np.array(v) for k, v in (arrays or {}).items()},
                             meta, tick))

    def event(self, kind, fields):
        pass


def test_the_actor_answers_every_control_tick_in_process():
    from sebvs_actors.event_tracker import EventTrackerDriver
    node = FakeNode()
    actor = EventTrackerDriver("driver", EventTrackerDriver.Params(), seed=0,
                               clock="lockstep", consumed=frozenset({"action"}),
                               connected=frozenset({"events"}), node=node)
    asyncio.run(actor.setup())
    for k in range(8):
        frame = blob_frame((120.0, 80.0)) if k < 5 else EMPTY
        msg = Message(topic="t", source="accumulator", output="frames", seq=k,
                      t_sim=k * 0.1, tick=k, stamps=[],
                      meta={"episode": 0, "control": True, "t_ep": k * 0.1},
                      arrays={"frame": frame})
        asyncio.run(actor.on_events(msg))
    skipped = Message(topic="t", source="accumulator", output="frames", seq=9, t_sim=0.85,
                      tick=9, stamps=[], meta={"episode": 0, "control": False},
                      arrays={"frame": blob_frame(path(8))})
    asyncio.run(actor.on_events(skipped))
    acts = [e for e in node.emitted if e[0] == "action"]
    assert [e[3] for e in acts] == list(range(8))
    for _, arrays, meta, _ in acts:
        assert arrays["action"].shape == (2,) and np.isfinite(arrays["action"]).all()
        assert meta["modality"] == "event_tracker"
    modes = [a[2]["mode"] for a in acts]
    # settle_s (0.2 s) still from the start, then a look finds the blob right of centre
    assert modes[:3] == ["settle/acquire", "look/track", "move/coast"], modes
    assert acts[0][2]["detection"] is None and not acts[0][1]["action"].any()
    assert acts[1][2]["detection"] is not None and acts[1][1]["action"][1] < 0
    stats = actor.stats()
    assert stats["actions"] == 8 and stats["driver_moves"] == 1


def test_the_topology_runs_in_lockstep_and_emits_finite_actions(tmp_path):
    from sebvs.runtime.supervisor import run_topology
    probe, track = tmp_path / "probe", tmp_path / "track.jsonl"
    topo = tmp_path / "nav_event_tracker_probe.toml"
    topo.write_text((ROOT / "topologies" / "nav_event_tracker.toml").read_text() + f"""
[actors.probe]
run = "actors.synthetic:Probe"
inputs = {{ action = "driver/action", episode = "sim/episode" }}
path = {json.dumps(str(probe))}
""")
    run_topology(topo, ["sim.episode_s=2.0", "sim.episodes=1", "sim.linger_s=2.0",
                        'sim.config.variant="outdoor"',
                        f"tracker.path={json.dumps(str(track))}"],
                 duration_s=120, runs_dir=tmp_path)
    entries = json.loads(probe.with_suffix(".json").read_text())
    acts = [e for e in entries if e["input"] == "action"]
    ticks = [a["tick"] for a in acts]
    assert ticks == list(range(len(ticks))) and len(ticks) >= 20, ticks
    assert all(a["arrays"]["action"] == [[2], "<f4"] for a in acts)
    assert all(a["meta"]["modality"] == "event_tracker" for a in acts)
    lines = [json.loads(x) for x in track.read_text().splitlines()]
    assert len(lines) == 1 and set(lines[0]["by_modality"]) == {"event_tracker"}
    assert lines[0]["health"]["nonfinite_actions"] == 0
    assert lines[0]["health"]["actions"] >= 19
