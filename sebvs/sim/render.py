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


class _Canvas:
    """One GL context, the current model's MjrContext and the posed scene: what the
    renderers of several sizes sharing it (FrameRenderer.view) draw from."""

    def __init__(self, max_geom: int, gl=None) -> None:
        """gl: another canvas's GL context to draw in (kept open by that canvas; the
        tiled renderer's models share one, sebvs.sim.tiles), else a context of its own."""
        from mujoco import gl_context
        if gl_context.GLContext is None:
            raise RuntimeError(f"no offscreen GL for MUJOCO_GL={os.environ.get('MUJOCO_GL')!r}")
        self.owns_gl = gl is None
        # the context's own surface is never drawn to: renders go to the model's
        # offscreen buffer (<visual><global offwidth offheight>)
        self.gl = gl_context.GLContext(1, 1) if gl is None else gl
        self.gl.make_current()
        self.max_geom = max_geom
        self.option = mujoco.MjvOption()
        self.camera = mujoco.MjvCamera()
        self.ctx: mujoco.MjrContext | None = None
        self.sizes: list[tuple[int, int]] = []     # (height, width) of every renderer on it

    def check(self, model: mujoco.MjModel, height: int, width: int) -> None:
        g = model.vis.global_
        if g.offwidth < width or g.offheight < height:
            raise ValueError(f"the model's offscreen buffer is {g.offwidth}x{g.offheight}, "
                             f"smaller than the {width}x{height} render: raise "
                             f"<visual><global offwidth=... offheight=...> in its XML")

    def unclamp_lighting(self) -> None:
        """Stop GL clamping lit vertex colours to [0, 1] before textures modulate them.

        MuJoCo draws with the fixed-function pipeline, which by default clamps the
        lighting result per vertex; only the written colour needs clamping (it is), and
        light brighter than 1 must reach the texture product for the radiance renderer's
        exposures (sebvs.sim.radiance). GL 3.0's glClampColor, on this context only."""
        from OpenGL import GL
        self.gl.make_current()
        GL.glClampColor(GL.GL_CLAMP_VERTEX_COLOR, GL.GL_FALSE)

    def set_model(self, model: mujoco.MjModel) -> None:
        for height, width in self.sizes:
            self.check(model, height, width)
        self.gl.make_current()
        if self.ctx is not None:
            self.ctx.free()
        self.model = model
        self.ctx = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_100)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self.ctx)
        # read depth as drawn (reversed Z: 1 at the near plane, 0 at the far one)
        self.ctx.readDepthMap = mujoco.mjtDepthMap.mjDEPTH_ZEROFAR
        self.scene = mujoco.MjvScene(model, maxgeom=self.max_geom)
        self.camera_ids: dict[str, int] = {}

    def update(self, data: mujoco.MjData, camera: "str | int | mujoco.MjvCamera") -> None:
        cam = self.camera
        if isinstance(camera, mujoco.MjvCamera):
            # a view the caller set up (a free or tracking camera, as Gymnasium's MuJoCo
            # envs render models that have no camera of their own): used as it is
            mujoco.mjv_updateScene(self.model, data, self.option, None, camera,
                                   mujoco.mjtCatBit.mjCAT_ALL, self.scene)
            return
        if isinstance(camera, str):
            cam_id = self.camera_ids.get(camera)
            if cam_id is None:
                cam_id = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_CAMERA, camera)
                if cam_id < 0:
                    raise ValueError(f"the model has no camera named {camera!r}")
                self.camera_ids[camera] = cam_id
        else:
            cam_id = int(camera)
            if not -1 <= cam_id < self.model.ncam:
                raise ValueError(f"camera id {cam_id} is not in [-1, {self.model.ncam})")
        if cam_id == -1:
            mujoco.mjv_defaultFreeCamera(self.model, cam)
        else:
            cam.type = mujoco.mjtCamera.mjCAMERA_FIXED
            cam.fixedcamid = cam_id
        mujoco.mjv_updateScene(self.model, data, self.option, None, cam,
                               mujoco.mjtCatBit.mjCAT_ALL, self.scene)

    def draw(self, rect: mujoco.MjrRect, rgb: np.ndarray | None, depth: np.ndarray | None,
             segment: bool) -> None:
        if self.ctx is None:
            raise RuntimeError("render after close() (a view closes with its renderer)")
        self.gl.make_current()
        flags = self.scene.flags
        saved = flags.copy()
        if segment:
            flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = 1
            flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = 1
        try:
            mujoco.mjr_render(rect, self.scene, self.ctx)
        finally:
            flags[:] = saved
        mujoco.mjr_readPixels(rgb, depth, rect, self.ctx)

    def close(self) -> None:
        self.gl.make_current()
        if self.ctx is not None:
            self.ctx.free()
            self.ctx = None
        if self.owns_gl:
            self.gl.free()


