"""Tiled renders: several views drawn into the layers of one framebuffer, read back once.

    with FrameRenderer(model, 160, 160) as r, TileRenderer(r, capacity=8) as tiles:
        for state in states:                       # up to 8 sample times of one scene
            pose(state); r.update(data, "front")
            tiles.draw()                           # its own mjr_render, into layer k
        rgb = tiles.rgb()                          # (n, H, W, 3) uint8: one readback

    with ModelTiles([model_a, model_b], 160, 160) as tiles:     # K scenes' models
        tiles.update(0, data_a, "front"); tiles.update(1, data_b, "front")
        rgb = tiles.rgb()                          # (2, H, W, 3)

    radiance = RadianceTiles(radiance_renderer, capacity=8)    # the physical sensor's light
    radiance.draw(data, "front", light_scale)      # per sample, as RadianceRenderer.update
    lum = radiance.luminance()                     # (n, H, W) float32 cd/m^2, one readback

Each view is the same bytes as a render of its own (FrameRenderer.rgb, .luma,
RadianceRenderer.luminance; tests/test_render_tiles.py). That is why the tiles are the
layers of one 2D array texture, each drawn at the viewport's origin, and not viewports
side by side in one image: on llvmpipe a view drawn away from the origin differs from
one drawn at it by 1 DN in a few hundred of 25,600 pixels (the rasteriser's sub-pixel
snapping and attribute interpolation round differently at larger window coordinates).
Every draw attaches its layer to the model's MjrContext's offscreen framebuffer, which
is what mjr_render draws into, and puts MuJoCo's own attachments back after it, so
FrameRenderer's own renders on the same context are unaffected between tiles. A tile is
not bound by the model's offscreen buffer size (<visual><global offwidth>).

What a tile saves, and what it does not (docs/sim.md, "Tiled renders"): every view is
still its own scene update and mjr_render; the readback, its sync with the rasteriser and
the format conversion are paid once per tile, and llvmpipe rasterises one layer while the
caller poses and draws the next.
"""
from __future__ import annotations

import ctypes
from typing import Sequence

import cv2
import mujoco
import numpy as np

from .radiance import RadianceRenderer, decode
from .render import FrameRenderer, _Canvas


