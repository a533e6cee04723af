"""Scenes declare their light in physical units (Scene.photometry), the HDR condition's
emitters (nav windows, the arm's lamp panel), the generalised flicker, and the physical
evaluation conditions."""
import math
from pathlib import Path

import numpy as np
import pytest

from sebvs.sim import make_scene  # sets MUJOCO_GL before mujoco
from sebvs.sim.render import FrameRenderer
from sebvs.sim.scene import DIM_LEVELS, HDR_LAMP, NOMINAL_LEVELS

import mujoco  # noqa: E402

GEOM = mujoco.mjtObj.mjOBJ_GEOM
DIM = sum(DIM_LEVELS) / sum(NOMINAL_LEVELS)         # 0.16


def build(task, seed=0, **config):
    scene = make_scene(task, **config)
    model = scene.compile()
    data = mujoco.MjData(model)
    scene.reset(model, data, np.random.default_rng(seed))
    return scene, model, data


# ---------------------------------------------------------------- photometry
@pytest.mark.parametrize("task, variant, nominal, hdr", [
    ("nav", "indoor", 400.0, 30.0), ("nav", "outdoor", 1e4, 50.0), ("arm", None, 500.0, 30.0)])
def test_photometry_per_lighting_and_variant(task, variant, nominal, hdr):
    kw = {"variant": variant} if variant else {}
    outdoor = variant == "outdoor"

    def ph(lighting, **more):
        return make_scene(task, lighting=lighting, **kw, **more).photometry()

    p = ph("nominal")
    assert p.illuminance_lux == nominal and p.render_level == pytest.approx(1.0)
    assert p.emissive == {} and p.flicker is None
    # the overcast sky that lights the ground at E has luminance E / pi
    assert p.sky_cd_m2 == (pytest.approx(nominal / math.pi) if outdoor else None)
    # a white lit surface renders at about render_level, i.e. has luminance E / pi
    assert p.unit_cd_m2 * p.render_level == pytest.approx(nominal / math.pi)

    p = ph("low")
    assert p.illuminance_lux == pytest.approx(nominal * 0.16)
    assert p.render_level == pytest.approx(0.16) and p.emissive == {}
    # the same physical lights as nominal: a pixel value means the same luminance
    assert p.unit_cd_m2 == pytest.approx(ph("nominal").unit_cd_m2)

    p = ph("dusk")
    assert p.illuminance_lux == 3.0 and p.render_level == pytest.approx(0.16)
    assert p.sky_cd_m2 == (pytest.approx(3.0 / math.pi) if outdoor else None)
    assert ph("dusk", dusk_lux=8.0).illuminance_lux == 8.0

    p = ph("hdr")
    assert p.illuminance_lux == hdr and p.render_level == pytest.approx(0.16)
    if outdoor:     # the sky is the emitter; no windows
        assert p.emissive == {} and p.sky_cd_m2 == 1e4
    else:
        assert p.emissive == {HDR_LAMP: 1e4} and p.sky_cd_m2 is None
    p = ph("hdr", hdr_lux=12.0, lamp_cd_m2=2e3)
    assert p.illuminance_lux == 12.0
    assert (p.sky_cd_m2 if outdoor else p.emissive[HDR_LAMP]) == 2e3
    # the emitter against a white surface in the shade: 1e4 / (30 / pi) ~ 60 dB indoors
    assert p.peak_cd_m2() == 2e3

    p = ph("flicker", flicker_hz=100.0, flicker_depth=0.5)
    assert p.illuminance_lux == nominal and p.flicker == (100.0, 0.5)
    assert ph("flicker").flicker == (10.0, 0.35)
    assert ph("nominal", illuminance_lux=250.0).illuminance_lux == 250.0
    assert ph("low", illuminance_lux=250.0).illuminance_lux == pytest.approx(40.0)


