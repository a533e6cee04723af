"""The sim and camera actors: in-process unit checks, then real runs through the runtime."""
import asyncio
import json
from pathlib import Path

import numpy as np
import pytest

from sebvs_actors.camera import Camera
from sebvs_actors.sim import NOISE_STREAM, Sim, episode_seed
from sebvs.runtime import Message
from sebvs.runtime.supervisor import run_topology

ROOT = Path(__file__).resolve().parents[1]
NAV_CAMERA = ROOT / "topologies" / "nav_camera.toml"


# ---------------------------------------------------------------- in process
class FakeNode:
    """Stands in for the runtime: records what the actor emits."""

    def __init__(self):
        self.emitted, self.events, self.finished = [], [], None

    def emit(self, output, arrays, *, meta=None, t_sim=None, tick=None, parent=None):
        if parent is not None:       # what the real node carries on from the parent
            t_sim = parent.t_sim if t_sim is None else t_sim
            tick = parent.tick if tick is None else tick
            meta = parent.meta if meta is None else meta
        self.emitted.append((output, {k: np.array(v) for k, v in (arrays or {}).items()},
                             meta, t_sim, tick))

    def reserve(self, output, specs):
        arrays = {n: np.empty(shape, dt) for n, (shape, dt) in specs.items()}
        self.reserved = arrays
        return arrays

    def event(self, kind, fields):
        self.events.append((kind, fields))

    def finish(self, reason):
        self.finished = reason


def make_sim(connected=frozenset(), clock="lockstep", **params):
    node = FakeNode()
    p = Sim.Params(**{"episode_s": 0.5, "render_hz": 100.0, **params})
    sim = Sim("sim", p, seed=7, clock=clock, consumed=frozenset({"state", "episode"}),
              connected=connected, node=node)
    asyncio.run(sim.setup())
    return sim, node


def test_divergence_ends_the_episode_and_no_nan_is_emitted(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)      # MuJoCo writes MUJOCO_LOG.TXT into the cwd on a warning
    sim, node = make_sim()
    scripted = sim.scene.scripted

    def poisoned(model, data):       # a blow-up mid-episode
        scripted(model, data)
        if data.time > 0.2:
            data.qvel[0] = np.nan

    sim.scene.scripted = poisoned
    asyncio.run(sim.run())
    ends = [m for o, _, m, *_ in node.emitted if o == "episode" and m["event"] == "end"]
    assert len(ends) == 1 and ends[0]["reason"].startswith("diverged:"), ends
    states = [a for o, a, *_ in node.emitted if o == "state"]
    assert states and all(np.isfinite(v).all() for s in states for v in s.values())
    assert any(k == "episode_end" and f["reason"].startswith("diverged") for k, f in node.events)
    assert node.finished


def test_state_stream_meta_ticks_and_truth():
    sim, node = make_sim(episodes=2)
    asyncio.run(sim.run())
    states = [(a, m, t, k) for o, a, m, t, k in node.emitted if o == "state"]
    # 0.5 s at 100 Hz: 51 samples per episode (both ends), every 5th a control tick
    assert len(states) == 102
    ctrl = [s for s in states if s[1]["control"]]
    assert len(ctrl) == 22 and all("truth" in m for _, m, _, _ in ctrl)
    assert [k for *_, k in ctrl] == list(range(22))
    assert states[0][1]["scene"] == "nav" and "config" in states[0][1]
    assert {m["episode"] for _, m, _, _ in states} == {0, 1}
    t = [ts for _, _, ts, _ in states]
    assert t == sorted(t)                                  # t_sim monotonic across episodes
    eps = [m for o, _, m, *_ in node.emitted if o == "episode"]
    assert [(m["event"], m["episode"]) for m in eps] == [("start", 0), ("end", 0),
                                                         ("start", 1), ("end", 1)]
    assert eps[0]["seed"] == episode_seed(7, 0) and eps[1]["reason"] == "time_limit"


