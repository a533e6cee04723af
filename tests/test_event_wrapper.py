"""sebvs.envs.EventCameraWrapper on stock Gymnasium MuJoCo envs and on a bare MuJoCo env:
Gymnasium's checker passes, events arrive on every step where the arm moves, a still
scene gives the preset's noise only (none on "paper"), the hook on do_simulation leaves
the env's physics as it was, the view is the env's own, and it runs in Sync and Async
vector envs and under RecordEpisodeStatistics."""
import numpy as np
import pytest

gym = pytest.importorskip("gymnasium")
pytest.importorskip("imageio")          # the stock MuJoCo envs' own need

from gymnasium.utils.env_checker import check_env  # noqa: E402
from gymnasium.utils.passive_env_checker import env_render_passive_checker  # noqa: E402

import mujoco  # noqa: E402

import sebvs  # noqa: E402
from sebvs.dvs.params import static_noise_rate_hz  # noqa: E402
from sebvs.envs import EventCameraWrapper  # noqa: E402
from sebvs.envs.wrapper import EventPacket  # noqa: E402
from tests.test_event_camera import ARM  # noqa: E402

PX = 32


class BareArm(gym.Env):
    """A MuJoCo env with no MujocoEnv behind it (no do_simulation: the wrapper
    interpolates between steps): the hinge arm of tests/test_event_camera.py, torque
    commanded, 10 physics steps a step; still at rest under zero torque."""
    metadata = {"render_modes": []}

    def __init__(self):
        self.model = mujoco.MjModel.from_xml_string(ARM)
        self.data = mujoco.MjData(self.model)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (2,), np.float64)
        self.dt = 10 * self.model.opt.timestep

    def _obs(self):
        return np.concatenate([self.data.qpos, self.data.qvel])

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        mujoco.mj_resetData(self.model, self.data)
        mujoco.mj_forward(self.model, self.data)
        return self._obs(), {}

    def step(self, action):
        self.data.ctrl[:] = 8.0 * np.asarray(action, np.float64)
        mujoco.mj_step(self.model, self.data, nstep=10)
        return self._obs(), 0.0, False, False, {}


def wrapped(env_id, **kw):
    return EventCameraWrapper(gym.make(env_id), width=PX, height=PX, **kw)


@pytest.mark.parametrize("env_id", ["Pusher-v5", "Reacher-v5"])
def test_gymnasium_s_checker_passes_on_stock_envs(env_id):
    """skip_render_check: the checker makes every render mode the stock env declares,
    "human" among them, which opens a window; render() itself is the env's own and is
    checked in rgb_array mode below."""
    env = wrapped(env_id)
    check_env(env, skip_render_check=True)
    env.close()
    env = EventCameraWrapper(gym.make(env_id, render_mode="rgb_array", width=PX, height=PX),
                             width=PX, height=PX)
    env.reset(seed=0)
    env_render_passive_checker(env)
    env.close()


@pytest.mark.parametrize("env_id", ["Pusher-v5", "Reacher-v5"])
def test_events_arrive_on_every_step_where_the_arm_moves(env_id):
    env = wrapped(env_id, raw_events=True)
    obs, info = env.reset(seed=1)
    assert obs["events"].shape == (2, PX, PX) and obs["events"].sum() == 0
    assert len(info["raw_events"]) == 0
    env.action_space.seed(1)
    for _ in range(8):
        obs, _, _, _, info = env.step(env.action_space.sample())
        packet = info["raw_events"]
        assert isinstance(packet, EventPacket) and len(packet) > 0
        assert int(obs["events"].sum()) > 0
        assert obs["rgb"].shape == (PX, PX, 3) and obs["rgb"].dtype == np.uint8
        assert packet.events["t"].max() <= round(env.unwrapped.data.time * 1e9)
    env.close()


def test_a_still_scene_gives_the_preset_s_noise_only_and_paper_none():
    """The bare arm at rest under zero torque, 2 s of 20 ms steps at the default 100 Hz
    luma: the physical preset's count within 25 % of its stated mean rate summed over the
    pixels' light (docs/dvs.md; about 8 % is one sigma here), the paper preset's zero."""
    seconds, zero = 2.0, np.zeros(1, np.float32)
    env = EventCameraWrapper(BareArm(), "front", width=PX, height=PX, raw_events=True)
    env.reset(seed=0)
    steps = round(seconds / env.unwrapped.dt)
    n = sum(len(env.step(zero)[4]["raw_events"]) for _ in range(steps))
    lum = env.camera.luma.astype(np.float64)
    expected = seconds * sum(static_noise_rate_hz(env.camera.params, float(v))
                             for v in lum.ravel())
    assert 0.75 * expected <= n <= 1.25 * expected, (n, expected)
    env.close()
    env = EventCameraWrapper(BareArm(), "front", width=PX, height=PX, preset="paper")
    env.reset(seed=0)
    assert sum(int(env.step(zero)[0]["events"].sum()) for _ in range(25)) == 0
    moving = [int(env.step(np.ones(1, np.float32))[0]["events"].sum()) for _ in range(12)]
    assert all(moving[4:]), moving       # from rest, and the paper's photoreceptor lags
    env.close()


