"""The camera's emitted frames, byte for byte, against hashes taken before its hot path was
trimmed (no full-size scene update on luma-only states, blur history reused, no re-pose
after the blur): a faster camera must not change one pixel of what the emulator and the
recorder get. The expected hashes were computed with the camera and renderer of commit
9d8cc25 on Mesa llvmpipe (the CPU renderer every install here uses); another GL driver may
rasterise differently, which these tests would then report."""
import asyncio
import hashlib

import numpy as np
import pytest

from sebvs_actors.camera import Camera
from sebvs_actors.sim import Sim
from sebvs.runtime import Message

from tests.test_sim_actors import FakeNode


def sim_states(config: dict, dvs_hz: float = 100.0) -> list[tuple]:
    """The state messages of one in-process nav episode of 0.3 s (31 states, 4 control)."""
    node = FakeNode()
    sim = Sim("sim", Sim.Params(scene="nav", config=config, episode_s=0.3, episodes=1,
                                render_hz=dvs_hz, control_hz=10.0),
              seed=3, clock="lockstep", consumed=frozenset({"state", "episode"}),
              connected=frozenset(), node=node)
    asyncio.run(sim.setup())
    asyncio.run(sim.run())
    return [(a, m, t, k) for o, a, m, t, k in node.emitted if o == "state"]


def camera_outputs(states, consumed, **params) -> list[tuple]:
    node = FakeNode()
    cam = Camera("camera", Camera.Params(**params), seed=0, clock="lockstep",
                 consumed=frozenset(consumed), node=node)

    async def feed():
        await cam.setup()
        for i, (arrays, meta, t_sim, tick) in enumerate(states):
            await cam.on_state(Message(topic="sim/state", source="sim", output="state",
                                       seq=i, t_sim=t_sim, tick=tick, stamps=[], meta=meta,
                                       arrays=arrays))
        await cam.teardown()

    asyncio.run(feed())
    return node.emitted


def digest(emitted, output: str) -> tuple[int, str]:
    """(count, sha256 prefix) over one output's arrays and timing meta, in emission order."""
    h, n = hashlib.sha256(), 0
    for out, arrays, meta, t_sim, tick in emitted:
        if out != output:
            continue
        n += 1
        h.update(repr((meta["episode"], meta["control"], round(meta["t_ep"], 9), tick)).encode())
        for name in sorted(arrays):
            h.update(name.encode() + arrays[name].tobytes())
    return n, h.hexdigest()[:16]


SMALL = {"width": 64, "height": 48}


@pytest.fixture(scope="module")
def sharp_states():
    return sim_states({**SMALL, "variant": "indoor"})


@pytest.fixture(scope="module")
def blurred_states():
    return sim_states({**SMALL, "variant": "outdoor", "rgb_blur": 3, "lighting": "flicker"})


def test_luma_at_a_fraction_and_rgb_are_the_bytes_of_before(sharp_states):
    # the recording topologies' setting: luma from its own renderer at half the size
    emitted = camera_outputs(sharp_states, {"rgb", "luma"}, dvs_hz=100.0, luma_scale=0.5)
    assert digest(emitted, "luma") == (31, "6afb15f547c9b3ba")
    assert digest(emitted, "rgb") == (4, "7d7921c516084624")


def test_shared_render_blur_depth_and_seg_are_the_bytes_of_before(blurred_states):
    # luma_scale 1: luma comes from the RGB render; blurred RGB from the state history
    emitted = camera_outputs(blurred_states, {"rgb", "luma", "depth", "seg"}, dvs_hz=50.0)
    assert digest(emitted, "luma") == (16, "4cb70ee4802cef72")
    assert digest(emitted, "rgb") == (4, "ce57f5b0a0cf46ca")
    assert digest(emitted, "depth") == (4, "fb8f3bc47345a6d8")
    assert digest(emitted, "seg") == (4, "78e581a06c04ecee")


def test_one_render_serves_rgb_and_luma_on_a_shared_sample(sharp_states):
    emitted = camera_outputs(sharp_states, {"rgb", "luma"}, dvs_hz=100.0)
    rgb = {tick: a["rgb"] for out, a, _, _, tick in emitted if out == "rgb"}
    shared = 0
    for out, a, meta, _, tick in emitted:
        if out == "luma" and meta["control"]:
            r, g, b = (rgb[tick][..., c].astype(np.float64) for c in range(3))
            # ITU-R 601 luma of that very RGB frame (OpenCV's fixed-point rounding: +-1)
            assert np.abs(a["luma"] - (0.299 * r + 0.587 * g + 0.114 * b)).max() <= 1
            shared += 1
    assert shared == len(rgb) == 4
