"""Recordings store the robot's proprioception (observation.state of a robot-learning
dataset): the sim actor sends what the Gymnasium env observes, the recorder stores it per
tick, `sebvs data check` checks it and notes episodes recorded before it. And a recorder
asked for raw events with nothing wired to send them is refused in one line."""
import asyncio
import dataclasses

import numpy as np
import pytest

from sebvs.cli import main
from sebvs.data.check import check_dataset
from sebvs.data.episode import EpisodeWriter, open_episode
from sebvs.data.index import DatasetIndex, make_entry
from sebvs.runtime.supervisor import run_topology
from sebvs.runtime.topology import load_topology
from sebvs.sim.arm_model import JOINTS
from sebvs.sim.proprio import proprio_reader
from sebvs.sim.stepper import SceneStepper
from sebvs_actors.sim import Sim
from tests.proprio_actors import NAMES, expected_proprio
from tests.test_sim_actors import FakeNode

ARM_NAMES = (*JOINTS, "finger_l", "finger_r")


# ---------------------------------------------------------------- the sim's proprio
@pytest.mark.parametrize("task", ["nav", "arm"])
def test_the_sim_actor_sends_the_proprioception_the_env_observes(task):
    """The env stepped with the idle command and the sim actor free-running on the env's
    own sim parameters and seed: the same float32 vectors, tick for tick."""
    gym = pytest.importorskip("gymnasium")
    from sebvs.envs import ENV_IDS
    env = gym.make(ENV_IDS[task], obs=("proprio",), width=32, height=32,
                   episode_s=0.5).unwrapped
    idle = env.sim.scene.idle_command().astype(np.float32)
    obs, _ = env.reset(seed=5)
    observed, done = [obs["proprio"]], False
    while not done:
        obs, _, terminated, truncated, _ = env.step(idle)
        observed.append(obs["proprio"])
        done = terminated or truncated
    params = dataclasses.replace(env.settings["sim"], episodes=1, linger_s=0.0)
    seed = env.sim_seed
    env.close()
    node = FakeNode()
    sim = Sim("sim", params, seed=seed, clock="lockstep",
              consumed=frozenset({"state", "proprio", "episode"}), node=node)
    asyncio.run(sim.setup())
    asyncio.run(sim.run())
    sent = [(a["proprio"], m, t, k) for o, a, m, t, k in node.emitted if o == "proprio"]
    control = [(a, t, k) for o, a, m, t, k in node.emitted if o == "state" and m["control"]]
    assert len(sent) == len(control) == len(observed) == 6
    for (p, meta, t_sim, tick), (state, t_state, tick_state), seen in zip(sent, control,
                                                                         observed):
        assert p.dtype == np.float32 and (tick, t_sim) == (tick_state, t_state)
        np.testing.assert_array_equal(p, seen)
        assert meta["episode"] == 0
    names = sent[0][1]["names"]
    if task == "arm":
        assert tuple(names) == ARM_NAMES
        adr = sim.scene.arm_qadr
        for (p, *_), (state, *_) in zip(sent, control):    # the state's own joint angles
            np.testing.assert_array_equal(p[:6], state["qpos"][adr].astype(np.float32))
    else:
        assert names == NAMES


def test_the_sim_sends_no_proprio_where_nobody_takes_it():
    node = FakeNode()
    sim = Sim("sim", Sim.Params(episode_s=0.2, render_hz=100.0, control_hz=10.0, linger_s=0.0),
              seed=1, clock="lockstep", consumed=frozenset({"state", "episode"}), node=node)
    asyncio.run(sim.setup())
    asyncio.run(sim.run())
    outputs = {o for o, *_ in node.emitted}
    assert "state" in outputs and "proprio" not in outputs


def test_nav_odometry_is_the_base_velocity_in_the_robot_frame():
    """Against finite differences of the base's pose, turned into the robot's frame."""
    sim = SceneStepper("nav", {"width": 32, "height": 32}, control_hz=10.0, render_hz=10.0,
                       episode_s=3.0)
    sim.start_episode(0, 0)
    reader = proprio_reader("nav", sim.scene, sim.model)
    assert reader.names == tuple(NAMES) and reader.lo.shape == reader.hi.shape == (3,)
    assert sim.apply(np.array([0.8, 0.5])) is None
    for _ in range(1500):                    # 1.5 s: past the drive's spin-up
        assert sim.advance() is None
    before = np.array(sim.scene.robot_pose(sim.data))
    v = reader.read(sim.data)
    n = 4
    for _ in range(n):
        sim.advance()
    after = np.array(sim.scene.robot_pose(sim.data))
    dt = n * sim.dt
    dx, dy = (after[:2] - before[:2]) / dt
    yaw = before[2]
    fwd = np.cos(yaw) * dx + np.sin(yaw) * dy
    lat = -np.sin(yaw) * dx + np.cos(yaw) * dy
    assert v[0] > 0.3 and v[2] > 0.2          # driving forward and turning left
    np.testing.assert_allclose(v, [fwd, lat, (after[2] - before[2]) / dt], atol=0.02)


def test_an_unknown_scene_has_no_proprioception():
    with pytest.raises(ValueError, match="scene 'no_such_scene' has no proprioception"):
        proprio_reader("no_such_scene", None, None)


