"""SEBVS's scenes and event sensor as Gymnasium environments (docs/envs.md).

    import gymnasium as gym
    import sebvs.envs                                     # registers the two ids
    env = gym.make("SEBVS/ERPNav-v0", condition="low_light", obs=("rgb", "events"))
    obs, info = env.reset(seed=3)          # episode 0 of `sebvs eval --seed 3`'s lockstep run

SEBVS/ERPNav-v0   the nav robot follows the red cube (ERPNavEnv)
SEBVS/ERPArm-v0   the UR5's pre-grasp pose above a cube on the conveyor (ERPArmEnv)

The step runs the topologies' own scene, camera, emulator and accumulator code in this
process (sebvs.sim.stepper, sebvs.sensors.camera, sebvs.dvs.stream). Needs the optional
extra: pip install 'sebvs[gym]'.
"""
from sebvs.extras import require

# one line naming the extra, not a traceback, when gymnasium is not installed
gymnasium = require("gymnasium", "gymnasium", "gym", "sebvs.envs")

from .erp import ERPArmEnv, ERPEnv, ERPNavEnv, OBS_KEYS  # noqa: E402
from .expert import ExpertPolicy  # noqa: E402

ENV_IDS = {"nav": "SEBVS/ERPNav-v0", "arm": "SEBVS/ERPArm-v0"}

for _task, _id in ENV_IDS.items():
    if _id not in gymnasium.registry:
        gymnasium.register(id=_id, entry_point=f"sebvs.envs.erp:ERP{_task.capitalize()}Env")

__all__ = ["ENV_IDS", "ERPArmEnv", "ERPEnv", "ERPNavEnv", "ExpertPolicy", "OBS_KEYS"]
