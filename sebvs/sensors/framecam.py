"""A frame camera after the EMVA 1288 linear model: scene luminance -> electrons -> DN -> image.

    camera = FrameCamera(preset("mv_global_shutter"), (H, W), seed=0)
    frame = camera.expose(luminance, t_end_s=0.1)   # cd/m^2 (H, W[, 3]), or sub-frames
    frame.image, frame.raw, frame.exposure_s, frame.gain_db   # uint8, uint16 DN, the AE's
    camera.snr(luminance, exposure_s)                # analytic EMVA 1288 SNR

Pure numpy. Luminance -> sensor-plane illuminance (lens) -> photons (555 nm equivalent)
-> electrons (QE, PRNU, dark current, shot noise, DSNU, read noise, full-well clip) -> DN
(gain, ADC, black level) -> an 8-bit image (tone curve); an auto exposure with a real
camera's lag; a global shutter. Blur comes from the caller's sub-frames over the exposure
(`subframe_times`). The model step by step, the analytic SNR, and the preset
"mv_global_shutter" (a 3.45 um Sony Pregius IMX273 / IMX264 class camera) with every
figure's source: docs/sensors.md, "The camera model in full".
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, fields

import numpy as np

from ..dvs.params import pick_preset

_PLANCK_J_S = 6.62607015e-34
_LIGHT_SPEED_M_S = 299_792_458.0
_LUMINOUS_EFFICACY_555_LM_W = 683.0
_WAVELENGTH_M = 555e-9
# photons per second, square metre and lux of 555 nm light (~4.09e15)
PHOTONS_PER_LUX_S_M2 = _WAVELENGTH_M / (_LUMINOUS_EFFICACY_555_LM_W * _PLANCK_J_S
                                        * _LIGHT_SPEED_M_S)
QUANTISATION_VAR_DN2 = 1.0 / 12.0
TONES = ("srgb", "gamma", "linear")
METERINGS = ("mean", "centre")
AE_MAX_STEP = 8.0
# a metered mean this high is mostly clipped pixels: how far too bright is unknown
AE_SATURATED_MEAN = 0.95

_POSITIVE = ("pixel_pitch_m", "f_number", "full_well_e", "frame_rate_hz", "exposure_min_s",
             "exposure_max_s", "ae_start_exposure_s")
_NON_NEGATIVE = ("read_noise_e", "dark_current_e_per_s", "dsnu_e", "black_level_dn",
                 "gain_db_max", "readout_s")
_UP_TO_ONE = ("lens_transmission", "quantum_efficiency", "ae_damping")   # (0, 1]
_BELOW_ONE = ("prnu",)                                                   # [0, 1)


@dataclass(frozen=True)
class FrameCameraParams:
    """Every knob of the camera; the defaults are the "mv_global_shutter" preset."""
    pixel_pitch_m: float = 3.45e-6       # square pixel pitch, m
    f_number: float = 2.0                # lens f-number N
    lens_transmission: float = 0.9       # lens transmission T_lens, (0, 1]
    quantum_efficiency: float = 0.68     # QE at 555 nm, (0, 1]
    full_well_e: float = 10_000.0        # saturation capacity, e-
    read_noise_e: float = 2.3            # temporal dark noise, e- rms
    dark_current_e_per_s: float = 3.0    # e-/s per pixel
    prnu: float = 0.005                  # photo-response non-uniformity, fraction rms
    dsnu_e: float = 1.0                  # dark-signal non-uniformity, e- rms
    shot_noise: bool = True              # Poisson noise on light and dark current
    adc_bits: int = 12                   # ADC resolution, 8..16
    black_level_dn: float = 64.0         # offset added before the ADC clips at 0, DN
    gain_db_max: float = 24.0            # highest analogue gain, dB
    exposure_min_s: float = 20e-6
    exposure_max_s: float = 0.1
    frame_rate_hz: float = 226.0         # the sensor's top frame rate
    readout_s: float = 0.005             # end of exposure -> frame available
    tone: str = "srgb"                   # "srgb", "gamma" or "linear"
    ae_target: float = 0.18              # metered mean of s the AE aims at, (0, 1)
    ae_lag_frames: int = 2               # frame n's correction lands on frame n + lag, >= 1
    ae_damping: float = 0.6              # fraction of the log error corrected per step
    ae_metering: str = "mean"            # "mean" or "centre"
    ae_start_exposure_s: float = 1e-3    # AE's first exposure (at 0 dB)

    def validate(self) -> "FrameCameraParams":
        """Return self, or raise ValueError naming the first bad field."""
        for f in fields(self):
            _check_type(f.name, getattr(self, f.name))
        for name in _POSITIVE:
            if getattr(self, name) <= 0:
                _fail(name, "positive", getattr(self, name))
        for name in _NON_NEGATIVE:
            if getattr(self, name) < 0:
                _fail(name, "non-negative", getattr(self, name))
        for name in _UP_TO_ONE:
            if not 0 < getattr(self, name) <= 1:
                _fail(name, "in (0, 1]", getattr(self, name))
        for name in _BELOW_ONE:
            if not 0 <= getattr(self, name) < 1:
                _fail(name, "in [0, 1)", getattr(self, name))
        if not 0 < self.ae_target < 1:
            _fail("ae_target", "in (0, 1)", self.ae_target)
        if not 8 <= self.adc_bits <= 16:
            _fail("adc_bits", "in 8..16", self.adc_bits)
        if self.black_level_dn >= self.max_dn:
            _fail("black_level_dn", f"below the top code {self.max_dn}", self.black_level_dn)
        if self.ae_lag_frames < 1:
            _fail("ae_lag_frames", "at least 1", self.ae_lag_frames)
        if self.tone not in TONES:
            _fail("tone", f"one of {', '.join(TONES)}", self.tone)
        if self.ae_metering not in METERINGS:
            _fail("ae_metering", f"one of {', '.join(METERINGS)}", self.ae_metering)
        if self.exposure_max_s < self.exposure_min_s:
            _fail("exposure_max_s", f"at least exposure_min_s = {self.exposure_min_s}",
                  self.exposure_max_s)
        if self.ae_exposure_cap_s < self.exposure_min_s:
            _fail("frame_rate_hz", f"at most 1 / exposure_min_s = {1 / self.exposure_min_s:g}",
                  self.frame_rate_hz)
        if not self.exposure_min_s <= self.ae_start_exposure_s <= self.exposure_max_s:
            _fail("ae_start_exposure_s", "within [exposure_min_s, exposure_max_s]",
                  self.ae_start_exposure_s)
        return self

    @property
    def max_dn(self) -> int:
        """The ADC's top code."""
        return 2 ** self.adc_bits - 1

    @property
    def ae_exposure_cap_s(self) -> float:
        """The longest exposure AE uses before it adds gain."""
        return min(self.exposure_max_s, 1.0 / self.frame_rate_hz)

    def conversion_gain(self, gain_db: float = 0.0) -> float:
        """K in DN per electron at `gain_db`."""
        k0 = (self.max_dn - self.black_level_dn) / self.full_well_e
        return k0 * 10.0 ** (gain_db / 20.0)


