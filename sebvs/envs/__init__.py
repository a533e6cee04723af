"""SEBVS's scenes and event sensor as Gymnasium environments (docs/envs.md).

    import gymnasium as gym
    import sebvs.envs                                     # registers the two ids
    env = gym.make("SEBVS/ERPNav-v1", condition="dusk", obs=("rgb", "events"))
    obs, info = env.reset(seed=3)          # episode 0 of `sebvs eval --seed 3`'s lockstep run

SEBVS/ERPNav-v1   the nav robot follows the red cube (ERPNavEnv)
SEBVS/ERPArm-v1   the UR5's pre-grasp pose above a cube on the conveyor (ERPArmEnv)

v1 runs the default sensor pair (physical) in its nominal condition unless told otherwise;
v0 is the same environment defaulting to the 8-bit benchmark's nominal condition, as v0
always did. A condition named to either runs as named.

The step runs the topologies' own scene, camera, emulator and accumulator code in this
process (sebvs.sim.stepper, sebvs.sensors.camera, sebvs.dvs.stream). Needs the optional
extra: pip install 'sebvs[gym]'.
"""
from sebvs.extras import require

# one line naming the extra, not a traceback, when gymnasium is not installed
gymnasium = require("gymnasium", "gymnasium", "gym", "sebvs.envs")

from sebvs.sensor_pairs import DEFAULT_CONDITION  # noqa: E402

from .erp import ERPArmEnv, ERPEnv, ERPNavEnv, OBS_KEYS  # noqa: E402
from .expert import ExpertPolicy  # noqa: E402
from .wrapper import EventCameraWrapper  # noqa: E402,F401  (light: sensors load on use)

ENV_IDS = {"nav": "SEBVS/ERPNav-v1", "arm": "SEBVS/ERPArm-v1"}
ENV_IDS_IDEAL8 = {"nav": "SEBVS/ERPNav-v0", "arm": "SEBVS/ERPArm-v0"}

for _task in ENV_IDS:
    _entry = f"sebvs.envs.erp:ERP{_task.capitalize()}Env"
    # N scenes in one process (sebvs/envs/vector.py): make_vec's "vector_entry_point" mode
    _vector_entry = f"sebvs.envs.vector:ERP{_task.capitalize()}VectorEnv"
    for _id, _kwargs in ((ENV_IDS[_task], {}),
                         (ENV_IDS_IDEAL8[_task], {"condition": DEFAULT_CONDITION["ideal8"]})):
        if _id not in gymnasium.registry:
            gymnasium.register(id=_id, entry_point=_entry, vector_entry_point=_vector_entry,
                               kwargs=_kwargs)

__all__ = ["ENV_IDS", "ENV_IDS_IDEAL8", "ERPArmEnv", "ERPEnv", "ERPNavEnv", "ExpertPolicy",
           "OBS_KEYS"]
