"""The expert actor: in process (answers every tick, detection or not), and in a real
lockstep run of topologies/nav_expert.toml (sim + camera + expert + tracker)."""
import asyncio
import json
from pathlib import Path

import cv2
import numpy as np

from sebvs_actors.expert import Expert
from sebvs.runtime import Message
from sebvs.runtime.supervisor import run_topology

ROOT = Path(__file__).resolve().parents[1]
NAV_EXPERT = ROOT / "topologies" / "nav_expert.toml"


class FakeNode:
    def __init__(self):
        self.emitted = []

    def emit(self, output, arrays, *, meta=None, t_sim=None, tick=None, parent=None):
        self.emitted.append((output, {k: np.array(v) for k, v in (arrays or {}).items()}, meta,
                             parent.tick if parent is not None else tick))

    def event(self, kind, fields):
        pass


def rgb_msg(img, tick, episode=0, control=True):
    return Message(topic="t", source="camera", output="rgb", seq=tick, t_sim=tick * 0.1,
                   tick=tick, stamps=[], meta={"episode": episode, "control": control},
                   arrays={"rgb": img})


def test_nav_expert_answers_every_control_tick_in_process():
    node = FakeNode()
    ex = Expert("expert", Expert.Params(), seed=0, clock="lockstep",
                consumed=frozenset({"action"}), connected=frozenset({"rgb"}), node=node)
    asyncio.run(ex.setup())
    seen = np.full((160, 160, 3), 120, np.uint8)
    cv2.rectangle(seen, (130, 70), (139, 79), (230, 38, 25), -1)     # right of centre
    empty = np.full((160, 160, 3), 120, np.uint8)
    frames = [seen, seen, empty, empty, empty, empty, empty, seen]
    for k, img in enumerate(frames):
        asyncio.run(ex.on_rgb(rgb_msg(img, k)))
    asyncio.run(ex.on_rgb(rgb_msg(seen, 8, control=False)))          # between ticks: ignored
    acts = [e for e in node.emitted if e[0] == "action"]
    assert [t for *_, t in acts] == list(range(len(frames)))
    for out, arrays, meta, _ in acts:
        assert arrays["action"].dtype == np.float32 and arrays["action"].shape == (2,)
        assert meta["expert"] is True
    assert acts[0][2]["detection"]["bbox"] == [130, 70, 10, 10]
    assert acts[0][1]["action"][1] < 0                               # turns right
    assert acts[2][2]["detection"] is None and acts[2][2]["mode"] == "hold"
    assert acts[6][2]["mode"] == "search" and acts[6][1]["action"][1] < 0   # toward last side
    assert ex.stats()["missed"] == 5


def test_nav_expert_actions_do_not_depend_on_where_the_run_started():
    """The same episode played by runs that started at different times (a worker of a
    fan-out starts at its first episode: another t_sim offset) gets the same control steps,
    bit for bit: dt comes from the episode's clock (meta t_ep), not from differences of
    t_sim, which round with the offset (and then, rarely, flip an action's last bit)."""
    img = np.full((160, 160, 3), 120, np.uint8)
    runs = []
    for offset in (0.0, 1470.0000000006694):        # t_sim of a late episode in one run
        node = FakeNode()
        ex = Expert("expert", Expert.Params(), seed=0, clock="lockstep",
                    consumed=frozenset({"action"}), connected=frozenset({"rgb"}), node=node)
        asyncio.run(ex.setup())
        steps, act = [], ex.nav.act
        ex.nav.act = lambda det, size, dt: steps.append(dt) or act(det, size, dt)
        for k in range(12):
            frame = img.copy()
            cv2.rectangle(frame, (20 + 11 * k, 70), (29 + 12 * k, 79 + k), (230, 38, 25), -1)
            t_ep = k * 0.1                            # accumulated as the sim's data.time
            msg = Message(topic="t", source="camera", output="rgb", seq=k,
                          t_sim=offset + t_ep, tick=k, stamps=[],
                          meta={"episode": 5, "control": True, "t_ep": t_ep},
                          arrays={"rgb": frame})
            asyncio.run(ex.on_rgb(msg))
        actions = [e[1]["action"].tobytes() for e in node.emitted if e[0] == "action"]
        runs.append((steps, actions))
    assert len(runs[0][0]) == 12 and runs[0] == runs[1]
    assert runs[0][0][1:] == [k * 0.1 - (k - 1) * 0.1 for k in range(1, 12)]