_INT_FIELDS = ("adc_bits", "ae_lag_frames")
_STR_FIELDS = ("tone", "ae_metering")


def _check_type(name: str, value) -> None:
    if name == "shot_noise":
        if not isinstance(value, bool):
            _fail(name, "true or false", value)
    elif name in _STR_FIELDS:
        if not isinstance(value, str):
            _fail(name, "a string", value)
    elif name in _INT_FIELDS:
        if isinstance(value, bool) or not isinstance(value, int):
            _fail(name, "an integer", value)
    elif isinstance(value, bool) or not isinstance(value, (int, float)) \
            or not math.isfinite(value):
        _fail(name, "a finite number", value)


def _fail(name: str, what: str, value) -> None:
    raise ValueError(f"frame camera: {name} must be {what}, got {value!r}")


PRESETS: dict[str, FrameCameraParams] = {
    "mv_global_shutter": FrameCameraParams(),
    # the same optics and well with every noise source off and a 16-bit ADC
    "ideal": FrameCameraParams(read_noise_e=0.0, dark_current_e_per_s=0.0, prnu=0.0,
                               dsnu_e=0.0, shot_noise=False, adc_bits=16, black_level_dn=0.0),
}


def preset(name: str, **overrides) -> FrameCameraParams:
    """A preset with some fields overridden; ValueError on an unknown name or key."""
    return pick_preset(PRESETS, "frame camera", name, overrides)


