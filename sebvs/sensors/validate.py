"""Validation of the sensor models against their fields' standards, as measurements.

    validate.radiance_range()["dynamic_range_db"]         # the radiance render's range
    validate.photon_transfer_errors(preset("mv_global_shutter"))   # EMVA 1288 K, sigma_d
    validate.blur_length(speed_px_s=2000.0, exposure_s=0.01)       # smear against v T
    validate.sensor_cell("nav", {"lighting": "hdr"}, seed=0)       # one benchmark cell

Each function builds what it measures (a scene, a flat field, an episode), runs the real
code path (radiance renderer, frame camera, event emulator) and returns figures: also
snr_curve (SNR against illuminance), step_range (a 10^4 : 1 step: lost frame pixels and
event edge coverage per side), nav_cell and arm_cell. tools/bench/bench_sensors.py prints
them as JSON (docs/sensors.md's tables); tests/test_sensors_radiance.py checks them at
small sizes. The event sensor runs preset version 1, the documented figures' (issue 67).
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
                subframe_s: float = 0.0005, max_subframes: int = 256, seed: int = 0,
                light_hz: float | None = None) -> dict:
    """A white bar on a black ground crossing the image at `speed_px_s`, exposed for
    `exposure_s` by the rig: the smear against speed x exposure. The smear is
    sqrt(12 (var_moving - var_still)) of the column profile (a box of width s convolved
    with the bar adds s^2 / 12 to its variance). With `light_hz` the frame integrates
    light samples at that rate (the camera's frame_light "shared": the event sensor's
    luma), on a grid that does not line up with the exposure, instead of sub-frames."""
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
                if light_hz is None:
                    rig.frame(history, pose, data, "cam", exposure_s, lambda s: 1.0,
                              exposure_s=exposure_s)
                else:
                    # a grid a third of a period off the exposure's ends, and beyond them
                    period = 1.0 / light_hz
                    for t in np.arange(-period * 2 / 3, exposure_s + period, period):
                        pose(history.at(model, float(t)))
                        rig.add_light(float(t), rig.luminance(data, "cam", 1.0))
                    rig.frame_shared(history, pose, data, "cam", exposure_s, lambda s: 1.0,
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
               dvs_hz: float = 500.0, seed: int = 0, event_preset_version: int = 1) -> dict:
    """Two striped panels, the right one self-luminous at `ratio_lux` x the left one's
    luminance, panning slowly under the camera. After the frame camera's auto exposure
    settles: per side, its lost pixels (top code, or SNR < 1 at their luminance), and
    the share of stripe edges the event sensor fires on per 0.1 s (the physical preset
    at `event_preset_version`, 1 as the documented figures: `_event_sensor`)."""
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
    emulator = _event_sensor("physical", seed, event_preset_version, blur=False)
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
                event_preset: str = "physical", frame_rate_hz: float | None = None,
                event_preset_version: int = 1) -> dict:
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
    at one frame period. The event sensor runs `event_preset` at `event_preset_version`:
    1 by default, the noise model docs/sensors.md's figures were measured with (see
    `_event_sensor`)."""
    if task not in ("nav", "arm"):
        raise ValueError(f"sensor_cell: task must be nav or arm, got {task!r}")
    cell = _CellEpisode(task, config, seed, size, physics_hz, frame_camera, event_preset,
                        event_preset_version)
    with FrameRenderer(cell.model, size, size) as colour:
        rig = SensorRig(colour, cell.scene.photometry(), cell.params,
                        frame_rate_hz or control_hz)
        rig.new_episode(seed)
        try:
            cell.play(colour, rig, episode_s, dvs_hz, control_hz)
        finally:
            rig.close()
    return cell.figures(control_hz)


def _event_sensor(name: str, seed: int, preset_version: int, **overrides) -> EventEmulator:
    """An emulator of preset `name` on 1:1 pixels. The preset version is pinned, not the
    default: docs/sensors.md's event figures (sections 5 and the step) and
    tools/bench/bench_sensors.py's cells were measured on version 1, and version 2 (issue
    67) halves the physical preset's shot noise, which moves the "noise alone" column and
    the coverage beyond it."""
    return EventEmulator(dvs_preset(name, downsample=1.0, seed=seed,
                                    preset_version=preset_version, **overrides))