def test_light_levels_are_dim_for_low_dusk_and_hdr():
    for lighting in ("low", "dusk", "hdr"):
        assert make_scene("nav", lighting=lighting).light_levels() == DIM_LEVELS
        assert make_scene("arm", lighting=lighting).light_levels() == DIM_LEVELS
    for lighting in ("nominal", "flicker"):
        assert make_scene("arm", lighting=lighting).light_levels() == NOMINAL_LEVELS


@pytest.mark.parametrize("task", ["nav", "arm"])
@pytest.mark.parametrize("key, bad", [
    ("illuminance_lux", 0), ("illuminance_lux", -5.0), ("illuminance_lux", "bright"),
    ("illuminance_lux", math.inf), ("dusk_lux", 0.0), ("dusk_lux", None), ("hdr_lux", -1.0),
    ("hdr_lux", True), ("lamp_cd_m2", 0.0), ("lamp_cd_m2", 2e9), ("lamp_cd_m2", math.nan),
    ("flicker_depth", 0.0), ("flicker_depth", 0.6), ("flicker_depth", None),
    ("lighting", "twilight")])
def test_bad_light_config_is_named(task, key, bad):
    with pytest.raises(ValueError, match=key):
        make_scene(task, **{key: bad})


# ---------------------------------------------------------------- the flicker
@pytest.mark.parametrize("task", ["nav", "arm"])
def test_flicker_default_is_unchanged_and_depth_generalises_it(task):
    scene, model, data = build(task, lighting="flicker")
    phase, hz = scene.flicker_phase, scene.config["flicker_hz"]
    base = model.light_diffuse.copy()
    for t in (0.0, 0.013, 0.05, 0.1234, 0.7):
        s = 0.65 + 0.35 * math.sin(2 * math.pi * hz * t + phase)    # the scale before depth
        assert scene.flicker_scale(t) == s                           # bit for bit
        data.time = t
        scene.flicker(model, data)
        np.testing.assert_array_equal(model.light_diffuse, scene.base_diffuse * s)
    assert (base > 0).any()
    deep = make_scene(task, lighting="flicker", flicker_depth=0.5, flicker_hz=100.0)
    deep.flicker_phase = 0.0
    assert deep.flicker_scale(0.0025) == pytest.approx(1.0)         # a quarter period
    assert deep.flicker_scale(0.0075) == pytest.approx(0.0, abs=1e-12)
    nominal, _, nominal_data = build(task)
    nominal_data.time = 0.2
    diffuse = model.light_diffuse.copy()
    nominal.flicker(model, nominal_data)                             # not "flicker": no-op
    np.testing.assert_array_equal(model.light_diffuse, diffuse)


# ---------------------------------------------------------------- HDR geometry
def _render(model, data, camera, size=64):
    with FrameRenderer(model, size, size) as r:
        r.update(data, camera)
        return r.rgb().copy(), r.segmentation().copy()


def test_hdr_geometry_only_under_hdr_and_mjcf_from_config_only():
    for task, kw in (("nav", {"variant": "indoor"}), ("arm", {})):
        for lighting in ("nominal", "low", "flicker", "dusk"):
            assert HDR_LAMP not in make_scene(task, lighting=lighting, **kw).mjcf()
        a, b = (make_scene(task, lighting="hdr", **kw) for _ in range(2))
        assert HDR_LAMP in a.mjcf() and a.mjcf() == b.mjcf()
    out = make_scene("nav", variant="outdoor", lighting="hdr").mjcf()
    assert HDR_LAMP not in out
    assert out == make_scene("nav", variant="outdoor", lighting="low").mjcf()


