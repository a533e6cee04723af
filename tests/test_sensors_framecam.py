"""The EMVA 1288 frame camera: photon transfer, saturation, SNR, blur, auto exposure."""
import math

import numpy as np
import pytest

from sebvs.sensors.framecam import (PHOTONS_PER_LUX_S_M2, FrameCamera, illuminance_for_snr,
                                    preset, subframe_times)
from sebvs.sensors.ptc import flat_field_series, photon_transfer

SHAPE = (64, 64)


def flat(luminance, shape=SHAPE):
    return np.full(shape, luminance, np.float32)


def test_photon_constant_is_555_nm_light():
    assert PHOTONS_PER_LUX_S_M2 == pytest.approx(4.09e15, rel=2e-3)


@pytest.mark.parametrize("gain_db", [0.0, 12.0])
def test_photon_transfer_recovers_gain_and_read_noise(gain_db):
    params = preset("mv_global_shutter")
    pairs, dark = flat_field_series(params, np.linspace(0.03, 1.2, 16), seed=3,
                                    gain_db=gain_db)
    result = photon_transfer(pairs, dark)
    assert result["gain_dn_per_e"] == pytest.approx(params.conversion_gain(gain_db), rel=0.05)
    assert result["read_noise_e"] == pytest.approx(params.read_noise_e, rel=0.05)
    # the levels past the top code saturate and are left out of the fit
    assert 4 <= result["points"]["used"].sum() < 16


def test_photon_transfer_needs_levels_below_saturation():
    params = preset("mv_global_shutter")
    pairs, dark = flat_field_series(params, [1.5, 2.0], shape=(16, 16))
    with pytest.raises(ValueError, match="70 %"):
        photon_transfer(pairs, dark)


def test_saturation_and_black():
    params = preset("mv_global_shutter")
    cam = FrameCamera(params, SHAPE, seed=0)
    bright = cam.expose(flat(1e7), t_end_s=1.0, exposure_s=0.01)
    assert bright.raw.dtype == np.uint16 and bright.image.dtype == np.uint8
    assert np.all(bright.raw == params.max_dn)
    assert bright.saturated_fraction == 1.0
    assert np.all(bright.image == 255)
    dark = cam.expose(flat(0.0), t_end_s=1.0, exposure_s=1e-3)
    assert abs(dark.raw.mean() - params.black_level_dn) < 0.5
    assert dark.saturated_fraction == 0.0
    assert dark.image.mean() < 2


def test_analytic_snr_matches_simulation():
    params = preset("mv_global_shutter")
    cam = FrameCamera(params, (128, 128), seed=5)
    exposure, gain = 1e-3, 6.0
    k = params.conversion_gain(gain)
    per_nit = float(cam.electrons_per_s(1.0)) * exposure
    for electrons in (15.0, 400.0, 3000.0):
        lum = electrons / per_nit
        a = cam.expose(flat(lum, (128, 128)), 0.0, exposure, gain).raw.astype(np.float64)
        b = cam.expose(flat(lum, (128, 128)), 0.0, exposure, gain).raw.astype(np.float64)
        signal = 0.5 * (a.mean() + b.mean()) - params.black_level_dn
        noise = np.std(a - b) / math.sqrt(2)   # temporal: the pair cancels PRNU and DSNU
        analytic = cam.snr(lum, exposure, gain)
        assert signal / noise == pytest.approx(analytic, rel=0.10)
        assert signal / k == pytest.approx(electrons, rel=0.05)


def test_illuminance_for_snr():
    params = preset("mv_global_shutter")
    cam = FrameCamera(params, SHAPE)
    lux = illuminance_for_snr(params, target_snr=1.0, exposure_s=0.01, albedo=0.5)
    luminance = 0.5 * lux / math.pi
    assert cam.snr(luminance, 0.01) == pytest.approx(1.0, rel=0.01)
    assert illuminance_for_snr(params, 1.0, exposure_s=0.001, albedo=0.5) > 5 * lux
    # the ideal camera is limited by quantisation alone
    ideal = preset("ideal")
    lux_ideal = illuminance_for_snr(ideal, 10.0, exposure_s=0.01)
    assert FrameCamera(ideal, SHAPE).snr(0.18 * lux_ideal / math.pi, 0.01) == \
        pytest.approx(10.0, rel=0.01)


def test_subframe_times():
    times = subframe_times(1.0, 0.01, 0.0005, 100)
    assert len(times) == 20
    assert times[0] == pytest.approx(0.99025) and times[-1] == pytest.approx(0.99975)
    assert len(subframe_times(1.0, 0.01, 0.0005, 8)) == 8
    assert len(subframe_times(1.0, 1e-5, 0.0005, 8)) == 1
    assert subframe_times(1.0, 1e-5, 0.0005, 8)[0] == pytest.approx(1.0 - 5e-6)