class _CellEpisode:
    """One episode of `sensor_cell`: the scene, its expert and both event sensors, and the
    per-tick scores as they accumulate."""

    def __init__(self, task: str, config: dict, seed: int, size: int, physics_hz: float,
                 frame_camera: str, event_preset: str, event_preset_version: int):
        from ..experts.nav import NavExpert, NavExpertConfig
        from ..sim import make_scene
        self.task, self.config, self.seed, self.size = task, config, seed, size
        self.physics_hz = physics_hz
        cfg = {"width": size, "height": size, **config, "timestep": 1.0 / physics_hz,
               "integrator": "discrete"}
        self.scene = make_scene(task, **cfg)
        self.model = self.scene.compile()
        self.data = mujoco.MjData(self.model)
        self.scene.reset(self.model, self.data, np.random.default_rng(seed))
        self.cam_name = self.scene.cameras[0]
        self.expert = NavExpert(NavExpertConfig()) if task == "nav" else None
        if self.expert is not None:
            self.expert.reset()
        self.emulator = _event_sensor(event_preset, seed, event_preset_version)
        # the ideal pixel on the same log range: what the scene's motion gives any sensor
        self.reference = _event_sensor("clean", seed, event_preset_version,
                                       reference_cd_m2=self.emulator.params.reference_cd_m2)
        self.params = camera_preset(frame_camera)
        self.history = StateHistory(self.params.exposure_max_s + self.params.readout_s + 0.05)
        self.ideal = np.empty((size, size, 3), np.uint8)
        self.hits, self.lost, self.coverage, self.coverage_ideal = [], [], [], []
        self.truths, self.exposures, self.expert_hits = [], [], []
        self.window: list[np.ndarray] = []          # the tick's event packets
        self.window_ideal: list[np.ndarray] = []
        self.t, self.state, self.lum = 0.0, None, None    # the last light sample's
        self.command = self.scene.idle_command()

    def pose(self, state: dict) -> None:
        self.scene.set_state(self.model, self.data, state)
        self.scene.kinematics(self.model, self.data)

    def play(self, colour: FrameRenderer, rig: SensorRig, episode_s: float, dvs_hz: float,
             control_hz: float) -> None:
        """Step the physics for `episode_s`: the light sampled at `dvs_hz` into both event
        sensors, and at `control_hz` a scored tick and the command it leads to."""
        steps_render = int(round(self.physics_hz / dvs_hz))
        steps_control = int(round(self.physics_hz / control_hz))
        n_steps = int(round(episode_s * self.physics_hz))
        for step in range(n_steps + 1):
            if step % steps_render == 0:
                self._sample_light(rig)
            if step % steps_control == 0:
                self._control_tick(colour, rig, control_hz)
            if step < n_steps:
                self.scene.scripted(self.model, self.data)
                mujoco.mj_step(self.model, self.data)

    def _sample_light(self, rig: SensorRig) -> None:
        """The scene's luminance now, into both event sensors' windows."""
        self.t = t = self.data.time
        self.state = self.scene.state(self.data)
        self.history.add(t, self.state)
        self.scene.kinematics(self.model, self.data)
        self.lum = rig.luminance(self.data, self.cam_name,
                                 getattr(self.scene, "light_scale", 1.0))
        self.window.append(self.emulator.step_luminance(self.lum, round(t * 1e9)))
        self.window_ideal.append(self.reference.step_luminance(self.lum, round(t * 1e9)))

    def _control_tick(self, colour: FrameRenderer, rig: SensorRig, control_hz: float) -> None:
        """A control tick: the expert's command from the ideal render, the tick's events
        scored on the target's edges, the modelled frame exposed and scored."""
        from ..experts.detector import ColorDetector
        size = self.size
        flat = ~cv2.dilate(_edges(self.lum, 0.05).astype(np.uint8),
                           np.ones((9, 9), np.uint8)).astype(bool)
        truth = self.scene.truth(self.model, self.data)
        colour.update(self.data, self.cam_name)
        colour.rgb(self.ideal)
        geom, target, rgb = self._target(colour, truth)
        detector = ColorDetector(rgb=rgb) if geom >= 0 else None
        if self.expert is not None:
            self.command = self.expert.act(detector.detect(self.ideal), (size, size),
                                           1.0 / control_hz)
        scored = self.t >= 1.0 and geom >= 0 and target.sum() >= 9
        if scored:
            edges = mask_edges(target)
            background = ~cv2.dilate(target.astype(np.uint8),
                                     np.ones((15, 15), np.uint8)).astype(bool) & flat
            self.coverage.append(edge_coverage(self.window, edges, background))
            self.coverage_ideal.append(edge_coverage(self.window_ideal, edges, background))
        self.window, self.window_ideal = [], []
        frame = rig.frame(self.history, self.pose, self.data, self.cam_name,
                          self.t - rig.readout_s,
                          lambda s: float(s["light"][0]) if "light" in s else 1.0)
        self.pose(self.state)
        if scored:
            self._score_frame(rig, frame, detector, target)
        self.truths.append(truth)
        self.scene.apply_command(self.model, self.data, self.command)

    def _target(self, colour: FrameRenderer, truth: dict) -> tuple[int, np.ndarray, tuple]:
        """(the target's geom id, its pixels in the ideal render, its colour); geom -1 and
        colour () when there is none (nav: the cube; arm: the truth's target cube)."""
        seg = colour.segmentation()
        if self.task == "nav":
            geom = self.model.geom("target").id
            rgb = tuple(self.model.geom_rgba[geom, :3])
        else:
            k = truth["target"]
            geom, rgb = ((int(self.scene.cube_geom[k]), tuple(truth["cubes"][k]["rgb"]))
                         if k >= 0 else (-1, ()))
        target = (seg[..., 0] == geom) & (seg[..., 1] == int(mujoco.mjtObj.mjOBJ_GEOM))
        return geom, target, rgb

    def _score_frame(self, rig: SensorRig, frame, detector, target: np.ndarray) -> None:
        """The modelled frame's scores: the detector's hit (and the expert's on the ideal
        render), the share of target pixels lost, the exposure."""
        self.hits.append(_found(detector.detect(frame.image), target))
        self.expert_hits.append(_found(detector.detect(self.ideal), target))
        snr = rig.camera.snr(rig.mean_luminance, frame.exposure_s, frame.gain_db)
        bad = (frame.raw >= self.params.max_dn).any(axis=-1) | (snr < 1.0)
        self.lost.append(float(bad[target].mean()))
        self.exposures.append((frame.exposure_s, frame.gain_db))

    def figures(self, control_hz: float) -> dict:
        """The episode's means: what `sensor_cell` returns."""
        from ..metrics import nav_episode_metrics
        size = self.size
        expert_rate = float(np.mean(self.expert_hits)) if self.expert_hits else float("nan")
        if self.task == "nav":
            cents = np.array([t["centroid"] for t in self.truths], np.float64)
            widths = np.array([t["bbox"][2] - t["bbox"][0] for t in self.truths], np.float64)
            vis = np.array([t["visible"] for t in self.truths], bool)
            expert_rate = nav_episode_metrics(cents, widths, vis, (size, size),
                                              len(self.truths) / control_hz
                                              ).as_dict()["success"]
        exp = np.array(self.exposures) if self.exposures else np.zeros((0, 2))
        photometry = self.scene.photometry()
        coverage = self.coverage

        def mean(xs):
            return float(np.mean(xs)) if xs else float("nan")
        return {"task": self.task, "config": self.config, "seed": self.seed,
                "scored_ticks": len(self.hits),
                "detector_hit_rate": mean(self.hits),
                "target_lost_fraction": mean(self.lost),
                "event_edge_coverage": _above_noise(coverage),
                "event_edge_coverage_raw": mean([c[0] for c in coverage]),
                "event_background_coverage": mean([c[1] for c in coverage]),
                "event_edge_coverage_ideal": _above_noise(self.coverage_ideal),
                # nav: the expert's paper rate; arm (home pose): the detector on the ideal view
                "expert_reference": expert_rate,
                "exposure_s_median": float(np.median(exp[:, 0])) if len(exp) else float("nan"),
                "gain_db_median": float(np.median(exp[:, 1])) if len(exp) else float("nan"),
                "photometry": {"illuminance_lux": photometry.illuminance_lux,
                               "peak_cd_m2": photometry.peak_cd_m2()}}


