"""Scene states between two samples: what a sensor integrating over an exposure renders.

The sim sends states (Scene.state(): qpos, mocap_pos, mocap_quat, light) at its render
rate; a frame camera's exposure needs poses at times in between. qpos moves along the
joints' own geometry (MuJoCo's mj_differentiatePos / mj_integratePos: hinge and slide
linearly, ball and free joints' quaternions on the sphere), mocap positions and the
light's scale linearly, mocap quaternions by normalised linear interpolation (the
sub-frame steps are small).
"""
from __future__ import annotations

import bisect

import mujoco
import numpy as np


def interpolate_state(model: mujoco.MjModel, a: dict, b: dict, alpha: float) -> dict:
    """The state a fraction `alpha` in [0, 1] of the way from `a` to `b`."""
    alpha = float(min(max(alpha, 0.0), 1.0))
    qvel = np.zeros(model.nv)
    mujoco.mj_differentiatePos(model, qvel, 1.0, a["qpos"], b["qpos"])
    qpos = np.array(a["qpos"], dtype=np.float64)
    mujoco.mj_integratePos(model, qpos, qvel, alpha)
    out = {"qpos": qpos,
           "mocap_pos": (1 - alpha) * a["mocap_pos"] + alpha * b["mocap_pos"]}
    qa, qb = np.asarray(a["mocap_quat"]), np.asarray(b["mocap_quat"])
    # the shorter way round: q and -q are one rotation
    sign = np.where(np.sum(qa * qb, axis=-1, keepdims=True) < 0, -1.0, 1.0)
    q = (1 - alpha) * qa + alpha * sign * qb
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
    out["mocap_quat"] = np.divide(q, norm, out=np.array(qa, dtype=np.float64),
                                  where=norm > 0)
    if "light" in a and "light" in b:
        out["light"] = (1 - alpha) * a["light"] + alpha * b["light"]
    return out


class StateHistory:
    """The recent states of one episode by time, and the state at any time between them
    (clamped to the oldest and newest kept)."""

    def __init__(self, keep_s: float) -> None:
        self.keep_s = float(keep_s)
        self.times: list[float] = []
        self.states: list[dict] = []

    def clear(self) -> None:
        self.times.clear()
        self.states.clear()

    def add(self, t: float, state: dict) -> None:
        """Keep a copy of `state` (its arrays may be views of a reused buffer)."""
        if self.times and t <= self.times[-1]:
            if t == self.times[-1]:
                return
            self.clear()                         # time went back: a new stream
        self.times.append(float(t))
        self.states.append({k: np.array(v) for k, v in state.items()})
        cut = bisect.bisect_left(self.times, t - self.keep_s)
        if cut > 1:                              # keep one state older than the window
            del self.times[:cut - 1], self.states[:cut - 1]

    def at(self, model: mujoco.MjModel, t: float) -> dict:
        if not self.times:
            raise LookupError("no state kept yet")
        i = bisect.bisect_right(self.times, t)
        if i == 0:
            return self.states[0]
        if i == len(self.times):
            return self.states[-1]
        t0, t1 = self.times[i - 1], self.times[i]
        return interpolate_state(model, self.states[i - 1], self.states[i],
                                 (t - t0) / (t1 - t0))