def electrons_per_s_per_cd_m2(params: FrameCameraParams) -> float:
    """Mean signal in e-/s of one pixel per cd/m^2 of scene luminance (steps 1-3, no PRNU)."""
    sensor_lux = math.pi * params.lens_transmission / (4.0 * params.f_number ** 2)
    return (params.quantum_efficiency * sensor_lux * PHOTONS_PER_LUX_S_M2
            * params.pixel_pitch_m ** 2)


def _noise_floor_e2(params: FrameCameraParams, exposure_s: float, gain_db: float) -> float:
    """Signal-independent temporal variance in e-^2: dark shot, read and quantisation noise."""
    dark_shot = params.dark_current_e_per_s * exposure_s if params.shot_noise else 0.0
    k = params.conversion_gain(gain_db)
    return dark_shot + params.read_noise_e ** 2 + QUANTISATION_VAR_DN2 / k ** 2


def illuminance_for_snr(params: FrameCameraParams, target_snr: float = 1.0,
                        exposure_s: float = 0.01, albedo: float = 0.18,
                        gain_db: float = 0.0) -> float:
    """Scene illuminance in lux at which a Lambertian surface of `albedo` (luminance
    albedo * lux / pi) reaches `target_snr` (analytic EMVA SNR, solved exactly)."""
    for name, value in (("target_snr", target_snr), ("exposure_s", exposure_s),
                        ("albedo", albedo)):
        if not 0 < value < math.inf:
            raise ValueError(f"illuminance_for_snr: {name} must be positive, got {value!r}")
    floor = _noise_floor_e2(params, exposure_s, gain_db)
    s2 = target_snr ** 2
    if params.shot_noise:
        # mu^2 = S^2 (mu + floor): the positive root of the quadratic
        mu_e = 0.5 * (s2 + math.sqrt(s2 * s2 + 4.0 * s2 * floor))
    else:
        mu_e = target_snr * math.sqrt(floor)
    luminance = mu_e / (electrons_per_s_per_cd_m2(params) * exposure_s)
    return math.pi * luminance / albedo


def subframe_times(t_end_s: float, exposure_s: float, spacing_s: float,
                   max_n: int) -> np.ndarray:
    """Sample times (n,) of the sub-frames of an exposure [t_end - exposure, t_end]: the
    centres of n equal slices, n = clamp(ceil(exposure / spacing), 1, max_n)."""
    if not (exposure_s > 0 and spacing_s > 0 and max_n >= 1):
        raise ValueError(f"subframe_times: exposure_s and spacing_s must be positive and "
                         f"max_n at least 1, got {exposure_s!r}, {spacing_s!r}, {max_n!r}")
    # rounding first keeps 0.01 / 0.0005 = 20.000000000000004 from asking for 21 slices
    n = min(max(math.ceil(round(exposure_s / spacing_s, 9)), 1), int(max_n))
    return t_end_s - exposure_s + (np.arange(n) + 0.5) * (exposure_s / n)


@dataclass
class Frame:
    """One exposure.

    raw        (H, W[, 3]) uint16 DN
    image      (H, W[, 3]) uint8, toned
    exposure_s, gain_db          the settings it was taken with
    t_start_s, t_end_s           the exposure interval
    t_ready_s                    t_end_s + readout_s: when the frame is available
    saturated_fraction           share of samples at the ADC's top code
    """
    raw: np.ndarray
    image: np.ndarray
    exposure_s: float
    gain_db: float
    t_start_s: float
    t_end_s: float
    t_ready_s: float
    saturated_fraction: float


