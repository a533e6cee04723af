"""Proprioception: what the robot of a scene knows of itself, one vector per state.

    from sebvs.sim.proprio import proprio_reader
    reader = proprio_reader("nav", scene, model)
    reader.names          # ("v_forward", "v_lateral", "yaw_rate")
    reader.read(data)     # float64 (3,)

One definition for the two places that give it out: the Gymnasium environments'
observation key "proprio" (sebvs/envs/erp.py) and the sim actor's output `proprio`, which
the recorder stores per control tick (the dataset `proprio`, docs/data.md), so an env's
observation and a recorded row of the same tick are the same numbers, and a
robot-learning dataset's `observation.state` can be filled from a recording.

    nav  the drive's odometry in the robot's frame: forward and lateral speed (m/s) and
         yaw rate (rad/s), from the base's planar joints x, y, yaw
    arm  the UR5's six joint angles (rad) and the two fingers' positions (m)
    mjcf every joint's qpos, then its qvel (sebvs/sim/mjcf_scene.py: anyone's model)
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, eq=False)
class ProprioReader:
    """Reads one scene's proprioception from an MjData of its model.

    names: one per component, in order; lo, hi: the bounds an observation space takes
    (beyond them the sim has ended the episode: a divergence, or a joint past its limit's
    soft margin).
    """
    names: tuple[str, ...]
    lo: np.ndarray
    hi: np.ndarray
    _read: Callable[[object], np.ndarray]

    def read(self, data) -> np.ndarray:
        """The proprioception of one state.

        Parameters:
            data: an MjData of the model the reader was built for.

        Returns:
            float64 (len(names),).
        """
        return self._read(data)


def _nav(scene, model) -> ProprioReader:
    dof = [int(model.jnt_dofadr[model.joint(n).id]) for n in ("x", "y", "yaw")]

    def read(data) -> np.ndarray:
        vx, vy, w = (float(data.qvel[i]) for i in dof)
        yaw = scene.robot_pose(data)[2]
        c, s = math.cos(yaw), math.sin(yaw)
        # world-frame velocities turned into the robot's: what wheel odometry measures
        return np.array([c * vx + s * vy, -s * vx + c * vy, w], np.float64)

    lim = scene.limits()
    hi = np.array([lim.max_speed, lim.max_speed, lim.max_angular], np.float64)
    return ProprioReader(("v_forward", "v_lateral", "yaw_rate"), -hi, hi, read)


def _arm(scene, model) -> ProprioReader:
    from .arm_model import JOINTS
    adr = np.concatenate([scene.arm_qadr, scene.finger_qadr]).astype(int)
    qadr_to_joint = {int(model.jnt_qposadr[j]): j for j in range(model.njnt)}
    rng = np.array([model.jnt_range[qadr_to_joint[int(a)]] for a in adr], np.float64)

    def read(data) -> np.ndarray:
        return np.array(data.qpos[adr], np.float64)

    # a joint's limit is a soft constraint: the margin keeps a state pressed against it
    # inside the bounds
    return ProprioReader((*JOINTS, "finger_l", "finger_r"), rng[:, 0] - 0.1, rng[:, 1] + 0.1,
                         read)


def _mjcf(scene, model) -> ProprioReader:
    return scene.proprio_reader(model)


READERS = {"nav": _nav, "arm": _arm, "mjcf": _mjcf}


def proprio_reader(scene_name: str, scene, model) -> ProprioReader:
    """The reader of scene `scene_name` ("nav" | "arm" | "mjcf"), built once per compiled model.

    Parameters:
        scene_name: the scene's name in sebvs.sim.SCENES.
        scene: the Scene instance whose model this is.
        model: its compiled MjModel.

    Returns:
        The ProprioReader. ValueError, in one line, for a scene that has none.
    """
    build = READERS.get(scene_name)
    if build is None:
        raise ValueError(f"scene {scene_name!r} has no proprioception (known: "
                         f"{', '.join(READERS)})")
    return build(scene, model)