def test_nav_indoor_windows_are_in_view_above_the_target():
    scene, model, data = build("nav", lighting="hdr")
    lamp = [model.geom(f"window_{n}").id for n in "nsew"]
    assert all(model.geom_contype[g] == 0 and model.geom_conaffinity[g] == 0 for g in lamp)
    target = model.geom("target").id
    for seed in range(3):
        scene.reset(model, data, np.random.default_rng(seed))
        ref_scene, ref_model, ref_data = build("nav", seed=seed)       # same episode, nominal
        _, ref_seg = _render(ref_model, ref_data, "front")
        for yaw in (0.0, math.pi / 2, math.pi, -math.pi / 2):         # whichever way it faces
            data.qpos[scene.qadr[2]] = yaw
            scene.kinematics(model, data)
            rgb, seg = _render(model, data, "front")
            bright = rgb.min(axis=2) >= 250
            window = np.isin(seg[..., 0], lamp) & (seg[..., 1] == GEOM)
            assert 0.10 <= bright.mean() <= 0.30, (seed, yaw, bright.mean())
            assert (bright == window).mean() > 0.99          # the windows are what is white
            rows = np.nonzero(window.any(axis=1))[0]
            assert rows.max() < 64 / 2                       # above the horizon
        data.qpos[scene.qadr[2]] = 0.0
        scene.kinematics(model, data)
        _, seg = _render(model, data, "front")
        rows = np.nonzero((np.isin(seg[..., 0], lamp) & (seg[..., 1] == GEOM)).any(axis=1))[0]
        mask = (seg[..., 0] == target) & (seg[..., 1] == GEOM)
        ref = (ref_seg[..., 0] == ref_model.geom("target").id) & (ref_seg[..., 1] == GEOM)
        # the target is as visible as without the windows, all below them
        assert mask.sum() > 0 and np.array_equal(mask, ref)
        assert np.nonzero(mask.any(axis=1))[0].min() > rows.max()


def test_arm_lamp_is_in_the_wrist_view_and_never_covers_a_cube():
    scene, model, data = build("arm", lighting="hdr", objects=3, conveyor="moving",
                               belt_speed=0.25)
    lamp = model.geom(HDR_LAMP).id
    assert model.geom_contype[lamp] == 0 and model.geom_conaffinity[lamp] == 0
    seen = 0
    for seed in range(3):
        scene.reset(model, data, np.random.default_rng(seed))
        ref_scene, ref_model, ref_data = build("arm", seed=seed, objects=3)
        _, ref_seg = _render(ref_model, ref_data, "wrist")
        for k in range(3):                                   # along a moving-belt episode
            rgb, seg = _render(model, data, "wrist")
            bright = rgb.min(axis=2) >= 250
            panel = (seg[..., 0] == lamp) & (seg[..., 1] == GEOM)
            cubes = np.isin(seg[..., 0], scene.cube_geom) & (seg[..., 1] == GEOM)
            assert 0.15 <= bright.mean() <= 0.35, (seed, k, bright.mean())
            assert (bright == panel).mean() > 0.99
            assert not (bright & cubes).any()
            if k == 0:     # at reset: every cube pixel as without the lamp
                ref = np.isin(ref_seg[..., 0], ref_scene.cube_geom) \
                    & (ref_seg[..., 1] == GEOM)
                assert np.array_equal(cubes, ref)
            seen += int(cubes.sum())
            for _ in range(300):
                scene.scripted(model, data)
                mujoco.mj_step(model, data)
    assert seen > 0


