"""The expert actor's per-tick logic without its messaging: detector + nav PID follower, or
detector + arm pre-grasp pose with its lead on a moving cube.

actors/expert.py wires this to the runtime; sebvs.envs.ExpertPolicy drives a Gymnasium
environment with it. One code path, so the expert acts the same in both for the same
frames.

    agent = ExpertAgent(params)                 # the expert actor's Params fields
    dt = agent.new_tick(episode, t_ep, t_sim)   # episode bookkeeping, s since the last tick
    cmd, det, mode = agent.nav_act(rgb, dt)     # nav: [v, w]
    pose, det, mode = agent.arm_act(rgb, depth, agent.arm_camera(scene, config), state)
"""
from __future__ import annotations

import math

import numpy as np

from .detector import ColorDetector


def make_detector(p) -> ColorDetector:
    """The colour detector of the expert's parameters (color, hue_tol, s_min, c_min,
    min_area)."""
    if len(p.color) != 3:
        raise ValueError(f"expert: color must be [r, g, b], got {p.color!r}")
    return ColorDetector(rgb=tuple(float(c) for c in p.color), hue_tol=p.hue_tol,
                         s_min=p.s_min, c_min=p.c_min, min_area=p.min_area)


def nav_config(p):
    """NavExpertConfig of the expert's parameters."""
    from .nav import NavExpertConfig
    from .pid import PIDGains
    return NavExpertConfig(
        yaw=PIDGains(kp=p.yaw_kp, ki=p.yaw_ki, kd=p.yaw_kd, i_min=-0.4, i_max=0.4,
                     tau_d=0.05, anti_windup=p.anti_windup),
        speed=PIDGains(kp=p.speed_kp, ki=p.speed_ki, kd=p.speed_kd, i_min=-0.3, i_max=0.3,
                       anti_windup=p.anti_windup),
        desired_width=p.desired_width, turn_slowdown=p.turn_slowdown, hold_s=p.hold_s,
        search_w=p.search_w)


class ExpertAgent:
    """One expert (task "nav" or "arm") over a run's episodes."""

    def __init__(self, params) -> None:
        self.params = params
        self.detector = make_detector(params)
        self.episode = None
        self.last_t: float | None = None
        if params.task == "nav":
            from .nav import NavExpert
            self.nav = NavExpert(nav_config(params))
        else:
            from .arm import TargetLead
            self.lead = TargetLead(params.lead_s)
            self.arm = None                 # built from the sim's scene + config
            self.arm_key = None

    def reconfigure(self) -> None:
        """The parameters changed: detector, gains and lead from them (PID state and the
        lead's velocity estimate kept)."""
        self.detector = make_detector(self.params)
        if self.params.task == "nav":
            cfg = nav_config(self.params)
            self.nav.cfg = cfg
            self.nav.yaw_pid.g, self.nav.speed_pid.g = cfg.yaw, cfg.speed
        else:
            self.lead.lead_s = self.params.lead_s

    def new_tick(self, episode, t_ep, t_sim: float | None) -> float:
        """Episode bookkeeping; returns dt (s) since the previous control tick."""
        # the episode's own clock when the frame carries it: t_sim counts from the start of
        # the run, and a difference of two large times rounds with that offset, so an
        # episode played by another worker (another offset) got dt, and so actions, a few
        # ulps apart (3 of 70 episodes of a 2-worker recording, `sebvs data compare`)
        t = t_ep
        if isinstance(t, bool) or not isinstance(t, (int, float)) or not math.isfinite(t):
            t = t_sim
        if episode != self.episode or self.last_t is None or t is None:
            self.episode = episode
            if self.params.task == "nav":
                self.nav.reset()
            else:
                self.lead.reset()
            dt = 1.0 / self.params.control_hz
        else:
            dt = t - self.last_t
            if not dt > 0:
                dt = 1.0 / self.params.control_hz
        self.last_t = t
        return dt

    def nav_act(self, rgb: np.ndarray, dt: float):
        """(command float32 [v, w], detection or None, mode) for one frame."""
        det = self.detector.detect(rgb)
        cmd = self.nav.act(det, (rgb.shape[1], rgb.shape[0]), dt)
        return cmd, det, self.nav.mode

    def arm_camera(self, scene: str, config: dict):
        """The wrist camera's model for the sim's scene + config (kept while they hold)."""
        if (scene, config) != self.arm_key:
            from .arm import ArmCameraModel
            self.arm = ArmCameraModel(scene, config, camera=self.params.camera)
            self.arm_key = (scene, config)
        return self.arm

    def arm_act(self, rgb: np.ndarray, depth: np.ndarray, arm, state: dict):
        """(pose float32 [6], detection or None, mode) for one tick's wrist frames and the
        arm's state, led by lead_s on a moving cube (after new_tick)."""
        from .arm import ArmExpertConfig, pregrasp_from_images
        cam = arm.camera_pose(state)
        pose, det, mode = pregrasp_from_images(
            rgb, depth, cam, self.detector,
            ArmExpertConfig(clearance=self.params.clearance, **arm.scene_constants()))
        if self.lead.lead_s > 0:
            pose[:2] += self.lead.update(self.last_t, pose[:2] if mode == "grasp" else None)
        return pose, det, mode
