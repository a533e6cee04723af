"""EMVA 1288 photon-transfer analysis, and the flat fields to feed it from a FrameCamera.

Per light level, from a pair of flat fields a, b (raw DN, N pixels each):
    mu_y      = (mean(a) + mean(b)) / 2
    sigma_y^2 = var(a - b) / 2          (the difference cancels PRNU and DSNU)
EMVA's linear model, in DN:
    sigma_y^2 = K^2 sigma_d^2 + sigma_q^2 + K (mu_y - mu_y.dark),   sigma_q^2 = 1/12 DN^2
so sigma_y^2 - sigma_y.dark^2 against mu_y - mu_y.dark is a line through the origin of
slope K (DN/e-), fitted by least squares on the levels up to 70 % of saturation, the
saturation point being where the variance peaks (EMVA's rule: clipping bends the curve
before it). The temporal dark noise follows from the dark pair:
    sigma_d [e-] = sqrt(sigma_y.dark^2 - 1/12) / K
One dark pair serves every level, so the levels must share one exposure time (as
`flat_field_series` makes them: it varies the light, not the exposure).
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
