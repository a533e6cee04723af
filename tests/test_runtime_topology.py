import os
from pathlib import Path

import pytest

from sebvs.runtime.graph import describe, to_dot
from sebvs.runtime.params import build_params, coerce_param
from sebvs.runtime.topology import TopologyError, load_topology

ROOT = Path(__file__).resolve().parents[1]
SYNTHETIC = ROOT / "topologies" / "synthetic.toml"

BASE = """
[topology]
name = "t"

[actors.source]
run = "actors.synthetic:PatternSource"

[actors.sink]
run = "actors.synthetic:Sink"
inputs = { frames = "source/frames" }
"""


def load(tmp_path, text, overrides=()):
    p = tmp_path / "topo.toml"
    p.write_text(text)
    return load_topology(p, overrides)


def test_synthetic_loads():
    topo = load_topology(SYNTHETIC)
    assert list(topo.active) == ["source", "relay", "sink"]
    assert topo.actors["sink"].inputs["frames"].queue == 8


@pytest.mark.parametrize("text, needle", [
    (BASE + "colour = 3\n", "[actors.sink]: unknown key 'colour'"),
    (BASE.replace('"source/frames"', '"camera/frames"'), "dangling input, no actor 'camera'"),
    (BASE.replace('"source/frames"', '"source/depth"'), "has no output 'depth'"),
    (BASE.replace('"actors.synthetic:Sink"', '"actors.nothere:Sink"'), "cannot import"),
    (BASE.replace('"actors.synthetic:Sink"', '"actors.synthetic:Nope"'), "is not an Actor"),
    (BASE.replace("[actors.source]\n", "[actors.source]\nwidth = \"wide\"\n"),
     "key 'width': expected int"),
    (BASE.replace("[actors.source]\n", "[actors.source]\nrate_hz = true\n"),
     "key 'rate_hz': expected float"),
    (BASE.replace('name = "t"', 'name = "t"\nclock = "sometimes"'), "key 'clock'"),
    (BASE.replace('name = "t"', 'name = "t"\nspeed = 1'), "[topology] unknown key 'speed'"),
    (BASE + "\n[actors.sink]\nrun = \"x:y\"\n", "topo.toml"),                 # duplicate table
    (BASE.replace('inputs = { frames = "source/frames" }',
                  'inputs = { frames = { from = "source/frames", queue = 0 } }'), "'queue'"),
    (BASE.replace('inputs = { frames = "source/frames" }', 'inputs = { rgb = "source/frames" }'),
     "has no input 'rgb'"),
    (BASE + "cpus = 0\n", "[actors.sink] key 'cpus': expected a non-empty list"),
    (BASE + "cpus = []\n", "key 'cpus': expected a non-empty list"),
    (BASE + "cpus = [0, 0]\n", "key 'cpus': expected a non-empty list of distinct"),
    (BASE + "cpus = [-1]\n", "key 'cpus'"),
    (BASE + "cpus = [100000]\n", "key 'cpus': CPU 100000 not available here"),
])
def test_validation_errors_name_file_table_and_key(tmp_path, text, needle):
    with pytest.raises(TopologyError) as err:
        load(tmp_path, text)
    assert needle in str(err.value)
    assert "topo.toml" in str(err.value)


def test_cpus_are_read_per_actor(tmp_path):
    cpu = min(os.sched_getaffinity(0))
    topo = load(tmp_path, BASE, [f"sink.cpus=[{cpu}]"])
    assert topo.actors["sink"].cpus == (cpu,)
    assert topo.actors["source"].cpus == ()
    assert "cpus" not in topo.actors["sink"].params   # runtime key, not an actor parameter