# ---------------------------------------------------------------- the physical conditions
def test_physical_conditions_are_separate_from_the_benchmark_and_named():
    from sebvs.conditions import TASKS
    from sebvs.eval.cli import conditions_of
    from sebvs.eval.plan import EvalPlan, Run
    from sebvs.runtime.overrides import leaves, lookup

    NAV_CONDITIONS, ARM_CONDITIONS = TASKS["nav"].names("ideal8"), TASKS["arm"].names("ideal8")
    NAV_PHYSICAL_CONDITIONS = TASKS["nav"].names("physical")
    ARM_PHYSICAL_CONDITIONS = TASKS["arm"].names("physical")
    assert NAV_CONDITIONS == ["nominal", "fast", "low_light", "flicker", "blur",
                              "fast_flicker"]
    assert ARM_CONDITIONS == ["nominal", "moving", "fast", "low_light", "flicker", "blur"]
    assert set(NAV_PHYSICAL_CONDITIONS) == {"nominal_physical", "hdr", "dusk", "dusk_fast",
                                            "flicker_100", "flicker_120", "fast_hdr"}
    assert set(ARM_PHYSICAL_CONDITIONS) == {"nominal_physical", "fast_physical", "hdr",
                                            "dusk_moving", "fast_hdr"}
    assert conditions_of("all", "nav", "ideal8") == NAV_CONDITIONS
    assert conditions_of("all", "nav") == NAV_PHYSICAL_CONDITIONS
    assert conditions_of("physical", "nav") == NAV_PHYSICAL_CONDITIONS
    assert conditions_of("physical", "arm") == ARM_PHYSICAL_CONDITIONS
    assert conditions_of("hdr,physical,hdr", "arm") == [
        "hdr", *(c for c in ARM_PHYSICAL_CONDITIONS if c != "hdr")]
    for task, physical in (("nav", NAV_PHYSICAL_CONDITIONS), ("arm", ARM_PHYSICAL_CONDITIONS)):
        for name in physical:
            parsed = {".".join(p): v for p, v in
                      leaves(TASKS[task].condition(name).overrides())}
            assert parsed["camera.sensor"] == "physical", name
            config = {k.split(".", 2)[2]: v for k, v in parsed.items()
                      if k.startswith("sim.config.")}
            make_scene(task, **config)                       # the scene accepts them
            if config.get("flicker_hz", 0) >= 100:           # mains flicker: no aliasing
                assert parsed["sim.render_hz"] >= 1000 and parsed["camera.dvs_hz"] >= 1000
        plan = EvalPlan(task=task, modalities=["rgb"], conditions=["nominal", *physical],
                        episodes=1, out=Path("/nonexistent"))
        plan.validate()
        for modality in ("expert", "no_action"):
            _, sets = plan.overrides(Run(physical[0], plan.scenarios[0], modality))
            assert lookup(sets, "camera", "sensor") == "physical"
    expected = {"hdr": ("hdr", "nominal", None), "dusk": ("dusk", "nominal", None),
                "dusk_fast": ("dusk", "fast", None), "flicker_100": ("flicker", "nominal", 100.0),
                "flicker_120": ("flicker", "nominal", 120.0), "fast_hdr": ("hdr", "fast", None)}
    for name, (lighting, speed, hz) in expected.items():
        c = TASKS["nav"].condition(name)
        assert (c.lighting, c.target_speed or "nominal", c.flicker_hz) == (lighting, speed, hz)
    arm = TASKS["arm"].conditions
    assert arm["dusk_moving"].belt_speed == 0.08
    assert arm["fast_hdr"].belt_speed == 0.25
    assert (arm["hdr"].conveyor or "static") == "static"
    with pytest.raises(ValueError, match="unknown condition 'dawn'"):
        EvalPlan(task="nav", modalities=["rgb"], conditions=["dawn"], episodes=1,
                 out=Path("/nonexistent")).validate()


def test_the_expert_row_keeps_a_conditions_render_rate():
    """The expert's run takes the policy topology's rates, but a condition's own (the mains
    flicker's 1 kHz renders) win: the expert sees what the policies see."""
    from sebvs.eval.plan import EvalPlan, Run
    from sebvs.runtime.topology import load_topology
    plan = EvalPlan(task="nav", modalities=["rgb"], conditions=["flicker_100"], episodes=1,
                    out=Path("/nonexistent"))
    for modality in ("expert", "rgb"):
        topo = load_topology(*plan.overrides(Run("flicker_100", "indoor", modality)))
        assert topo.actors["sim"].params["render_hz"] == 1000.0, modality
        assert topo.actors["camera"].params["dvs_hz"] == 1000.0, modality