class _Layers:
    """A colour and a depth-stencil 2D array texture of `count` layers (H x W each), in
    the formats of MuJoCo's offscreen renderbuffers, in one GL context."""

    def __init__(self, canvas: _Canvas, height: int, width: int, count: int) -> None:
        from OpenGL import GL
        self.GL = GL
        self.canvas = canvas
        self.height, self.width, self.count = int(height), int(width), int(count)
        ctx = canvas.ctx
        canvas.gl.make_current()
        top = int(GL.glGetIntegerv(GL.GL_MAX_ARRAY_TEXTURE_LAYERS))
        if not 1 <= self.count <= top:
            raise ValueError(f"tiles: {count} tiles; this GL holds 1 to {top} layers")
        formats = []
        for buffer in (ctx.offColor, ctx.offDepthStencil):
            GL.glBindRenderbuffer(GL.GL_RENDERBUFFER, buffer)
            formats.append(int(GL.glGetRenderbufferParameteriv(
                GL.GL_RENDERBUFFER, GL.GL_RENDERBUFFER_INTERNAL_FORMAT)))
        self.colour, self.depth = (int(t) for t in GL.glGenTextures(2))
        for tex, fmt in zip((self.colour, self.depth), formats):
            GL.glBindTexture(GL.GL_TEXTURE_2D_ARRAY, tex)
            GL.glTexStorage3D(GL.GL_TEXTURE_2D_ARRAY, 1, fmt, self.width, self.height,
                              self.count)
        GL.glBindTexture(GL.GL_TEXTURE_2D_ARRAY, 0)
        self._checked: set[tuple[int, int, int]] = set()     # (FBO, colour, depth) seen
        self._rect = mujoco.MjrRect(0, 0, self.width, self.height)
        # GL's rows, bottom first, layer after layer
        self._raw = np.empty((self.count, self.height, self.width, 3), np.uint8)
        from OpenGL.raw.GL.VERSION.GL_4_5 import glGetTextureSubImage
        self._get_sub = glGetTextureSubImage if bool(glGetTextureSubImage) else None

    def _check_attachments(self, ctx: mujoco.MjrContext) -> None:
        """MuJoCo's offscreen framebuffer holds offColor and offDepthStencil as the
        draw restores them (once per MjrContext's buffers)."""
        key = (ctx.offFBO, ctx.offColor, ctx.offDepthStencil)
        if key in self._checked:
            return
        if ctx.offSamples > 0:
            raise ValueError(f"tiles: the model's offscreen buffer is multisampled "
                             f"({ctx.offSamples} samples), which a tile cannot be bit for "
                             f"bit: give its XML <quality offsamples=\"0\"/>")
        GL = self.GL
        name = GL.GL_FRAMEBUFFER_ATTACHMENT_OBJECT_NAME
        GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, ctx.offFBO)
        found = [int(GL.glGetFramebufferAttachmentParameteriv(GL.GL_FRAMEBUFFER, a, name))
                 for a in (GL.GL_COLOR_ATTACHMENT0, GL.GL_DEPTH_ATTACHMENT,
                           GL.GL_STENCIL_ATTACHMENT)]
        if found != [ctx.offColor, ctx.offDepthStencil, ctx.offDepthStencil]:
            raise RuntimeError(f"tiles: MuJoCo's offscreen framebuffer holds {found} as "
                               f"colour, depth, stencil, not offColor {ctx.offColor} and "
                               f"offDepthStencil {ctx.offDepthStencil}")
        self._checked.add(key)

    def draw(self, canvas: _Canvas, layer: int) -> None:
        """Render `canvas`'s posed scene with its MjrContext into layer `layer`.

        Parameters:
            canvas: a canvas in this GL context whose scene is posed (its update()).
            layer: the layer, 0 <= layer < count.
        """
        if canvas.ctx is None:
            raise RuntimeError("tiles: render after close() (a view closes with its renderer)")
        GL = self.GL
        canvas.gl.make_current()
        ctx = canvas.ctx
        self._check_attachments(ctx)
        GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, ctx.offFBO)
        GL.glFramebufferTextureLayer(GL.GL_FRAMEBUFFER, GL.GL_COLOR_ATTACHMENT0,
                                     self.colour, 0, layer)
        GL.glFramebufferTextureLayer(GL.GL_FRAMEBUFFER, GL.GL_DEPTH_STENCIL_ATTACHMENT,
                                     self.depth, 0, layer)
        try:
            mujoco.mjr_render(self._rect, canvas.scene, ctx)
        finally:
            # MuJoCo's own buffer back at once: a FrameRenderer render between two tiles
            # (the camera's colour frame between luma samples) draws where it always did
            GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, ctx.offFBO)
            GL.glFramebufferRenderbuffer(GL.GL_FRAMEBUFFER, GL.GL_COLOR_ATTACHMENT0,
                                         GL.GL_RENDERBUFFER, ctx.offColor)
            GL.glFramebufferRenderbuffer(GL.GL_FRAMEBUFFER, GL.GL_DEPTH_STENCIL_ATTACHMENT,
                                         GL.GL_RENDERBUFFER, ctx.offDepthStencil)

    def read_rgb(self, n: int, out: np.ndarray) -> np.ndarray:
        """Read layers [0, n) back in one call, top row first.

        Parameters:
            n: how many layers, 1 <= n <= count.
            out: (>= n, H, W, 3) uint8; its first n images are written.

        Returns:
            out[:n].
        """
        GL = self.GL
        self.canvas.gl.make_current()
        pack = int(GL.glGetIntegerv(GL.GL_PACK_ALIGNMENT))
        GL.glPixelStorei(GL.GL_PACK_ALIGNMENT, 1)
        try:
            raw = self._raw[:n]
            pointer = raw.ctypes.data_as(ctypes.c_void_p)
            if self._get_sub is not None:
                self._get_sub(self.colour, 0, 0, 0, 0, self.width, self.height, n,
                              GL.GL_RGB, GL.GL_UNSIGNED_BYTE, raw.nbytes, pointer)
            else:       # before GL 4.5: every layer
                raw = self._raw
                GL.glBindTexture(GL.GL_TEXTURE_2D_ARRAY, self.colour)
                from OpenGL.raw.GL.VERSION.GL_1_0 import glGetTexImage
                glGetTexImage(GL.GL_TEXTURE_2D_ARRAY, 0, GL.GL_RGB, GL.GL_UNSIGNED_BYTE,
                              raw.ctypes.data_as(ctypes.c_void_p))
                GL.glBindTexture(GL.GL_TEXTURE_2D_ARRAY, 0)
        finally:
            GL.glPixelStorei(GL.GL_PACK_ALIGNMENT, pack)
        out[:n] = self._raw[:n, ::-1]
        return out[:n]

    def free(self) -> None:
        """Delete the textures (nothing left to delete once the context is closed)."""
        if self.colour and self.canvas.ctx is not None:
            self.canvas.gl.make_current()
            self.GL.glDeleteTextures([self.colour, self.depth])
        self.colour = self.depth = 0


