"""sebvs.envs.vector: N scenes in one process give what N separate envs give, bit for bit
(observations, rewards, ends, infos, through autoresets), the batched event sensor keeps
each env's fixed pattern and random stream, and make_vec builds it from the ids."""
import numpy as np
import pytest

gym = pytest.importorskip("gymnasium")

import sebvs.envs  # noqa: E402
from sebvs.dvs.emulator import EventEmulator  # noqa: E402
from sebvs.dvs.params import preset  # noqa: E402
from sebvs.envs import ENV_IDS, ENV_IDS_IDEAL8  # noqa: E402
from sebvs.envs import vector_events  # noqa: E402
from sebvs.envs.vector import ERPNavVectorEnv  # noqa: E402

# five control ticks (10 Hz) per episode at 48 px: eight steps cross an autoreset
SMALL = {"width": 48, "height": 48, "episode_s": 0.5}
N = 3


def same(a, b, where: str = "") -> None:
    """a and b equal, recursively through dicts, sequences and object arrays."""
    if isinstance(a, dict):
        assert isinstance(b, dict) and a.keys() == b.keys(), where
        for k in a:
            same(a[k], b[k], f"{where}.{k}")
    elif isinstance(a, np.ndarray) and a.dtype == object:
        assert isinstance(b, np.ndarray) and a.shape == b.shape, where
        for i, (x, y) in enumerate(zip(a.ravel(), b.ravel())):
            same(x, y, f"{where}[{i}]")
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            same(x, y, f"{where}[{i}]")
    elif isinstance(a, (np.ndarray, np.generic, float, int)) and not isinstance(a, bool):
        np.testing.assert_array_equal(a, b, err_msg=where)
    else:
        assert a == b, where


@pytest.fixture
def stack_calls(monkeypatch):
    """Counts the batched emulator steps (stacks of two or more sensors)."""
    calls = []
    real = vector_events._step_stack

    def spy(emus, *args):
        calls.append(len(emus))
        return real(emus, *args)
    monkeypatch.setattr(vector_events, "_step_stack", spy)
    return calls


def play_both(env_id: str, steps: int, mode=gym.vector.AutoresetMode.NEXT_STEP, seed=5,
              threads: int = 1):
    """The shared-process vector env and SyncVectorEnv of the same id and options,
    stepped with the same seeded random actions; every result compared."""
    mine = gym.make_vec(env_id, num_envs=N, vectorization_mode="vector_entry_point",
                        autoreset_mode=mode, threads=threads, **SMALL)
    ref = gym.vector.SyncVectorEnv([lambda: gym.make(env_id, **SMALL)] * N,
                                   autoreset_mode=mode)
    ends = 0
    try:
        got, want = mine.reset(seed=seed), ref.reset(seed=seed)
        same(got, want, "reset")
        assert mine.observation_space.contains(got[0])
        rng = np.random.default_rng(seed)
        for k in range(steps):
            actions = rng.uniform(-1, 1, (N, 2)).astype(np.float32)
            got, want = mine.step(actions), ref.step(actions)
            same(got, want, f"step {k}")
            assert mine.observation_space.contains(got[0])
            assert got[1].dtype == np.float64 and got[2].dtype == got[3].dtype == np.bool_
            ends += int((got[2] | got[3]).sum())
    finally:
        mine.close()
        ref.close()
    return ends


def test_make_vec_gives_the_shared_process_env_with_batched_spaces():
    envs = gym.make_vec(ENV_IDS["nav"], num_envs=N, vectorization_mode="vector_entry_point",
                        **SMALL)
    single = gym.make(ENV_IDS["nav"], **SMALL)
    try:
        assert isinstance(envs.unwrapped, ERPNavVectorEnv) and envs.num_envs == N
        assert envs.metadata["autoreset_mode"] == gym.vector.AutoresetMode.NEXT_STEP
        assert envs.single_observation_space == single.observation_space
        assert envs.single_action_space == single.action_space
        assert envs.observation_space == gym.vector.utils.batch_space(
            single.observation_space, N)
        assert envs.action_space.shape == (N, 2)
        # the vector wrappers take it (they read the autoreset mode)
        stats = gym.wrappers.vector.RecordEpisodeStatistics(envs)
        obs, _ = stats.reset(seed=1)
        assert obs["rgb"].shape == (N, 48, 48, 3) and obs["events"].shape == (N, 2, 48, 48)
    finally:
        envs.close()
        single.close()


