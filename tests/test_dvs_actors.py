"""Emulator and accumulator actors in a real run, fed by the synthetic pattern (no MuJoCo)."""
import json

import numpy as np

from sebvs.runtime.supervisor import run_topology

TOPOLOGY = """
[topology]
name = "events"
seed = 1

[actors.source]
run = "actors.synthetic:PatternSource"
width = 64
height = 48
rate_hz = 20.0
luma_hz = 200.0
speed_px_s = 200.0
max_frames = 12

[actors.emulator]
run = "actors.emulator:Emulator"
inputs = {{ luma = {{ from = "source/luma", queue = 256 }} }}
preset = "{preset}"

[actors.accumulator]
run = "actors.accumulator:Accumulator"
inputs = {{ events = {{ from = "emulator/events", queue = 256 }} }}
window_s = 0.05

[actors.probe]
run = "actors.synthetic:Probe"
inputs = {{ frames = {{ from = "accumulator/frames", queue = 256 }} }}
path = "{path}"
"""


def test_emulator_and_accumulator_make_an_event_frame_per_control_tick(tmp_path):
    topo = tmp_path / "events.toml"
    topo.write_text(TOPOLOGY.format(preset="paper", path=tmp_path / "probe"))
    run_topology(topo, duration_s=30, runs_dir=tmp_path)
    entries = json.loads((tmp_path / "probe.json").read_text())
    arrays = np.load(tmp_path / "probe.npz")
    ticks = [e["tick"] for e in entries]
    assert ticks == list(range(ticks[0], ticks[0] + len(ticks))) and len(ticks) >= 10
    for i, e in enumerate(entries):
        assert e["arrays"]["frame"] == [[2, 48, 64], "|u1"]       # at the luma (RGB) size
        assert e["meta"]["event_sensor"] == [32, 24]               # paper: downsample 0.5
        assert e["meta"]["event_scale"] == [2.0, 2.0]
        assert [s[0] for s in e["stamps"]] == ["source", "emulator", "accumulator"]
    counts = [int(arrays[f"{i}.frames.frame"].sum()) for i in range(1, len(entries))]
    assert min(counts) > 0            # a drifting texture keeps every window busy
    on = sum(int(arrays[f"{i}.frames.frame"][0].sum()) for i in range(1, len(entries)))
    off = sum(int(arrays[f"{i}.frames.frame"][1].sum()) for i in range(1, len(entries)))
    assert on > 0 and off > 0


class _Node:
    """Stands in for the runtime: records the packets the actor emits."""

    def __init__(self):
        self.sent = []

    def emit(self, output, arrays, *, meta=None, t_sim=None, tick=None, parent=None):
        self.sent.append((parent.tick, arrays["events"].copy()))


def test_emulator_actor_counts_bad_frames_and_gap_restarts_and_goes_on():
    import asyncio
    import math

    from sebvs_actors.emulator import Emulator
    from sebvs.runtime.wire import Message

    node = _Node()
    actor = Emulator("emulator", Emulator.Params(preset="noisy",
                                                 overrides={"downsample": 1.0}), node=node)
    t_sims = [0.0, 0.01, math.nan, math.inf, 1e10,   # NaN, inf, past int64 ns: refused
              0.02, 0.015,                          # back in time: refused
              2e6, 2e6 + 0.01]                      # a 2e6 s gap: restart, then on
    luma = [np.full((16, 16), 80 + 5 * i, np.uint8) for i in range(len(t_sims))]

    async def scenario():
        await actor.setup()
        for tick, (t, f) in enumerate(zip(t_sims, luma)):
            await actor.on_luma(Message(topic="source/luma", source="source", output="luma",
                                        seq=tick, t_sim=t, tick=tick, meta={"episode": 0},
                                        arrays={"luma": f}, stamps=[]))

    asyncio.run(scenario())
    stats = actor.stats()
    assert stats["bad_frames"] == 4 and stats["gap_restarts"] == 1
    assert [tick for tick, _ in node.sent] == [0, 1, 5, 7, 8]
    restart = dict(node.sent)[7]
    assert restart.size == 0 and dict(node.sent)[8]["t"].min() > round(2e6 * 1e9)