def _found(det, mask: np.ndarray) -> bool:
    """Whether a detection's centroid lies in the mask's box (2 px margin)."""
    if det is None:
        return False
    rows, cols = np.nonzero(mask)
    return bool(cols.min() - 2 <= det.centroid[0] <= cols.max() + 3
                and rows.min() - 2 <= det.centroid[1] <= rows.max() + 3)


def nav_cell(config: dict, **kw) -> dict:
    """sensor_cell for the nav scene."""
    return sensor_cell("nav", config, **kw)


def arm_cell(config: dict, **kw) -> dict:
    """sensor_cell for the arm scene."""
    return sensor_cell("arm", config, **kw)


# ----------------------------------------------------------------- one light stream
def frame_light_agreement(task: str = "nav", config: dict | None = None,
                          seconds: float = 3.0, dvs_hz: float = 200.0, seed: int = 0,
                          command: tuple | None = (0.4, 1.0)) -> dict:
    """The frame camera on the event sensor's light samples (camera frame_light "shared")
    against its own sub-frames ("subframes"), on one episode of a scene, every control tick.

    Four cameras read the same states. A noise-free pair, one on sub-frames and one on
    shared light (no shot, read or dark noise, no fixed pattern), differ only by how the
    light was sampled; a noisy pair on sub-frames with two seeds differs by the camera's
    own noise and fixed pattern. "The same within the frame's noise": the first
    difference well below the second.

    Parameters:
        task: "nav" or "arm" (its scene and camera at the default size).
        config: scene config overrides (e.g. {"lighting": "hdr"}).
        seconds: episode length; dvs_hz: the luma (light sample) rate.
        seed: the episode's and the cameras' seed.
        command: held for the whole episode (nav [v, w]: turning, the whole image moves,
            at w_max the scene sweeps about 1 rad/s past the camera); None: none.

    Returns:
        {"ticks", "light_dn_median" and "light_dn_p99" (per tick, the noise-free pair's
        mean and 99th percentile |difference| in DN; then the median over ticks),
        "noise_dn_median" (the noisy pair's mean |difference|), "ratio_median" (light
        over noise, per tick), "exposure_ratio_max" (the noise-free pair's exposures,
        furthest from 1), "renders" (each camera's light samples and sub-frames)}.
    """
    from types import SimpleNamespace

    from ..sim.stepper import SceneStepper
    from .camera import CameraCore
    sim = SceneStepper(task, dict(config or {}), control_hz=10.0, render_hz=dvs_hz,
                       episode_s=seconds)
    clean = {"read_noise_e": 0.0, "dsnu_e": 0.0, "prnu": 0.0, "dark_current_e_per_s": 0.0,
             "shot_noise": False}

    def camera(frame_light: str, camera_seed: int, overrides: dict) -> CameraCore:
        params = SimpleNamespace(
            camera="", rgb_hz=0.0, dvs_hz=dvs_hz, luma_scale=1.0, sensor="physical",
            frame_camera="mv_global_shutter", frame_overrides=overrides, subframe_s=0.004,
            max_subframes=8, radiance_ratio=16.0, frame_light=frame_light,
            luma_sampling="fixed")
        return CameraCore(params, {"rgb", "luma"}, seed=camera_seed)

    cams = {"subframes": camera("subframes", seed, clean), "shared": camera("shared", seed, clean),
            "noisy_a": camera("subframes", seed, {}), "noisy_b": camera("subframes", seed + 1, {})}
    rows = []
    try:
        sim.start_episode(seed, 0)
        if command is not None:
            sim.apply(np.asarray(command, np.float64))
        while True:
            if sim.render_due:
                state, meta = sim.scene.state(sim.data), sim.sample_meta(0)
                frames = {}
                for name, cam in cams.items():
                    for output, arrays, m in cam.sample(state, meta):
                        if output == "rgb":
                            frames[name] = (arrays["rgb"].astype(np.int16), m["exposure_s"])
                if len(frames) == 4:
                    light = np.abs(frames["shared"][0] - frames["subframes"][0])
                    noise = np.abs(frames["noisy_b"][0] - frames["noisy_a"][0])
                    rows.append((light.mean(), np.percentile(light, 99), noise.mean(),
                                 frames["shared"][1] / frames["subframes"][1]))
            if sim.advance():
                break
        renders = {k: {"light": c.counts["luma"] + c.counts.get("light_extra", 0),
                       "subframes": c.counts["subframes"]} for k, c in cams.items()}
    finally:
        for cam in cams.values():
            cam.close()
    light, light_p99, noise, exposure = (np.array(col, float) for col in zip(*rows))
    return {"task": task, "config": dict(config or {}), "dvs_hz": dvs_hz, "ticks": len(rows),
            "command": None if command is None else list(command),
            "light_dn_median": float(np.median(light)),
            "light_dn_p99": float(np.median(light_p99)),
            "noise_dn_median": float(np.median(noise)),
            "ratio_median": float(np.median(light / np.maximum(noise, 1e-9))),
            "exposure_ratio_max": float(exposure[np.argmax(np.abs(np.log(exposure)))]),
            "renders": renders}