@pytest.mark.parametrize("integrator", ["discrete", "rk4", "implicitfast", "euler"])
def test_a_tick_says_the_next_ticks_time_bit_for_bit(integrator):
    """What a frame camera renders ahead with (sebvs/sensors/rig.py): equal, not close."""
    sim, node = make_sim(integrator=integrator)
    asyncio.run(sim.run())
    ticks = [m for o, _, m, *_ in node.emitted if o == "state" and m["control"]]
    assert len(ticks) == 11 and "t_next_control" not in ticks[-1]   # the time is up
    for tick, following in zip(ticks, ticks[1:]):
        assert tick["t_next_control"] == following["t_ep"]


def test_bad_commands_rejected_last_good_kept():
    sim, node = make_sim(clock="realtime", connected=frozenset({"action"}))

    def msg(cmd, tick):
        return Message(topic="t", source="x", output="action", seq=0, t_sim=0.0, tick=tick,
                       stamps=[], meta={}, arrays={"action": np.asarray(cmd, float)})

    asyncio.run(sim.on_action(msg([0.5, -0.5], 0)))
    good = sim.data.ctrl.copy()
    for bad in ([np.nan, 0.0], [np.inf, 0.0], [1.0, 2.0, 3.0]):
        asyncio.run(sim.on_action(msg(bad, 1)))
        np.testing.assert_array_equal(sim.data.ctrl, good)
    assert sim.counts["rejected"] == 3
    assert [k for k, _ in node.events].count("command_rejected") == 3


def _applied(sim, commands):
    """Apply `commands` one per realtime tick -> the nav ctrl the scene got for each."""
    scale = np.array([sim.scene.config["v_max"], sim.scene.config["w_max"]], float)
    out = []
    for i, cmd in enumerate(commands):
        asyncio.run(sim.on_action(Message(topic="t", source="x", output="action", seq=i,
                                          t_sim=0.0, tick=i, stamps=[], meta={},
                                          arrays={"action": np.asarray(cmd, float)})))
        out.append(sim.data.ctrl[:2] / scale)
    return np.array(out)


def test_command_noise_is_zero_mean_with_its_std_and_reproducible_from_the_seed():
    cmd = [[0.2, -0.1]] * 2000
    clean, _ = make_sim(clock="realtime", connected=frozenset({"action"}))
    np.testing.assert_allclose(_applied(clean, cmd[:5]), cmd[:5])       # off: as commanded
    runs = []
    for _ in range(2):
        sim, _ = make_sim(clock="realtime", connected=frozenset({"action"}),
                          command_noise=[0.1, 0.05])
        sim.noise_rng = np.random.default_rng([episode_seed(7, 0), NOISE_STREAM])
        runs.append(_applied(sim, cmd))
    np.testing.assert_array_equal(runs[0], runs[1])
    err = runs[0] - np.array(cmd)
    np.testing.assert_allclose(err.std(axis=0), [0.1, 0.05], rtol=0.08)
    np.testing.assert_allclose(err.mean(axis=0), [0.0, 0.0], atol=0.01)
    assert sim.counts["noised"] == 2000
    assert sim.command.tolist() == [0.2, -0.1]       # the clean command is what is kept


def test_command_noise_clipped_by_the_scene_and_drawn_per_episode_seed():
    sim, _ = make_sim(clock="realtime", connected=frozenset({"action"}), command_noise=[5.0, 5.0])
    assert np.abs(_applied(sim, [[0.9, -0.9]] * 50)).max() <= 1.0 + 1e-12
    sim, node = make_sim(episodes=2, command_noise=[0.1, 0.1])
    asyncio.run(sim.run())             # lockstep without an action wired: no command, no draw
    assert sim.counts["noised"] == 0
    # reseeded from the last episode's seed, its own stream (not the scene's)
    assert sim.noise_rng.normal() == \
        np.random.default_rng([episode_seed(7, 1), NOISE_STREAM]).normal()