def test_nav_expert_topology_closes_the_loop(tmp_path):
    probe = tmp_path / "probe"
    track = tmp_path / "track.jsonl"
    topo = tmp_path / "nav_expert_probe.toml"
    topo.write_text(NAV_EXPERT.read_text() + f"""
[actors.probe]
run = "actors.synthetic:Probe"
inputs = {{ action = "expert/action", episode = "sim/episode" }}
path = {json.dumps(str(probe))}
""")
    # linger: the last tick's action is not waited for by the sim; under load it needs time
    run_topology(topo, ["sim.episode_s=3.0", "sim.episodes=2", "sim.linger_s=2.0",
                        f"tracker.path={json.dumps(str(track))}"],
                 duration_s=90, runs_dir=tmp_path)
    entries = json.loads(probe.with_suffix(".json").read_text())
    acts = [e for e in entries if e["input"] == "action"]
    # 3 s at 10 Hz: 31 control samples per episode (both ends), one action each; the sim
    # waits for all but the very last (the run ends after it), which may come too late
    ticks = [a["tick"] for a in acts]
    assert ticks == list(range(len(ticks))) and len(ticks) >= 61, ticks
    assert all(a["arrays"]["action"] == [[2], "<f4"] for a in acts)
    assert all(a["meta"]["expert"] is True for a in acts)
    assert all(a["meta"]["detection"] is not None for a in acts)    # never lost the cube
    eps = [e["meta"] for e in entries if e["input"] == "episode"]
    assert [m["reason"] for m in eps if m["event"] == "end"] == ["time_limit"] * 2
    lines = [json.loads(x) for x in track.read_text().splitlines()]
    assert len(lines) == 2 and all(x["metrics"]["success"] > 0.95 for x in lines)
    assert all(set(x["by_modality"]) == {"expert"} for x in lines)


def test_arm_task_joins_rgb_depth_and_state_by_tick_in_process():
    """The arm path's plumbing, with the nav scene standing in for the arm scene (any scene
    with a camera and a coloured cube will do): rgb, depth and state arrive in any order;
    one pose per tick, in tick order, with the cube's world position from depth."""
    import mujoco
    from sebvs.sim import make_scene
    from sebvs.sim.render import FrameRenderer
    config = {"width": 160, "height": 160}
    scene = make_scene("nav", **config)
    model = scene.compile()
    data = mujoco.MjData(model)
    scene.reset(model, data, np.random.default_rng(4))
    node = FakeNode()
    ex = Expert("expert", Expert.Params(task="arm", clearance=0.1, camera="front"), seed=0,
                clock="lockstep", consumed=frozenset({"action"}),
                connected=frozenset({"rgb", "depth", "state"}), node=node)
    asyncio.run(ex.setup())
    truths = []
    with FrameRenderer(model, 160, 160) as r:
        for tick in range(4):
            truth = scene.truth(model, data)
            truths.append(truth)
            r.update(data, "front")
            rgb, depth = r.rgb(), r.depth()
            if tick == 3:
                rgb[:] = 120                         # nothing to see: HOME
            meta = {"episode": 0, "control": True, "t_ep": tick * 0.1}
            state_meta = {**meta, **({"scene": "nav", "config": config} if tick == 0 else {})}

            def m(output, arrays, meta):
                return Message(topic="t", source="x", output=output, seq=tick, t_sim=tick * 0.1,
                               tick=tick, stamps=[], meta=meta, arrays=arrays)
            msgs = [m("state", scene.state(data), state_meta), m("rgb", {"rgb": rgb}, meta),
                    m("depth", {"depth": depth}, meta)]
            order = [(0, 1, 2), (2, 1, 0), (1, 0, 2), (1, 2, 0)][tick]
            for i in order:
                out = msgs[i].output
                asyncio.run(getattr(ex, f"on_{out}")(msgs[i]))
            for _ in range(50):
                scene.scripted(model, data)
                mujoco.mj_step(model, data)
    acts = [e for e in node.emitted if e[0] == "action"]
    assert [t for *_, t in acts] == [0, 1, 2, 3]
    for (_, arrays, meta, tick), truth in zip(acts[:3], truths):
        pose = arrays["pose"]
        assert pose.dtype == np.float32 and pose.shape == (6,)
        tx, ty, tz = truth["target"]
        if meta["mode"] == "grasp":
            # the nav camera sees the 0.2 m cube from the side at grazing angle to its top
            # face, so "the top face" is its front top edge: within a half side (the arm's
            # wrist camera looks down; tests/test_experts_arm.py measures that case in mm)
            assert np.hypot(pose[0] - tx, pose[1] - ty) < 0.12, (pose, truth["target"])
            assert abs(pose[1] - ty) < 0.02
            assert abs(pose[2] - (tz + 0.1 + 0.1)) < 0.02
        else:
            assert meta["mode"] == "home_workspace" and ty > 0.449
    assert acts[3][2]["mode"] == "home_none" and acts[3][2]["detection"] is None


