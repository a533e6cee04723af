"""The policy actor in a real run: actions per tick, live modality swaps, refusals."""
import asyncio
import json
import time

import numpy as np
import pytest
import torch

from sebvs_actors.policy import Policy
from sebvs.policy.checkpoint import model_config, save_checkpoint
from sebvs.policy.inputs import Normalisation, channels
from sebvs.policy.model import ERP
from sebvs.runtime.supervisor import Supervisor
from sebvs.runtime.topology import load_topology
from sebvs.runtime.wire import Message


@pytest.fixture(scope="module")
def ckpts(tmp_path_factory):
    d = tmp_path_factory.mktemp("ckpt")
    torch.manual_seed(0)
    for m in ("rgb", "event", "rgb+event"):
        save_checkpoint(ERP("nav", channels(m), 32), model_config("nav", m, Normalisation(32)), d)
    return d


def topology(tmp_path, ckpts, *, events=True, modality="rgb+event", only=None):
    wired = '{ rgb = "source/rgb", events = "source/events" }' if events else \
        '{ rgb = "source/rgb" }'
    source = f'directory = "{ckpts}"' if only is None else \
        "checkpoints = { " + ", ".join(f'"{m}" = "{ckpts}/nav-{m}.pt"' for m in only) + " }"
    path = tmp_path / "policy.toml"
    path.write_text(f"""
[topology]
name = "policy-test"
[actors.source]
run = "tests.policy_actors:TickSource"
rate_hz = 40.0
[actors.policy]
run = "actors.policy:Policy"
inputs = {wired}
{source}
modality = "{modality}"
[actors.probe]
run = "actors.synthetic:Probe"
inputs = {{ action = "policy/action" }}
path = "{tmp_path / 'probe'}"
max_arrays = 5
""")
    return path


def ctl(sup, actor, **req):
    reply = sup.request(actor, req, 5.0)
    assert reply is not None, f"{actor} did not answer {req}"
    return reply