def bar_subframes(velocity_px_s, exposure_s, t_end_s, width=4.0, start_px=10.0,
                  luminance=150.0, shape=(8, 64)):
    """A bright vertical bar [x, x + width) rendered with exact pixel coverage at each
    sub-frame time, starting at start_px at the exposure's start."""
    times = subframe_times(t_end_s, exposure_s, 2.5e-4, 200)
    edges = np.arange(shape[1] + 1, dtype=np.float64)
    frames = []
    for t in times:
        x = start_px + velocity_px_s * (t - (t_end_s - exposure_s))
        cover = np.clip(np.minimum(edges[1:], x + width) - np.maximum(edges[:-1], x), 0, 1)
        frames.append(np.broadcast_to(luminance * cover, shape))
    return np.asarray(frames, np.float32)


@pytest.mark.parametrize("velocity", [0.0, 2000.0])
def test_motion_blur_smears_by_velocity_times_exposure(velocity):
    exposure, width = 0.01, 4.0
    cam = FrameCamera(preset("ideal"), (8, 64))
    frame = cam.expose(bar_subframes(velocity, exposure, 1.0, width), 1.0, exposure)
    profile = frame.raw.astype(np.float64).mean(axis=0)
    lit = np.flatnonzero(profile > 0.02 * profile.max())
    smear = lit[-1] - lit[0] + 1 - width
    assert smear == pytest.approx(velocity * exposure, abs=0.1 * 20.0)
    assert frame.saturated_fraction == 0.0


def test_colour_frames_measure_channels_independently():
    cam = FrameCamera(preset("ideal"), SHAPE)
    rgb = np.zeros((*SHAPE, 3), np.float32)
    rgb[..., 1] = 200.0
    frame = cam.expose(rgb, 0.0, 1e-3)
    assert frame.raw.shape == (*SHAPE, 3) and frame.image.shape == (*SHAPE, 3)
    assert np.all(frame.raw[..., [0, 2]] == 0) and np.all(frame.raw[..., 1] > 0)
    mono = cam.expose(flat(200.0), 0.0, 1e-3)
    np.testing.assert_array_equal(mono.raw, frame.raw[..., 1])


def run_ae(cam, luminances):
    frames = [cam.expose(flat(lum, cam.shape), t_end_s=i / 100) for i, lum in
              enumerate(luminances)]
    means = [float(np.mean((f.raw - cam.params.black_level_dn)
                           / (cam.params.max_dn - cam.params.black_level_dn))) for f in frames]
    return frames, means


def test_auto_exposure_step_lag_and_convergence():
    params = preset("mv_global_shutter")
    lag, step_at, n = params.ae_lag_frames, 20, 40
    scene = [100.0] * step_at + [1e4] * (n - step_at)
    frames, means = run_ae(FrameCamera(params, (32, 32), seed=2), scene)
    control, _ = run_ae(FrameCamera(params, (32, 32), seed=2), [100.0] * n)
    # settled on the dim scene first
    assert means[step_at - 1] == pytest.approx(params.ae_target, rel=0.2)
    exposure = [f.exposure_s for f in frames]
    # frames up to step + lag - 1 were committed before the step was seen
    for i in range(step_at + lag):
        assert exposure[i] == control[i].exposure_s
    assert exposure[step_at + lag] < exposure[step_at] / 4
    assert frames[step_at].saturated_fraction == 1.0
    for i in range(step_at + 10, n):
        assert means[i] == pytest.approx(params.ae_target, rel=0.2)
    # 100x the light, about 1/100 the exposure, still at 0 dB
    assert exposure[-1] == pytest.approx(exposure[step_at - 1] / 100, rel=0.25)
    assert frames[-1].gain_db == 0.0


def test_auto_exposure_in_the_dark_spends_exposure_then_gain():
    params = preset("mv_global_shutter")
    cam = FrameCamera(params, (32, 32), seed=4)
    frames, _ = run_ae(cam, [0.2] * 30)
    cap = params.ae_exposure_cap_s
    for f in frames:
        assert f.gain_db == 0.0 or f.exposure_s == cap
    assert frames[0].exposure_s == params.ae_start_exposure_s
    assert frames[-1].exposure_s == cap and frames[-1].gain_db == pytest.approx(24.0)
    assert cam.exposure_s == cap and cam.gain_db == pytest.approx(params.gain_db_max)


def test_centre_metering_ignores_the_border():
    params = preset("mv_global_shutter", ae_metering="centre")
    scene = np.zeros((32, 32), np.float32)
    scene[8:24, 8:24] = 100.0
    cam = FrameCamera(params, (32, 32))
    for i in range(25):
        frame = cam.expose(scene, i / 100)
    s = (frame.raw.astype(np.float64) - params.black_level_dn) / \
        (params.max_dn - params.black_level_dn)
    assert s[8:24, 8:24].mean() == pytest.approx(params.ae_target, rel=0.2)


