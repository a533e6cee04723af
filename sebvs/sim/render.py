"""Offscreen rendering into caller-provided arrays (e.g. shared-memory slots).

MUJOCO_GL must be set before `mujoco` is first imported, so this module sets it (only if
the user has not): "egl" (Debian libegl1 libegl-mesa0 libgl1-mesa-dri libopengl0).
"osmesa" (libosmesa6) works as well and renders at the same speed on llvmpipe; choose it
with `MUJOCO_GL=osmesa` in the environment. Import this module before anything imports
mujoco (sebvs.sim.scene does) in a process that renders.

Speed: scenes carry `<quality offsamples="0" shadowsize="0"/>` and shadowless lights;
MuJoCo's defaults (4x MSAA, 4096 shadow map) are 20-40x slower on a CPU renderer.

Arrays (row 0 is the top of the image):
  rgb           (H, W, 3) uint8
  luma          (H, W) uint8, ITU-R 601 luma of the RGB render (cv2 RGB2GRAY)
  depth         (H, W) float32, metres
  segmentation  (H, W, 2) int32: object id, object type (mjtObj), -1 where empty
"""
from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")

import cv2  # noqa: E402
import mujoco  # noqa: E402
import numpy as np  # noqa: E402


class FrameRenderer:
    """A mujoco.Renderer of one size, rendering named cameras into given arrays.

    Use as a context manager (or call close()): it owns a GL context.
        with FrameRenderer(model, 160, 160) as r:
            r.update(data, "front")
            r.rgb(out_rgb); r.luma(out_luma, src=out_rgb)   # one render serves both
    """

    def __init__(self, model: mujoco.MjModel, height: int, width: int) -> None:
        self.model = model
        self.height, self.width = int(height), int(width)
        self._r = mujoco.Renderer(model, self.height, self.width)
        self._scratch = np.empty((self.height, self.width, 3), np.uint8)
        self._acc: np.ndarray | None = None
        self._mode = "rgb"

    # -- lifecycle ------------------------------------------------------------------
    def close(self) -> None:
        if self._r is not None:
            self._r.close()
            self._r = None

    def __enter__(self) -> "FrameRenderer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- rendering ------------------------------------------------------------------
    def _set_mode(self, mode: str) -> None:
        if mode == self._mode:
            return
        r = self._r
        r.disable_depth_rendering()
        r.disable_segmentation_rendering()
        if mode == "depth":
            r.enable_depth_rendering()
        elif mode == "seg":
            r.enable_segmentation_rendering()
        self._mode = mode

    def update(self, data: mujoco.MjData, camera: str | int) -> None:
        """Pose the scene from `data` (its kinematics must be current) for `camera`."""
        self._r.update_scene(data, camera=camera)

    def rgb(self, out: np.ndarray | None = None) -> np.ndarray:
        """Render RGB into `out` ((H, W, 3) uint8, C-contiguous) or a new array."""
        self._set_mode("rgb")
        if out is None:
            out = np.empty((self.height, self.width, 3), np.uint8)
        self._r.render(out=out)
        return out

    def luma(self, out: np.ndarray | None = None, src: np.ndarray | None = None) -> np.ndarray:
        """Luma (H, W) uint8 of `src` (an RGB render of the current pose, when the caller
        has one: MuJoCo renders colour anyway, and the conversion of 160x160 costs ~20 us),
        else of a fresh render."""
        if out is None:
            out = np.empty((self.height, self.width), np.uint8)
        if src is None:
            src = self.rgb(self._scratch)
        cv2.cvtColor(src, cv2.COLOR_RGB2GRAY, dst=out)
        return out

    def depth(self, out: np.ndarray | None = None) -> np.ndarray:
        """Depth (H, W) float32 in metres."""
        self._set_mode("depth")
        if out is None:
            out = np.empty((self.height, self.width), np.float32)
        self._r.render(out=out)
        return out

    def segmentation(self, out: np.ndarray | None = None) -> np.ndarray:
        """Segmentation (H, W, 2) int32: [object id, object type]; -1 for background."""
        self._set_mode("seg")
        if out is None:
            out = np.empty((self.height, self.width, 2), np.int32)
        self._r.render(out=out)
        return out

    def rgb_blurred(self, data: mujoco.MjData, camera: str | int, poses, out: np.ndarray,
                    pose_fn) -> np.ndarray:
        """Motion-blurred RGB: the mean of one render per sub-frame pose.

        poses    sequence of scene states (oldest first) within the exposure
        pose_fn  callable(state) that writes a state into `data` and updates kinematics
        out      (H, W, 3) uint8. The event path never uses this.
        """
        if self._acc is None:
            self._acc = np.empty((self.height, self.width, 3), np.uint16)
        self._acc[...] = 0
        n = 0
        for state in poses:
            pose_fn(state)
            self.update(data, camera)
            self.rgb(self._scratch)
            self._acc += self._scratch
            n += 1
        self._acc += n // 2                       # round to nearest, in place
        np.floor_divide(self._acc, max(n, 1), out=self._acc)
        out[...] = self._acc
        return out
