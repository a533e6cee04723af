"""Emulator parameters and presets (the paper's Table 2 values are the `paper` preset)."""
from __future__ import annotations

from dataclasses import asdict, dataclass, fields, replace

MAX_LEAK_EVENTS = 1000


@dataclass(frozen=True)
class EmulatorParams:
    pos_thres: float = 0.3            # ON contrast threshold, log units
    neg_thres: float = 0.3            # OFF contrast threshold, log units
    sigma_thres: float = 0.09         # pixel-to-pixel threshold spread (fixed-pattern)
    cutoff_hz: float = 15.0           # photoreceptor low-pass at full intensity; 0: off
    leak_rate_hz: float = 0.0         # ON leak events per pixel per second
    leak_jitter_fraction: float = 0.1 # spread of the per-pixel leak rate
    shot_noise_rate_hz: float = 0.0   # noise events per pixel per second (in the dark)
    noise_rate_cov_decades: float = 0.1  # per-pixel spread of the shot-noise rate
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


PRESETS: dict[str, EmulatorParams] = {
    # Table 2 of the paper (v2e settings of the SEBVS package)
    "paper": EmulatorParams(),
    # the ideal pixel: no mismatch, no filter, no noise
    "clean": EmulatorParams(sigma_thres=0.0, cutoff_hz=0.0),
    # a dim, leaky, noisy sensor (v2e's "noisy" spirit: shot noise, leak, refractory)
    "noisy": EmulatorParams(shot_noise_rate_hz=5.0, leak_rate_hz=0.1,
                            refractory_period_s=0.0005, noise_rate_cov_decades=0.5),
    # the paper's thresholds on a chip's linear light: the photoreceptor's log range
    # reaches down to its dark-current break (x = 20) at 0.1 cd/m^2, 120 dB below sunlit
    # surfaces (event sensors' published ~120 dB); bandwidth cutoff_hz x (x + 20) / 275:
    # ~2 kHz in office light (x ~ 2e4), ~10 Hz at dusk; background activity of a real
    # chip's order (between v2e's clean and noisy presets: 5 Hz shot noise in its noisy one)
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
    """A preset with some fields overridden; ValueError on an unknown name or key."""
    return pick_preset(PRESETS, "emulator", name, overrides)