def _check_capacity(capacity: int) -> int:
    if isinstance(capacity, bool) or not isinstance(capacity, (int, np.integer)) \
            or capacity < 1:
        raise ValueError(f"tiles: capacity must be an integer >= 1, got {capacity!r}")
    return int(capacity)


def _luma(rgb: np.ndarray, out: np.ndarray | None) -> np.ndarray:
    """(n, H, W, 3) uint8 -> (n, H, W) uint8 luma, as FrameRenderer.luma converts one."""
    n, h, w = rgb.shape[:3]
    if out is None:
        out = np.empty((n, h, w), np.uint8)
    flat = out[:n].reshape(n * h, w)
    cv2.cvtColor(np.ascontiguousarray(rgb).reshape(n * h, w, 3), cv2.COLOR_RGB2GRAY,
                 dst=flat)
    return out[:n]


class TileRenderer:
    """Up to `capacity` renders of one FrameRenderer's scene, each posed anew by the
    caller, drawn into the layers of one framebuffer and read back in one call.

    Parameters:
        renderer: the FrameRenderer (or a view() of one) whose GL context, model, scene
            and size the tiles use; it stays the caller's to close (close this first).
        capacity: the most views drawn between two reads.
    """

    def __init__(self, renderer: FrameRenderer, capacity: int) -> None:
        self.capacity = _check_capacity(capacity)
        self.renderer = renderer
        self.height, self.width = renderer.height, renderer.width
        self._layers = _Layers(renderer._canvas, self.height, self.width, self.capacity)
        self.pending = 0            # views drawn since the last read

    def draw(self) -> int:
        """Render the renderer's posed scene (its last update()) into the next layer.

        Returns:
            The view's index in the next read.
        """
        if self.pending >= self.capacity:
            raise RuntimeError(f"tiles: {self.capacity} views drawn; read them before "
                               "drawing more")
        self._layers.draw(self.renderer._canvas, self.pending)
        self.pending += 1
        return self.pending - 1

    def rgb(self, out: np.ndarray | None = None) -> np.ndarray:
        """The views drawn since the last read, in the order drawn; the tile is then empty.

        Parameters:
            out: (>= n, H, W, 3) uint8 to write into, or None for a new array.

        Returns:
            (n, H, W, 3) uint8, each view as FrameRenderer.rgb() renders it.
        """
        n = self.pending
        if n == 0:
            raise RuntimeError("tiles: nothing drawn since the last read")
        if out is None:
            out = np.empty((n, self.height, self.width, 3), np.uint8)
        self._layers.read_rgb(n, out)
        self.pending = 0
        return out[:n]

    def luma(self, out: np.ndarray | None = None) -> np.ndarray:
        """As rgb(), as luma: (n, H, W) uint8, each as FrameRenderer.luma() gives it."""
        return _luma(self.rgb(), out)

    def close(self) -> None:
        self._layers.free()

    def __enter__(self) -> "TileRenderer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class RadianceTiles:
    """The physical sensor's luminance at up to `capacity` sample times, one readback.

    Parameters:
        radiance: the RadianceRenderer whose grey model, size and exposures are used
            (its update() poses each sample, light_scale included); the caller's to close.
        capacity: the most samples drawn between two reads.
    """

    def __init__(self, radiance: RadianceRenderer, capacity: int) -> None:
        self.radiance = radiance
        self.tiles = TileRenderer(radiance._renderer, capacity)
        self.clipped: list[int] = []     # per sample of the last read: red-clipped pixels

    @property
    def pending(self) -> int:
        return self.tiles.pending

    def draw(self, data: mujoco.MjData, camera: str | int, light_scale: float = 1.0) -> int:
        """Pose the scene as RadianceRenderer.update does and draw it into the next layer.

        Returns:
            The sample's index in the next read.
        """
        self.radiance.update(data, camera, light_scale)
        return self.tiles.draw()

    def luminance(self, out: np.ndarray | None = None) -> np.ndarray:
        """The samples drawn since the last read, in cd/m^2, each the bytes that
        RadianceRenderer.luminance() gives for it; `clipped` counts per sample.

        Parameters:
            out: (>= n, H, W) float32 to write into, or None for a new array.

        Returns:
            (n, H, W) float32.
        """
        rgb = self.tiles.rgb()
        n = rgb.shape[0]
        if out is None:
            out = np.empty((n, self.tiles.height, self.tiles.width), np.float32)
        rr = self.radiance
        gain = np.float32(rr.unit / rr.scale)
        self.clipped = []
        for k in range(n):
            _, clipped = decode(rgb[k], rr.gains, out[k])
            out[k] *= gain
            self.clipped.append(clipped)
        return out[:n]

    def close(self) -> None:
        self.tiles.close()