def test_gains_change_while_running_and_bad_values_are_refused():
    import pytest
    node = FakeNode()
    ex = Expert("expert", Expert.Params(), seed=0, clock="lockstep",
                consumed=frozenset({"action"}), connected=frozenset({"rgb"}), node=node)
    asyncio.run(ex.setup())
    assert asyncio.run(ex.control("yaw_kp", 3.0)) == {"yaw_kp": 3.0}
    assert ex.nav.yaw_pid.g.kp == 3.0
    with pytest.raises(ValueError, match="grey"):
        asyncio.run(ex.control("color", [0.5, 0.5, 0.5]))
    assert ex.params.color == [0.9, 0.15, 0.1]
    with pytest.raises(ValueError, match="cannot change"):
        asyncio.run(ex.control("task", "arm"))


def arm_expert_poses(lead_s: float, ticks: int = 8):
    """The arm expert actor in process on the arm scene with one cube on a 25 cm/s belt,
    its lead set through `sebvs ctl ... set lead_s=` after setup: (poses it answered, the
    target's true position at each tick)."""
    from sebvs.sim.render import FrameRenderer    # sets MUJOCO_GL before mujoco loads
    import mujoco
    from sebvs.sim import make_scene
    config = {"conveyor": "moving", "belt_speed": 0.25, "objects": 1,
              "spawn_y": [-0.08, -0.06], "width": 160, "height": 160}
    scene = make_scene("arm", **config)
    model = scene.compile()
    data = mujoco.MjData(model)
    scene.reset(model, data, np.random.default_rng(0))
    node = FakeNode()
    ex = Expert("expert", Expert.Params(task="arm", hue_tol=360.0), seed=0,
                clock="lockstep", consumed=frozenset({"action"}),
                connected=frozenset({"rgb", "depth", "state"}), node=node)
    asyncio.run(ex.setup())
    assert asyncio.run(ex.control("lead_s", lead_s)) == {"lead_s": lead_s}
    truth = []
    steps = round(0.1 / model.opt.timestep)
    with FrameRenderer(model, 160, 160) as r:
        for tick in range(ticks):
            t = scene.truth(model, data)
            truth.append(t["cubes"][t["target"]]["pos"][:2] if t["target"] >= 0 else None)
            r.update(data, "wrist")
            meta = {"episode": 0, "control": True, "t_ep": float(data.time)}
            state_meta = {**meta, **({"scene": "arm", "config": config} if tick == 0 else {})}
            for output, arrays, m in (("state", scene.state(data), state_meta),
                                      ("rgb", {"rgb": r.rgb()}, meta),
                                      ("depth", {"depth": r.depth()}, meta)):
                asyncio.run(getattr(ex, f"on_{output}")(Message(
                    topic="t", source="x", output=output, seq=tick, t_sim=float(data.time),
                    tick=tick, stamps=[], meta=m, arrays=arrays)))
            for _ in range(steps):
                scene.scripted(model, data)
                mujoco.mj_step(model, data)
    poses = [(a["pose"], meta["mode"]) for out, a, meta, _ in node.emitted if out == "action"]
    return poses, truth


