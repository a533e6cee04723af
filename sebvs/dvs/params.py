"""Emulator parameters and presets (the paper's Table 2 values are the `paper` preset).

Preset versions (docs/dvs.md, "Noise and preset versions"): `preset_version` names the
noise model a preset's figures mean. 2, the current one: `shot_noise_rate_hz` and
`leak_rate_hz` are the array's mean rates from the first frame. 1, the model before issue
67 (every recording, table and checkpoint made before it): the shot-noise rate is the
median of its per-pixel spread (the mean is exp((c ln 10)^2 / 2) times it, 1.94x at
c = 0.5 decades) and every pixel's leak starts at zero phase, so none fires before
1 / leak_rate_hz. A recorded `emulator` dict without the key was written by version 1.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace

MAX_LEAK_EVENTS = 1000
PRESET_VERSION = 2            # what a preset means unless told otherwise
PRESET_VERSIONS = (1, 2)


@dataclass(frozen=True)
class EmulatorParams:
    pos_thres: float = 0.3            # ON contrast threshold, log units
    neg_thres: float = 0.3            # OFF contrast threshold, log units
    sigma_thres: float = 0.09         # pixel-to-pixel threshold spread (fixed-pattern)
    cutoff_hz: float = 15.0           # photoreceptor low-pass at full intensity; 0: off
    leak_rate_hz: float = 0.0         # ON leak events per pixel per second (version 1:
                                      # none before 1 / leak_rate_hz)
    leak_jitter_fraction: float = 0.1 # spread of the per-pixel leak rate
    shot_noise_rate_hz: float = 0.0   # noise events per pixel per second in the dark, the
                                      # array's mean (version 1: its median)
    noise_rate_cov_decades: float = 0.1  # per-pixel log-normal spread of the shot-noise
                                      # rate, decades (v2e spreads its leak instead)
    refractory_period_s: float = 0.0  # a pixel cannot fire again within this
    max_gap_s: float = 10.0           # a longer gap between frames restarts the sensor
    downsample: float = 0.5           # input resize factor before emulation
    blur: bool = True                 # 3x3 Gaussian before emulation
    seed: int = 0
    reference_cd_m2: float = 127.0    # linear input: the luminance read as 255 DN, a
                                      # white surface under 400 lux (office light)
    lowpass_hold: str = "step"        # the low-pass's input between two frames: "step",
                                      # held at the new frame's level over the interval
                                      # (v2e's); "linear", moving from the previous
                                      # frame's level to the new one, as the crossing
                                      # times assume (docs/dvs.md, "Adaptive sampling")
    preset_version: int = PRESET_VERSION  # the noise model (above): 2, the stated rates are
                                      # means from the first frame; 1, before issue 67

    def validate(self) -> "EmulatorParams":
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name == "lowpass_hold":
                if v not in ("step", "linear"):
                    raise ValueError(f"emulator: lowpass_hold must be 'step' or 'linear', "
                                     f"got {v!r}")
                continue
            if f.name in ("blur",):
                if not isinstance(v, bool):
                    raise ValueError(f"emulator: {f.name} must be true or false, got {v!r}")
                continue
            if f.name == "preset_version":
                # 2.0 or True would pass an equality test and then name no version
                if type(v) is not int or v not in PRESET_VERSIONS:
                    raise ValueError(f"emulator: preset_version must be one of "
                                     f"{', '.join(map(str, PRESET_VERSIONS))}, got {v!r}")
                continue
            if f.name == "seed":
                if not isinstance(v, int) or isinstance(v, bool):
                    raise ValueError(f"emulator: seed must be an integer, got {v!r}")
                continue
            if not isinstance(v, (int, float)) or isinstance(v, bool) or v != v \
                    or v in (float("inf"), float("-inf")):
                raise ValueError(f"emulator: {f.name} must be a finite number, got {v!r}")
            if v < 0:
                raise ValueError(f"emulator: {f.name} must not be negative, got {v!r}")
        if self.max_gap_s <= 0:
            raise ValueError("emulator: max_gap_s must be positive")
        # the leak's crossings are expanded one by one: this bounds them per pixel and frame
        if self.leak_rate_hz * self.max_gap_s > MAX_LEAK_EVENTS:
            raise ValueError(f"emulator: leak_rate_hz * max_gap_s = "
                             f"{self.leak_rate_hz * self.max_gap_s:g} leak events per pixel in "
                             f"one frame interval, over {MAX_LEAK_EVENTS}; lower max_gap_s")
        if self.reference_cd_m2 <= 0:
            raise ValueError("emulator: reference_cd_m2 must be positive")
        if self.pos_thres <= 0 or self.neg_thres <= 0:
            raise ValueError("emulator: pos_thres and neg_thres must be positive")
        if not 0 < self.downsample <= 1:
            raise ValueError(f"emulator: downsample must be in (0, 1], got {self.downsample}")
        return self

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "EmulatorParams":
        """The parameters a recorded `emulator` dict (to_dict's) names, validated.

        Parameters:
            d: field -> value; a dict without preset_version was written before the
               field existed, by version 1.
        Returns:
            the EmulatorParams; ValueError naming an unknown key or a bad value.
        """
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(d) - known)
        if unknown:
            raise ValueError(f"unknown emulator parameter {unknown[0]!r}")
        return cls(**{"preset_version": 1, **d}).validate()


def lognormal_mean(decades: float) -> float:
    """The mean of 10 ** (decades * N(0, 1)): how far a log-normal spread's mean lies above
    its median (1.0269 at 0.1 decades, 1.9401 at 0.5).

    Parameters:
        decades: the spread's standard deviation in decades (noise_rate_cov_decades).
    Returns:
        exp((decades ln 10)^2 / 2).
    """
    return math.exp((decades * math.log(10)) ** 2 / 2)


def static_noise_rate_hz(params: EmulatorParams, luminance_cd_m2: float) -> float:
    """The mean noise events per pixel per second of a static scene of linear light, as the
    model defines it (docs/dvs.md, "Noise and preset versions"; measured against the
    emulator in tests/test_dvs_noise.py).

    Shot noise at shot_noise_rate_hz (times the spread's mean over its median in version
    1) times the brightness factor 1 - 0.75 min(x / 255, 1), x = 255 L / reference_cd_m2;
    plus the leak's leak_rate_hz in version 2. Version 1's leak fires its first events
    only after 1 / leak_rate_hz, all pixels together, so its figure here, the one over
    the first 1 / leak_rate_hz seconds, leaves the leak out. Not counted: the cap of one
    shot-noise event per pixel and frame, which the spread's tail passes (at 100 frames a
    second 0.65 % of the noisy preset's shot noise, 2.6 % in version 1; at 30, 6.4 and
    16 %), and the refractory period's losses (nil at these rates).

    Parameters:
        params: the emulator's parameters (a preset's).
        luminance_cd_m2: the scene's luminance, cd/m^2 (non-negative).
    Returns:
        events per pixel per second.
    """
    if not luminance_cd_m2 >= 0:
        raise ValueError(f"luminance must be a non-negative number of cd/m^2, "
                         f"got {luminance_cd_m2!r}")
    x = 255.0 * luminance_cd_m2 / params.reference_cd_m2
    shot = params.shot_noise_rate_hz * (1.0 - 0.75 * min(x / 255.0, 1.0))
    if params.preset_version == 1:
        return shot * lognormal_mean(params.noise_rate_cov_decades)
    return shot + params.leak_rate_hz


# The figures are the same in both versions (version 2 makes them mean what they say),
# so preset_version is an override like any other; a version that changes a figure will
# need a table per version. Sources: docs/dvs.md, "Noise and preset versions".
PRESETS: dict[str, EmulatorParams] = {
    # Table 2 of the paper (v2e settings of the SEBVS package)
    "paper": EmulatorParams(),
    # the ideal pixel: no mismatch, no filter, no noise
    "clean": EmulatorParams(sigma_thres=0.0, cutoff_hz=0.0),
    # a dim, leaky, noisy sensor: v2e's "noisy" model's 5 Hz shot noise (its mean: v2e
    # spreads only the leak) and 0.1 Hz leak, with a refractory period and hot pixels
    "noisy": EmulatorParams(shot_noise_rate_hz=5.0, leak_rate_hz=0.1,
                            refractory_period_s=0.0005, noise_rate_cov_decades=0.5),
    # the paper's thresholds on a chip's linear light: the photoreceptor's log range
    # reaches down to its dark-current break (x = 20) at 0.1 cd/m^2, 120 dB below sunlit
    # surfaces (event sensors' published ~120 dB); bandwidth cutoff_hz x (x + 20) / 275:
    # ~2 kHz in office light (x ~ 2e4), ~10 Hz at dusk; background activity of a real
    # chip's order: 0.5 Hz mean in the dark, a quarter of it from 1.27 cd/m^2, leak
    # 0.05 Hz (between v2e's good-light defaults, 0.001 and 0.01 Hz, and its noisy model)
    "physical": EmulatorParams(reference_cd_m2=1.27, cutoff_hz=30.0, shot_noise_rate_hz=0.5,
                               leak_rate_hz=0.05, refractory_period_s=0.0005,
                               noise_rate_cov_decades=0.5),
}



def pick_preset(presets: dict, what: str, name: str, overrides: dict):
    """presets[name] with some fields overridden, validated; ValueError naming `what` on
    an unknown name or key (any frozen dataclass of parameters with a validate())."""
    if name not in presets:
        raise ValueError(f"unknown {what} preset {name!r} (one of {', '.join(presets)})")
    known = {f.name for f in fields(next(iter(presets.values())))}
    unknown = sorted(set(overrides) - known)
    if unknown:
        raise ValueError(f"unknown {what} parameter {unknown[0]!r}")
    return replace(presets[name], **overrides).validate()


def preset(name: str, **overrides) -> EmulatorParams:
    """A preset with some fields overridden; ValueError on an unknown name or key.
    ``preset_version=1`` gives the preset as it was before issue 67, bit for bit."""
    return pick_preset(PRESETS, "emulator", name, overrides)