def test_manual_exposure_leaves_auto_exposure_alone():
    params = preset("mv_global_shutter")
    cam = FrameCamera(params, SHAPE, seed=1)
    twin = FrameCamera(params, SHAPE, seed=1)
    for i in range(3):
        cam.expose(flat(50.0), i / 100)
        twin.expose(flat(50.0), i / 100)
    before = (cam.exposure_s, cam.gain_db)
    for lum in (1e5, 0.0):
        manual = cam.expose(flat(lum), 1.0, exposure_s=0.002, gain_db=6.0)
        assert (manual.exposure_s, manual.gain_db) == (0.002, 6.0)
    assert (cam.exposure_s, cam.gain_db) == before
    # the queued corrections are untouched too
    for i in range(3):
        assert cam.expose(flat(50.0), 2.0).exposure_s == twin.expose(flat(50.0), 2.0).exposure_s


def test_frame_timing():
    params = preset("mv_global_shutter")
    frame = FrameCamera(params, SHAPE).expose(flat(10.0), t_end_s=2.0, exposure_s=0.004)
    assert frame.t_start_s == pytest.approx(1.996)
    assert frame.t_end_s == 2.0
    assert frame.t_ready_s == pytest.approx(2.0 + params.readout_s)


def test_same_seed_same_frame():
    params = preset("mv_global_shutter")
    subframes = np.stack([flat(30.0), flat(60.0)])
    a = FrameCamera(params, SHAPE, seed=7).expose(subframes, 1.0)
    b = FrameCamera(params, SHAPE, seed=7).expose(subframes, 1.0)
    c = FrameCamera(params, SHAPE, seed=8).expose(subframes, 1.0)
    np.testing.assert_array_equal(a.raw, b.raw)
    np.testing.assert_array_equal(a.image, b.image)
    assert not np.array_equal(a.raw, c.raw)


def test_tone_curves():
    lum = np.linspace(0.0, 2000.0, 64, dtype=np.float32)[None, :].repeat(4, axis=0)
    images = {tone: FrameCamera(preset("ideal", tone=tone), (4, 64)).expose(
        lum, 0.0, 1e-3).image.astype(int) for tone in ("srgb", "gamma", "linear")}
    middle = slice(5, 40)
    assert np.all(images["srgb"][:, middle] > images["linear"][:, middle])
    assert np.all(images["gamma"][:, middle] > images["linear"][:, middle])
    assert np.all(np.diff(images["srgb"][0]) >= 0)


@pytest.mark.parametrize("overrides, field", [
    ({"adc_bits": 20}, "adc_bits"),
    ({"adc_bits": 12.0}, "adc_bits"),
    ({"tone": "log"}, "tone"),
    ({"read_noise_e": -1.0}, "read_noise_e"),
    ({"quantum_efficiency": 1.5}, "quantum_efficiency"),
    ({"full_well_e": float("nan")}, "full_well_e"),
    ({"shot_noise": 1}, "shot_noise"),
    ({"ae_lag_frames": 0}, "ae_lag_frames"),
    ({"ae_metering": "spot"}, "ae_metering"),
    ({"exposure_max_s": 1e-6}, "exposure_max_s"),
    ({"black_level_dn": 5000.0}, "black_level_dn"),
])
def test_validation_names_the_field(overrides, field):
    with pytest.raises(ValueError, match=field):
        preset("mv_global_shutter", **overrides)


def test_preset_and_input_errors():
    with pytest.raises(ValueError, match="unknown frame camera preset"):
        preset("nope")
    with pytest.raises(ValueError, match="'bogus'"):
        preset("ideal", bogus=1)
    cam = FrameCamera(preset("mv_global_shutter"), SHAPE)
    with pytest.raises(ValueError, match="shape"):
        cam.expose(np.zeros((10, 10), np.float32), 0.0)
    with pytest.raises(ValueError, match="dtype"):
        cam.expose(np.zeros(SHAPE, np.uint8), 0.0)
    with pytest.raises(ValueError, match=">= 0"):
        cam.expose(flat(-1.0), 0.0)
    with pytest.raises(ValueError, match="finite"):
        cam.expose(flat(np.inf), 0.0)
    with pytest.raises(ValueError, match="exposure_s"):
        cam.expose(flat(1.0), 0.0, exposure_s=1.0)
    with pytest.raises(ValueError, match="gain_db"):
        cam.expose(flat(1.0), 0.0, exposure_s=1e-3, gain_db=40.0)
    with pytest.raises(ValueError, match="gain_db"):
        cam.expose(flat(1.0), 0.0, gain_db=6.0)