def test_the_physical_pair_equals_sync_vector_env_through_an_autoreset(stack_calls):
    # two threads: envs 0 and 2 on one (their sensors stacked), env 1 on the other
    ends = play_both(ENV_IDS["nav"], steps=8, threads=2)
    assert ends == N                         # each env's 5-tick episode ended once
    assert stack_calls and set(stack_calls) == {2}


@pytest.mark.filterwarnings("ignore:.*SEBVS/ERPNav-v0 is out of date")
def test_same_step_autoreset_on_the_8bit_pair_equals_sync_vector_env(stack_calls):
    # the 8-bit camera and the paper's emulator: the uint8 path of the emulator
    ends = play_both(ENV_IDS_IDEAL8["nav"], steps=6, mode=gym.vector.AutoresetMode.SAME_STEP)
    assert ends == N and set(stack_calls) == {N}      # one thread: all three stacked


def test_disabled_autoreset_needs_a_reset_mask():
    envs = ERPNavVectorEnv(2, autoreset_mode="Disabled", obs=("proprio",), **SMALL)
    try:
        envs.reset(seed=0)
        for _ in range(5):
            _, _, _, truncated, _ = envs.step(np.zeros((2, 2), np.float32))
        assert truncated.all()
        with pytest.raises(RuntimeError, match="autoreset is disabled"):
            envs.step(np.zeros((2, 2), np.float32))
        _, infos = envs.reset(options={"reset_mask": np.array([True, False])})
        assert infos["_tick"].tolist() == [True, False] and infos["episode_index"][0] == 1
    finally:
        envs.close()


def test_a_seedless_first_reset_gives_each_env_its_own_episodes():
    envs = ERPNavVectorEnv(2, seed=7, obs=("proprio",), **SMALL)
    try:
        _, infos = envs.reset()
        _, seeded = envs.reset(seed=7)
        assert infos["seed"].tolist() == seeded["seed"].tolist()
        assert infos["seed"][0] != infos["seed"][1]
    finally:
        envs.close()


def _emulators(seeds, name, **overrides):
    out = []
    for s in seeds:
        emu = EventEmulator(preset(name, seed=s, **overrides))
        emu.rng = np.random.default_rng([s, 0])      # as SensorStream seeds episode 0
        out.append(emu)
    return out


@pytest.mark.parametrize("name,overrides,linear", [
    ("physical", {"downsample": 1.0, "preset_version": 1}, True),
    ("noisy", {}, False)])
def test_the_batched_emulator_equals_separate_emulators(name, overrides, linear):
    seeds = [11, 12, 13, 14]
    alone, batched = _emulators(seeds, name, **overrides), _emulators(seeds, name, **overrides)
    stacks = vector_events.Stacks()
    rng = np.random.default_rng(0)
    scene = [rng.random((24, 32)) for _ in seeds]
    total = 0
    for k in range(10):
        light = [s * (1.0 + 0.3 * np.sin(0.7 * k + i)) for i, s in enumerate(scene)]
        frames = [(x * 3).astype(np.float32) if linear else
                  np.clip(x * 200, 0, 255).astype(np.uint8) for x in light]
        times = [k * 10_000_000] * len(seeds)
        if k == 5:
            times[1] += 7          # one sensor off the others' time: it steps alone
        want = [e.step_luminance(f, t) if linear else e.step(f, t)
                for e, f, t in zip(alone, frames, times)]
        got = vector_events.emulate_batch(batched, frames, times, [linear] * len(seeds),
                                          stacks)
        for w, g in zip(want, got):
            np.testing.assert_array_equal(w, g)
            total += w.size
        for a, b in zip(alone, batched):
            for field in ("lp", "base", "last_t"):
                np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
            assert a.t_ns == b.t_ns and a.frames == b.frames
    assert total > 200                       # the frames made events to compare
    # each sensor its own fixed pattern, not one drawn for the stack
    assert not np.array_equal(batched[0].theta_on, batched[1].theta_on)


@pytest.mark.parametrize("bad", [0, -2, 2.5, True, "8", None])
def test_a_bad_num_envs_is_refused_in_one_line(bad):
    with pytest.raises(ValueError) as err:
        gym.make_vec(ENV_IDS["nav"], num_envs=bad, vectorization_mode="vector_entry_point",
                     **SMALL)
    message = str(err.value)
    assert message == f"num_envs must be an integer >= 1, got {bad!r}" and "\n" not in message


def test_a_bad_thread_count_is_refused_in_one_line():
    with pytest.raises(ValueError, match=r"^threads must be an integer from 1 to num_envs "
                                         r"\(2\), got 3$"):
        ERPNavVectorEnv(2, threads=3, **SMALL)