def test_arm_expert_with_a_lead_aims_where_the_cube_will_be_at_the_next_tick():
    """On a 25 cm/s belt the cube moves 2.5 cm per 0.1 s control period: with lead_s = 0.1
    the expert's pose at a tick is where the cube is at the next tick; without, where it
    was."""
    errors = {}
    for lead_s in (0.0, 0.1):
        poses, truth = arm_expert_poses(lead_s)
        assert len(poses) == len(truth)
        now, ahead = [], []
        for k in range(2, len(poses) - 1):            # velocity known from the second tick
            (pose, mode), here, there = poses[k], truth[k], truth[k + 1]
            if mode != "grasp" or here is None or there is None:
                continue
            now.append(np.hypot(*(pose[:2] - np.asarray(here))))
            ahead.append(np.hypot(*(pose[:2] - np.asarray(there))))
        assert len(now) >= 3, poses
        errors[lead_s] = (np.round(now, 4), np.round(ahead, 4))
    # at every tick, not most: a lead on every other tick once passed a median
    still, led = errors[0.0], errors[0.1]
    assert max(still[0]) < 0.01 and min(still[1]) > 0.02, errors   # on it now, behind next
    assert max(led[1]) < 0.01 and min(led[0]) > 0.02, errors       # ahead now, on it next


def test_arm_expert_answers_an_episode_s_last_tick_after_the_next_episode_began():
    """The next episode's first state (another scene: three cubes, not one) can reach the
    expert before the images of this episode's last tick: that tick is answered with the
    model of its own episode, not refused for a state of the wrong size."""
    from sebvs.sim.render import FrameRenderer    # sets MUJOCO_GL before mujoco loads
    import mujoco
    from sebvs.sim import make_scene
    node = FakeNode()
    ex = Expert("expert", Expert.Params(task="arm", hue_tol=360.0), seed=0,
                clock="lockstep", consumed=frozenset({"action"}),
                connected=frozenset({"rgb", "depth", "state"}), node=node)
    asyncio.run(ex.setup())
    frames = []
    for episode, objects in enumerate((1, 3)):
        config = {"objects": objects, "spawn_y": [-0.05, 0.25], "width": 160, "height": 160}
        scene = make_scene("arm", **config)
        model = scene.compile()
        data = mujoco.MjData(model)
        scene.reset(model, data, np.random.default_rng(episode))
        with FrameRenderer(model, 160, 160) as r:
            r.update(data, "wrist")
            frames.append((episode, config, scene.state(data), r.rgb(), r.depth()))

    def message(tick, output, arrays, meta):
        return Message(topic="t", source="x", output=output, seq=tick, t_sim=tick * 0.1,
                       tick=tick, stamps=[], meta=meta, arrays=arrays)
    for tick, (episode, config, state, _, _) in enumerate(frames):      # both states first
        meta = {"episode": episode, "control": True, "t_ep": 0.0, "scene": "arm",
                "config": config}
        asyncio.run(ex.on_state(message(tick, "state", state, meta)))
    for tick, (episode, _, _, rgb, depth) in enumerate(frames):
        meta = {"episode": episode, "control": True, "t_ep": 0.0}
        asyncio.run(ex.on_rgb(message(tick, "rgb", {"rgb": rgb}, meta)))
        asyncio.run(ex.on_depth(message(tick, "depth", {"depth": depth}, meta)))
    acts = [(tick, meta["mode"]) for out, _, meta, tick in node.emitted if out == "action"]
    assert acts == [(0, "grasp"), (1, "grasp")]