class ModelTiles:
    """One view of each of K models (K scenes, e.g. the environments of a vector env),
    posed and drawn one by one into the layers of one framebuffer, read back in one call.
    One GL context for all of them, each model its own MjrContext and scene.

    Parameters:
        models: the K models.
        height, width: every view's size (px).
        max_geom: each scene's geom budget, as FrameRenderer's.
    """

    def __init__(self, models: Sequence[mujoco.MjModel], height: int, width: int,
                 max_geom: int = 10_000) -> None:
        if not models:
            raise ValueError("tiles: no models")
        self.height, self.width = int(height), int(width)
        first = _Canvas(max_geom)
        self._canvases = [first]
        try:
            first.set_model(models[0])
            for model in models[1:]:
                canvas = _Canvas(max_geom, gl=first.gl)
                self._canvases.append(canvas)
                canvas.set_model(model)
            self._layers = _Layers(first, self.height, self.width, len(models))
        except BaseException:
            self._close_canvases()
            raise
        self.drawn = np.zeros(len(models), bool)     # since the last read

    def __len__(self) -> int:
        return len(self._canvases)

    def unclamp_lighting(self) -> None:
        """As FrameRenderer.unclamp_lighting, for all K (one GL context)."""
        self._canvases[0].unclamp_lighting()

    def set_model(self, i: int, model: mujoco.MjModel) -> None:
        """Model `i` from now on (uploaded anew in the shared context); update() it next."""
        self._canvases[i].set_model(model)
        self.drawn[i] = False

    def update(self, i: int, data: mujoco.MjData, camera: str | int) -> None:
        """Pose scene `i` from `data` (its kinematics current) for `camera`, and draw it
        into layer `i` (llvmpipe rasterises it while the next one is posed)."""
        canvas = self._canvases[i]
        canvas.update(data, camera)
        self._layers.draw(canvas, i)
        self.drawn[i] = True

    def rgb(self, out: np.ndarray | None = None) -> np.ndarray:
        """Every model's view, in model order, each as FrameRenderer.rgb() renders it.

        Parameters:
            out: (K, H, W, 3) uint8 to write into, or None for a new array.

        Returns:
            (K, H, W, 3) uint8.
        """
        if not self.drawn.all():
            raise RuntimeError(f"tiles: models {np.flatnonzero(~self.drawn).tolist()} not "
                               "updated since the last read")
        if out is None:
            out = np.empty((len(self), self.height, self.width, 3), np.uint8)
        self._layers.read_rgb(len(self), out)
        self.drawn[:] = False
        return out

    def luma(self, out: np.ndarray | None = None) -> np.ndarray:
        """As rgb(), as luma: (K, H, W) uint8."""
        return _luma(self.rgb(), out)

    def _close_canvases(self) -> None:
        # the others first: the first holds the GL context they draw in
        for canvas in self._canvases[:0:-1] + self._canvases[:1]:
            canvas.close()

    def close(self) -> None:
        if not self._canvases:
            return
        self._layers.free()
        self._close_canvases()
        self._canvases = []

    def __enter__(self) -> "ModelTiles":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
