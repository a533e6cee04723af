"""Linear luminance beyond 8 bits from MuJoCo's 8-bit renderer: one render, three exposures.

MuJoCo writes 8 bits per channel and clamps the written colour at 1, but its lighting is
linear, computed per channel in float, and neither light colours nor emission are
clamped (once GL's clamp of lit vertex colours is off: FrameRenderer.unclamp_lighting,
else a textured surface's light stops at 1 before the texture multiplies it). So a copy of the model whose surfaces are grey (each one's luminance) and whose
lights are coloured (1, K, K^2) * s renders the scene's luminance three times at once:
red is the shortest exposure, blue K^2 times longer. Decoding takes, per pixel, the most
exposed channel that is not clipped. With K = 16 one render spans

    top     255 DN in red                      = 1 / s           (relative radiance)
    floor   the blue channel's quantisation    = 0.29 / (255 s K^2)
            noise, 1/sqrt(12) DN (what EMVA 1288 counts as the dark noise of an ideal
            quantiser), so the range is 255 K^2 / 0.29 = 2.3e5 : 1 = 107 dB,

and a relative quantisation step of at most 1 / 15.9 (when blue and then green clip,
the next channel holds at least 255 / K DN). `scale` s puts the top at the brightest
luminance the scene declares (sebvs.sim.light.Photometry.peak_cd_m2, x HEADROOM):
brighter light clips, as on any sensor, and is counted in `RadianceRenderer.clipped`.

The grey copy (grey_model):
  textures   each texel's luminance in all three channels; the skybox, which is drawn
             unlit, is encoded directly: channel c = Y(texel) * sky * s * gain_c (clipped)
  materials  rgba -> luminance; an emissive material gets rgba (1/K^2, 1/K, 1) and
             emission L * s * K^2 (L its declared luminance, relative), so its light is
             exact per channel; its diffuse reflection is then tinted, negligible beside a
             declared emitter's own light
  geoms      rgba -> luminance
  lights     diffuse, ambient, specular -> luminance of the colour * s * gain_c; the
             headlight alike
  haze       off (a blend towards a colour that the gains cannot encode), reflectance off
Luminance is Rec. 709's Y of linear RGB. For a textured material with a coloured rgba,
Y(tex * rgba) is taken as Y(tex) * Y(rgba): exact when either is grey (every scene here).
"""
from __future__ import annotations

import copy
import math

import mujoco
import numpy as np

from .light import Photometry
from .render import FrameRenderer

REC709 = np.array([0.2126, 0.7152, 0.0722])
SATURATED = 254          # a channel at or above this DN is taken as clipped
QUANT_NOISE_DN = 1.0 / math.sqrt(12.0)
HEADROOM = 1.25          # the top sits this far above the brightest declared luminance


def luminance(rgb) -> np.ndarray:
    """Rec. 709 luminance of linear RGB (..., 3) -> (...)."""
    return np.asarray(rgb, np.float64)[..., :3] @ REC709


def channel_gains(ratio: float) -> np.ndarray:
    """Exposure of (red, green, blue) relative to red: (1, K, K^2)."""
    return np.array([1.0, ratio, ratio * ratio])


def grey_model(model: mujoco.MjModel, photometry: Photometry, ratio: float
               ) -> tuple[mujoco.MjModel, float]:
    """A copy of `model` that renders luminance in three exposures; and its scale s
    (relative radiance 1 renders at 255 * s DN in red)."""
    if not 1.0 < ratio <= 64.0:
        raise ValueError(f"radiance: channel ratio must be in (1, 64], got {ratio}")
    g = copy.deepcopy(model)
    gains = channel_gains(ratio)
    unit = photometry.unit_cd_m2
    scale = unit / (HEADROOM * photometry.peak_cd_m2())
    for t in range(g.ntex):
        _grey_texture(g, t, gains, scale, photometry, unit)
    emissive = {}
    for name, cd in photometry.emissive.items():
        mat = mujoco.mj_name2id(g, mujoco.mjtObj.mjOBJ_MATERIAL, name)
        if mat < 0:
            raise ValueError(f"radiance: the scene declares emissive material {name!r}, "
                             "which its model does not have")
        emissive[mat] = cd / unit
    for m in range(g.nmat):
        rgba = g.mat_rgba[m]
        if m in emissive or g.mat_emission[m] > 0:
            rel = emissive.get(m, float(g.mat_emission[m] * luminance(rgba)))
            rgba[:3] = gains / gains[-1]
            g.mat_emission[m] = rel * scale * gains[-1]
        else:
            rgba[:3] = luminance(rgba)
        g.mat_reflectance[m] = 0.0
    g.geom_rgba[:, :3] = luminance(g.geom_rgba)[:, None]
    for field in ("light_diffuse", "light_ambient", "light_specular"):
        arr = getattr(g, field)
        arr[:] = luminance(arr)[:, None] * scale * gains
    head = g.vis.headlight
    for field in ("ambient", "diffuse", "specular"):
        setattr(head, field, float(luminance(getattr(head, field))) * scale * gains)
    g.vis.rgba.haze[3] = 0.0
    return g, scale


