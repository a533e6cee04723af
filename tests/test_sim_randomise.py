"""Per-episode scene randomisation: the draws, their checks, and the sim playing them."""
import asyncio
import collections

import mujoco
import numpy as np
import pytest

from sebvs_actors.sim import episode_seed
from sebvs.sim.randomise import SceneRandomiser
from tests.test_sim_actors import make_sim

NAV_BASE = {"width": 32, "height": 32}
SPEC = {"variant": ["indoor", "outdoor"], "lighting": ["nominal", "low", "flicker"],
        "rgb_blur": [0, 8], "flicker_hz": {"uniform": [5.0, 20.0]}}


def test_draws_depend_on_the_episode_seed_only_and_cover_every_choice():
    a = SceneRandomiser("nav", NAV_BASE, SPEC)
    b = SceneRandomiser("nav", NAV_BASE, dict(reversed(list(SPEC.items()))))  # key order
    draws = [a.draw(episode_seed(0, k)) for k in range(200)]
    assert draws == [b.draw(episode_seed(0, k)) for k in range(200)]
    assert draws[0] != draws[1] or draws[1] != draws[2]
    for key in ("variant", "lighting", "rgb_blur"):
        seen = collections.Counter(d[key] for d in draws)
        assert set(seen) == set(SPEC[key]), (key, seen)
        assert min(seen.values()) > 200 / len(SPEC[key]) / 2     # roughly uniform
    hz = np.array([d["flicker_hz"] for d in draws])
    assert 5.0 <= hz.min() and hz.max() <= 20.0 and hz.std() > 3
    assert all(d["width"] == 32 and d["height"] == 32 for d in draws)   # base kept


def test_a_repeated_choice_weights_it():
    r = SceneRandomiser("nav", NAV_BASE, {"rgb_blur": [0, 0, 0, 8]})
    blurred = sum(r.draw(episode_seed(1, k))["rgb_blur"] == 8 for k in range(400))
    assert 60 < blurred < 140                                   # ~1 in 4


def test_list_valued_choices_are_drawn_whole():
    """A colour is one choice, not three: the appearance keys of the floor/contrast study."""
    shades = [[0.5, 0.06, 0.04], [0.9, 0.15, 0.1], [1.0, 0.45, 0.4]]
    r = SceneRandomiser("nav", NAV_BASE, {"target_rgb": shades, "floor": ["checker", "plain"]})
    draws = [r.draw(episode_seed(2, k)) for k in range(60)]
    assert {tuple(d["target_rgb"]) for d in draws} == {tuple(c) for c in shades}
    assert {d["floor"] for d in draws} == {"checker", "plain"}


@pytest.mark.parametrize("spec, words", [
    ({"variant": ["indoor", "attic"]}, ["randomise.variant", "'attic'"]),
    ({"rgb_blur": [0, 99]}, ["randomise.rgb_blur", "99"]),
    ({"colour": ["red"]}, ["randomise.colour", "unknown config key"]),
    ({"variant": []}, ["randomise.variant", "non-empty list"]),
    ({"variant": "indoor"}, ["randomise.variant", "non-empty list"]),
    ({"fovy": {"uniform": [80, 60]}}, ["randomise.fovy", "lo <= hi"]),
    ({"fovy": {"uniform": [60, float("nan")]}}, ["randomise.fovy", "finite"]),
    ({"fovy": {"normal": [70, 5]}}, ["randomise.fovy", "uniform"]),
    ({"fovy": {"uniform": [60, 200]}}, ["randomise.fovy", "200"]),
    ({"timestep": [0.001, 0.002]}, ["randomise.timestep", "sim setting"]),
    ({"floor": ["checker", "carpet"]}, ["randomise.floor", "'carpet'"]),
    ({"target_rgb": [[0.9, 0.15, 0.1], [2.0, 0, 0]]}, ["randomise.target_rgb", "2.0"]),
])
def test_a_bad_spec_names_the_key_and_the_value(spec, words):
    with pytest.raises(ValueError) as err:
        SceneRandomiser("nav", NAV_BASE, spec)
    for w in words:
        assert w in str(err.value), (w, str(err.value))


def test_the_sim_plays_each_episode_in_its_drawn_scene(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    spec = {"variant": ["indoor", "outdoor"], "lighting": ["nominal", "low"]}
    sim, node = make_sim(config=NAV_BASE, randomise=spec, episodes=6, episode_s=0.05,
                         linger_s=0.0)
    walls = []
    build = sim.core.build          # the sim actor's physics (sebvs.sim.stepper)

    def spy(config):
        build(config)
        walls.append(mujoco.mj_name2id(sim.model, mujoco.mjtObj.mjOBJ_GEOM, "wall_n") >= 0)

    sim.core.build = spy
    asyncio.run(sim.run())
    starts = [m for o, _, m, *_ in node.emitted if o == "episode" and m["event"] == "start"]
    firsts = [m for o, _, m, *_ in node.emitted if o == "state" and "config" in m]
    draw = SceneRandomiser("nav", {**NAV_BASE, "integrator": "discrete", "timestep": 0.001},
                           spec).draw
    assert [m["config"] for m in starts] == [draw(episode_seed(7, k)) for k in range(6)]
    assert [m["config"] for m in firsts] == [m["config"] for m in starts]   # the camera's
    assert {m["config"]["variant"] for m in starts} == {"indoor", "outdoor"}
    # the model really changes with the draw: the indoor room has walls, outdoors has none
    assert walls == [m["config"]["variant"] == "indoor" for m in starts]


def test_without_a_spec_the_episodes_are_as_before(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    plain, n1 = make_sim(config=NAV_BASE, episodes=2, episode_s=0.05, linger_s=0.0)
    fixed, n2 = make_sim(config=NAV_BASE, episodes=2, episode_s=0.05, linger_s=0.0,
                         randomise={"variant": ["indoor"]})     # one choice: the base
    asyncio.run(plain.run())
    asyncio.run(fixed.run())
    qa = [a["qpos"].tobytes() for o, a, *_ in n1.emitted if o == "state"]
    qb = [a["qpos"].tobytes() for o, a, *_ in n2.emitted if o == "state"]
    assert qa and qa == qb          # the reset stream is not touched by the draws
