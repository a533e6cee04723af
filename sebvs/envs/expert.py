"""The expert of `sebvs eval`'s reference row, driving an environment (sebvs.envs).

    env = gymnasium.make("SEBVS/ERPArm-v1", privileged=True)
    expert = ExpertPolicy(env)
    obs, info = env.reset(seed=3)
    while True:
        obs, reward, terminated, truncated, info = env.step(expert(obs, info))
        if terminated or truncated:
            break

It reads the expert's inputs from the privileged info (the ideal 8-bit render, the arm's
depth and state) and acts with the expert actor's own code (sebvs.experts.agent) and
parameters (topologies/nav_expert.toml, arm_expert.toml), so it commands what the expert
actor commands on the same frames.
"""
from __future__ import annotations

import numpy as np


class ExpertPolicy:
    """obs, info -> the expert's command for that tick (float32)."""

    def __init__(self, env) -> None:
        from sebvs.experts.agent import ExpertAgent
        base = getattr(env, "unwrapped", env)
        if not getattr(base, "privileged", False):
            raise ValueError("the expert reads the privileged view: make the environment "
                             "with privileged=True")
        self.env = base
        self.agent = ExpertAgent(base.settings["expert"])

    def __call__(self, obs, info: dict) -> np.ndarray:
        agent = self.agent
        dt = agent.new_tick(info["episode_index"], info["t_ep"], info["t_sim"])
        if self.env.task == "nav":
            return agent.nav_act(info["ideal"], dt)[0]
        sim = self.env.sim
        arm = agent.arm_camera(sim.scene_name, sim.config)
        return agent.arm_act(info["ideal"], info["depth"], arm, info["state"])[0]