class FrameCamera:
    """One camera: its fixed pattern, its noise stream and its auto-exposure loop.

    shape is (H, W); each expose() takes monochrome (H, W) or colour (H, W, 3) luminance.
    The same seed and the same calls give the same frames.
    """

    def __init__(self, params: FrameCameraParams, shape: tuple[int, int], seed: int = 0):
        self.params = params.validate()
        if len(shape) != 2 or any(isinstance(v, bool) or not isinstance(v, (int, np.integer))
                                  or v < 1 for v in shape):
            raise ValueError(f"frame camera: shape must be (H, W) of positive integers, "
                             f"got {shape!r}")
        self.shape = (int(shape[0]), int(shape[1]))
        pattern_seed, noise_seed = np.random.SeedSequence(seed).spawn(2)
        # the fixed pattern has its own stream so it does not depend on how many frames ran
        pattern = np.random.default_rng(pattern_seed)
        self._prnu = pattern.normal(0.0, params.prnu, (*self.shape, 3))
        self._dsnu = pattern.normal(0.0, params.dsnu_e, (*self.shape, 3))
        self._rng = np.random.default_rng(noise_seed)
        self._product = params.ae_start_exposure_s
        self._pending = deque([self._product] * (params.ae_lag_frames - 1))

    @property
    def exposure_s(self) -> float:
        """The exposure the next auto-exposed frame gets."""
        return self._split(self._product)[0]

    @property
    def gain_db(self) -> float:
        """The gain the next auto-exposed frame gets."""
        return self._split(self._product)[1]

    def electrons_per_s(self, luminance) -> np.ndarray:
        """Mean signal in e-/s per pixel of luminance (cd/m^2, any shape): QE applied, no
        PRNU, no dark current."""
        return np.asarray(luminance, np.float64) * electrons_per_s_per_cd_m2(self.params)

    def snr(self, luminance, exposure_s: float, gain_db: float = 0.0):
        """Analytic EMVA 1288 SNR of a pixel at `luminance` (cd/m^2, scalar or array);
        docs/sensors.md, "The camera model in full". It does not drop to 0 above the full
        well."""
        mu_e = self.electrons_per_s(luminance) * exposure_s
        shot = mu_e if self.params.shot_noise else 0.0
        return mu_e / np.sqrt(shot + _noise_floor_e2(self.params, exposure_s, gain_db))

    def expose(self, subframes, t_end_s: float, exposure_s: float | None = None,
               gain_db: float | None = None) -> Frame:
        """Expose over [t_end_s - exposure, t_end_s].

        subframes: (n, H, W[, 3]) or (H, W[, 3]) float luminance in cd/m^2, finite and
        >= 0, spanning the exposure oldest first (their mean is integrated). With
        exposure_s None the AE loop's setting is used and the frame feeds the loop; with
        exposure_s given (gain_db defaults to 0 dB) the AE state is left alone.
        """
        luminance = self._mean_luminance(subframes)
        auto = exposure_s is None
        if auto:
            if gain_db is not None:
                raise ValueError("frame camera: gain_db is a manual setting; give exposure_s "
                                 "with it")
            exposure_s, gain_db = self._split(self._product)
        else:
            gain_db = 0.0 if gain_db is None else gain_db
            self._check_manual(exposure_s, gain_db)
        raw = self._digitise(self._electrons(luminance, exposure_s), gain_db)
        signal = self._normalise(raw)
        if auto:
            self._feed_ae(signal)
        return Frame(raw=raw, image=self._tone_lut[raw], exposure_s=float(exposure_s),
                     gain_db=float(gain_db), t_start_s=t_end_s - exposure_s, t_end_s=t_end_s,
                     t_ready_s=t_end_s + self.params.readout_s,
                     saturated_fraction=float(np.mean(raw == self.params.max_dn)))

    def _mean_luminance(self, subframes) -> np.ndarray:
        arr = np.asarray(subframes)
        if not np.issubdtype(arr.dtype, np.floating):
            raise ValueError(f"frame camera: subframes must be a float array of cd/m^2, "
                             f"got dtype {arr.dtype}")
        frame_shapes = (self.shape, (*self.shape, 3))
        if arr.shape in frame_shapes:
            arr = arr[None]
        elif arr.ndim not in (3, 4) or arr.shape[1:] not in frame_shapes or len(arr) == 0:
            raise ValueError(f"frame camera: subframes must have shape (H, W), (H, W, 3), "
                             f"(n, H, W) or (n, H, W, 3) with (H, W) = {self.shape} and "
                             f"n >= 1, got {arr.shape}")
        if not np.all(np.isfinite(arr)) or np.any(arr < 0):
            raise ValueError("frame camera: subframe luminance must be finite and >= 0")
        return arr.mean(axis=0, dtype=np.float64)

    def _check_manual(self, exposure_s: float, gain_db: float) -> None:
        p = self.params
        if not p.exposure_min_s <= exposure_s <= p.exposure_max_s:
            raise ValueError(f"frame camera: exposure_s must be within [{p.exposure_min_s}, "
                             f"{p.exposure_max_s}], got {exposure_s!r}")
        if not 0 <= gain_db <= p.gain_db_max:
            raise ValueError(f"frame camera: gain_db must be within [0, {p.gain_db_max}], "
                             f"got {gain_db!r}")

    def _electrons(self, luminance: np.ndarray, exposure_s: float) -> np.ndarray:
        p = self.params
        colour = luminance.ndim == 3
        prnu = self._prnu if colour else self._prnu[..., 0]
        dsnu = self._dsnu if colour else self._dsnu[..., 0]
        light = self.electrons_per_s(luminance) * exposure_s * (1.0 + prnu)
        # charge past the well is lost anyway; the cap keeps Poisson finite at any luminance
        # (and a PRNU draw below -1 cannot make a negative rate)
        mean = np.clip(light + p.dark_current_e_per_s * exposure_s, 0.0, 2.0 * p.full_well_e)
        charge = self._rng.poisson(mean).astype(np.float64) if p.shot_noise else mean
        read = self._rng.normal(0.0, p.read_noise_e, mean.shape)
        return np.minimum(charge + dsnu + read, p.full_well_e)

    def _digitise(self, electrons: np.ndarray, gain_db: float) -> np.ndarray:
        p = self.params
        dn = np.rint(p.conversion_gain(gain_db) * electrons + p.black_level_dn)
        return np.clip(dn, 0, p.max_dn).astype(np.uint16)

    def _normalise(self, raw: np.ndarray) -> np.ndarray:
        p = self.params
        s = (raw.astype(np.float32) - p.black_level_dn) / (p.max_dn - p.black_level_dn)
        return np.clip(s, 0.0, 1.0)

    @property
    def _tone_lut(self) -> np.ndarray:
        """The toned 8-bit value of every raw code (max_dn + 1 entries): one lookup per
        pixel instead of a power per pixel."""
        if getattr(self, "_lut", None) is None:
            self._lut = self._tone(self._normalise(np.arange(self.params.max_dn + 1)))
        return self._lut

    def _tone(self, s: np.ndarray) -> np.ndarray:
        if self.params.tone == "srgb":
            v = np.where(s <= 0.0031308, 12.92 * s, 1.055 * np.power(s, 1 / 2.4) - 0.055)
        elif self.params.tone == "gamma":
            v = np.power(s, 1 / 2.2)
        else:
            v = s
        return np.rint(255.0 * v).astype(np.uint8)

    def _meter(self, s: np.ndarray) -> float:
        if self.params.ae_metering == "centre":
            h, w = self.shape
            s = s[h // 4:h - h // 4, w // 4:w - w // 4]
        return float(np.mean(s))

    def _ae_step(self, measured: float) -> float:
        p = self.params
        if measured >= AE_SATURATED_MEAN:
            return 1.0 / AE_MAX_STEP
        ratio = p.ae_target / max(measured, 1e-9)
        return min(max(ratio ** p.ae_damping, 1.0 / AE_MAX_STEP), AE_MAX_STEP)

    def _feed_ae(self, signal: np.ndarray) -> None:
        # the correction is relative to the setting this frame used, and lands lag frames on:
        # the frames in between were already committed, as in a camera's register pipeline
        p = self.params
        wanted = self._product * self._ae_step(self._meter(signal))
        ceiling = p.ae_exposure_cap_s * 10.0 ** (p.gain_db_max / 20.0)
        self._pending.append(min(max(wanted, p.exposure_min_s), ceiling))
        self._product = self._pending.popleft()

    def _split(self, product: float) -> tuple[float, float]:
        """exposure x gain -> (exposure_s, gain_db): exposure first, then gain."""
        p = self.params
        exposure = min(max(product, p.exposure_min_s), p.ae_exposure_cap_s)
        gain = min(max(product / exposure, 1.0), 10.0 ** (p.gain_db_max / 20.0))
        return exposure, 20.0 * math.log10(gain)
