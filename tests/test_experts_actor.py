"""The expert actor: in process (answers every tick, detection or not), and in a real
lockstep run of topologies/nav_expert.toml (sim + camera + expert + tracker)."""
import asyncio
import json
from pathlib import Path

import cv2
import numpy as np

from actors.expert import Expert
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
    run_topology(topo, ["sim.episode_s=3.0", "sim.episodes=2", f"tracker.path={json.dumps(str(track))}"],
                 duration_s=60, runs_dir=tmp_path)
    entries = json.loads(probe.with_suffix(".json").read_text())
    acts = [e for e in entries if e["input"] == "action"]
    # 3 s at 10 Hz: 31 control samples per episode (both ends), one action each
    assert [a["tick"] for a in acts] == list(range(62))
    assert all(a["arrays"]["action"] == [[2], "<f4"] for a in acts)
    assert all(a["meta"]["expert"] is True for a in acts)
    assert all(a["meta"]["detection"] is not None for a in acts)    # never lost the cube
    eps = [e["meta"] for e in entries if e["input"] == "episode"]
    assert [m["reason"] for m in eps if m["event"] == "end"] == ["time_limit"] * 2
    lines = [json.loads(x) for x in track.read_text().splitlines()]
    assert len(lines) == 2 and all(x["metrics"]["success"] > 0.95 for x in lines)
    assert all(set(x["by_modality"]) == {"expert"} for x in lines)
