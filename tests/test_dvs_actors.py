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