def test_command_noise_of_the_wrong_length_refused_at_setup_and_at_set():
    with pytest.raises(ValueError, match="command_noise has 3 values.*has 2"):
        make_sim(command_noise=[0.1, 0.1, 0.1])
    sim, _ = make_sim(command_noise=[0.1, 0.1])
    with pytest.raises(ValueError, match="command_noise has 1 values"):
        asyncio.run(sim.control("command_noise", [0.3]))
    assert sim.params.command_noise == [0.1, 0.1]
    with pytest.raises(ValueError):
        asyncio.run(sim.control("command_noise", [-0.1, 0.1]))     # a std is >= 0
    assert asyncio.run(sim.control("command_noise", [0.2, 0.0])) == {"command_noise": [0.2, 0.0]}


def test_camera_renders_consumed_outputs_and_luma_on_every_control_sample():
    sim, sim_node = make_sim(config={"width": 48, "height": 32, "rgb_blur": 3},
                             episodes=2, episode_s=0.3)
    asyncio.run(sim.run())
    node = FakeNode()
    cam = Camera("camera", Camera.Params(dvs_hz=30.0, luma_scale=0.5), seed=0, clock="lockstep",
                 consumed=frozenset({"rgb", "luma", "seg"}), node=node)

    async def feed():
        await cam.setup()
        for i, (out, arrays, meta, t_sim, tick) in enumerate(sim_node.emitted):
            if out == "state":
                await cam.on_state(Message(topic="sim/state", source="sim", output="state",
                                           seq=i, t_sim=t_sim, tick=tick, stamps=[],
                                           meta=meta, arrays=arrays))
        await cam.teardown()

    asyncio.run(feed())
    states = [m for o, _, m, *_ in sim_node.emitted if o == "state"]
    controls = [m for m in states if m["control"]]
    by = {o: [(a, m, k) for oo, a, m, _, k in node.emitted if oo == o]
          for o in ("rgb", "luma", "seg", "depth")}
    assert not by["depth"]                                  # not consumed: never rendered
    assert len(by["rgb"]) == len(by["seg"]) == len(controls) == 14
    luma_ctrl = [(m["t_ep"], k) for _, m, k in by["luma"] if m["control"]]
    assert luma_ctrl == [(m["t_ep"], i) for i, m in enumerate(controls)]
    assert len(by["luma"]) > len(controls)                  # plus the 30 Hz samples
    a, m, _ = by["rgb"][3]
    assert a["rgb"].shape == (32, 48, 3) and a["rgb"].std() > 3
    assert m["truth"]["image"] == [48, 32] and m["episode"] == 0
    assert by["luma"][0][0]["luma"].shape == (16, 24)        # luma_scale 0.5
    assert by["luma"][0][0]["luma"].std() > 3
    assert by["seg"][0][0]["seg"].shape == (32, 48, 2)
    assert cam.counts["no_model"] == 0


def test_default_rates_are_accepted():
    # the defaults are docs/numerics.md's (discrete, 1 kHz) and pass the actor's own checks
    sim, _ = make_sim(render_hz=Sim.Params().render_hz)      # every rate at its default
    assert sim.params.integrator == "discrete" and sim.params.physics_hz == 1000.0
    assert sim.steps_per_render == 5 and sim.steps_per_control == 50


def test_bad_rates_are_refused():
    with pytest.raises(ValueError, match="multiple"):
        make_sim(control_hz=20.0, render_hz=50.0)
    with pytest.raises(ValueError, match="render_hz 200 must divide physics_hz 500"):
        make_sim(physics_hz=500.0, render_hz=200.0)
    with pytest.raises(ValueError, match="'integrator' as a sim parameter"):
        make_sim(config={"integrator": "rk4"})
    with pytest.raises(ValueError, match="'colour'"):
        make_sim(config={"colour": "red"})


# ---------------------------------------------------------------- through the runtime
def entries(path):
    return json.loads(Path(path).with_suffix(".json").read_text())


