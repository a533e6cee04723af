"""sebvs.envs: the Gymnasium environments pass Gymnasium's checker in every observation
mode, play the lockstep topology's episodes (the same frames and event frames, the same
expert metrics as `sebvs eval`), clip and refuse actions as the sim does, and run in an
AsyncVectorEnv; gymnasium stays an optional extra."""
import contextlib
import itertools
import subprocess
import sys
import warnings

import numpy as np
import pytest

gym = pytest.importorskip("gymnasium")

import sebvs.envs  # noqa: E402
from sebvs.envs import ENV_IDS, OBS_KEYS, ExpertPolicy  # noqa: E402
from tests.tools_loader import tool_module  # noqa: E402

SMALL = {"width": 48, "height": 48, "episode_s": 0.5}
# the arm's action is the pose the expert commands, in m and rad, not a [-1, 1] box: the
# checker's advice about that is the one warning let through
NORMALISED_ADVICE = ".*symmetric and normalized space"


@contextlib.contextmanager
def strict_warnings():
    """A checker's warning fails the test, the arm's action-scale advice apart."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warnings.filterwarnings("ignore", message=NORMALISED_ADVICE)
        yield
MODES = [m for n in range(1, 4) for m in itertools.combinations(OBS_KEYS, n)]


def test_import_sebvs_leaves_gymnasium_alone():
    code = "import sys, sebvs, sebvs.cli; print('gymnasium' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == "False"


def test_without_gymnasium_the_import_names_the_extra_in_one_line():
    code = ("import sys\n"
            "class Block:\n"
            "    def find_spec(self, name, path=None, target=None):\n"
            "        if name.split('.')[0] == 'gymnasium':\n"
            "            raise ImportError('no gymnasium')\n"
            "sys.meta_path.insert(0, Block())\n"
            "try:\n"
            "    import sebvs.envs\n"
            "except ImportError as exc:\n"
            "    print(exc)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == "sebvs.envs needs gymnasium: pip install 'sebvs[gym]'"


@pytest.mark.parametrize("task", ["nav", "arm"])
@pytest.mark.parametrize("obs", MODES, ids=["+".join(m) for m in MODES])
def test_check_env_passes_in_every_observation_mode(task, obs):
    from gymnasium.utils.env_checker import check_env
    env = gym.make(ENV_IDS[task], obs=obs, render_mode="rgb_array", **SMALL)
    with strict_warnings():
        check_env(env.unwrapped, skip_render_check=False)
    assert set(env.observation_space.spaces) == set(obs)
    env.close()


@pytest.mark.parametrize("task", ["nav", "arm"])
def test_check_env_passes_with_a_voxel_grid_and_the_physical_sensor(task):
    from gymnasium.utils.env_checker import check_env
    condition = "dusk" if task == "nav" else "nominal_physical"
    env = gym.make(ENV_IDS[task], bins=4, condition=condition, **SMALL)
    space = env.observation_space["events"]
    assert space.shape == (4, 48, 48) and space.dtype == np.float32
    base = env.unwrapped
    assert base.settings["camera"].sensor == "physical"
    assert base.settings["emulator"].preset == "physical"
    with strict_warnings():
        check_env(base)
    env.close()


ADAPTIVE = ('camera.luma_sampling="adaptive"',)


@pytest.mark.parametrize("task,condition,extra", [("nav", "flicker", ()),
                                                  ("arm", "fast_physical", ()),
                                                  ("nav", "fast_flicker", ADAPTIVE)],
                         ids=["nav-flicker", "arm-fast_physical", "nav-fast_flicker-adaptive-luma"])
def test_the_env_plays_the_topology_s_frames_and_event_frames(tmp_path, task, condition,
                                                               extra):
    """The lockstep topology (`sebvs eval`'s no-action run, event chain kept, a probe
    saving every tick's RGB and event frame) and the env stepped with the same idle
    command: the same frames bit for bit, for the same topology seed."""
    seed, small = 5, ["sim.config.width=48", "sim.config.height=48",
                      "accumulator.out_width=48", "accumulator.out_height=48", *extra]
    with tool_module("bench/bench_env") as bench:
        out = bench.run_topology(task, condition, None, seed, 0.5, tmp_path, max_arrays=1000,
                                 extra=small)
    by_input = {"rgb": [], "events": []}
    for i, e in enumerate(out["entries"]):
        name = "rgb" if e["input"] == "rgb" else "frame"
        by_input[e["input"]].append((e["tick"], out["arrays"][f"{i}.{e['input']}.{name}"]))
    env = gym.make(ENV_IDS[task], condition=condition, width=48, height=48, episode_s=0.5,
                   overrides=extra)
    idle = env.unwrapped.sim.scene.idle_command().astype(np.float32)
    obs, _ = env.reset(seed=seed)
    frames = [obs]
    done = False
    while not done:
        obs, _, terminated, truncated, _ = env.step(idle)
        frames.append(obs)
        done = terminated or truncated
    env.close()
    assert len(by_input["rgb"]) == len(by_input["events"]) == len(frames) == 6
    for k, obs in enumerate(frames):
        assert by_input["rgb"][k][0] == by_input["events"][k][0] == k
        np.testing.assert_array_equal(obs["rgb"], by_input["rgb"][k][1])
        np.testing.assert_array_equal(obs["events"], by_input["events"][k][1])
    assert sum(int(f["events"].sum()) for f in frames) > 0


def test_the_expert_through_the_env_scores_what_sebvs_eval_scores(tmp_path):
    """One seed, short episodes, through tools/checks/env_parity.py: the nav metrics
    equal (every figure), the arm's grasp outcomes the same."""
    with tool_module("checks/env_parity") as study:
        nav = study.compare("nav", "nominal", "indoor", seed=3, episodes=2, episode_s=1.5,
                            out=tmp_path / "nav")
        arm = study.compare("arm", "nominal", "multi", seed=3, episodes=1, episode_s=None,
                            out=tmp_path / "arm")
    assert nav["episodes"] == 2 and nav["seeds_match"] and nav["identical_metrics"] == 2
    assert abs(nav["paper_rate_diff_points"]) < 0.5
    assert arm["episodes"] == 1 and arm["seeds_match"] and arm["same_outcomes"] == 1
    assert arm["env_outcomes"] == arm["eval_outcomes"]


@pytest.mark.filterwarnings("ignore:.*is out of date")     # Gymnasium's word on a v0
@pytest.mark.parametrize("task", ["nav", "arm"])
def test_v1_runs_the_physical_pair_and_v0_the_8_bit_benchmark_unless_told(task):
    from sebvs.envs import ENV_IDS_IDEAL8
    made = {}
    for name, env_id, kwargs in (("v1", ENV_IDS[task], {}), ("v0", ENV_IDS_IDEAL8[task], {}),
                                 ("v0 dusk", ENV_IDS_IDEAL8[task],
                                  {"condition": "dusk_moving" if task == "arm" else "dusk"})):
        env = gym.make(env_id, **SMALL, **kwargs).unwrapped
        made[name] = (env.condition, env.camera_params.sensor, env.emulator_params.preset)
        env.close()
    assert made["v1"] == ("nominal_physical", "physical", "physical")
    assert made["v0"] == ("nominal", "ideal8", "paper")
    assert made["v0 dusk"][1:] == ("physical", "physical")


def test_actions_are_clipped_and_bad_ones_refused_as_the_sim_does():
    env = gym.make(ENV_IDS["nav"], **SMALL)
    base = env.unwrapped
    env.reset(seed=1)
    cfg = base.sim.scene.config
    _, _, _, _, info = env.step(np.array([5.0, -5.0], np.float32))
    np.testing.assert_allclose(base.sim.data.ctrl[:2], [cfg["v_max"], -cfg["w_max"]])
    assert not info["rejected"]
    env.step(np.array([0.5, 0.25], np.float32))
    ctrl = base.sim.data.ctrl.copy()
    _, _, _, _, info = env.step(np.array([np.nan, 0.0], np.float32))
    assert info["rejected"] and info["command"].tolist() == [0.5, 0.25]
    np.testing.assert_array_equal(base.sim.data.ctrl, ctrl)
    env.close()
    arm = gym.make(ENV_IDS["arm"], **SMALL)
    arm.reset(seed=1)
    arm.step(np.array([2.0, -2.0, 0.3, 4.0, 0.0, 0.0], np.float32))
    pose = arm.unwrapped.sim.scene.command_pose
    np.testing.assert_allclose(pose[:3], [0.9, -0.9, 0.3])
    assert -np.pi < pose[3] <= np.pi
    arm.close()


def test_reset_continues_the_run_and_a_seed_restarts_it():
    env = gym.make(ENV_IDS["nav"], **SMALL)
    seeds = []
    _, info = env.reset(seed=4)
    seeds.append(info["seed"])
    for _ in range(2):
        _, info = env.reset()
        seeds.append(info["seed"])
    from sebvs.runtime.topology import Topology
    from sebvs.sim.stepper import episode_seed
    sim_seed = Topology(path=None, name="t", seed=4).actor_seed("sim")
    assert seeds == [episode_seed(sim_seed, k) for k in range(3)]
    _, info = env.reset(seed=4, options={"episode": 2})
    assert info["seed"] == seeds[2] and info["episode_index"] == 2
    env.close()


def test_the_expert_needs_the_privileged_view_and_grasps_through_the_arm_env():
    with pytest.raises(ValueError, match="privileged=True"):
        ExpertPolicy(gym.make(ENV_IDS["arm"], **SMALL))
    env = gym.make(ENV_IDS["arm"], privileged=True)
    expert = ExpertPolicy(env)
    obs, info = env.reset(seed=0)
    assert {"ideal", "depth", "state"} <= set(info)
    total, steps, done = 0.0, 0, False
    while not done:
        obs, reward, terminated, truncated, info = env.step(expert(obs, info))
        total, steps, done = total + reward, steps + 1, terminated or truncated
    assert steps == 20 and terminated and not truncated
    assert info["outcome"]["outcome"] in ("lifted_and_held", "home_correct")
    assert total == 1.0 and info["episode_metrics"]["metrics"]["grasp_success"] in (True, None)
    env.close()


def test_an_async_vector_of_two_envs_steps_and_resets_itself():
    # spawned workers: a worker forked from a process that has rendered (this one, in the
    # tests before) inherits its GL state and hangs; "module:id" registers the ids there
    nav_id = "sebvs.envs:" + ENV_IDS["nav"]
    envs = gym.vector.AsyncVectorEnv(
        [lambda: gym.make(nav_id, width=48, height=48, episode_s=0.3)] * 2, context="spawn")
    try:
        obs, infos = envs.reset(seed=[1, 2])
        assert obs["rgb"].shape == (2, 48, 48, 3) and obs["events"].shape == (2, 2, 48, 48)
        assert obs["proprio"].shape == (2, 3)
        assert infos["seed"][0] != infos["seed"][1]
        ends = 0
        for _ in range(5):
            obs, reward, terminated, truncated, infos = envs.step(np.zeros((2, 2), np.float32))
            assert reward.shape == (2,) and obs["rgb"].dtype == np.uint8
            ends += int(truncated.sum())
        assert ends == 2            # 0.3 s at 10 Hz: three steps, then the autoreset
    finally:
        envs.close()
