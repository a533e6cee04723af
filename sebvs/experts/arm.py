"""The arm expert (paper's "YOLO + MoveIt" pick module): wrist-camera RGB + depth -> a 6-DoF
pre-grasp pose [x, y, z, roll, pitch, yaw] (m, rad, world frame) hovering above the cube.

Geometry:
  1. The detector segments the cube colour; every blob pixel is back-projected with its
     depth through the pinhole camera (f = H / (2 tan(fovy / 2)) px, MuJoCo's camera looks
     along its -z with +x right and +y up; the depth image holds the distance along the
     view axis, as MuJoCo's depth render does).
  2. The cube's top face is the set of back-projected points within `top_band` of the
     highest one. Its centroid is the cube's (x, y) (the top face is centred on the cube
     whatever the viewing angle; the side faces a slanted view also sees are left out), its
     height the cube's top z.
  3. Yaw: the minimum-area rectangle of the top-face points in the world xy plane, its angle
     folded into the cube's 90 deg symmetry, [-pi/4, pi/4). The gripper closes along the
     cube's sides either way.
  4. Pose: (x, y, top z + clearance, roll, pitch, yaw + yaw_offset) with the gripper pointing
     down (roll/pitch from the config: they depend on the end-effector frame of the arm
     model). HOME_POSE when nothing is detected or the object lies beyond the workspace
     (world y > y_limit, the paper's 0.449 m rule).
  5. Several cubes: the leftmost one in the image (smallest u of the blob centroid) unless the
     config says otherwise; a scene can define it through `ArmCameraModel.scene_constants`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from sebvs.sim.arm import fold_yaw

from .detector import ColorDetector, Detection

# The paper's workspace rule: objects beyond this world y get HOME_POSE.
Y_LIMIT = 0.449
# Fallback home pose; the arm scene's own HOME (if it exports one) replaces it.
HOME_POSE = (0.3, 0.0, 0.45, math.pi, 0.0, 0.0)


@dataclass
class CameraPose:
    """A pinhole camera in the world.

    pos (3,) m; mat (3, 3) columns = camera x (right), y (up), z (backward) axes in world
    (MuJoCo's data.cam_xmat reshaped); fovy deg (vertical); width, height px.
    """
    pos: np.ndarray
    mat: np.ndarray
    fovy: float
    width: int
    height: int

    @property
    def f(self) -> float:
        """Focal length in px."""
        return 0.5 * self.height / math.tan(math.radians(self.fovy) / 2)

    def backproject(self, u: np.ndarray, v: np.ndarray, depth: np.ndarray) -> np.ndarray:
        """Pixel coordinates (continuous, pixel centres at i + 0.5) and view-axis depth (m)
        -> (N, 3) world points."""
        u, v, d = (np.asarray(a, np.float64).reshape(-1) for a in (u, v, depth))
        pc = np.stack([(u - self.width / 2) / self.f * d,
                       -(v - self.height / 2) / self.f * d,
                       -d], axis=1)
        return self.pos[None, :] + pc @ np.asarray(self.mat).T

    def project(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) world points -> (N, 2) pixel coordinates."""
        pc = (np.asarray(points, np.float64) - self.pos) @ np.asarray(self.mat)
        d = -pc[:, 2]
        return np.stack([self.width / 2 + self.f * pc[:, 0] / d,
                         self.height / 2 - self.f * pc[:, 1] / d], axis=1)


@dataclass
class ArmExpertConfig:
    """clearance m above the cube's top face; top_band m (which points count as the top
    face); roll/pitch rad of a downward-pointing gripper and yaw_offset rad between the cube's
    edge and the gripper's yaw (end-effector frame conventions of the arm model); home: the
    pose when there is nothing to grasp; y_limit m (paper: 0.449); leftmost "image_u" |
    "world_x" | "world_y" (smallest wins) or "-world_y" etc. (largest wins)."""
    clearance: float = 0.10
    top_band: float = 0.008
    roll: float = math.pi
    pitch: float = 0.0
    yaw_offset: float = 0.0
    home: tuple = HOME_POSE
    y_limit: float = Y_LIMIT
    leftmost: str = "image_u"
    max_depth: float = 5.0          # m: depth beyond is background / far plane


@dataclass
class ObjectEstimate:
    """A cube seen by the wrist camera: top-face centre (world, m), yaw (rad, folded), the
    detection and the number of top-face points used."""
    position: np.ndarray
    yaw: float
    detection: Detection
    points: int
    extra: dict = field(default_factory=dict)


def estimate_object(det: Detection, mask: np.ndarray, depth: np.ndarray, cam: CameraPose,
                    cfg: ArmExpertConfig) -> ObjectEstimate | None:
    """World top-face centre and yaw of the blob `det` (pixels: mask within its bbox)."""
    x, y, w, h = det.bbox
    sub = mask[y:y + h, x:x + w] > 0
    d = depth[y:y + h, x:x + w]
    ok = sub & np.isfinite(d) & (d > 0) & (d < cfg.max_depth)
    vs, us = np.nonzero(ok)
    if len(us) < 3:
        return None
    pts = cam.backproject(us + x + 0.5, vs + y + 0.5, d[vs, us])
    top = pts[pts[:, 2] >= pts[:, 2].max() - cfg.top_band]
    if len(top) < 3:
        top = pts
    centre = top.mean(axis=0)
    centre[2] = float(np.median(top[:, 2]))
    # minAreaRect on the top face in world xy (mm: float32 keeps sub-mm precision)
    (_, _), (rw, rh), ang = cv2.minAreaRect((top[:, :2] * 1000.0).astype(np.float32))
    yaw = fold_yaw(math.radians(ang))
    return ObjectEstimate(position=centre, yaw=yaw, detection=det, points=int(len(top)),
                          extra={"rect_mm": [float(rw), float(rh)]})


def _leftmost_key(cfg: ArmExpertConfig):
    sign, key = (-1.0, cfg.leftmost[1:]) if cfg.leftmost.startswith("-") else (1.0, cfg.leftmost)
    if key == "image_u":
        return lambda o: sign * o.detection.centroid[0]
    axis = {"world_x": 0, "world_y": 1}.get(key)
    if axis is None:
        raise ValueError(f"arm expert: leftmost {cfg.leftmost!r} is not image_u, world_x, "
                         f"world_y (optionally with a leading '-')")
    return lambda o: sign * float(o.position[axis])


def pregrasp_pose(obj: ObjectEstimate, cfg: ArmExpertConfig) -> np.ndarray:
    """[x, y, z, roll, pitch, yaw] float32 hovering `clearance` above the top face."""
    x, y, z = (float(c) for c in obj.position)
    return np.array([x, y, z + cfg.clearance, cfg.roll, cfg.pitch,
                     fold_yaw(obj.yaw + cfg.yaw_offset)], dtype=np.float32)


def pregrasp_from_images(rgb: np.ndarray, depth: np.ndarray, cam: CameraPose,
                         detector: ColorDetector, cfg: ArmExpertConfig | None = None
                         ) -> tuple[np.ndarray, Detection | None, str]:
    """The expert's answer for one frame: (pose float32[6], chosen detection or None, mode).

    mode: "grasp" (a pre-grasp pose), "home_none" (nothing detected), "home_workspace"
    (the chosen object lies beyond y_limit).
    """
    cfg = cfg or ArmExpertConfig()
    home = np.asarray(cfg.home, dtype=np.float32)
    dets = detector.detect_all(rgb)
    if not dets:
        return home.copy(), None, "home_none"
    mask = detector.mask(rgb)
    objs = [o for o in (estimate_object(d, mask, depth, cam, cfg) for d in dets) if o is not None]
    if not objs:
        return home.copy(), dets[0], "home_none"
    obj = min(objs, key=_leftmost_key(cfg))
    if obj.position[1] > cfg.y_limit:
        return home.copy(), obj.detection, "home_workspace"
    return pregrasp_pose(obj, cfg), obj.detection, "grasp"


class TargetLead:
    """Where a moving target will be ``lead_s`` from now, for a pose that is acted on later.

    The arm's last command is grasped one control period after its image, when the belt
    stops: a cube on a 25 cm/s belt has moved 2.5 cm by then. The velocity comes from the
    target's positions at consecutive control ticks (a belt-tracking pick cell estimates
    it the same way); a jump faster than ``max_speed`` is another object becoming the
    target, or a misdetection, and keeps the previous velocity, as does a tick without a
    target. Every cube rides the same belt, so the velocity carries over a change of
    target. lead_s 0 leaves poses unchanged.
    """

    def __init__(self, lead_s: float = 0.0, max_speed: float = 0.5):
        if not (math.isfinite(lead_s) and lead_s >= 0):
            raise ValueError(f"lead_s must be a finite number >= 0, got {lead_s!r}")
        if not (math.isfinite(max_speed) and max_speed > 0):
            raise ValueError(f"max_speed must be a finite number > 0, got {max_speed!r}")
        self.lead_s, self.max_speed = lead_s, max_speed
        self.reset()

    def reset(self) -> None:
        """A new episode: nothing seen, no velocity."""
        self.velocity = np.zeros(2)
        self._last: tuple[float, np.ndarray] | None = None

    def update(self, t: float, xy) -> np.ndarray:
        """The target's world (x, y) in m at time t s, or None when there is none; returns
        the (x, y) offset to add to its pose."""
        if xy is None:
            self._last = None
            return np.zeros(2)
        # a copy: callers shift the pose this may be a view of by the returned offset
        xy = np.array(xy, np.float64)[:2]
        if self._last is not None:
            t0, xy0 = self._last
            dt = t - t0
            if dt > 0:
                v = (xy - xy0) / dt
                if float(np.hypot(*v)) <= self.max_speed:
                    self.velocity = v
        self._last = (t, xy)
        return self.velocity * self.lead_s


def leading_poses(poses, modes, times, lead_s: float) -> np.ndarray:
    """One episode's poses [T, 6], each grasp pose led as the expert leads its own
    (TargetLead over the ticks in order; actors/expert.py): [T, 6] float64.

    ``modes`` [T] says which ticks aim at a target ("grasp"); the others keep their pose
    and break the velocity estimate as a tick without a target does. ``times`` [T] s.
    lead_s 0 returns the poses unchanged. The arm tracker scores poses against this with
    the lead the labels were made with, not against where the cube is at the tick.
    """
    out = np.array(poses, np.float64).reshape(-1, 6)
    if len(modes) != len(out) or len(times) != len(out):
        raise ValueError(f"{len(out)} poses, {len(modes)} modes, {len(times)} times: "
                         f"one of each per tick")
    lead = TargetLead(lead_s)
    if lead_s == 0:
        return out
    for k, (mode, t) in enumerate(zip(modes, times)):
        out[k, :2] += lead.update(float(t), out[k, :2] if mode == "grasp" else None)
    return out


class ArmCameraModel:
    """The wrist camera's pose from the sim's state, with the expert's own copy of the arm
    model (compiled from the sim's scene + config, like the camera actor's)."""

    def __init__(self, scene_name: str, config: dict, camera: str = "") -> None:
        from sebvs.sim import make_scene
        import mujoco
        self._mj = mujoco
        self.scene = make_scene(scene_name, **config)
        self.model = self.scene.compile()
        self.data = mujoco.MjData(self.model)
        self.camera = camera or self.scene.cameras[0]
        self.cam_id = self.model.camera(self.camera).id
        self.height, self.width = self.scene.image_shape()

    def camera_pose(self, state: dict) -> CameraPose:
        self.scene.set_state(self.model, self.data, state)
        self.scene.kinematics(self.model, self.data)
        return CameraPose(pos=self.data.cam_xpos[self.cam_id].copy(),
                          mat=self.data.cam_xmat[self.cam_id].reshape(3, 3).copy(),
                          fovy=float(self.model.cam_fovy[self.cam_id]),
                          width=self.width, height=self.height)

    def scene_constants(self) -> dict:
        """ArmExpertConfig overrides the arm scene module exports, if it does: HOME_POSE,
        Y_LIMIT (workspace rule), LEFTMOST (which object counts as leftmost)."""
        import importlib
        mod = importlib.import_module(type(self.scene).__module__)
        out = {}
        for name, key in (("HOME_POSE", "home"), ("Y_LIMIT", "y_limit"),
                          ("WORKSPACE_Y_MAX", "y_limit"), ("LEFTMOST", "leftmost")):
            if hasattr(mod, name):
                out[key] = getattr(mod, name)
        return out
