"""Your own MJCF in a topology (scene "mjcf", sebvs/sim/mjcf_scene.py): the scene on the
stock Reacher model, the sim taking a policy's commands and playing its script, a short
`sebvs record` of topologies/mjcf_reacher.toml that `sebvs data check` passes, and bad
input refused in one line with exit 2."""
import asyncio
import json
import tomllib
from pathlib import Path

import numpy as np
import pytest

from sebvs.cli import main
from sebvs.data.check import check_dataset
from sebvs.data.episode import open_episode
from sebvs.data.index import DatasetIndex
from sebvs.runtime import Message
from sebvs.runtime.topology import load_topology
from sebvs.sim import make_scene
from sebvs_actors.sim import Sim
from tests.test_sim_actors import FakeNode

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "topologies" / "mjcf_reacher.toml"
CONFIG = tomllib.loads(EXAMPLE.read_text())["actors"]["sim"]["config"]
SMALL = ["--set", "sim.config.width=48", "--set", "sim.config.height=48",
         "--set", "accumulator.out_width=48", "--set", "accumulator.out_height=48",
         "--set", "sim.episode_s=2.0"]


def reacher(**changes):
    return make_scene("mjcf", **{**CONFIG, **changes})


def test_the_stock_reacher_is_a_scene_with_its_actuators_and_the_added_camera():
    scene = reacher()
    assert scene.cameras == ("top",) and scene.command_dim == 2
    model = scene.compile()
    assert model.ncam == 1 and model.vis.quality.offsamples == 0
    assert scene.photometry().illuminance_lux == 400.0
    lum = reacher(illuminance_lux=None, luminance_cd_m2=100.0).photometry()
    assert lum.illuminance_lux == pytest.approx(100.0 * np.pi)
    names = scene.proprio_reader(model).names
    assert names[:2] == ("qpos.joint0", "qpos.joint1") and len(names) == model.nq + model.nv
    # commands: clipped to ctrlrange [-1, 1], another length or NaN refused
    np.testing.assert_array_equal(scene.clip_command(np.array([5.0, -0.25])), [1.0, -0.25])
    for bad in ([1.0], [0.0, 0.0, 0.0], [np.nan, 0.0]):
        with pytest.raises(ValueError):
            scene.apply_command(model, None, np.array(bad))


def test_the_script_stays_in_ctrlrange_and_follows_the_seed():
    import mujoco
    scene = reacher(script_amplitude=1.0)
    model = scene.compile()
    data = mujoco.MjData(model)

    def play(seed):
        scene.reset(model, data, np.random.default_rng(seed))
        out = []
        for t in np.linspace(0.0, 10.0, 201):
            data.time = t
            out.append(scene.scripted_command(model, data))
        return np.array(out)

    a, b, c = play(1), play(1), play(2)
    assert np.abs(a).max() <= 1.0 and np.abs(a).max() > 0.9     # the range, all of it
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c)
    still = reacher(script="hold")
    np.testing.assert_array_equal(still.scripted_command(model, data), [0.0, 0.0])


def make_sim(connected=frozenset(), clock="lockstep", **params):
    node = FakeNode()
    p = Sim.Params(**{"scene": "mjcf", "config": dict(CONFIG), "episode_s": 1.0,
                      "render_hz": 100.0, "control_hz": 10.0, **params})
    sim = Sim("sim", p, seed=3, clock=clock, connected=connected, node=node,
              consumed=frozenset({"state", "episode", "action", "proprio"}))
    asyncio.run(sim.setup())
    return sim, node


def test_a_policy_commands_the_actuators_clipped_and_bad_ones_are_counted():
    sim, node = make_sim(clock="realtime", connected=frozenset({"action"}))

    def send(cmd, tick):
        asyncio.run(sim.on_action(Message(topic="t", source="p", output="action", seq=tick,
                                          t_sim=0.0, tick=tick, stamps=[], meta={},
                                          arrays={"action": np.asarray(cmd, float)})))

    send([3.0, -0.5], 0)
    np.testing.assert_array_equal(sim.data.ctrl, [1.0, -0.5])
    for bad in ([0.1], [0.1, 0.2, 0.3], [np.nan, 0.0]):
        send(bad, 1)
    np.testing.assert_array_equal(sim.data.ctrl, [1.0, -0.5])
    assert sim.counts["rejected"] == 3


def test_with_no_policy_the_sim_plays_the_script_and_sends_each_ticks_command():
    sim, node = make_sim()
    asyncio.run(sim.run())
    sent = [(a["action"], m, k) for o, a, m, _, k in node.emitted if o == "action"]
    assert [k for *_, k in sent] == list(range(11))     # every tick, the last included
    assert all(m["source"] == "scripted" and m["episode"] == 0 for _, m, _ in sent)
    assert all(a.shape == (2,) and np.abs(a).max() <= 0.05 + 1e-12 for a, *_ in sent)
    states = [a["qpos"] for o, a, m, _, _ in node.emitted if o == "state"]
    assert np.abs(states[-1][:2] - states[0][:2]).max() > 0.05   # the script moved the arm
    assert sim.counts["rejected"] == 0