def test_overrides(tmp_path):
    topo = load(tmp_path, BASE, ["source.width=320", "topology.clock=lockstep",
                                  "sink.work_ms=2.5"])
    assert topo.actors["source"].params["width"] == 320
    assert topo.clock == "lockstep"
    assert topo.actors["sink"].params["work_ms"] == 2.5
    with pytest.raises(TopologyError, match="no actor 'camera'"):
        load(tmp_path, BASE, ["camera.width=3"])
    # an actor added from the command line: `run` first, then its keys
    topo = load(tmp_path, BASE, ['tap.run="actors.synthetic:Sink"',
                                 'tap.inputs={frames="source/frames"}'])
    assert topo.actors["tap"].inputs["frames"].source == "source/frames"
    with pytest.raises(TopologyError, match="expected int"):
        load(tmp_path, BASE, ["source.width=wide"])


def test_unconsumed_actors_are_pruned_transitively(tmp_path):
    text = BASE + """
[actors.relay]
run = "actors.synthetic:Relay"
inputs = { frames = "source/frames" }

[actors.relay2]
run = "actors.synthetic:Relay"
inputs = { frames = "relay/frames" }
"""
    topo = load(tmp_path, text)
    assert topo.actors["relay"].pruned and topo.actors["relay2"].pruned
    assert not topo.actors["sink"].pruned and not topo.actors["source"].pruned
    assert "[pruned" in describe(topo) and "(pruned)" in to_dot(topo)
    kept = load(tmp_path, text.replace('inputs = { frames = "relay/frames" }',
                                       'inputs = { frames = "relay/frames" }\nkeep = true'))
    assert not kept.actors["relay2"].pruned and not kept.actors["relay"].pruned


def test_cycle_without_clock_source_is_refused(tmp_path):
    text = """
[topology]
name = "loop"

[actors.a]
run = "actors.synthetic:Relay"
inputs = { frames = "b/frames" }

[actors.b]
run = "actors.synthetic:Relay"
inputs = { frames = "a/frames" }

[actors.sink]
run = "actors.synthetic:Sink"
inputs = { frames = "a/frames" }
"""
    with pytest.raises(TopologyError, match="no clock source"):
        load(tmp_path, text)


def test_actor_seeds_are_stable_and_distinct():
    topo = load_topology(SYNTHETIC)
    assert topo.actor_seed("source") == load_topology(SYNTHETIC).actor_seed("source")
    assert topo.actor_seed("source") != topo.actor_seed("sink")


def test_param_coercion():
    from typing import Literal, Optional
    assert coerce_param(float, 3, where="w") == 3.0
    assert coerce_param(Optional[int], None, where="w") is None
    assert coerce_param(list[int], [1, 2], where="w") == [1, 2]
    assert coerce_param(list, [1, "a"], where="w") == [1, "a"]
    with pytest.raises(ValueError, match="expected a list"):
        coerce_param(list, 3, where="w")
    with pytest.raises(ValueError, match="one of"):
        coerce_param(Literal["a", "b"], "c", where="w")
    with pytest.raises(ValueError, match="expected int"):
        coerce_param(int, True, where="w")
    from sebvs_actors.synthetic import PatternSource
    with pytest.raises(ValueError, match="unknown key 'colour'"):
        build_params(PatternSource.Params, {"colour": 1}, where="w")


def test_a_max_bytes_below_a_known_inline_frame_is_refused_before_start():
    """synthetic_hosts with the sink's max_bytes at 50,000 (its frames are 76,800 B, inline
    across the two hosts) used to run with the sink receiving nothing, silently: the size
    the source's parameters give is carried through the relay and checked at load."""
    from sebvs.runtime.topology import TopologyError, load_topology
    small = 'sink.inputs.frames={from="relay/frames", queue=8, max_bytes=50000}'
    with pytest.raises(TopologyError, match=r"max_bytes 50,000 is below the 76,800-byte "
                                            r"arrays of relay/frames.*at least 80,896"):
        load_topology("topologies/synthetic_hosts.toml", [small])
    load_topology("topologies/synthetic_hosts.toml",
                  ['sink.inputs.frames={from="relay/frames", queue=8, max_bytes=90000}'])
    # one host: the frames travel in shared memory, the header alone on the socket
    load_topology("topologies/synthetic.toml", [small])
