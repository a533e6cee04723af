"""Light in physical units: what a scene declares and what the sensors read.

A scene's render is linear in its lights: a white Lambertian surface facing the key light
renders at a relative radiance of about `render_level` (the lights' key diffuse plus
ambient, as the scene sets them). `Photometry.illuminance_lux` says what illuminance that
surface receives, so a pixel of relative radiance r has luminance

    L = r * illuminance_lux / (pi * render_level)      [cd/m^2]

(a Lambertian surface of albedo rho under illuminance E has luminance rho * E / pi).
Self-luminous surfaces (a window, a lamp) are not lit: they declare their own luminance
in cd/m^2, by material name, in `Photometry.emissive`; the skybox declares the luminance
of a texel of value 1 in `sky_cd_m2`.

Reference illuminances (lux), public orders of magnitude: direct sun ~1e5, overcast day
~1e4, office 300-500, street lighting ~10-20, dusk 1-10, full moon ~0.1.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

ILLUMINANCE_LUX = {"sun": 1e5, "overcast": 1e4, "office": 400.0, "dusk": 3.0, "moon": 0.1}


@dataclass(frozen=True)
class Photometry:
    """The physical scale of a scene's light.

    illuminance_lux  the illuminance the scene's lights give a surface facing the key light
    render_level     the relative radiance at which a white surface receiving that
                     illuminance renders (key diffuse + ambient of the lights in force)
    emissive         material name -> luminance in cd/m^2 of a self-luminous surface
                     (its colour comes from the material's rgba)
    sky_cd_m2        luminance of a skybox texel of value 1, or None (no skybox)
    flicker          (frequency Hz, depth) of the lights' modulation, or None; depth d
                     scales every light by 1 - d + d * sin(...) around 1 - d
    """
    illuminance_lux: float
    render_level: float = 1.0
    emissive: dict[str, float] = field(default_factory=dict)
    sky_cd_m2: float | None = None
    flicker: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        e = self.illuminance_lux
        if isinstance(e, bool) or not isinstance(e, (int, float)) or not 0 < e < math.inf:
            raise ValueError(f"photometry: illuminance_lux must be a positive finite number, "
                             f"got {e!r}")
        r = self.render_level
        if isinstance(r, bool) or not isinstance(r, (int, float)) or not 0 < r < math.inf:
            raise ValueError(f"photometry: render_level must be a positive finite number, "
                             f"got {r!r}")
        named = dict(self.emissive)
        if self.sky_cd_m2 is not None:
            named["<sky>"] = self.sky_cd_m2
        for name, lum in named.items():
            if isinstance(lum, bool) or not isinstance(lum, (int, float)) \
                    or not 0 < lum < math.inf:
                raise ValueError(f"photometry: emissive {name!r} luminance must be a positive "
                                 f"finite number of cd/m^2, got {lum!r}")

    @property
    def unit_cd_m2(self) -> float:
        """Luminance of relative radiance 1."""
        return self.illuminance_lux / (math.pi * self.render_level)

    def relative(self, luminance_cd_m2: float) -> float:
        """A luminance as relative radiance (the render's unit)."""
        return luminance_cd_m2 / self.unit_cd_m2

    def peak_cd_m2(self, headroom: float = 1.5) -> float:
        """The brightest luminance the scene declares: its brightest emitter or sky, or a
        white lit surface with `headroom` for specular highlights and lights adding up."""
        sky = [] if self.sky_cd_m2 is None else [self.sky_cd_m2]
        return max([headroom * self.render_level * self.unit_cd_m2, *self.emissive.values(),
                    *sky])


def lambertian_cd_m2(albedo: float, illuminance_lux: float) -> float:
    """Luminance of a matte surface of this albedo under this illuminance."""
    return albedo * illuminance_lux / math.pi
