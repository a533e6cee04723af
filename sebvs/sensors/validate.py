"""Validation of the sensor models against their fields' standards, as measurements.

Each function builds what it measures (a scene, a flat field, an episode), runs the real
code path (radiance renderer, frame camera, event emulator) and returns figures;
tools/bench/bench_sensors.py prints them as JSON and tests/test_sensors_validate.py checks
them at small sizes.

  radiance_range      the radiance render's range: patches from albedo 1 to 1e-9 under a
                      uniform light, decoded against their true luminance
  photon_transfer_errors  EMVA 1288 photon transfer on simulated flat fields: conversion
                      gain and read noise recovered against the configured ones
  snr_curve           the frame camera's SNR against scene illuminance, and where SNR = 1
  blur_length         a bar moving at v px/s rendered through the whole rig (state
                      interpolation, sub-frames, integration) under exposure T: its smear
                      against v * T, from the profile's second moment
  step_range          a 10^4 : 1 luminance step of striped panels panning slowly: per
                      side, the frame camera's lost pixels (clipped, or below SNR 1) and
                      the share of stripe edges the event sensor fires on per 0.1 s
  nav_cell            a nav episode driven by the privileged expert, per control tick the
                      modelled frame's detection and the events' coverage of the target's
                      edges
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from ..sim.render import FrameRenderer  # sets MUJOCO_GL before mujoco is imported

import cv2  # noqa: E402
import mujoco  # noqa: E402

from ..dvs.emulator import EVENT_DTYPE, EventEmulator  # noqa: E402
from ..dvs.params import preset as dvs_preset  # noqa: E402
from ..sim.poses import StateHistory  # noqa: E402
from ..sim.radiance import RadianceRenderer, channel_gains  # noqa: E402
from .framecam import FrameCamera, FrameCameraParams, illuminance_for_snr  # noqa: E402
from .framecam import preset as camera_preset  # noqa: E402
from ..sim.light import Photometry  # noqa: E402
from .ptc import flat_field_series, photon_transfer  # noqa: E402
from .rig import SensorRig  # noqa: E402

_HEAD = """<mujoco>
  <visual><quality offsamples="0" shadowsize="0"/><global offwidth="{w}" offheight="{h}"/>
    <headlight ambient="{amb} {amb} {amb}" diffuse="0 0 0" specular="0 0 0"/>
    <rgba haze="0 0 0 0"/></visual>"""


# ----------------------------------------------------------------------- radiance range
def radiance_range(ratio: float = 16.0, size: int = 128, decades: float = 9.0) -> dict:
    """Decode a grid of patches whose albedo falls from 1 by `decades` decades, lit by a
    uniform ambient light of 1 (luminance = albedo x unit), against their truth."""
    n = 8
    albedo = 10.0 ** (-np.arange(n * n) * decades / (n * n - 1))
    step = 2.0 / n
    geoms = "\n".join(
        f'<geom type="box" size="{step / 2:g} {step / 2:g} 0.01" '
        f'pos="{-1 + step * (i % n + 0.5):g} {1 - step * (i // n + 0.5):g} 0" '
        f'rgba="{a:.6e} {a:.6e} {a:.6e} 1"/>' for i, a in enumerate(albedo))
    xml = _HEAD.format(w=size, h=size, amb=1.0) + f"""
  <worldbody>{geoms}
    <camera name="top" pos="0 0 2" xyaxes="1 0 0 0 1 0" fovy="{2 * math.degrees(math.atan(0.5)):g}"/>
  </worldbody></mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    photometry = Photometry(illuminance_lux=math.pi)          # unit: 1 cd/m^2
    with RadianceRenderer(model, photometry, size, size, ratio) as rr:
        rr.update(data, "top")
        lum = rr.luminance().astype(np.float64)
        top, floor = rr.top_cd_m2, rr.floor_cd_m2
    cell = size // n
    measured = np.array([np.median(lum[(i // n) * cell + cell // 4:(i // n + 1) * cell - cell // 4,
                                       (i % n) * cell + cell // 4:(i % n + 1) * cell - cell // 4])
                         for i in range(n * n)])
    truth = albedo * photometry.unit_cd_m2
    gains = channel_gains(ratio)
    lsb_blue = top / (255.0 * gains[2])
    # the channel each patch reads from: the most exposed one that has not clipped
    channel = np.select([truth < 254 * lsb_blue, truth < 254 * lsb_blue * gains[2] / gains[1]],
                        [2, 1], 0)
    lsb = top / (255.0 * gains[channel])
    inside = (truth <= top) & (truth >= lsb_blue)
    err_lsb = np.abs(measured - truth) / lsb
    rel = np.abs(measured - truth) / truth
    ok5 = inside & (rel <= 0.05)
    detectable = (truth <= top) & (rel <= 0.5)
    return {
        "ratio": ratio, "top_cd_m2": top, "floor_cd_m2": floor,
        "dynamic_range_db": 20 * math.log10(top / floor),
        "max_error_lsb": float(err_lsb[inside].max()),
        "range_5pct_db": 20 * math.log10(truth[ok5].max() / truth[ok5].min()),
        "range_detectable_db": 20 * math.log10(truth[detectable].max()
                                               / truth[detectable].min()),
        "patches": {"truth_cd_m2": truth.tolist(), "measured_cd_m2": measured.tolist()},
    }


# ----------------------------------------------------------------------- frame camera
def photon_transfer_errors(params: FrameCameraParams, gain_db: float = 0.0,
                           seed: int = 0) -> dict:
    """EMVA photon transfer on 20 flat-field pairs: recovered K and read noise against the
    configured ones (relative errors)."""
    levels = np.linspace(0.02, 0.98, 20)
    pairs, dark = flat_field_series(params, levels, seed=seed, gain_db=gain_db)
    fit = photon_transfer(pairs, dark)
    k_true = params.conversion_gain(gain_db)
    return {"gain_db": gain_db, "gain_dn_per_e": fit["gain_dn_per_e"],
            "gain_true": k_true, "read_noise_e": fit["read_noise_e"],
            "read_noise_true": params.read_noise_e,
            "gain_error": abs(fit["gain_dn_per_e"] / k_true - 1),
            "read_noise_error": abs(fit["read_noise_e"] / params.read_noise_e - 1)}


def snr_curve(params: FrameCameraParams, exposure_s: float, albedo: float = 0.5,
              lux=None) -> dict:
    """Analytic SNR of a Lambertian surface against illuminance at a fixed exposure and
    0 dB, and the illuminance where SNR = 1."""
    lux = np.logspace(-3, 5, 33) if lux is None else np.asarray(lux, np.float64)
    cam = FrameCamera(params, (1, 1))
    lum = albedo * lux / math.pi
    well = cam.electrons_per_s(lum) * exposure_s >= params.full_well_e
    snr = np.where(well, 0.0, cam.snr(lum, exposure_s))
    return {"exposure_s": exposure_s, "albedo": albedo, "lux": lux.tolist(),
            "snr": snr.tolist(),
            "lux_at_snr1": illuminance_for_snr(params, 1.0, exposure_s=exposure_s,
                                               albedo=albedo)}


def _strip_scene(size: int, fovy: float, extra: str, assets: str = "") -> mujoco.MjModel:
    xml = _HEAD.format(w=size, h=size, amb=0.0) + f"""
  <asset>{assets}</asset>
  <worldbody>
    <light pos="0 0 5" dir="0 0 -1" directional="true" diffuse="1 1 1" specular="0 0 0"
           castshadow="false"/>
    {extra}
    <camera name="cam" pos="0 0 2" xyaxes="1 0 0 0 1 0" fovy="{fovy:g}"/>
  </worldbody></mujoco>"""
    return mujoco.MjModel.from_xml_string(xml)


def blur_length(speed_px_s: float = 2000.0, exposure_s: float = 0.01, size: int = 96,
                subframe_s: float = 0.0005, max_subframes: int = 256, seed: int = 0) -> dict:
    """A white bar on a black ground crossing the image at `speed_px_s`, exposed for
    `exposure_s` by the rig: the smear against speed x exposure. The smear is
    sqrt(12 (var_moving - var_still)) of the column profile (a box of width s convolved
    with the bar adds s^2 / 12 to its variance)."""
    fovy = 60.0
    f = 0.5 * size / math.tan(math.radians(fovy) / 2)          # px per (m / m)
    metres_per_px = 2.0 / f                                    # at the plane 2 m away
    bar = f'''<body name="bar" mocap="true" pos="0 0 0.01">
      <geom type="box" size="{2 * metres_per_px:g} 1 0.005" rgba="1 1 1 1"/></body>'''
    model = _strip_scene(size, fovy, bar)
    data = mujoco.MjData(model)
    params = replace(camera_preset("mv_global_shutter"), read_noise_e=0.0, dsnu_e=0.0,
                     prnu=0.0, dark_current_e_per_s=0.0)
    photometry = Photometry(illuminance_lux=200.0)
    profiles = {}
    with FrameRenderer(model, size, size) as colour:
        rig = SensorRig(colour, photometry, params, 10.0, subframe_s=subframe_s,
                        max_subframes=max_subframes)
        try:
            for label, speed in (("still", 0.0), ("moving", speed_px_s)):
                rig.new_episode(seed)
                history = StateHistory(1.0)
                x0 = -0.5 * speed * exposure_s * metres_per_px
                for t in np.linspace(0.0, exposure_s, 11):
                    history.add(float(t), {"qpos": data.qpos.copy(),
                                           "mocap_pos": np.array([[x0 + speed * t * metres_per_px,
                                                                   0.0, 0.01]]),
                                           "mocap_quat": np.array([[1.0, 0, 0, 0]])})

                def pose(state):
                    data.mocap_pos[:] = state["mocap_pos"]
                    mujoco.mj_forward(model, data)
                rig.frame(history, pose, data, "cam", exposure_s, lambda s: 1.0,
                          exposure_s=exposure_s)
                profiles[label] = rig.mean_luminance.mean(axis=0)
        finally:
            rig.close()
    x = np.arange(size) + 0.5

    def variance(p):
        w = p / p.sum()
        mu = (w * x).sum()
        return (w * (x - mu) ** 2).sum()
    smear = math.sqrt(max(12 * (variance(profiles["moving"]) - variance(profiles["still"])), 0))
    expected = speed_px_s * exposure_s
    return {"speed_px_s": speed_px_s, "exposure_s": exposure_s, "smear_px": smear,
            "expected_px": expected, "blur_length_error": abs(smear / expected - 1)}


# ----------------------------------------------------------------------- dynamic range
def step_range(ratio_lux: float = 1e4, size: int = 96, seconds: float = 0.6,
               dvs_hz: float = 500.0, seed: int = 0) -> dict:
    """Two striped panels, the right one self-luminous at `ratio_lux` x the left one's
    luminance, panning slowly under the camera. After the frame camera's auto exposure
    settles: per side, its lost pixels (top code, or SNR < 1 at their luminance), and
    the share of stripe edges the event sensor fires on per 0.1 s."""
    fovy = 60.0
    f = 0.5 * size / math.tan(math.radians(fovy) / 2)
    half_w = size / f                                         # half the view at 2 m, m
    assets = ('<texture name="stripes" type="2d" builtin="checker" rgb1="0.8 0.8 0.8" '
              'rgb2="0.2 0.2 0.2" width="64" height="64"/>'
              '<material name="dim" texture="stripes" texrepeat="6 1"/>'
              '<material name="bright" texture="stripes" texrepeat="6 1" emission="1"/>')
    panels = f'''<body name="panels" mocap="true" pos="0 0 0">
      <geom type="box" size="{half_w / 2:g} {half_w * 2:g} 0.01" pos="{-half_w / 2:g} 0 0"
            material="dim"/>
      <geom type="box" size="{half_w / 2:g} {half_w * 2:g} 0.01" pos="{half_w / 2:g} 0 0"
            material="bright"/></body>'''
    model = _strip_scene(size, fovy, panels, assets)
    data = mujoco.MjData(model)
    lux = 10.0
    # the lit side: a white texel renders at ~1 x 0.8 x unit under the directional light
    photometry = Photometry(illuminance_lux=lux, emissive={"bright": ratio_lux * lux / math.pi})
    speed_m_s = 40.0 / f                                       # 40 px/s
    emulator = EventEmulator(dvs_preset("physical", downsample=1.0, blur=False, seed=seed))
    frame_params = camera_preset("mv_global_shutter")
    out = {}
    with FrameRenderer(model, size, size) as colour:
        rig = SensorRig(colour, photometry, frame_params, 10.0)
        try:
            rig.new_episode(seed)
            history = StateHistory(1.0)
            events = []
            n = int(round(seconds * dvs_hz))
            for i in range(n + 1):
                t = i / dvs_hz
                # the step's edge pans from left of centre to right of it
                data.mocap_pos[0] = [speed_m_s * (t - seconds / 2), 0.0, 0.0]
                mujoco.mj_forward(model, data)
                state = {"qpos": data.qpos.copy(), "mocap_pos": data.mocap_pos.copy(),
                         "mocap_quat": data.mocap_quat.copy()}
                history.add(t, state)
                lum = rig.luminance(data, "cam", 1.0)
                ev = emulator.step_luminance(lum, round(t * 1e9))
                if t > seconds - 0.1:
                    events.append(ev)
            last_lum = lum.copy()

            def pose(s):
                data.mocap_pos[:] = s["mocap_pos"]
                mujoco.mj_forward(model, data)
            for _ in range(30):                        # let the auto exposure settle
                frame = rig.frame(history, pose, data, "cam", seconds, lambda s: 1.0)
        finally:
            rig.close()
    cam = rig.camera
    snr = cam.snr(rig.mean_luminance, frame.exposure_s, frame.gain_db)
    lost = (frame.raw >= frame_params.max_dn).any(axis=-1) | (snr < 1.0)
    ev = np.concatenate(events)
    fired = np.zeros((size, size), bool)
    fired[ev["y"], ev["x"]] = True
    fired = cv2.dilate(fired.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    edges = _edges(last_lum)
    boundary = round(size / 2 + f * speed_m_s * seconds / 2 / 2.0)   # px, the camera 2 m up
    for side, cols in (("dim", slice(2, boundary - 3)), ("bright", slice(boundary + 3, size - 2))):
        e = edges[:, cols]
        out[side] = {"frame_lost_fraction": float(lost[:, cols].mean()),
                     "event_edge_coverage": float(fired[:, cols][e].mean()) if e.any() else 0.0,
                     "edge_pixels": int(e.sum())}
    out.update({"ratio": ratio_lux, "exposure_s": frame.exposure_s, "gain_db": frame.gain_db})
    return out


def _edges(lum: np.ndarray, contrast: float = 0.5) -> np.ndarray:
    """Pixels on a luminance edge: log-luminance differs from a 4-neighbour by more than
    `contrast`."""
    log = np.log(np.maximum(lum, 1e-6))
    e = np.zeros(lum.shape, bool)
    dx = np.abs(np.diff(log, axis=1)) > contrast
    dy = np.abs(np.diff(log, axis=0)) > contrast
    e[:, 1:] |= dx
    e[:, :-1] |= dx
    e[1:, :] |= dy
    e[:-1, :] |= dy
    return e


# ----------------------------------------------------------------------- nav cells
def mask_edges(mask: np.ndarray) -> np.ndarray:
    """The boundary pixels of a boolean mask (the mask less its 3x3 erosion)."""
    m = mask.astype(np.uint8)
    return mask & ~cv2.erode(m, np.ones((3, 3), np.uint8)).astype(bool)


def edge_coverage(packets: list[np.ndarray], edges: np.ndarray,
                  background: np.ndarray) -> tuple[float, float]:
    """The share of `edges` pixels with an event of `packets` in their 3 x 3
    neighbourhood, and the same share of `background` pixels (what noise alone covers)."""
    ev = np.concatenate(packets) if packets else np.zeros(0, EVENT_DTYPE)
    fired = np.zeros(edges.shape, np.uint8)
    fired[ev["y"], ev["x"]] = 1
    fired = cv2.dilate(fired, np.ones((3, 3), np.uint8)).astype(bool)
    return float(fired[edges].mean()), float(fired[background].mean())


def _above_noise(coverage: list[tuple[float, float]]) -> float:
    """Mean over windows of the edge coverage beyond what noise covers anyway:
    (edge - background) / (1 - background), 0 when noise covers as much."""
    if not coverage:
        return float("nan")
    return float(np.mean([max(e - b, 0.0) / (1.0 - b) if b < 1 else 0.0
                          for e, b in coverage]))


def sensor_cell(task: str, config: dict, seed: int = 0, episode_s: float = 6.0,
                control_hz: float = 10.0, dvs_hz: float = 100.0, physics_hz: float = 1000.0,
                size: int = 160, frame_camera: str = "mv_global_shutter",
                event_preset: str = "physical", frame_rate_hz: float | None = None) -> dict:
    """One episode of `task` ("nav" or "arm") under scene `config`, seen by both modelled
    sensors. Nav is driven by its expert on the ideal render (the expert's privileged
    view); the arm holds its home pose over the belt, as it does until its grasp, so
    its wrist camera watches the cubes pass.

    Per control tick, on the target's pixels (segmentation; nav: the cube, arm: the
    target cube of the truth): does the colour detector (tuned to the target's colour)
    find it in the modelled frame (centroid inside the target's box, 2 px margin); what
    share of its pixels the frame lost (top code, or SNR < 1 at their luminance); what
    share of its edge pixels the event sensor fired on (3 x 3 neighbourhood) in the
    tick's window beyond what noise alone covers on flat background ((edge - bg) /
    (1 - bg); raw and background beside it), and the same for the ideal pixel (preset
    clean, the same log range) on the same light: the most the scene's motion gives any
    sensor. Ticks of the first second (auto exposure settling) and ticks where the
    target shows fewer than 9 pixels are not scored. The camera runs at
    `frame_rate_hz` (default the control rate, as the camera actor), its exposure capped
    at one frame period."""
    from ..experts.detector import ColorDetector
    from ..experts.nav import NavExpert, NavExpertConfig
    from ..metrics import nav_episode_metrics
    from ..sim import make_scene

    if task not in ("nav", "arm"):
        raise ValueError(f"sensor_cell: task must be nav or arm, got {task!r}")
    cfg = {"width": size, "height": size, **config, "timestep": 1.0 / physics_hz,
           "integrator": "discrete"}
    scene = make_scene(task, **cfg)
    model = scene.compile()
    data = mujoco.MjData(model)
    scene.reset(model, data, np.random.default_rng(seed))
    cam_name = scene.cameras[0]
    expert = NavExpert(NavExpertConfig()) if task == "nav" else None
    if expert is not None:
        expert.reset()
    chip = dvs_preset(event_preset, downsample=1.0, seed=seed)
    emulator = EventEmulator(chip)
    reference = EventEmulator(dvs_preset("clean", downsample=1.0, seed=seed,
                                         reference_cd_m2=chip.reference_cd_m2))
    params = camera_preset(frame_camera)
    steps_render = int(round(physics_hz / dvs_hz))
    steps_control = int(round(physics_hz / control_hz))
    n_steps = int(round(episode_s * physics_hz))
    history = StateHistory(params.exposure_max_s + params.readout_s + 0.05)
    ideal = np.empty((size, size, 3), np.uint8)
    hits, lost, coverage, coverage_ideal, truths, exposures = [], [], [], [], [], []
    expert_hits = []
    window: list[np.ndarray] = []
    window_ideal: list[np.ndarray] = []

    def pose(state):
        scene.set_state(model, data, state)
        scene.kinematics(model, data)

    def target_of(truth) -> tuple[int, tuple]:
        """(geom id, colour) of the target, or (-1, ()) when there is none."""
        if task == "nav":
            return model.geom("target").id, tuple(model.geom_rgba[model.geom("target").id, :3])
        k = truth["target"]
        return (int(scene.cube_geom[k]), tuple(truth["cubes"][k]["rgb"])) if k >= 0 else (-1, ())

    def found(det, mask) -> bool:
        if det is None:
            return False
        rows, cols = np.nonzero(mask)
        return bool(cols.min() - 2 <= det.centroid[0] <= cols.max() + 3
                    and rows.min() - 2 <= det.centroid[1] <= rows.max() + 3)

    command = scene.idle_command()
    with FrameRenderer(model, size, size) as colour:
        rig = SensorRig(colour, scene.photometry(), params, frame_rate_hz or control_hz)
        rig.new_episode(seed)
        try:
            for step in range(n_steps + 1):
                if step % steps_render == 0:
                    t = data.time
                    state = scene.state(data)
                    history.add(t, state)
                    scene.kinematics(model, data)
                    lum = rig.luminance(data, cam_name, getattr(scene, "light_scale", 1.0))
                    window.append(emulator.step_luminance(lum, round(t * 1e9)))
                    window_ideal.append(reference.step_luminance(lum, round(t * 1e9)))
                if step % steps_control == 0:
                    flat = ~cv2.dilate(_edges(lum, 0.05).astype(np.uint8),
                                       np.ones((9, 9), np.uint8)).astype(bool)
                    truth = scene.truth(model, data)
                    colour.update(data, cam_name)
                    colour.rgb(ideal)
                    seg = colour.segmentation()
                    geom, rgb = target_of(truth)
                    target = (seg[..., 0] == geom) & (seg[..., 1] == int(mujoco.mjtObj.mjOBJ_GEOM))
                    detector = ColorDetector(rgb=rgb) if geom >= 0 else None
                    if expert is not None:
                        command = expert.act(detector.detect(ideal), (size, size),
                                             1.0 / control_hz)
                    scored = t >= 1.0 and geom >= 0 and target.sum() >= 9
                    if scored:
                        edges = mask_edges(target)
                        background = ~cv2.dilate(target.astype(np.uint8),
                                                 np.ones((15, 15), np.uint8)).astype(bool) & flat
                        coverage.append(edge_coverage(window, edges, background))
                        coverage_ideal.append(edge_coverage(window_ideal, edges, background))
                    window, window_ideal = [], []
                    frame = rig.frame(history, pose, data, cam_name, t - rig.readout_s,
                                      lambda s: float(s["light"][0]) if "light" in s else 1.0)
                    pose(state)
                    if scored:
                        hits.append(found(detector.detect(frame.image), target))
                        expert_hits.append(found(detector.detect(ideal), target))
                        snr = rig.camera.snr(rig.mean_luminance, frame.exposure_s,
                                             frame.gain_db)
                        bad = (frame.raw >= params.max_dn).any(axis=-1) | (snr < 1.0)
                        lost.append(float(bad[target].mean()))
                        exposures.append((frame.exposure_s, frame.gain_db))
                    truths.append(truth)
                    scene.apply_command(model, data, command)
                if step < n_steps:
                    scene.scripted(model, data)
                    mujoco.mj_step(model, data)
        finally:
            rig.close()
    expert_rate = float(np.mean(expert_hits)) if expert_hits else float("nan")
    if task == "nav":
        cents = np.array([t["centroid"] for t in truths], np.float64)
        widths = np.array([t["bbox"][2] - t["bbox"][0] for t in truths], np.float64)
        vis = np.array([t["visible"] for t in truths], bool)
        expert_rate = nav_episode_metrics(cents, widths, vis, (size, size),
                                          len(truths) / control_hz).as_dict()["success"]
    exp = np.array(exposures) if exposures else np.zeros((0, 2))
    photometry = scene.photometry()

    def mean(xs):
        return float(np.mean(xs)) if xs else float("nan")
    return {"task": task, "config": config, "seed": seed, "scored_ticks": len(hits),
            "detector_hit_rate": mean(hits),
            "target_lost_fraction": mean(lost),
            "event_edge_coverage": _above_noise(coverage),
            "event_edge_coverage_raw": mean([c[0] for c in coverage]),
            "event_background_coverage": mean([c[1] for c in coverage]),
            "event_edge_coverage_ideal": _above_noise(coverage_ideal),
            # nav: the expert's paper rate; arm (home pose): the detector on the ideal view
            "expert_reference": expert_rate,
            "exposure_s_median": float(np.median(exp[:, 0])) if len(exp) else float("nan"),
            "gain_db_median": float(np.median(exp[:, 1])) if len(exp) else float("nan"),
            "photometry": {"illuminance_lux": photometry.illuminance_lux,
                           "peak_cd_m2": photometry.peak_cd_m2()}}


def nav_cell(config: dict, **kw) -> dict:
    """sensor_cell for the nav scene."""
    return sensor_cell("nav", config, **kw)


def arm_cell(config: dict, **kw) -> dict:
    """sensor_cell for the arm scene."""
    return sensor_cell("arm", config, **kw)
