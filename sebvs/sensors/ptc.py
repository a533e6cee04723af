"""EMVA 1288 photon-transfer analysis, and the flat fields to feed it from a FrameCamera.

    pairs, dark = flat_field_series(preset("mv_global_shutter"), np.linspace(0.02, 0.98, 20))
    fit = photon_transfer(pairs, dark)      # gain_dn_per_e K, read_noise_e sigma_d, ...

Per level, the mean and half the variance of a pair's difference (which cancels PRNU and
DSNU); the variance above dark against the mean above dark is a line of slope K (DN/e-),
fitted up to 70 % of saturation (where the variance peaks); sigma_d follows from the dark
pair. One dark pair serves every level, so the levels share one exposure (the light
varies). The formulas: docs/sensors.md, "Photon transfer".
"""
from __future__ import annotations

import numpy as np

from .framecam import FrameCamera, FrameCameraParams, QUANTISATION_VAR_DN2

FIT_FRACTION_OF_SATURATION = 0.7


def _pair_stats(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    if a.shape != b.shape:
        raise ValueError(f"photon_transfer: a pair's frames differ in shape: {a.shape} vs "
                         f"{b.shape}")
    return 0.5 * (a.mean() + b.mean()), float(np.var(a - b) / 2.0)


def photon_transfer(frame_pairs, dark_pair) -> dict:
    """EMVA 1288 photon transfer from flat-field pairs at increasing light and a dark pair.

    frame_pairs: list of (a, b) raw DN arrays, one pair per level, same exposure time
    dark_pair:   (a, b) raw DN arrays with no light, same exposure time
    Returns gain_dn_per_e (K), read_noise_e (sigma_d), read_noise_dn (K sigma_d: the dark
    noise without quantisation), saturation_mean_dn (mean above dark where the variance
    peaks) and points: mean_dn and variance_dn2 (both above dark, one per level) and used
    (the levels the fit took).
    """
    mu_dark, var_dark = _pair_stats(*dark_pair)
    stats = np.array([_pair_stats(a, b) for a, b in frame_pairs], np.float64).reshape(-1, 2)
    mean = stats[:, 0] - mu_dark
    var = stats[:, 1] - var_dark
    if len(mean) == 0:
        raise ValueError("photon_transfer: no flat-field pairs")
    saturation = float(mean[np.argmax(var)])
    used = (mean > 0) & (mean <= FIT_FRACTION_OF_SATURATION * saturation)
    if used.sum() < 2:
        raise ValueError("photon_transfer: fewer than two levels between dark and 70 % of "
                         "saturation; add lower levels")
    k = float(np.sum(mean[used] * var[used]) / np.sum(mean[used] ** 2))
    read_dn = float(np.sqrt(max(var_dark - QUANTISATION_VAR_DN2, 0.0)))
    return {"gain_dn_per_e": k, "read_noise_e": read_dn / k, "read_noise_dn": read_dn,
            "saturation_mean_dn": saturation,
            "points": {"mean_dn": mean, "variance_dn2": var, "used": used}}


def flat_field_series(camera_params: FrameCameraParams, levels, seed: int = 0,
                      shape: tuple[int, int] = (128, 128), exposure_s: float = 1e-3,
                      gain_db: float = 0.0):
    """Flat-field pairs for `photon_transfer`, simulated with one FrameCamera (AE off).

    levels: mean signal of each level as a fraction of the ADC range above black at
    `gain_db` (1.0 reaches the top code; go past it to see saturation). All frames share
    `exposure_s`; the light varies. Returns (pairs, dark_pair) of raw uint16 (H, W) arrays.
    """
    camera = FrameCamera(camera_params, shape, seed)
    adc_range_e = ((camera_params.max_dn - camera_params.black_level_dn)
                   / camera_params.conversion_gain(gain_db))
    nit_e = float(camera.electrons_per_s(1.0)) * exposure_s

    def pair(luminance: float) -> tuple[np.ndarray, np.ndarray]:
        flat = np.full(shape, luminance, np.float32)
        return tuple(camera.expose(flat, 0.0, exposure_s, gain_db).raw for _ in range(2))

    pairs = [pair(level * adc_range_e / nit_e) for level in levels]
    return pairs, pair(0.0)