class FrameRenderer:
    """Renders named cameras of a model at one size into given arrays.

    Use as a context manager (or call close()): it owns a GL context, unless it is a
    view() of another renderer, which then holds the context for both.
        with FrameRenderer(model, 160, 160) as r:
            small = r.view(80, 80)                          # the same scene, 80 px
            r.update(data, "front")                         # poses both
            r.rgb(out_rgb); r.luma(out_luma, src=out_rgb)   # one render serves both
            small.luma(out_small)
            r.set_model(other_model)                        # a new scene, same context

    Built on MuJoCo's rendering calls (mjv_updateScene, mjr_render, mjr_readPixels) rather
    than mujoco.Renderer, so that a new model reuses the GL context: in a fresh context
    the first MjrContext and render cost about 120 ms on llvmpipe (shader compilation),
    in a warm one about 22 ms. A camera whose scene changes every episode (randomised
    recording) pays that once per process instead of once per episode and renderer; and
    renderers of several sizes (the camera's RGB and its smaller luma) share one context,
    one upload of the model and one scene update per pose.
    """

    def __init__(self, model: mujoco.MjModel, height: int, width: int,
                 max_geom: int = 10_000, *, _canvas: _Canvas | None = None) -> None:
        self.height, self.width = int(height), int(width)
        self._owner = _canvas is None
        canvas = _Canvas(max_geom) if _canvas is None else _canvas
        canvas.check(model if _canvas is None else canvas.model, self.height, self.width)
        canvas.sizes.append((self.height, self.width))
        self._canvas = canvas
        self._rect = mujoco.MjrRect(0, 0, self.width, self.height)
        self._scratch = np.empty((self.height, self.width, 3), np.uint8)
        self._depth_raw: np.ndarray | None = None
        self._acc: np.ndarray | None = None
        if self._owner:
            canvas.set_model(model)

    def unclamp_lighting(self) -> None:
        """Let light brighter than 1 through to textured surfaces (see _Canvas); for
        this renderer's context and its views."""
        self._canvas.unclamp_lighting()

    def view(self, height: int, width: int) -> "FrameRenderer":
        """A renderer of another size on this one's GL context, model and scene: update()
        on either poses both, set_model() on either switches both. Closed with this one."""
        return FrameRenderer(self._canvas.model, height, width, _canvas=self._canvas)

    @property
    def model(self) -> mujoco.MjModel:
        return self._canvas.model

    def set_model(self, model: mujoco.MjModel) -> None:
        """Render `model` from now on (its textures and meshes uploaded anew, in the same
        GL context); call update() before the next render."""
        self._canvas.set_model(model)

    # -- lifecycle ------------------------------------------------------------------
    def close(self) -> None:
        if self._owner and self._canvas.ctx is not None:
            self._canvas.close()

    def __enter__(self) -> "FrameRenderer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- rendering ------------------------------------------------------------------
    def update(self, data: mujoco.MjData, camera: "str | int | mujoco.MjvCamera") -> None:
        """Pose the scene from `data` (its kinematics must be current) for `camera` (a
        name or an id of the model's cameras; -1: the free camera; or a mujoco.MjvCamera
        the caller set up, drawn as it is)."""
        self._canvas.update(data, camera)

    def _draw(self, rgb: np.ndarray | None, depth: np.ndarray | None,
              segment: bool = False) -> None:
        """Render the posed scene and read it back, bottom row first (OpenGL's order).

        segment: draw each geom in a flat colour that encodes its segid + 1 (0 where
        nothing is drawn), without the skybox: what segmentation() decodes, and what
        depth() reads, so that empty pixels lie on the far plane.
        """
        self._canvas.draw(self._rect, rgb, depth, segment)

    def rgb(self, out: np.ndarray | None = None) -> np.ndarray:
        """Render RGB into `out` ((H, W, 3) uint8) or a new array."""
        if out is None:
            out = np.empty((self.height, self.width, 3), np.uint8)
        self._draw(self._scratch, None)
        cv2.flip(self._scratch, 0, dst=out)
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

    def albedo(self, out: np.ndarray | None = None) -> np.ndarray:
        """The posed scene's surface colours, unshaded: (H, W, 3) uint8 of texture x rgba
        under a white ambient light of 1, emission off (the skybox as drawn). What a
        colour camera's chroma is taken from when its light comes from elsewhere
        (sebvs.sim.radiance): the lights' geometry does not colour it, and it never
        clips above the surface's own colour."""
        if out is None:
            out = np.empty((self.height, self.width, 3), np.uint8)
        scene = self._canvas.scene
        lights = [scene.lights[i] for i in range(scene.nlight)]
        geoms = [scene.geoms[i] for i in range(scene.ngeom)]
        saved = ([(lt.ambient.copy(), lt.diffuse.copy(), lt.specular.copy()) for lt in lights],
                 [g.emission for g in geoms])
        try:
            for i, lt in enumerate(lights):
                lt.ambient[:] = 1.0 if i == 0 else 0.0
                lt.diffuse[:] = 0.0
                lt.specular[:] = 0.0
            for g in geoms:
                g.emission = 0.0
            self._draw(self._scratch, None)
        finally:
            for lt, (a, d, sp) in zip(lights, saved[0]):
                lt.ambient[:], lt.diffuse[:], lt.specular[:] = a, d, sp
            for g, e in zip(geoms, saved[1]):
                g.emission = e
        cv2.flip(self._scratch, 0, dst=out)
        return out

    def depth(self, out: np.ndarray | None = None) -> np.ndarray:
        """Depth (H, W) float32 in metres along the camera axis."""
        if out is None:
            out = np.empty((self.height, self.width), np.float32)
        if self._depth_raw is None:
            self._depth_raw = np.empty((self.height, self.width), np.float32)
        self._draw(None, self._depth_raw, segment=True)
        # reversed Z (readDepthMap, set_model): 1 at the near clipping plane, 0 at the far
        # one. Undone with the projection's own coefficients, rounded to float32 as the GL
        # matrix holds them (exact ones are off by ~3e-4 relative), then in float64: the
        # hyperbola loses centimetres at range in float32.
        f32 = np.float32
        extent = self.model.stat.extent
        near, far = f32(self.model.vis.map.znear * extent), f32(self.model.vis.map.zfar * extent)
        d = self._depth_raw.astype(np.float64)
        if self._canvas.scene.camera[0].orthographic:
            metres = far - d * (far - near)
        else:
            # the standard frustum's depth row (-(f+n)/(f-n), -2fn/(f-n)), mapped to
            # reversed Z's [1, 0]
            a = f32(-0.5) * (-(far + near) / (far - near)) - f32(0.5)
            b = f32(-0.5) * (-(f32(2) * far * near) / (far - near))
            metres = b / (d + a)
        out[...] = metres[::-1]
        return out

    def segmentation(self, out: np.ndarray | None = None) -> np.ndarray:
        """Segmentation (H, W, 2) int32: [object id, object type]; -1 for background."""
        if out is None:
            out = np.empty((self.height, self.width, 2), np.int32)
        self._draw(self._scratch, None, segment=True)
        code = self._scratch.astype(np.int32)
        code = code[..., 0] | (code[..., 1] << 8) | (code[..., 2] << 16)
        scene = self._canvas.scene
        n = scene.ngeom
        table = np.full((n + 2, 2), -1, np.int32)
        for geom in scene.geoms[:n]:
            if geom.segid >= 0:
                table[geom.segid + 1] = (geom.objid, geom.objtype)
        # a code past the table (not a colour this scene drew) reads as background
        np.minimum(code, n + 1, out=code)
        out[...] = table[code[::-1]]
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
