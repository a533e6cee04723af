"""The noise of a static scene, measured on the emulator beside what the model states
(params.static_noise_rate_hz; docs/dvs.md, "Noise and preset versions"). Used by
tests/test_dvs_noise.py, which holds the two within 10 %, and tools/bench/bench_sensors.py.

A uniform field of linear light (cd/m^2) is held still, so every event is noise: shot
noise and the leak. Downsampling and blur change nothing on a uniform field; they are
turned off so that `side` is the emulated sensor.
"""
from __future__ import annotations

import numpy as np

from .emulator import EventEmulator
from .params import PRESET_VERSIONS, PRESETS, preset, static_noise_rate_hz

LEVELS_CD_M2 = (0.01, 1.0, 100.0)   # a dark room, dusk indoors, a lit office's walls
SIDE = 128          # 16,384 pixels: the spread's fixed pattern within 1.3 % (one sigma)
SECONDS = 5.0       # below version 1's first leak event (10 s on noisy, 20 s physical)
FPS = 100.0         # the topologies' luma rate


def measure_static_noise_hz(name: str, luminance_cd_m2: float, *, preset_version: int,
                            side: int = SIDE, seconds: float = SECONDS, fps: float = FPS,
                            seed: int = 0) -> float:
    """Events per pixel per second from a preset's emulator on a still uniform field.

    Parameters:
        name: the emulator preset.
        luminance_cd_m2: the field's luminance, cd/m^2, read through step_luminance.
        preset_version: the preset's version (params.PRESET_VERSIONS).
        side: the emulated sensor's side in pixels.
        seconds: simulated time after the first frame.
        fps: frames per second.
        seed: the emulator's seed.
    Returns:
        the events over side^2 pixels and the simulated seconds.
    """
    if side < 1 or seconds <= 0 or fps <= 0:
        raise ValueError(f"noise measurement: side {side}, seconds {seconds} and fps {fps} "
                         "must be positive")
    emu = EventEmulator(preset(name, preset_version=preset_version, downsample=1.0,
                               blur=False, seed=seed))
    field = np.full((side, side), luminance_cd_m2, np.float32)
    dt_ns = round(1e9 / fps)
    frames = round(seconds * fps)
    emu.step_luminance(field, 0)
    events = sum(emu.step_luminance(field, k * dt_ns).size for k in range(1, frames + 1))
    return events / (side * side * frames * dt_ns * 1e-9)


def noise_table(names=tuple(PRESETS), versions=PRESET_VERSIONS,
                levels=LEVELS_CD_M2, **kw) -> list[dict]:
    """Measured and stated static-scene noise per preset, version and light level.

    Parameters:
        names: presets; versions: preset versions; levels: luminances, cd/m^2.
        kw: passed to measure_static_noise_hz (side, seconds, fps, seed).
    Returns:
        one dict per (preset, version, level): preset, preset_version, luminance_cd_m2,
        measured_hz, stated_hz (params.static_noise_rate_hz) and ratio (measured over
        stated; None where the stated rate is 0).
    """
    rows = []
    for name in names:
        for v in versions:
            params = preset(name, preset_version=v)
            for level in levels:
                measured = measure_static_noise_hz(name, level, preset_version=v, **kw)
                stated = static_noise_rate_hz(params, level)
                rows.append({"preset": name, "preset_version": v, "luminance_cd_m2": level,
                             "measured_hz": round(measured, 5), "stated_hz": round(stated, 5),
                             "ratio": round(measured / stated, 4) if stated else None})
    return rows