# ---------------------------------------------------------------- the recorder
def record_topology(tmp_path, out, proprio: bool = True):
    wired = ', proprio = "source/proprio"' if proprio else ""
    path = tmp_path / "record.toml"
    path.write_text(f"""
[topology]
name = "record_proprio"
seed = 0
[actors.source]
run = "tests.proprio_actors:ProprioSource"
frames = 6
episodes = 2
[actors.recorder]
run = "actors.recorder:Recorder"
inputs = {{ rgb = "source/rgb", action = "source/action", episode = "source/episode", \
events = "source/events"{wired} }}
out = "{out}"
episodes = 2
""")
    return path


def test_the_recorder_stores_each_tick_s_proprioception(tmp_path):
    out = tmp_path / "ds"
    run_topology(record_topology(tmp_path, out), duration_s=20, runs_dir=tmp_path)
    paths = DatasetIndex(out).episode_paths()
    assert len(paths) == 2
    for path in paths:
        with open_episode(path) as ep:
            ticks = ep.tick[:]
            assert ep.proprio.dtype == np.float32 and ep.proprio.shape == (6, 3)
            np.testing.assert_array_equal(ep.proprio[:], [expected_proprio(t) for t in ticks])
            assert ep.proprio_names == tuple(NAMES)
            assert "proprio" in ep.attrs["streams"]
            assert np.isfinite(ep.latency["source->recorder"][:]).all()
    rep = check_dataset(out)
    assert rep.ok and not rep.no_proprio
    assert not any(line.startswith("note:") for line in rep.lines())


def write_episode(idx: DatasetIndex, proprio=None) -> str:
    path = idx.path_for(idx.next_episode_number())
    w = EpisodeWriter(path, "nav", {"scene": "nav", "conditions": {}, "seed": 1})
    for k in range(3):
        w.append(rgb=np.zeros((4, 4, 3), np.uint8), action=[0.0, 0.0], t_sim=k * 0.1, tick=k,
                 proprio=None if proprio is None else proprio[k])
    if proprio is not None:
        w.set_attrs({"proprio_names": NAMES})
    w.finish("time_limit")
    idx.add(make_entry(path))
    return path.name


def test_data_check_notes_episodes_without_proprioception_and_refuses_a_torn_one(tmp_path):
    idx = DatasetIndex(tmp_path / "ds", task="nav")
    old = [write_episode(idx), write_episode(idx)]      # as recorded before it was stored
    write_episode(idx, proprio=np.ones((3, 3), np.float32))
    rep = check_dataset(tmp_path / "ds")
    assert rep.ok and rep.no_proprio == old             # a note, not a problem
    note = [line for line in rep.lines() if line.startswith("note:")]
    assert len(note) == 1 and "2 of 3 episode(s) hold no proprioception" in note[0]
    assert all(name in note[0] for name in old)
    with open_episode(idx.episode_paths()[0]) as ep:
        assert ep.proprio is None and ep.proprio_names == ()
    torn = np.ones((3, 3), np.float32)
    torn[1] = np.nan
    bad = write_episode(idx, proprio=torn)
    rep = check_dataset(tmp_path / "ds")
    assert not rep.ok and rep.problems == [f"{bad}: proprio holds NaN/inf in 1 of 3 rows"]


def test_the_writer_refuses_a_proprio_that_changes_length(tmp_path):
    w = EpisodeWriter(tmp_path / "episode_0000.h5", "nav", {})
    with w:
        w.append(rgb=np.zeros((4, 4, 3), np.uint8), action=[0, 0], t_sim=0.0, tick=0,
                 proprio=[1.0, 2.0, 3.0])
        with pytest.raises(ValueError, match="proprio must have 3 values every frame, got 2"):
            w.append(rgb=np.zeros((4, 4, 3), np.uint8), action=[0, 0], t_sim=0.1, tick=1,
                     proprio=[1.0, 2.0])


def test_sebvs_record_of_the_arm_records_its_joints(tmp_path):
    """The shipped record topology wires the sim's proprio: an episode starts at HOME."""
    out = tmp_path / "ds"
    assert main(["record", "topologies/arm_record.toml", "--episodes", "1", "--out", str(out),
                 "--runs-dir", str(tmp_path / "runs"), "--quiet", "--set", "sim.randomise={}",
                 "--set", "sim.episode_s=0.3"]) == 0
    with open_episode(DatasetIndex(out).episode_paths()[0]) as ep:
        proprio, names, frames = ep.proprio[:], ep.proprio_names, len(ep)
    assert frames == 4 and proprio.shape == (4, 8) and names == ARM_NAMES
    home = SceneStepper("arm", {"objects": 1, "width": 160, "height": 160}).scene.home_q
    np.testing.assert_allclose(proprio[0, :6], home, atol=1e-6)
    assert np.isfinite(proprio).all()
    assert check_dataset(out).ok


# ---------------------------------------------------------------- raw events
def test_raw_events_with_nothing_to_send_them_are_refused_in_one_line(tmp_path, capsys):
    out = tmp_path / "ds"
    code = main(["record", "topologies/nav_record.toml", "--episodes", "1", "--out", str(out),
                 "--runs-dir", str(tmp_path / "runs"), "--quiet",
                 "--set", "recorder.raw_events=true"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1, err
    assert "[actors.recorder]" in err and "input 'raw' is not wired" in err
    assert not out.exists() and not (tmp_path / "runs").exists()
    # wired as the line says, the topology loads and the recorder takes the emulator's events
    topo = load_topology("topologies/nav_record.toml", [
        "recorder.raw_events=true", 'recorder.inputs.raw={from="emulator/events", queue=256}'])
    raw = topo.actors["recorder"].inputs["raw"]
    assert (raw.producer, raw.output) == ("emulator", "events")
