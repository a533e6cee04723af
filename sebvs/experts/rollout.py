"""Closed-loop navigation episodes in one process (no actors): scene physics + front-camera
render + detector + expert, for tests and tools/checks/expert_study.py.

The loop mirrors the sim actor's lockstep order: at each control tick the truth and the
frame are taken of the current state, the expert's command is applied, then the scene is
stepped for one control period (scripted target motion before every mj_step).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from sebvs.sim import make_scene  # sets MUJOCO_GL before mujoco is imported
from sebvs.sim.render import FrameRenderer

import mujoco  # noqa: E402

from ..metrics import nav_episode_metrics  # noqa: E402
from .detector import ColorDetector  # noqa: E402
from .nav import NavExpert, NavExpertConfig  # noqa: E402


@dataclass
class NavEpisode:
    """What one episode gave. Per control tick: truth centroid/bbox, detection (or None),
    command; and the paper's Table 4 metrics of the whole episode."""
    seed: int
    metrics: dict
    truth: list = field(default_factory=list)        # scene.truth() per tick
    detections: list = field(default_factory=list)   # Detection | None per tick
    commands: np.ndarray | None = None               # [T, 2]
    frames: list = field(default_factory=list)       # RGB frames, if keep_frames


def detection_errors(truth: list, detections: list) -> dict[str, np.ndarray]:
    """Per frame where both the truth says visible (box fully inside the image) and the
    detector found something: centroid error (px, Euclidean), bbox edge error (px, the
    largest of the 4 edges' absolute differences). Also the miss / false-alarm counts."""
    cerr, berr, miss, false = [], [], 0, 0
    for t, d in zip(truth, detections):
        if not t["visible"]:
            false += d is not None
            continue
        if d is None:
            miss += 1
            continue
        w, h = t["image"]
        u0, v0, u1, v1 = t["bbox"]
        if u0 <= 0 or v0 <= 0 or u1 >= w or v1 >= h:
            continue        # cut by the image border: the projected centre is off the blob
        x, y, bw, bh = d.bbox
        cerr.append(float(np.hypot(d.centroid[0] - t["centroid"][0],
                                   d.centroid[1] - t["centroid"][1])))
        berr.append(max(abs(x - u0), abs(y - v0), abs(x + bw - u1), abs(y + bh - v1)))
    return {"centroid": np.array(cerr), "bbox": np.array(berr), "misses": miss,
            "false_alarms": false}


def run_nav_episode(seed: int, *, episode_s: float = 12.0, control_hz: float = 10.0,
                    physics_hz: float = 1000.0, integrator: str = "discrete",
                    config: dict | None = None,
                    expert: NavExpert | None = None, detector: ColorDetector | None = None,
                    keep_frames: bool = False, drive: bool = True) -> NavEpisode:
    """One seeded episode of the nav scene driven by the expert.

    config: nav scene config (default 160x160 indoor nominal); physics as in
    topologies/nav_expert.toml (discrete integrator, 1 kHz); drive=False sends zero
    commands (an open-loop view for detector checks). Returns a NavEpisode.
    """
    cfg = {"width": 160, "height": 160, **(config or {}), "timestep": 1.0 / physics_hz,
           "integrator": integrator}
    scene = make_scene("nav", **cfg)
    model = scene.compile()
    data = mujoco.MjData(model)
    scene.reset(model, data, np.random.default_rng(seed))
    expert = expert or NavExpert(NavExpertConfig())
    expert.reset()
    detector = detector or ColorDetector()
    h, w = scene.image_shape()
    steps = int(round(physics_hz / control_hz))
    dt = steps / physics_hz
    n_ticks = int(round(episode_s * control_hz))
    ep = NavEpisode(seed=seed, metrics={})
    cmds = np.zeros((n_ticks, 2), np.float32)
    frame = np.empty((h, w, 3), np.uint8)
    with FrameRenderer(model, h, w) as r:
        for k in range(n_ticks):
            truth = scene.truth(model, data)        # runs the kinematics the render needs
            r.update(data, "front")
            r.rgb(frame)
            det = detector.detect(frame)
            cmd = expert.act(det, (w, h), dt) if drive else np.zeros(2, np.float32)
            scene.apply_command(model, data, cmd)
            ep.truth.append(truth)
            ep.detections.append(det)
            cmds[k] = cmd
            if keep_frames:
                ep.frames.append(frame.copy())
            for _ in range(steps):
                scene.scripted(model, data)
                mujoco.mj_step(model, data)
    ep.commands = cmds
    cents = np.array([t["centroid"] for t in ep.truth], np.float64)
    widths = np.array([t["bbox"][2] - t["bbox"][0] for t in ep.truth], np.float64)
    vis = np.array([t["visible"] for t in ep.truth], bool)
    ep.metrics = nav_episode_metrics(cents, widths, vis, (w, h), n_ticks / control_hz).as_dict()
    return ep
