"""One seed rule: a topology seed is 0 <= seed < 2**31, the range on which each actor's seed
is one-to-one with it, so that no seed a recording accepts plays a test-split episode."""
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sebvs.data.splits import SPLITS, check_recording_seed
from sebvs.runtime.topology import SEED_LIMIT, Topology, TopologyError, check_seed, \
    load_topology

ROOT = Path(__file__).resolve().parents[1]
RECORD_TOPOLOGIES = ("nav_record.toml", "arm_record.toml")
TEST = SPLITS["test"]


def sim_seed(topology_seed: int) -> int:
    return Topology(Path("t.toml"), "t", seed=topology_seed).actor_seed("sim")


@pytest.fixture(scope="module")
def test_sim_seeds() -> set[int]:
    """The sim seeds of every topology seed of the test split: its episodes are
    SeedSequence([sim seed, k]), so these are what no recording may reach."""
    return {sim_seed(s) for s in range(TEST.first, TEST.last + 1)}


def recorded_sim_seed(topology: str, seed: int) -> int | None:
    """The sim seed a `sebvs record` of this topology seed would play, or None where the
    recording path refuses the seed (the topology loader or the split guard)."""
    try:
        topo = load_topology(ROOT / "topologies" / topology, [f"topology.seed={seed}"])
        check_recording_seed(topo.seed)
    except (TopologyError, ValueError):
        return None
    return topo.actor_seed("sim")


@settings(max_examples=150, deadline=None)
@given(seed=st.one_of(st.integers(-2 ** 70, 2 ** 70),
                      # the wrapped images of the test split, which the old rule accepted
                      st.integers(TEST.first, TEST.last).flatmap(
                          lambda s: st.sampled_from([s + SEED_LIMIT, s + 2 ** 32,
                                                     s + 2 ** 64, s - SEED_LIMIT]))),
       topology=st.sampled_from(RECORD_TOPOLOGIES))
def test_no_accepted_recording_seed_reaches_the_test_split(seed, topology, test_sim_seeds):
    got = recorded_sim_seed(topology, seed)
    assert got is None or got not in test_sim_seeds, seed


def test_the_wrapped_test_seed_that_recorded_before_is_refused():
    # 2**31 + 100,000 recorded the test split's first episode seed: actor_seed wrapped
    assert recorded_sim_seed("nav_record.toml", SEED_LIMIT + TEST.first) is None
    assert recorded_sim_seed("nav_record.toml", TEST.first) is None
    assert recorded_sim_seed("nav_record.toml", 7) == sim_seed(7)


def test_actor_seeds_are_one_to_one_on_the_accepted_range():
    # an odd multiplier modulo 2**31: distinct accepted seeds, distinct actor seeds
    seeds = [0, 1, 2, TEST.first, TEST.last, SEED_LIMIT - 1, SEED_LIMIT // 2]
    assert len({sim_seed(s) for s in seeds}) == len(seeds)
    with pytest.raises(ValueError, match="2\\*\\*31"):
        Topology(Path("t.toml"), "t", seed=SEED_LIMIT).actor_seed("sim")


@pytest.mark.parametrize("bad", [-1, SEED_LIMIT, 2 ** 32 + 5, 2 ** 64, 1.5, "3", True, None])
def test_check_seed_refuses_in_one_line(bad):
    with pytest.raises(ValueError) as err:
        check_seed(bad, "--seed")
    assert "\n" not in str(err.value) and str(err.value).startswith(f"--seed {bad!r}")


def test_record_refuses_a_wrapped_seed_before_any_run(tmp_path, capsys):
    from sebvs.cli import main
    code = main(["record", str(ROOT / "topologies" / "nav_record.toml"), "--episodes", "1",
                 "--out", str(tmp_path / "ds"), "--set", f"topology.seed={SEED_LIMIT + TEST.first}",
                 "--quiet"])
    assert code == 2
    assert "out of range" in capsys.readouterr().err
    assert not (tmp_path / "ds").exists()


@pytest.mark.parametrize("seed", [2 ** 32, 2 ** 64, 2 ** 32 + 5, -1])
def test_the_env_refuses_a_seed_that_would_wrap(seed):
    pytest.importorskip("gymnasium")
    from sebvs.envs.erp import ERPNavEnv
    with pytest.raises(ValueError, match="2\\*\\*31"):
        ERPNavEnv(seed=seed)
    env = ERPNavEnv(obs=("proprio",))
    try:
        with pytest.raises(ValueError, match="2\\*\\*31"):
            env.reset(seed=seed)
        env.reset(seed=5)       # the env is still usable after the refusal
    finally:
        env.close()


def test_a_closed_env_says_so():
    gymnasium = pytest.importorskip("gymnasium")
    from sebvs.envs.erp import ERPNavEnv
    env = ERPNavEnv(obs=("proprio",))
    env.reset(seed=1)
    env.close()
    for call in (lambda: env.step([0.0, 0.0]), lambda: env.reset()):
        with pytest.raises(gymnasium.error.ClosedEnvironmentError, match="closed env"):
            call()


def test_info_command_is_the_command_in_force():
    pytest.importorskip("gymnasium")
    from sebvs.envs.erp import ERPNavEnv
    env = ERPNavEnv(obs=("proprio",))
    try:
        env.reset(seed=1)
        _, _, _, _, info = env.step([5.0, -3.0])
        assert info["command"].tolist() == [1.0, -1.0]       # clipped, as the wheels take it
    finally:
        env.close()
