"""Gymnasium's own wrappers on the SEBVS environments: RecordEpisodeStatistics, single and
vector, owns info["episode"] (the env's episode number is info["episode_index"]), and
RecordVideo writes the episode (the `[gym]` extra brings moviepy for it)."""
import numpy as np
import pytest

gym = pytest.importorskip("gymnasium")

import sebvs.envs  # noqa: E402
from sebvs.envs import ENV_IDS  # noqa: E402

# three control ticks (10 Hz) at 32 px, proprioception only: nothing rendered per step but
# what the episode's own chain needs
SHORT = {"width": 32, "height": 32, "episode_s": 0.3, "obs": ("proprio",)}
TASKS = ["nav", "arm"]


def play(env, seed: int) -> tuple[dict, float, int]:
    """One episode with seeded random actions; (the last info, the return, the steps)."""
    _, info = env.reset(seed=seed)
    assert "episode" not in info and info["episode_index"] == 0
    env.action_space.seed(seed)
    total, steps = 0.0, 0
    while True:
        _, reward, terminated, truncated, info = env.step(env.action_space.sample())
        total, steps = total + float(reward), steps + 1
        if terminated or truncated:
            return info, total, steps


@pytest.mark.parametrize("task", TASKS)
def test_record_episode_statistics_reports_the_episode(task):
    env = gym.wrappers.RecordEpisodeStatistics(gym.make(ENV_IDS[task], **SHORT))
    try:
        info, total, steps = play(env, seed=2)
        stats = info["episode"]
        assert steps == 3 and int(stats["l"]) == steps
        assert float(stats["r"]) == pytest.approx(total)
        assert info["episode_index"] == 0 and "episode_metrics" in info
        assert list(env.length_queue) == [steps]
        # the next reset plays the run's next episode, still counted by the env
        _, info = env.reset()
        assert info["episode_index"] == 1 and "episode" not in info
    finally:
        env.close()


@pytest.mark.parametrize("task", TASKS)
def test_the_vector_record_episode_statistics_reports_each_env(task):
    # sync: the wrapper is what is tested (tests/test_envs.py runs the async vector env)
    envs = gym.wrappers.vector.RecordEpisodeStatistics(
        gym.vector.SyncVectorEnv([lambda: gym.make(ENV_IDS[task], **SHORT)] * 2))
    try:
        _, infos = envs.reset(seed=[3, 4])
        assert "episode" not in infos
        np.testing.assert_array_equal(infos["episode_index"], [0, 0])
        envs.action_space.seed(3)
        done_infos, returns = None, np.zeros(2)
        for _ in range(3):
            _, reward, terminated, truncated, infos = envs.step(envs.action_space.sample())
            returns += reward
            if (terminated | truncated).any():
                done_infos = infos
        assert done_infos is not None and done_infos["_episode"].all()
        np.testing.assert_array_equal(done_infos["episode"]["l"], [3, 3])
        np.testing.assert_allclose(done_infos["episode"]["r"], returns, rtol=1e-5)
    finally:
        envs.close()


def test_record_video_writes_the_episode(tmp_path):
    pytest.importorskip("moviepy")
    env = gym.wrappers.RecordVideo(
        gym.make(ENV_IDS["nav"], render_mode="rgb_array", width=32, height=32, episode_s=0.3,
                 obs=("rgb",)),
        str(tmp_path / "videos"), episode_trigger=lambda k: True, disable_logger=True)
    try:
        play(env, seed=1)
    finally:
        env.close()
    videos = sorted((tmp_path / "videos").glob("*.mp4"))
    assert len(videos) == 1 and videos[0].stat().st_size > 0


ALL_KEYS = {**SHORT, "obs": ("rgb", "events", "proprio")}


@pytest.mark.parametrize("task, camera", [("nav", "front"), ("arm", "wrist")])
def test_the_lerobot_layout_names_what_lerobot_eval_reads(task, camera):
    """obs_layout="lerobot": pixels {camera: rgb} and agent_pos, the keys lerobot-eval maps
    to observation.images.<camera> and observation.state (the export's names)."""
    env = gym.make(ENV_IDS[task], obs_layout="lerobot", **ALL_KEYS)
    try:
        obs, _ = env.reset(seed=1)
        space = env.observation_space
        assert set(obs) == set(space.spaces) == {"pixels", "agent_pos", "events"}
        assert set(obs["pixels"]) == {camera}
        assert obs["pixels"][camera].shape == space["pixels"][camera].shape
        assert obs["pixels"][camera].dtype == np.uint8 and obs["pixels"][camera].shape[-1] == 3
        assert space.contains(obs)
        plain = gym.make(ENV_IDS[task], **ALL_KEYS)
        try:
            ref, _ = plain.reset(seed=1)
            assert np.array_equal(ref["rgb"], obs["pixels"][camera])
            assert np.array_equal(ref["proprio"], obs["agent_pos"])
        finally:
            plain.close()
    finally:
        env.close()
    with pytest.raises(ValueError, match="obs_layout must be one of sebvs, lerobot"):
        gym.make(ENV_IDS[task], obs_layout="lerobot2", **SHORT)