def test_the_example_topology_loads_with_every_actor():
    topo = load_topology(EXAMPLE)
    assert topo.actors["sim"].params["scene"] == "mjcf"
    assert sorted(topo.active) == ["accumulator", "camera", "emulator", "recorder", "sim"]


def record(tmp_path, name, *extra) -> Path:
    out = tmp_path / name
    assert main(["record", str(EXAMPLE), "--episodes", "1", "--out", str(out),
                 "--runs-dir", str(tmp_path), "--quiet", "--timeout", "90", *SMALL,
                 *extra]) == 0
    report = check_dataset(out)
    assert report.ok, report.lines()
    (path,) = DatasetIndex(out).episode_paths()
    return path


def event_counts(ep) -> np.ndarray:
    return ep.event_frame[:].reshape(len(ep), -1).sum(axis=1)


def test_a_short_record_passes_data_check_and_events_come_when_the_arm_moves(tmp_path):
    with open_episode(record(tmp_path, "moving")) as ep:
        assert ep.task == "mjcf" and len(ep) == 21
        assert ep.target.shape == (21, 2) and np.abs(ep.target[:]).max() <= 0.05 + 1e-6
        assert ep.rgb.shape == (21, 48, 48, 3) and ep.event_frame.shape == (21, 2, 48, 48)
        q = ep.proprio[:, :2]                               # joint0, joint1 (rad)
        moving = event_counts(ep)
    # the arm held still: the physical preset's noise alone (~40 events a frame here)
    with open_episode(record(tmp_path, "still", "--set", 'sim.config.script="hold"',
                             "--set", "sim.episode_s=1.0")) as ep:
        assert np.abs(ep.proprio[:, :2]).max() == 0.0
        still = event_counts(ep)[1:]
    moved = np.abs(np.diff(q, axis=0)).max(axis=1) > 0.02   # over one tick, 0.1 s
    assert moved.sum() >= 10
    assert (moving[1:][moved] > np.median(still)).all(), (moving, still)
    assert np.median(moving[1:][moved]) > 2 * np.median(still), (moving, still)
    # and it goes to a LeRobot dataset: the actuators' commands as action, qpos and qvel
    # as observation.state
    pytest.importorskip("pyarrow")
    from sebvs.data.export_lerobot import export_lerobot
    export_lerobot(tmp_path / "moving", tmp_path / "lerobot", progress=False)
    info = json.loads((tmp_path / "lerobot" / "meta" / "info.json").read_text())
    assert info["features"]["action"]["names"] == ["ctrl_0", "ctrl_1"]
    assert info["features"]["observation.state"]["shape"] == [8]   # Reacher: nq 4, nv 4
    assert info["total_frames"] == 21


def one_line_exit_2(capsys, *args) -> str:
    code = main(["run", str(EXAMPLE), "--for", "1", *args])
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    return err


def config(**keys) -> str:
    return "sim.config=" + "{ " + ", ".join(f"{k} = {json.dumps(v)}"
                                             for k, v in keys.items()) + " }"


MODEL = """<mujoco><worldbody><light pos="0 0 2"/>{camera}
<body><joint type="hinge"/><geom type="box" size=".1 .1 .1"/></body></worldbody>
<actuator><motor joint="{joint}"/></actuator></mujoco>"""


def test_bad_input_is_one_line_and_exit_2(tmp_path, capsys):
    side = tmp_path / "side.xml"
    side.write_text(MODEL.format(camera='<camera name="side" pos="0 -1 0"/>', joint="j")
                    .replace('type="hinge"', 'name="j" type="hinge"'))
    none = tmp_path / "none.xml"
    none.write_text(MODEL.format(camera="", joint="j").replace('type="hinge"',
                                                               'name="j" type="hinge"'))
    broken = tmp_path / "broken.xml"
    broken.write_text(MODEL.format(camera="", joint="nowhere"))
    err = one_line_exit_2(capsys, "--set", config(path=str(side), camera="wrist"))
    assert "no camera named 'wrist'" in err and "'side'" in err
    err = one_line_exit_2(capsys, "--set", config(path=str(none)))
    assert "has no camera" in err and "camera_pose" in err
    err = one_line_exit_2(capsys, "--set", config(path=str(broken)))
    assert "does not compile" in err and str(broken) in err
    err = one_line_exit_2(capsys, "--set", config(path=str(tmp_path / "missing.xml")))
    assert "no such MJCF file" in err
    err = one_line_exit_2(capsys, "--set", "sim.config.camera_pose.lookat=[0.0, 0.0, 0.6]")
    assert "lookat must differ from pos" in err
    # the side model compiles and names its camera: the same line does not refuse it
    assert load_topology(EXAMPLE, [config(path=str(side), camera="side")])


def test_a_stock_model_without_its_package_says_which_extra(monkeypatch, capsys):
    import importlib.util
    from types import SimpleNamespace
    import sebvs.sim.mjcf_source as source

    def find_spec(name, package=None):
        return None if name == "gymnasium" else importlib.util.find_spec(name, package)

    # the module's own view of importlib only: nothing else loses gymnasium
    monkeypatch.setattr(source, "importlib", SimpleNamespace(util=SimpleNamespace(
        find_spec=find_spec)))
    err = one_line_exit_2(capsys)
    assert "package 'gymnasium'" in err and "pip install 'sebvs[gym]'" in err