def test_the_hook_leaves_the_env_s_physics_bit_for_bit_and_samples_every_frame():
    plain, env = gym.make("Pusher-v5"), wrapped("Pusher-v5", raw_events=True)
    assert env._hooked
    a, _ = plain.reset(seed=4)
    b, _ = env.reset(seed=4)
    np.testing.assert_array_equal(a, b["state"])
    plain.action_space.seed(4)
    for _ in range(5):
        act = plain.action_space.sample()
        a, ra, *_ = plain.step(act)
        b, rb, *_ = env.step(act)
        np.testing.assert_array_equal(a, b["state"])
        assert ra == rb
    # frame_skip 5 of 10 ms: every frame's state kept for the 100 Hz samples
    assert len(env._substates) == env.unwrapped.frame_skip
    env.close()
    assert "do_simulation" not in vars(env.unwrapped)          # unhooked on close


def test_without_substeps_the_poses_are_interpolated_between_steps():
    env = wrapped("Pusher-v5", substeps=False)
    env.reset(seed=2)
    env.action_space.seed(2)
    counts = [int(env.step(env.action_space.sample())[0]["events"].sum()) for _ in range(5)]
    assert not env._substates and all(counts)
    env.close()


def test_the_default_view_is_the_one_env_render_draws():
    """Pusher has no camera: the wrapper's free view is set up as Gymnasium's renderer
    sets its own, so on the 8-bit sensor its frame is env.render()'s scene (MSAA and
    shadows, which the wrapper's copy leaves out, apart)."""
    env = EventCameraWrapper(gym.make("Pusher-v5", render_mode="rgb_array", width=48,
                                      height=48), preset="paper", fast_render=False)
    obs, _ = env.reset(seed=0)
    ours, theirs = obs["rgb"].astype(float), env.render().astype(float)
    assert ours.shape == theirs.shape == (48, 48, 3)
    assert np.abs(ours - theirs).mean() < 3.0
    env.close()


def make_reacher():
    return wrapped("Reacher-v5")


@pytest.mark.parametrize("vector", ["sync", "async"])
def test_it_runs_in_vector_envs(vector):
    if vector == "sync":
        envs = gym.vector.SyncVectorEnv([make_reacher, make_reacher])
    else:
        # spawned workers: one forked from a process that has rendered (this one, in the
        # tests before) inherits its GL state and hangs (tests/test_envs.py alike)
        make = lambda: EventCameraWrapper(gym.make("Reacher-v5"), width=PX, height=PX)  # noqa: E731
        envs = gym.vector.AsyncVectorEnv([make, make], context="spawn")
    obs, _ = envs.reset(seed=[0, 1])
    assert obs["events"].shape == (2, 2, PX, PX) and obs["rgb"].shape == (2, PX, PX, 3)
    envs.action_space.seed(0)
    total = 0
    for _ in range(3):
        obs, *_ = envs.step(envs.action_space.sample())
        assert obs in envs.observation_space
        total += int(obs["events"].sum())
    assert total > 0
    envs.close()


def test_record_episode_statistics_runs_on_the_wrapped_env():
    env = gym.wrappers.RecordEpisodeStatistics(wrapped("Reacher-v5"))
    env.reset(seed=0)
    done, info = False, {}
    while not done:
        _, _, terminated, truncated, info = env.step(env.action_space.sample())
        done = terminated or truncated
    assert info["episode"]["l"] == 50          # Reacher-v5's time limit
    env.close()
    envs = gym.wrappers.vector.RecordEpisodeStatistics(
        gym.vector.SyncVectorEnv([make_reacher]))
    envs.reset(seed=0)
    for _ in range(50):
        _, _, _, truncated, info = envs.step(envs.action_space.sample())
    assert truncated[0] and info["episode"]["l"][0] == 50
    envs.close()


def test_bad_input_is_one_line():
    with pytest.raises(sebvs.UnknownCamera, match="no camera named 'wrist'") as err:
        wrapped("Reacher-v5", camera="wrist")
    assert "\n" not in str(err.value)

    class NotMuJoCo(gym.Env):
        observation_space = gym.spaces.Box(0, 1, (1,))
        action_space = gym.spaces.Box(0, 1, (1,))

    with pytest.raises(TypeError, match="has no MuJoCo model and data"):
        EventCameraWrapper(NotMuJoCo())
    with pytest.raises(ValueError, match="obs must name"):
        wrapped("Reacher-v5", obs=("depth",))