def wait_emitted(sup, n, timeout=15.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        st = ctl(sup, "policy", cmd="stats")["result"]["actor_stats"]
        if st["emitted"] >= n:
            return st
        time.sleep(0.05)
    raise AssertionError(f"policy emitted {st['emitted']} < {n} actions")


def test_swap_takes_effect_at_next_tick_without_dropping_one(tmp_path, ckpts):
    sup = Supervisor(load_topology(topology(tmp_path, ckpts)), runs_dir=tmp_path,
                     echo=lambda s: None)
    sup.start()
    try:
        st = wait_emitted(sup, 5)
        r = ctl(sup, "policy", cmd="set", key="modality", value="event")
        assert r["ok"], r
        first_swap = r["result"]
        assert first_swap["modality"] == "event" and first_swap["effective_tick"] >= 5
        st = wait_emitted(sup, st["emitted"] + 6)
        bad = ctl(sup, "policy", cmd="set", key="modality", value="depth")
        assert not bad["ok"] and "unknown modality 'depth'" in bad["error"]
        r = ctl(sup, "policy", cmd="set", key="modality", value="rgb")
        assert r["ok"]
        second_swap = r["result"]
        st = wait_emitted(sup, st["emitted"] + 6)
        assert st["modality"] == "rgb" and st["skipped_ticks"] == 0
        assert st["inference_ms"]["p50"] > 0
    finally:
        assert sup.stop() == 0
    entries = json.loads((tmp_path / "probe.json").read_text())
    ticks = [e["tick"] for e in entries]
    assert ticks == list(range(ticks[0], ticks[0] + len(ticks))), "a tick was dropped"
    assert ticks[0] == 0
    by_tick = {e["tick"]: e["meta"]["modality"] for e in entries}
    k1, k2 = first_swap["effective_tick"], second_swap["effective_tick"]
    assert {by_tick[t] for t in range(0, k1)} == {"rgb+event"}
    assert {by_tick[t] for t in range(k1, k2)} == {"event"}
    assert {m for t, m in by_tick.items() if t >= k2} == {"rgb"}
    e = entries[-1]
    assert e["arrays"]["action"] == [[2], "<f4"]
    assert e["meta"]["input_ticks"] == {"rgb": e["tick"]} and e["meta"]["inference_ms"] > 0
    assert [s[0] for s in e["stamps"]] == ["source", "policy"]


def test_rgb_only_topology_refuses_event_modalities(tmp_path, ckpts):
    topo = topology(tmp_path, ckpts, events=False, modality="rgb", only=["rgb", "event"])
    sup = Supervisor(load_topology(topo), runs_dir=tmp_path, echo=lambda s: None)
    sup.start()
    try:
        wait_emitted(sup, 3)
        bad = ctl(sup, "policy", cmd="set", key="modality", value="event")
        assert not bad["ok"]
        assert "needs input(s) events" in bad["error"] and "does not wire" in bad["error"]
        bad = ctl(sup, "policy", cmd="set", key="modality", value="rgb+event")
        assert not bad["ok"] and "no checkpoint loaded (loaded: rgb, event)" in bad["error"]
        assert ctl(sup, "policy", cmd="get", key="modality")["result"] == {"modality": "rgb"}
        st = wait_emitted(sup, 6)
        assert st["modality"] == "rgb" and st["swaps"] == []
        assert not ctl(sup, "policy", cmd="set", key="directory", value="/x")["ok"]
    finally:
        sup.stop()


class _Node:
    """Stands in for the runtime: records what the actor emits and publishes."""

    def __init__(self):
        self.sent, self.events, self.metas = [], [], []

    def emit(self, output, arrays, *, meta=None, t_sim=None, tick=None, parent=None):
        self.sent.append((tick, meta["modality"], {k: v.copy() for k, v in arrays.items()}))
        self.metas.append(meta)

    def event(self, kind, fields):
        self.events.append((kind, fields))


def _msg(stream, tick, array):
    return Message(topic=f"src/{stream}", source="src", output=stream, seq=tick, t_sim=tick / 10,
                   tick=tick, meta={}, arrays={"rgb" if stream == "rgb" else "frame": array},
                   stamps=[])


def test_swap_order_in_process(ckpts):
    """Deterministic swap semantics: the tick after the last acted one, buffered frames used."""
    node = _Node()
    actor = Policy("policy", Policy.Params(directory=str(ckpts), modality="rgb"),
                   connected=frozenset({"rgb", "events"}), node=node)
    rgb, ev = np.zeros((32, 32, 3), np.uint8), np.zeros((2, 32, 32), np.uint8)

    async def scenario():
        await actor.setup()
        await actor.on_rgb(_msg("rgb", 0, rgb))          # rgb acts at once
        await actor.on_events(_msg("events", 0, ev))
        await actor.on_events(_msg("events", 1, ev))     # tick 1: events first, rgb not yet
        reply = await actor.control("modality", "event")  # tick 1's events are buffered:
        assert reply == {"modality": "event", "effective_tick": 1}   # acted on right away
        await actor.on_rgb(_msg("rgb", 1, rgb))          # stale for tick 1: ignored
        await actor.on_events(_msg("events", 2, ev))
        with pytest.raises(ValueError, match="unknown modality"):
            await actor.control("modality", "thermal")
        await actor.control("modality", "rgb+event")
        await actor.on_events(_msg("events", 3, ev))     # waits for rgb 3
        await actor.on_rgb(_msg("rgb", 3, rgb))

    asyncio.run(scenario())
    assert [(t, m) for t, m, _ in node.sent] == [(0, "rgb"), (1, "event"), (2, "event"),
                                                 (3, "rgb+event")]
    assert all(a["action"].shape == (2,) and a["action"].dtype == np.float32
               for _, _, a in node.sent)
    swaps = [f for k, f in node.events if k == "modality_swap"]
    assert swaps == [{"from": "rgb", "to": "event", "effective_tick": 1},
                     {"from": "event", "to": "rgb+event", "effective_tick": 3}]
    assert sum(k == "inference" for k, _ in node.events) == 4
    assert actor.stats()["skipped_ticks"] == 0


def test_frozen_graph_acts_like_eager_and_stays_for_the_run(ckpts):
    """policy.graph="frozen" (sebvs/policy/graph.py) gives the eager actions to float32
    rounding, says so in stats, and cannot be switched while running."""
    rng = np.random.default_rng(5)
    frames = [(rng.integers(0, 256, (32, 32, 3), dtype=np.uint8),
               rng.integers(0, 6, (2, 32, 32), dtype=np.uint8)) for _ in range(3)]
    actions, actors = {}, {}
    for graph in ("eager", "frozen"):
        node = _Node()
        actor = Policy("policy", Policy.Params(directory=str(ckpts), graph=graph),
                       connected=frozenset({"rgb", "events"}), node=node)

        async def scenario():
            await actor.setup()
            for tick, (rgb, ev) in enumerate(frames):
                await actor.on_rgb(_msg("rgb", tick, rgb))
                await actor.on_events(_msg("events", tick, ev))
            with pytest.raises(ValueError, match="'graph' cannot change while running"):
                await actor.control("graph", "eager")

        asyncio.run(scenario())
        actions[graph] = np.stack([a["action"] for _, _, a in node.sent])
        actors[graph] = actor
    assert actions["frozen"].shape == (3, 2)
    np.testing.assert_allclose(actions["frozen"], actions["eager"], atol=1e-5)
    assert actors["frozen"].stats()["graphs"] == \
        {"rgb": "frozen", "event": "frozen", "rgb+event": "frozen"}
    assert set(actors["eager"].stats()["graphs"].values()) == {"eager"}


@pytest.mark.parametrize("clock, expected", [("realtime", "frozen"), ("lockstep", "eager")])
def test_the_default_graph_is_frozen_on_the_realtime_clock_and_eager_in_lockstep(
        ckpts, clock, expected):
    """graph="auto" (the default): the chain's latency matters on the realtime clock, bit
    for bit reproduction in lockstep."""
    actor = Policy("policy", Policy.Params(directory=str(ckpts)), clock=clock,
                   connected=frozenset({"rgb", "events"}), node=_Node())
    asyncio.run(actor.setup())
    assert set(actor.stats()["graphs"].values()) == {expected}


def _actions_on(ckpts, event_frames, **params):
    """The rgb+event actions of one actor fed one RGB frame and these event frames, and
    the actor (its stats, the metas it sent)."""
    node = _Node()
    actor = Policy("policy", Policy.Params(directory=str(ckpts), graph="eager", **params),
                   connected=frozenset({"rgb", "events"}), node=node)
    rgb = np.full((32, 32, 3), 90, np.uint8)

    async def scenario():
        await actor.setup()
        for tick, ev in enumerate(event_frames):
            await actor.on_rgb(_msg("rgb", tick, rgb))
            await actor.on_events(_msg("events", tick, ev))

    asyncio.run(scenario())
    return np.stack([a["action"] for _, _, a in node.sent]), actor, node


def test_an_ablated_stream_is_held_at_its_level_and_named_where_a_user_looks(ckpts):
    """policy.ablate holds the named input channels at the given levels: the rgb+event
    policy's actions no longer depend on the events and equal the whole policy's on event
    frames at those levels; every action's meta and the stats name the ablation."""
    rng = np.random.default_rng(2)
    frames = [rng.integers(0, 8, (2, 32, 32), dtype=np.uint8) for _ in range(3)]
    whole, _, _ = _actions_on(ckpts, frames)
    assert np.ptp(whole, axis=0).max() > 1e-6          # the events move the whole policy
    # event channels are 3 and 4 (after r, g, b); levels in model input units
    spec = {"rgb+event": {"channels": [3, 4], "levels": [0.0, 0.0]}}
    ablated, actor, node = _actions_on(ckpts, frames, ablate=spec)
    np.testing.assert_array_equal(ablated, np.repeat(ablated[:1], 3, axis=0))
    no_events, _, _ = _actions_on(ckpts, [np.zeros((2, 32, 32), np.uint8)] * 3)
    np.testing.assert_allclose(ablated, no_events, atol=1e-6)   # empty frames -> input 0
    assert all(m["ablated_channels"] == [3, 4] for m in node.metas)
    assert actor.stats()["ablated"] == {"rgb+event": {"channels": [3, 4], "levels": [0.0, 0.0]}}
    _, plain, plain_node = _actions_on(ckpts, frames[:1])
    assert plain.stats()["ablated"] == {} and "ablated_channels" not in plain_node.metas[0]


@pytest.mark.parametrize("spec, match", [
    ({"thermal": {"channels": [0], "levels": [0.0]}}, "'thermal' has no checkpoint"),
    ({"rgb+event": {"channels": [3, 4], "levels": [0.0]}}, "2 channels and 1 levels"),
    ({"rgb+event": {"channels": [5], "levels": [0.0]}}, "in 0..4"),
    ({"rgb+event": {"channels": [3, 3], "levels": [0.0, 0.0]}}, "distinct"),
    ({"rgb+event": {"channels": [3], "levels": [float("nan")]}}, "finite"),
    ({"rgb+event": [3, 4]}, "ablate.rgb\\+event must be"),
    ({"rgb+event": {"channels": 3, "levels": [0.0]}}, "ablate.rgb\\+event must be"),
    ({"rgb+event": {"channels": [3], "levels": ["dark"]}}, "finite numbers"),
])
def test_a_bad_ablation_is_refused_with_what_is_wrong(ckpts, spec, match):
    with pytest.raises(ValueError, match=match):
        _actions_on(ckpts, [], ablate=spec)