def _grey_texture(g: mujoco.MjModel, t: int, gains: np.ndarray, scale: float,
                  photometry: Photometry, unit: float) -> None:
    nc = int(g.tex_nchannel[t])
    if nc < 3:
        return                                   # already grey (or alpha only)
    n = int(g.tex_width[t] * g.tex_height[t])
    adr = int(g.tex_adr[t])
    texels = g.tex_data[adr:adr + n * nc].reshape(n, nc)
    y = luminance(texels.astype(np.float64) / 255.0)
    if g.tex_type[t] == mujoco.mjtTexture.mjTEXTURE_SKYBOX:
        sky = (photometry.sky_cd_m2 if photometry.sky_cd_m2 is not None else unit) / unit
        enc = np.clip(y[:, None] * sky * scale * gains, 0.0, 1.0)
    else:
        enc = np.repeat(y[:, None], 3, axis=1)
    texels[:, :3] = np.rint(enc * 255.0).astype(np.uint8)


def decode(rgb: np.ndarray, gains: np.ndarray, out: np.ndarray | None = None
           ) -> tuple[np.ndarray, int]:
    """(H, W, 3) uint8 render of the grey model -> (relative radiance * scale (H, W)
    float32, pixels clipped in red)."""
    r, g, b = (rgb[..., i].astype(np.float32) for i in range(3))
    use_b, use_g = b < SATURATED, g < SATURATED
    value = np.where(use_b, b / np.float32(gains[2]),
                     np.where(use_g, g / np.float32(gains[1]), r))
    if out is None:
        out = np.empty(rgb.shape[:2], np.float32)
    np.multiply(value, np.float32(1.0 / 255.0), out=out)
    return out, int(np.count_nonzero(r >= SATURATED))


class RadianceRenderer:
    """Scene luminance (H, W) float32 in cd/m^2, one 8-bit render per image.

        with RadianceRenderer(model, scene.photometry(), 160, 160) as rr:
            rr.update(data, "front")
            lum = rr.luminance()                # cd/m^2
            rr.top_cd_m2, rr.floor_cd_m2        # the range one image holds
    It owns its own GL context (the grey model's textures differ from the colour
    model's). `light_scale` in update() is the scene's flicker, applied to all of the
    scene's light (see update).
    """

    def __init__(self, model: mujoco.MjModel, photometry: Photometry, height: int,
                 width: int, ratio: float = 16.0) -> None:
        self.ratio = float(ratio)
        self.gains = channel_gains(self.ratio)
        self.height, self.width = int(height), int(width)
        self._renderer: FrameRenderer | None = None
        self._rgb = np.empty((self.height, self.width, 3), np.uint8)
        self.clipped = 0
        self.set_model(model, photometry)

    def set_model(self, model: mujoco.MjModel, photometry: Photometry) -> None:
        self.grey, self.scale = grey_model(model, photometry, self.ratio)
        self.photometry = photometry
        self.unit = photometry.unit_cd_m2
        self.base_diffuse = self.grey.light_diffuse.copy()
        self.base_ambient = self.grey.light_ambient.copy()
        self.base_headlight = self.grey.vis.headlight.ambient.copy()
        if self._renderer is None:
            self._renderer = FrameRenderer(self.grey, self.height, self.width)
            self._renderer.unclamp_lighting()
        else:
            self._renderer.set_model(self.grey)

    @property
    def top_cd_m2(self) -> float:
        """The luminance at which red clips."""
        return self.unit / self.scale

    @property
    def floor_cd_m2(self) -> float:
        """The luminance of blue's quantisation noise (1/sqrt(12) DN)."""
        return self.top_cd_m2 * QUANT_NOISE_DN / (255.0 * self.gains[2])

    @property
    def dynamic_range_db(self) -> float:
        return 20.0 * math.log10(self.top_cd_m2 / self.floor_cd_m2)

    def update(self, data: mujoco.MjData, camera: str | int, light_scale: float = 1.0) -> None:
        """Pose the scene; `light_scale` is the flicker's: every light of the scene, its
        ambient (indirect) light and the headlight's with it, since the indirect light of
        a flickering lamp flickers too. (The 8-bit colour path modulates the lights'
        diffuse only, as it always has.)"""
        self.grey.light_diffuse[:] = self.base_diffuse * light_scale
        self.grey.light_ambient[:] = self.base_ambient * light_scale
        self.grey.vis.headlight.ambient = self.base_headlight * light_scale
        self._renderer.update(data, camera)

    def luminance(self, out: np.ndarray | None = None) -> np.ndarray:
        """Render the posed scene: luminance (H, W) float32, cd/m^2."""
        self._renderer.rgb(self._rgb)
        lum, self.clipped = decode(self._rgb, self.gains, out)
        lum *= np.float32(self.unit / self.scale)
        return lum

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    def __enter__(self) -> "RadianceRenderer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