def test_nav_camera_topology_delivers_frames_and_episodes(tmp_path):
    probe = tmp_path / "probe"
    run_topology(NAV_CAMERA, [f"probe.path={json.dumps(str(probe))}", "sim.episode_s=0.5"],
                 duration_s=60, runs_dir=tmp_path)
    e = entries(probe)
    rgb = [x for x in e if x["input"] == "rgb"]
    luma = [x for x in e if x["input"] == "luma"]
    eps = [x["meta"] for x in e if x["input"] == "episode"]
    assert [(m["event"], m["episode"]) for m in eps] == [("start", 0), ("end", 0),
                                                         ("start", 1), ("end", 1)]
    assert all(m["reason"] in ("", "time_limit") for m in eps)
    assert len(rgb) == 22 and len(luma) == 102             # no frame lost in lockstep
    assert rgb[0]["arrays"]["rgb"] == [[160, 160, 3], "|u1"]
    assert luma[0]["arrays"]["luma"] == [[160, 160], "|u1"]
    assert all(x["meta"]["truth"]["image"] == [160, 160] for x in rgb)
    assert [x["tick"] for x in rgb] == list(range(22))
    assert sum(x["meta"]["control"] for x in luma) == 22
    arrays = np.load(probe.with_suffix(".npz"))
    first = next(i for i, x in enumerate(e) if x["input"] == "rgb")
    frame = arrays[f"{first}.rgb.rgb"]
    assert frame.std() > 5                                  # a real picture, not black
    # the target is where the truth says it is: red pixels around the true centroid
    u, v = (int(round(c)) for c in rgb[0]["meta"]["truth"]["centroid"])
    px = frame[v, u].astype(int)
    assert px[0] > px[1] + 30 and px[0] > px[2] + 30, px


CLOSED_LOOP = """
[topology]
name = "nav_loop"
clock = "{clock}"
seed = 3
[actors.sim]
run = "actors.sim:Sim"
scene = "nav"
config = {{ variant = "outdoor", width = 64, height = 64 }}
control_hz = 20.0
render_hz = 20.0
episode_s = 1.0
episodes = 2
inputs = {{ action = "driver/action" }}
[actors.camera]
run = "actors.camera:Camera"
inputs = {{ state = "sim/state" }}
[actors.driver]
run = "tests.sim_actors:Driver"
inputs = {{ rgb = "camera/rgb" }}
nan_at_tick = 5
[actors.probe]
run = "actors.synthetic:Probe"
inputs = {{ state = "sim/state", episode = "sim/episode" }}
path = {probe}
"""


def closed_loop(tmp_path, clock, tag):
    probe = tmp_path / f"probe_{tag}"
    topo = tmp_path / f"loop_{tag}.toml"
    topo.write_text(CLOSED_LOOP.format(clock=clock, probe=json.dumps(str(probe))))
    rundir = run_topology(topo, duration_s=60, runs_dir=tmp_path / tag)
    return entries(probe), np.load(probe.with_suffix(".npz")), rundir


def test_lockstep_closed_loop_is_bit_reproducible_and_rejects_nan(tmp_path):
    ea, aa, rundir = closed_loop(tmp_path, "lockstep", "a")
    eb, ab, _ = closed_loop(tmp_path, "lockstep", "b")
    qa = [aa[f"{i}.state.qpos"] for i, x in enumerate(ea) if x["input"] == "state"]
    qb = [ab[f"{i}.state.qpos"] for i, x in enumerate(eb) if x["input"] == "state"]
    assert len(qa) == 42 and len(qa) == len(qb)
    for x, y in zip(qa, qb):
        assert x.tobytes() == y.tobytes()
    assert abs(qa[20][0]) > 0.05                            # the driver's commands moved it
    sim_log = (rundir / "logs" / "sim.log").read_text()
    assert "command rejected at tick 5" in sim_log
    assert "no action for tick" not in sim_log


def test_realtime_keeps_wall_clock_pace(tmp_path):
    e, _, rundir = closed_loop(tmp_path, "realtime", "rt")
    states = [x for x in e if x["input"] == "state" and x["meta"]["episode"] == 0]
    wall = (states[-1]["recv_ns"] - states[0]["recv_ns"]) / 1e9
    assert 0.8 < wall < 1.6, wall                           # 1 s episode at factor 1
    # the clock counts its control deadlines per episode (20 ticks of 50 ms each)
    log = (rundir / "logs" / "sim.log").read_text()
    assert "episode 0:" in log and "control ticks missed their deadline (50 ms)" in log
