#!/usr/bin/env python3
"""Simulation and rendering speed: physics steps/s per integrator, camera fps per image kind.

physics   the sim actor's per-step work: scene.scripted + mj_step + stability check,
          steps per second (median of repeats), per scene and integrator
render    the camera actor's per-frame work: set_state + kinematics + update_scene + render
          into a preallocated array (luma: + RGB->gray), frames per second, per scene,
          camera, size and kind (rgb, luma, depth, seg)
pipeline  real-time factor of the navigation expert topology with the event chain, the
          issue's target: topologies/nav_expert.toml (sim + camera + expert + tracker,
          lockstep, 160 px) at dvs_hz 200 with the emulator, the accumulator and a probe
          on its event frames added (`--set NAME.run=...`), on the ideal8 pair (8-bit luma,
          the paper preset: bench_pipeline's sensor="physical" runs the other). The expert
          paces the sim; the probe counts the event frames, so the entry says whether the
          event chain kept up (event_frames == ticks). Also topologies/nav_record.toml at
          dvs_hz 200 (the same chain with the recorder pacing the sim and writing HDF5) on
          its shipped pair, the physical one: the recording speed.
ceiling   CPU seconds per simulated second of a nav recording's compute with no runtime
          around it, split by stage, and the real-time factor that bounds any placement on
          1 and 2 cores: N / that (issue 18's 15x and 10x targets read against it). Rows
          [ideal8]: physics 1 kHz, 8-bit luma at dvs_hz through the paper emulator, the
          ideal RGB at 10 Hz (the computation this has always been). Rows [physical]: the
          shipped pair through the camera's own CameraCore (radiance luma, the frame
          camera's renders, integral and noise, the ideal view) and the physical emulator.
          Every row names its "sensor".
sensors   nav recording at dvs_hz 200 with the camera's sensor "ideal8" and "physical"
          (`sebvs record --sensor`, alternating, one episode each per repeat): the real-time
          factors' medians and their ratio (issue 34: >= 0.7)
ceiling vs record  `--ceiling-vs-record`: the physical pair's ceiling and its measured
          recording rate (nav_record on the ceiling's scene, start-up included) side by
          side in one run, with their ratio, the ideal8 ceiling beside them
frame ready  `--frame-ready-only`: the camera's frame_ready "ahead" (the default: a tick's
          frame made on the states before it) against "tick" at the shipped 100 Hz: the
          noise-free frames' difference against the noise, and each one's CPU on the tick
adaptive  issue 37: adaptive luma sampling (camera luma_sampling "adaptive") against a dense
          fixed-rate reference (luma at every 1 kHz sim state), on the nav and arm expert
          topologies with the event chain (80 px luma, paper preset, linear low-pass hold)
          and an event tap that paces the lockstep sim to the chain; the two alternate per
          repeat. One row per scene with exactly: scene, real_time_factor,
          reference_real_time_factor, event_count_ratio, count_correlation,
          median_time_error_ms (sebvs/dvs/fidelity.py); `adaptive_detail` beside it (sample
          rates, matched fraction, runs). Without --quick also nav_record with either
          sampling, alternating (rows in `pipeline` with luma_sampling)
scene switch  milliseconds from a new model to its first frame: a fresh renderer against
          FrameRenderer.set_model() in a warm GL context (what a randomised recording's
          camera pays per episode)

Targets (issue 4): nav front camera RGB 160x160 >= 1000 fps; arm wrist camera RGB 320x320
>= 80 fps; nav expert topology >= 5x real time.

`--placement isolated,auto` runs the pipeline (and the recording) under each process
placement (`[topology] placement`, docs/runtime.md "Process groups"), alternating within
each repeat, and reports the median per placement; `--pipeline-only` skips physics and
rendering.

    tools/bench/bench_sim.py [--quick] [--json FILE] [--placement P[,P...]] [--pipeline-only]
                       [--ceiling-only] [--sensors-only] [--ceiling-vs-record]
                       [--frame-ready-only] [--adaptive-only | --no-adaptive]
                       [--adaptive-set KEY=VALUE ...]
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from sebvs.sim import make_scene  # noqa: E402  (sets MUJOCO_GL before mujoco)
from sebvs.sim.render import FrameRenderer  # noqa: E402
from sebvs.sim.scene import INTEGRATORS  # noqa: E402
from sebvs.sim.stability import StabilityMonitor  # noqa: E402

import mujoco  # noqa: E402


SCENES = ("nav", "arm")


def bench_physics(scene_name: str, integrator: str, steps: int, repeats: int) -> float:
    scene = make_scene(scene_name, integrator=integrator)
    model = scene.compile()
    data = mujoco.MjData(model)
    scene.reset(model, data, np.random.default_rng(0))
    mon = StabilityMonitor(model, scene.limits())
    mon.reset(data)
    cmd = np.full(scene.command_dim, 0.3)
    scene.apply_command(model, data, cmd)
    rates = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(steps):
            scene.scripted(model, data)
            mujoco.mj_step(model, data)
            mon.check(model, data)
        rates.append(steps / (time.perf_counter() - t0))
    return statistics.median(rates)


def _states(scene, model, data, n: int) -> list[dict]:
    """n states along a short driven trajectory (so each frame differs)."""
    scene.reset(model, data, np.random.default_rng(1))
    scene.apply_command(model, data, np.full(scene.command_dim, 0.3))
    out = []
    for _ in range(n):
        for _ in range(5):
            scene.scripted(model, data)
            mujoco.mj_step(model, data)
        out.append(scene.state(data))
    return out


def bench_render(scene_name: str, config: dict, camera: str, size: int, kinds: list[str],
                 frames: int, repeats: int) -> list[dict]:
    scene = make_scene(scene_name, **config)
    model = scene.compile()
    data = mujoco.MjData(model)
    states = _states(scene, model, data, frames)
    rows = []
    with FrameRenderer(model, size, size) as r:
        bufs = {"rgb": np.empty((size, size, 3), np.uint8),
                "luma": np.empty((size, size), np.uint8),
                "depth": np.empty((size, size), np.float32),
                "seg": np.empty((size, size, 2), np.int32)}
        render = {"rgb": lambda: r.rgb(bufs["rgb"]), "luma": lambda: r.luma(bufs["luma"]),
                  "depth": lambda: r.depth(bufs["depth"]),
                  "seg": lambda: r.segmentation(bufs["seg"])}
        for kind in kinds:
            fn = render[kind]
            fn()  # warm up (mode switch, first-frame costs)
            rates = []
            for _ in range(repeats):
                t0 = time.perf_counter()
                for s in states:
                    scene.set_state(model, data, s)
                    scene.kinematics(model, data)
                    r.update(data, camera)
                    fn()
                rates.append(len(states) / (time.perf_counter() - t0))
            variant = config.get("variant")
            rows.append({"scene": scene_name + (f"/{variant}" if variant else ""),
                         "camera": camera, "size": f"{size}x{size}", "kind": kind,
                         "fps": round(statistics.median(rates), 1)})
    return rows


def bench_scene_switch(size: int, repeats: int) -> dict:
    """Milliseconds from a new model to its first frame, the nav variants alternating (what
    the camera pays per randomised episode and renderer): a fresh FrameRenderer (its own
    GL context, as mujoco.Renderer would) against set_model() in a warm one."""
    models = []
    for variant in ("outdoor", "indoor"):
        scene = make_scene("nav", variant=variant)
        model = scene.compile()
        data = mujoco.MjData(model)
        mujoco.mj_forward(model, data)
        models.append((model, data))
    frame = np.empty((size, size, 3), np.uint8)
    fresh, switch = [], []
    with FrameRenderer(models[0][0], size, size) as warm:
        for i in range(2 * repeats):
            model, data = models[i % 2]
            t0 = time.perf_counter()
            with FrameRenderer(model, size, size) as r:
                r.update(data, "front")
                r.rgb(frame)
                fresh.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            warm.set_model(model)
            warm.update(data, "front")
            warm.rgb(frame)
            switch.append(time.perf_counter() - t0)
    return {"size": f"{size}x{size}",
            "fresh_renderer_ms": round(1e3 * statistics.median(fresh), 1),
            "set_model_ms": round(1e3 * statistics.median(switch), 1), "switches": len(fresh)}


EVENT_CHAIN = [
    'emulator.run="actors.emulator:Emulator"',
    'emulator.inputs={luma={from="camera/luma", queue=256}}',
    'emulator.preset="paper"', "emulator.overrides={downsample=1.0}",
    'accumulator.run="actors.accumulator:Accumulator"',
    'accumulator.inputs={events={from="emulator/events", queue=256}}',
    "accumulator.window_s=0.1", "accumulator.out_width=160", "accumulator.out_height=160",
    'probe.run="actors.synthetic:Probe"', "probe.max_arrays=0",
    'probe.inputs={events={from="accumulator/frames", queue=256}, rgb={from="camera/rgb", '
    'queue=256}}',
    "camera.luma_scale=0.5",
    # the topology's process groups (placement "auto"): the event chain with the expert
    'emulator.process="work"', 'accumulator.process="work"', 'probe.process="work"',
]


def bench_ceiling(seconds: float, dvs_hz: float = 200.0, luma_size: int = 160,
                  rgb_hz: float = 10.0, rgb_size: int = 160, repeats: int = 3,
                  variant: str = "indoor") -> dict:
    """The compute of `seconds` of nav recording with no runtime around it, in one thread:
    physics at 1 kHz (scripted target and stability check as the sim actor does them), a
    luma frame at `dvs_hz` run through the emulator (paper preset), an RGB frame at
    `rgb_hz`. CPU seconds per simulated second (`time.process_time`, so llvmpipe's render
    threads count), split by stage; `ceiling_x_on_N_cores` = N / that: the real-time factor
    no placement of the actors can beat on N cores, whatever the runtime costs (it costs
    more than nothing). Median of `repeats`. `variant`: the nav scene's (nav_expert is
    indoor; nav_record draws both, and the indoor checker floor makes more events)."""
    from sebvs.dvs.emulator import EventEmulator
    from sebvs.dvs.params import preset
    scene = make_scene("nav", variant=variant, width=rgb_size, height=rgb_size)
    model = scene.compile()
    data = mujoco.MjData(model)
    physics_hz = 1000.0
    luma_every = round(physics_hz / dvs_hz)
    rgb_every = round(physics_hz / rgb_hz)
    steps = round(seconds * physics_hz)
    rgb = np.empty((rgb_size, rgb_size, 3), np.uint8)
    luma = np.empty((luma_size, luma_size), np.uint8)
    runs = []
    with FrameRenderer(model, rgb_size, rgb_size) as r:
        luma_view = r.view(luma_size, luma_size) if luma_size != rgb_size else r
        for _ in range(repeats):
            scene.reset(model, data, np.random.default_rng(3))
            mon = StabilityMonitor(model, scene.limits())
            mon.reset(data)
            scene.apply_command(model, data, np.array([0.3, 0.4]))
            emulator = EventEmulator(preset("paper"))
            cpu = {"physics": 0.0, "luma_render": 0.0, "emulator": 0.0, "rgb_render": 0.0}
            events = 0
            frames = {"luma": 0, "rgb": 0}
            for k in range(1, steps + 1):
                c0 = time.process_time()
                scene.scripted(model, data)
                mujoco.mj_step(model, data)
                mon.check(model, data)
                c1 = time.process_time()
                cpu["physics"] += c1 - c0
                rendered = None
                if k % rgb_every == 0:      # RGB first, as the camera emits it
                    r.update(data, "front")
                    rendered = r.rgb(rgb)
                    frames["rgb"] += 1
                    c2 = time.process_time()
                    cpu["rgb_render"] += c2 - c1
                    c1 = c2
                if k % luma_every == 0:
                    if rendered is not None and luma_size == rgb_size:
                        luma_view.luma(luma, src=rendered)   # the camera reuses the render
                    else:
                        luma_view.update(data, "front")
                        luma_view.luma(luma)
                    c2 = time.process_time()
                    events += len(emulator.step(luma, round(data.time * 1e9)))
                    frames["luma"] += 1
                    c3 = time.process_time()
                    cpu["luma_render"] += c2 - c1
                    cpu["emulator"] += c3 - c2
            runs.append({**{key: v / seconds for key, v in cpu.items()}, "events": events,
                         "frames": frames})
    return _ceiling_row(f"nav {variant}, physics 1 kHz + luma {luma_size} px at {dvs_hz:g} Hz "
                        f"through the emulator + RGB {rgb_size} px at {rgb_hz:g} Hz, no runtime",
                        "ideal8", runs, ("physics", "luma_render", "emulator", "rgb_render"),
                        seconds, repeats)


def _ceiling_row(what: str, sensor: str, runs: list[dict], stages: tuple, seconds: float,
                 repeats: int) -> dict:
    """A ceiling's row from its runs ({stage: CPU s per sim s, "events", "frames"}): the
    stages' medians, their total and the real-time factors it bounds on 1 and 2 cores."""
    per_s = {key: statistics.median(run[key] for run in runs) for key in stages}
    total = sum(per_s.values())
    return {"what": what, "sensor": sensor,
            "cpu_s_per_sim_s": {key: round(v, 4) for key, v in per_s.items()},
            "cpu_s_per_sim_s_total": round(total, 4),
            "ceiling_x_on_1_core": round(1.0 / total, 2),
            "ceiling_x_on_2_cores": round(2.0 / total, 2),
            "events_per_run": [run["events"] for run in runs],
            "frames_per_run": runs[0]["frames"],
            "sim_s": seconds, "repeats": repeats}


# the nav_record camera's outputs that someone consumes: the recorder's frame, the emulator's
# luma and the expert's privileged view
RECORD_OUTPUTS = frozenset({"rgb", "luma", "ideal"})
PHYSICAL_EMULATOR = {"downsample": 1.0, "preset_version": 1}     # nav_record's overrides


def bench_ceiling_physical(seconds: float, dvs_hz: float = 200.0, luma_size: int = 160,
                           rgb_size: int = 160, repeats: int = 3, variant: str = "indoor",
                           frame_ready: str = "ahead") -> dict:
    """bench_ceiling for the physical pair, through the recording's own code with no runtime
    around it, in one thread: the sim's SceneStepper at 1 kHz (states at `dvs_hz`, a control
    tick at 10 Hz, a command held), the camera's CameraCore on sensor "physical" making what
    nav_record consumes (the frame camera's image per tick, the radiance luma at `dvs_hz`,
    the ideal render per tick), and the emulator's SensorStream on preset "physical" as
    nav_record sets it. CPU seconds per simulated second by stage: physics, luma_render,
    ideal_render, frame_camera (its renders, integral and noise, wherever frame_ready puts
    them), emulator.

    Parameters:
        seconds: simulated seconds per repeat; dvs_hz: the state and luma rate.
        luma_size, rgb_size: the event sensor's and the frame camera's side, px.
        repeats: runs, each a fresh episode of the same seed (medians reported).
        variant: the nav scene's ("indoor" or "outdoor"), nominal light.
        frame_ready: the camera's (actors/camera.py).

    Returns:
        bench_ceiling's row, with these stages and "sensor": "physical".
    """
    from actors.camera import Camera
    from sebvs.sensors.camera import CameraCore
    from sebvs.sim.stepper import SceneStepper
    params = Camera.Params(sensor="physical", dvs_hz=dvs_hz, luma_scale=luma_size / rgb_size,
                           frame_ready=frame_ready)
    stages = ("physics", "luma_render", "ideal_render", "frame_camera", "emulator")
    sim = SceneStepper("nav", {"variant": variant, "width": rgb_size, "height": rgb_size},
                       control_hz=10.0, render_hz=dvs_hz, episode_s=seconds)
    camera = CameraCore(params, RECORD_OUTPUTS, seed=0)
    runs = []
    try:
        # episode 0, untimed: the camera compiles its model and warms its renderers up
        _physical_episode(sim, camera, 0, 0.2, stages)
        for k in range(1, repeats + 1):
            runs.append(_physical_episode(sim, camera, k, seconds, stages))
    finally:
        camera.close()
    return _ceiling_row(f"nav {variant}, physical pair: physics 1 kHz + radiance luma "
                        f"{luma_size} px at {dvs_hz:g} Hz through the physical emulator + "
                        f"the frame camera {rgb_size} px and the ideal render at 10 Hz "
                        f"(frame_ready {frame_ready}), no runtime", "physical", runs, stages,
                        seconds, repeats)


def _physical_episode(sim, camera, k: int, seconds: float, stages: tuple) -> dict:
    """One timed episode of bench_ceiling_physical (the same start each time, numbered k
    so the camera and the emulator begin afresh): {stage: CPU s per sim s, "events",
    "frames"}; at most `seconds` of it."""
    from sebvs.dvs.params import preset
    from sebvs.dvs.stream import SensorStream
    bucket = {"luma": "luma_render", "ideal": "ideal_render", "rgb": "frame_camera"}
    stream = SensorStream(preset("physical", seed=0, **PHYSICAL_EMULATOR))
    cpu = dict.fromkeys(stages, 0.0)
    events, frames = 0, {"luma": 0, "rgb": 0, "ideal": 0}
    sim.start_episode(0, 0)
    sim.apply(np.array([0.3, 0.4]))
    steps = round(seconds / sim.dt)
    while True:
        if sim.render_due:
            state, meta = sim.scene.state(sim.data), sim.sample_meta(k)
            c0 = time.process_time()
            for output, arrays, _ in camera.sample(state, meta):
                c1 = time.process_time()
                cpu[bucket[output]] += c1 - c0
                frames[output] += 1
                if output == "luma":
                    events += len(stream.frame(arrays["luma"], sim.data.time, k, "cd/m2"))
                    c2 = time.process_time()
                    cpu["emulator"] += c2 - c1
                    c1 = c2
                c0 = c1
            # what follows the last output: the next tick's frame, made ahead
            cpu["frame_camera"] += time.process_time() - c0
        c0 = time.process_time()
        done = sim.advance() or sim.step >= steps
        cpu["physics"] += time.process_time() - c0
        if done:
            break
    return {**{key: v / seconds for key, v in cpu.items()}, "events": events,
            "frames": frames}


def shipped_sensor(topology: Path) -> str:
    """The sensor pair a topology file runs as shipped: its camera's `sensor` (the camera
    actor's default, "ideal8", where it names none)."""
    import tomllib
    with open(topology, "rb") as f:
        camera = tomllib.load(f).get("actors", {}).get("camera", {})
    return camera.get("sensor", "ideal8")


def sensor_of(sets, sensor: str | None, topology: Path) -> str:
    """The pair a run of `topology` with these --set lines and --sensor records on."""
    if sensor:
        return sensor
    for text in sets:
        if isinstance(text, str) and text.replace(" ", "").startswith("camera.sensor="):
            return text.split("=", 1)[1].strip().strip('"')
    return shipped_sensor(topology)


# the event chain of bench_pipeline on the physical pair (nav_record's emulator settings)
PIPELINE_PHYSICAL = ['camera.sensor="physical"', 'emulator.preset="physical"',
                     "emulator.overrides={downsample=1.0, preset_version=1}"]


def bench_pipeline(seconds: float, dvs_hz: float = 200.0, placement: str | None = None,
                   sensor: str = "ideal8") -> dict:
    """nav_expert + the event chain at `dvs_hz`, one episode of `seconds`: real-time factor
    from the probe's first to last RGB frame (start-up excluded), event frames against
    control ticks. `sensor`: "ideal8" (the chain's paper preset on 8-bit luma, as this
    benchmark always ran) or "physical" (the camera's physical sensor and the emulator's
    physical preset, as nav_record runs them)."""
    from sebvs.runtime.supervisor import run_topology
    if sensor not in ("ideal8", "physical"):
        raise ValueError(f"bench_pipeline: sensor must be 'ideal8' or 'physical', got {sensor!r}")
    with tempfile.TemporaryDirectory() as tmp:
        probe = Path(tmp) / "probe"
        overrides = [*EVENT_CHAIN, *(PIPELINE_PHYSICAL if sensor == "physical" else ()),
                     f"probe.path={json.dumps(str(probe))}",
                     f"sim.render_hz={dvs_hz}", f"camera.dvs_hz={dvs_hz}",
                     f"sim.episode_s={seconds}", "sim.episodes=1", 'tracker.path=""']
        if placement:
            overrides.append(f"topology.placement={json.dumps(placement)}")
        t0 = time.perf_counter()
        run_topology(ROOT / "topologies" / "nav_expert.toml", overrides, duration_s=300,
                     runs_dir=tmp)
        total = time.perf_counter() - t0
        entries = json.loads(probe.with_suffix(".json").read_text())
    rgb = [e for e in entries if e["input"] == "rgb"]
    events = [e for e in entries if e["input"] == "events"]
    wall = (rgb[-1]["recv_ns"] - rgb[0]["recv_ns"]) / 1e9 if len(rgb) > 1 else float("nan")
    sim = (rgb[-1]["t_sim"] - rgb[0]["t_sim"]) if len(rgb) > 1 else float("nan")
    return {"topology": f"nav_expert + emulator + accumulator (dvs_hz {dvs_hz:g}, lockstep, "
                        f"160 px)", "sensor": sensor,
            "placement": placement or "topology's",
            "real_time_factor": round(sim / wall, 2) if wall > 0 else None,
            "ticks": len(rgb), "event_frames": len(events),
            "sim_s": round(sim, 3), "wall_s": round(wall, 3),
            "wall_s_incl_startup": round(total, 2)}


def bench_record(episodes: int, seconds: float, dvs_hz: float = 200.0,
                 placement: str | None = None, sets: list[str] = (),
                 sensor: str | None = None) -> dict:
    """`sebvs record topologies/nav_record.toml` at `dvs_hz` into a temporary dataset:
    simulated seconds per wall second of the whole command (start-up included). ``sets``:
    further --set overrides; ``sensor``: its --sensor pair."""
    import subprocess
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "-m", "sebvs.cli", "record",
               str(ROOT / "topologies" / "nav_record.toml"), "--episodes", str(episodes),
               "--out", str(Path(tmp) / "ds"), "--runs-dir", str(Path(tmp) / "runs"),
               "--quiet", "--set", f"sim.episode_s={seconds}",
               "--set", f"sim.render_hz={dvs_hz}", "--set", f"camera.dvs_hz={dvs_hz}"]
        if placement:
            cmd += ["--set", f"topology.placement={json.dumps(placement)}"]
        for text in sets:
            cmd += ["--set", text]
        if sensor:
            cmd += ["--sensor", sensor]
        t0 = time.perf_counter()
        done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=900)
        wall = time.perf_counter() - t0
        if done.returncode != 0:
            raise RuntimeError(f"sebvs record failed: {done.stderr.strip()[-400:]}")
        index = json.loads((Path(tmp) / "ds" / "index.json").read_text())
    frames = sum(e["frames"] for e in index["episodes"])
    return {"topology": f"nav_record (dvs_hz {dvs_hz:g}, recorder paces the sim, HDF5)",
            "sensor": sensor_of(sets, sensor, ROOT / "topologies" / "nav_record.toml"),
            "placement": placement or "topology's", "sets": list(sets),
            "real_time_factor": round(episodes * seconds / wall, 2), "episodes": episodes,
            "frames": frames, "wall_s_incl_startup": round(wall, 2)}


# Adaptive luma sampling against a dense fixed-rate reference (issue 37): each scene's
# expert topology with the event chain above, its events kept by a tap beside the
# emulator; the reference renders luma at every 1 kHz sim state, the adaptive camera
# between the topology's own states (docs/dvs.md, "Adaptive sampling"). Both emulators
# use the linear hold; lockstep makes the two runs drive the same trajectory.
ADAPTIVE_SCENES = {
    # scene: (topology, its --set, seconds per episode full / quick, episodes full / quick)
    "nav": ("nav_expert.toml", [], (20.0, 5.0), (1, 1)),
    # the arm holds HOME while the expert aims (the grasp comes after the episode), so a
    # static belt makes no events at all: three cubes on the moving belt, 8 cm/s
    "arm": ("arm_expert.toml",
            ['sim.config={conveyor="moving", objects=3, width=160, height=160}'],
            (4.0, 4.0), (2, 1)),
}
REFERENCE_HZ = 1000.0
EVENT_TAP = [
    # the tap keeps the events and passes the expert's action on once its tick's events
    # have come: the lockstep sim waits for the event chain, so no luma frame is lost
    # while the emulator runs behind a 1 kHz camera (a loss would read as infidelity)
    'tap.run="actors.bench:EventTap"', 'tap.process="work"',
    'tap.inputs={events={from="emulator/events", queue=100000}, action="expert/action"}',
    'sim.inputs={action="tap/action"}', "sim.linger_s=2.0",
    'emulator.inputs={luma={from="camera/luma", queue=100000}}',
    'emulator.overrides={downsample=1.0, lowpass_hold="linear"}',
]


def _adaptive_run(topology: str, seconds: float, episodes: int, sets: list[str]) -> dict:
    """One run of `topology` with the event chain and the tap: its real-time factor (from
    the first RGB frame to the last RGB or event frame, so an event chain that lags
    counts) and its events."""
    from sebvs.runtime.supervisor import run_topology
    with tempfile.TemporaryDirectory() as tmp:
        probe, tap = Path(tmp) / "probe", Path(tmp) / "tap"
        overrides = [*EVENT_CHAIN, *EVENT_TAP, f"probe.path={json.dumps(str(probe))}",
                     f"tap.path={json.dumps(str(tap))}", f"sim.episode_s={seconds}",
                     f"sim.episodes={episodes}", 'tracker.path=""', *sets]
        run_topology(ROOT / "topologies" / topology, overrides, duration_s=600, runs_dir=tmp)
        entries = json.loads(probe.with_suffix(".json").read_text())
        events = np.load(tap.with_suffix(".npy"))
        info = json.loads(tap.with_suffix(".json").read_text())
    rgb = [e for e in entries if e["input"] == "rgb"]
    frames = [e for e in entries if e["input"] == "events"]
    end = max(e["recv_ns"] for e in rgb + frames)
    wall = (end - rgb[0]["recv_ns"]) / 1e9
    sim = rgb[-1]["t_sim"] - rgb[0]["t_sim"]
    w, h = info["sensor"]
    return {"real_time_factor": sim / wall if wall > 0 else float("nan"),
            "events": events, "shape": (h, w), "luma_frames": info["packets"],
            "ticks": len(rgb), "event_frames": len(frames), "sim_s": sim}


def bench_adaptive(scene: str, quick: bool, repeats: int, sets: list[str] = ()) -> tuple:
    """Adaptive sampling on `scene`'s expert topology against the 1 kHz reference, the two
    alternating `repeats` times: (row, detail). The row has exactly the issue's keys; the
    detail adds the sample rates, the matched fraction and the spread of the runs."""
    from sebvs.dvs.fidelity import compare_streams
    topology, scene_sets, secs, eps = ADAPTIVE_SCENES[scene]
    seconds, episodes = secs[quick], eps[quick]
    reference_sets = [*scene_sets, f"sim.render_hz={REFERENCE_HZ}",
                      f"camera.dvs_hz={REFERENCE_HZ}", 'camera.luma_sampling="fixed"']
    adaptive_sets = [*scene_sets, 'camera.luma_sampling="adaptive"', *sets]
    runs: dict[str, list[dict]] = {"reference": [], "adaptive": []}
    figures = []
    for _ in range(repeats):
        ref = _adaptive_run(topology, seconds, episodes, reference_sets)
        ada = _adaptive_run(topology, seconds, episodes, adaptive_sets)
        runs["reference"].append(ref)
        runs["adaptive"].append(ada)
        figures.append(compare_streams(ada["events"], ref["events"], ref["shape"]))
        print(f"adaptive {scene}: {ada['real_time_factor']:.2f}x real time "
              f"({ada['luma_frames'] / ada['sim_s']:.0f} luma/s), reference "
              f"{ref['real_time_factor']:.2f}x; events {figures[-1].count_ratio:.4f} of the "
              f"reference, correlation {figures[-1].count_correlation:.4f}, median time error "
              f"{figures[-1].median_time_error_ms:.3f} ms", flush=True)

    def med(values):
        return round(statistics.median(values), 4)
    row = {"scene": scene,
           "real_time_factor": med([r["real_time_factor"] for r in runs["adaptive"]]),
           "reference_real_time_factor": med([r["real_time_factor"]
                                              for r in runs["reference"]]),
           "event_count_ratio": med([f.count_ratio for f in figures]),
           "count_correlation": med([f.count_correlation for f in figures]),
           "median_time_error_ms": med([f.median_time_error_ms for f in figures])}
    # context, once: a fixed 200 Hz camera (today's pipeline rate) against the same
    # reference, with the emulator's default step hold (today's) and the linear hold
    fixed = {}
    for hold in ("step", "linear"):
        run = _adaptive_run(topology, seconds, episodes, [
            *scene_sets, "sim.render_hz=200.0", "camera.dvs_hz=200.0",
            f'emulator.overrides={{downsample=1.0, lowpass_hold="{hold}"}}'])
        f = compare_streams(run["events"], runs["reference"][0]["events"],
                            runs["reference"][0]["shape"])
        fixed[f"fixed_200hz_{hold}_hold"] = {
            "real_time_factor": round(run["real_time_factor"], 3),
            "event_count_ratio": round(f.count_ratio, 4),
            "count_correlation": round(f.count_correlation, 4),
            "median_time_error_ms": round(f.median_time_error_ms, 4)}
        print(f"fixed 200 Hz {scene}, {hold} hold: {fixed[f'fixed_200hz_{hold}_hold']}",
              flush=True)
    detail = {"scene": scene, "topology": topology, "episodes": episodes, **fixed,
              "episode_s": seconds, "adaptive_sets": adaptive_sets,
              "luma_per_sim_s": med([r["luma_frames"] / r["sim_s"] for r in runs["adaptive"]]),
              "reference_luma_per_sim_s": med([r["luma_frames"] / r["sim_s"]
                                               for r in runs["reference"]]),
              "events": [f.events for f in figures],
              "reference_events": [f.reference_events for f in figures],
              "matched_fraction": med([f.matched_fraction for f in figures]),
              "real_time_factor_runs": [round(r["real_time_factor"], 3)
                                        for r in runs["adaptive"]],
              "reference_real_time_factor_runs": [round(r["real_time_factor"], 3)
                                                  for r in runs["reference"]],
              "event_frames_per_tick": [f"{r['event_frames']}/{r['ticks']}"
                                        for r in runs["adaptive"] + runs["reference"]]}
    return row, detail


def bench_sensors(repeats: int, seconds: float) -> dict:
    """Recording throughput with either sensor, alternating so a slow phase of this
    shared machine hits both. Each run names its pair (`sebvs record --sensor`): nav_record
    ships the physical one, so a run without it records that."""
    rates: dict[str, list[float]] = {"ideal8": [], "physical": []}
    for _ in range(repeats):
        for name in rates:
            row = bench_record(1, seconds, sensor=name)
            rates[name].append(row["real_time_factor"])
            print(f"sensors {name:8s} record {row['real_time_factor']}x real time", flush=True)
    med = {k: statistics.median(v) for k, v in rates.items()}
    return {"what": f"nav_record at dvs_hz 200, one {seconds:g} s episode per run",
            "runs": rates, "median": med,
            "physical_over_ideal8": round(med["physical"] / med["ideal8"], 3)}


# nav_record on one fixed scene, the ceiling's: its own config (indoor, nominal light)
FIXED_SCENE = ("sim.randomise={}",)


def bench_ceiling_vs_record(repeats: int, ceiling_s: float, record_s: float,
                            dvs_hz: float = 200.0) -> dict:
    """The physical pair's compute ceiling and its recording, side by side in one run.

    The ceiling is bench_ceiling_physical (the recording's compute with no runtime, indoor
    nominal nav); the recording `sebvs record topologies/nav_record.toml --sensor physical`
    on that one scene (sim.randomise={}), one `record_s` episode per repeat, start-up
    included (bench_record). The ideal8 ceiling (bench_ceiling, what `--ceiling-only` has
    always computed) stands beside them for the figures quoted against it before.

    Parameters:
        repeats: the ceiling's repeats and the recordings.
        ceiling_s, record_s: simulated seconds per ceiling repeat and per recording.
        dvs_hz: the state and luma rate of both.

    Returns:
        {"sensor", "dvs_hz", "record_x_real_time" (median), "ceiling_x_on_2_cores",
        "record_over_ceiling" (their ratio: the share of its own compute the recording
        reaches on two cores), "record_over_ideal8_ceiling", "ceiling", "ceiling_ideal8",
        "records" (each run's row)}.
    """
    ceiling = bench_ceiling_physical(ceiling_s, dvs_hz, repeats=repeats)
    print(f"ceiling physical: {ceiling['cpu_s_per_sim_s_total']} CPU s per sim s "
          f"{ceiling['cpu_s_per_sim_s']}, at most {ceiling['ceiling_x_on_2_cores']}x real "
          f"time on 2 cores", flush=True)
    ideal = bench_ceiling(ceiling_s, dvs_hz, repeats=repeats)
    records = []
    for _ in range(repeats):
        records.append(bench_record(1, record_s, dvs_hz, sets=list(FIXED_SCENE),
                                    sensor="physical"))
        print(f"record physical: {records[-1]['real_time_factor']}x real time", flush=True)
    rate = statistics.median(r["real_time_factor"] for r in records)
    top = ceiling["ceiling_x_on_2_cores"]
    return {"what": f"nav_record on the physical pair at dvs_hz {dvs_hz:g} (indoor nominal, "
                    f"sim.randomise={{}}, one {record_s:g} s episode per run, start-up "
                    f"included) against its compute with no runtime",
            "sensor": "physical", "dvs_hz": dvs_hz,
            "record_x_real_time": rate, "ceiling_x_on_2_cores": top,
            "record_over_ceiling": round(rate / top, 3),
            "record_over_ideal8_ceiling": round(rate / ideal["ceiling_x_on_2_cores"], 3),
            "ceiling": ceiling, "ceiling_ideal8": ideal, "records": records}


def bench_frame_ready(config: dict | None = None, seconds: float = 3.0,
                      dvs_hz: float = 100.0, seed: int = 0,
                      command: tuple = (0.4, 1.0), size: int = 160) -> dict:
    """The camera's frame_ready "ahead" against "tick" on one nav episode, every tick after
    the first: what it changes in the frames, against the frame camera's own noise, and
    what each costs on the tick's path (issue 64, item 2).

    Four cameras read the same states (sebvs.sim.stepper, a command held): a noise-free
    pair (preset "ideal"), one per frame_ready, differs only by when its exposures end; a
    noisy pair ("mv_global_shutter", "ahead") with two seeds differs by the camera's noise
    and fixed pattern; and the noisy cameras' CPU time while each tick's state is handled
    (its luma, its ideal view and whatever of its frame is left), against one noisy camera
    on "tick" beside them.

    Parameters:
        config: nav config overrides (e.g. {"lighting": "dusk"}); seconds: episode length.
        dvs_hz: the state and luma rate (the shipped topologies' 100 Hz: states sparser
            than the 5 ms readout, so "ahead" moves the exposures' end).
        seed: the episode's and the cameras' seed; command: nav [v, w], held.
        size: the image side, px.

    Returns:
        {"ticks", "moved_dn_median" / "moved_dn_p99" (per tick the noise-free pair's mean
        and 99th percentile |difference| in DN, median over ticks), "noise_dn_median",
        "ratio_median" (moved over noise, per tick), "readout_ms" (each frame_ready's median
        tick - exposure end), "tick_ms_p50" (each frame_ready's CPU while a tick's state is
        handled, median), "period_cpu_ms" (its CPU over all states per control period: the
        work moved, not removed), "counts" (the noise-free "ahead" camera's)}.
    """
    from actors.camera import Camera
    from sebvs.sensors.camera import CameraCore
    from sebvs.sim.stepper import SceneStepper
    sim = SceneStepper("nav", {"width": size, "height": size, **(config or {})},
                       control_hz=10.0, render_hz=dvs_hz, episode_s=seconds)

    def camera(frame_ready: str, frame_camera: str, camera_seed: int) -> CameraCore:
        return CameraCore(Camera.Params(sensor="physical", dvs_hz=dvs_hz,
                                        frame_camera=frame_camera, frame_ready=frame_ready),
                          RECORD_OUTPUTS, seed=camera_seed)

    cams = {"clean_ahead": camera("ahead", "ideal", seed),
            "clean_tick": camera("tick", "ideal", seed),
            "ahead": camera("ahead", "mv_global_shutter", seed),
            "ahead_b": camera("ahead", "mv_global_shutter", seed + 1),
            "tick": camera("tick", "mv_global_shutter", seed)}
    timed = ("ahead", "tick")
    cpu = {name: {"tick": [], "state": []} for name in timed}
    frames: dict[str, list] = {name: [] for name in cams}
    try:
        sim.start_episode(seed, 0)
        sim.apply(np.asarray(command, np.float64))
        while True:
            if sim.render_due:
                state, meta = sim.scene.state(sim.data), sim.sample_meta(0)
                for name, cam in cams.items():
                    c0 = time.process_time()
                    for output, arrays, m in cam.sample(state, meta):
                        if output == "rgb":
                            frames[name].append((arrays["rgb"].astype(np.int16), m))
                    if name in timed:
                        cpu[name]["tick" if meta["control"] else "state"].append(
                            time.process_time() - c0)
            if sim.advance():
                break
        counts = dict(cams["clean_ahead"].counts)
    finally:
        for cam in cams.values():
            cam.close()

    def mean_abs(a: str, b: str) -> np.ndarray:
        return np.array([np.abs(x[0] - y[0]).mean() for x, y in
                         zip(frames[a][1:], frames[b][1:])])
    moved, noise = mean_abs("clean_ahead", "clean_tick"), mean_abs("ahead", "ahead_b")
    p99 = [np.percentile(np.abs(x[0] - y[0]), 99) for x, y in
           zip(frames["clean_ahead"][1:], frames["clean_tick"][1:])]

    def readout_ms(name: str) -> float:
        return round(1e3 * float(np.median([m["t_ep"] - m["t_exposure_end"]
                                            for _, m in frames[name][1:]])), 3)
    # the first tick compiles the model: left out like the first frame
    return {"config": dict(config or {}), "dvs_hz": dvs_hz, "size": size,
            "command": list(command), "ticks": len(moved),
            "moved_dn_median": round(float(np.median(moved)), 4),
            "moved_dn_p99": round(float(np.median(p99)), 4),
            "noise_dn_median": round(float(np.median(noise)), 4),
            "ratio_median": round(float(np.median(moved / np.maximum(noise, 1e-9))), 4),
            "readout_ms": {name: readout_ms(name) for name in timed},
            "tick_ms_p50": {name: round(1e3 * float(np.median(cpu[name]["tick"][1:])), 3)
                            for name in timed},
            "period_cpu_ms": {name: round(1e3 * (sum(cpu[name]["tick"][1:])
                                                 + sum(cpu[name]["state"])) / len(moved), 3)
                              for name in timed},
            "counts": {k: counts[k] for k in ("frames_ahead", "exposure_end_moved",
                                              "light_extra")}}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="fewer steps and frames (< 40 s)")
    ap.add_argument("--json", metavar="FILE", help="write the results here")
    ap.add_argument("--no-pipeline", action="store_true", help="skip the topology run")
    ap.add_argument("--pipeline-only", action="store_true",
                    help="only the topology runs (no physics or render figures)")
    ap.add_argument("--ceiling-only", action="store_true",
                    help="only the compute ceiling (no physics, render or topology rows)")
    ap.add_argument("--sensors-only", action="store_true",
                    help="only the ideal8 / physical sensor recording comparison")
    ap.add_argument("--ceiling-vs-record", action="store_true",
                    help="only the physical pair's compute ceiling and its measured "
                         "recording rate side by side, with their ratio (and the ideal8 "
                         "ceiling beside them)")
    ap.add_argument("--frame-ready-only", action="store_true",
                    help="only the camera's frame_ready ahead against tick: the frames' "
                         "difference against the noise, and the tick's CPU")
    ap.add_argument("--adaptive-only", action="store_true",
                    help="only adaptive luma sampling against the 1 kHz reference (and, "
                         "without --quick, recording with it)")
    ap.add_argument("--no-adaptive", action="store_true",
                    help="skip adaptive luma sampling")
    ap.add_argument("--adaptive-set", action="append", default=[], metavar="KEY=VALUE",
                    help="a further --set for the adaptive runs, e.g. "
                         "camera.luma_fraction=0.3 (repeatable)")
    ap.add_argument("--placement", default="",
                    help="comma-separated [topology] placements to compare, alternating "
                         "(isolated, auto); default: the topology files' own")
    ap.add_argument("--repeats", type=int, default=0,
                    help="pipeline runs per placement (default 1 with --quick, else 3)")
    args = ap.parse_args()
    steps, frames, repeats = (1000, 100, 3) if args.quick else (5000, 300, 5)
    out: dict = {"physics": [], "render": [], "pipeline": [], "adaptive": [],
                 "config": {"quick": args.quick, "repeats": repeats, "steps": steps,
                            "frames": frames, "statistic": "median"}}
    notes = []
    if args.ceiling_vs_record or args.frame_ready_only:
        if args.ceiling_vs_record:
            row = bench_ceiling_vs_record(args.repeats or (1 if args.quick else 3),
                                          1.0 if args.quick else 3.0,
                                          10.0 if args.quick else 20.0)
            out["ceiling_vs_record"] = row
            print(f"physical pair: recording {row['record_x_real_time']}x real time, ceiling "
                  f"{row['ceiling_x_on_2_cores']}x on 2 cores: {row['record_over_ceiling']} "
                  f"of it ({row['record_over_ideal8_ceiling']} of the ideal8 ceiling "
                  f"{row['ceiling_ideal8']['ceiling_x_on_2_cores']}x)", flush=True)
        if args.frame_ready_only:
            out["frame_ready"] = []
            cells = [{}, {"lighting": "dusk", "target_speed": "fast"}]
            for config in cells[:1] if args.quick else cells:
                row = bench_frame_ready(config, seconds=1.5 if args.quick else 3.0)
                out["frame_ready"].append(row)
                print(f"frame_ready {config or 'nominal'}: ahead - tick {row['moved_dn_median']}"
                      f" DN against the noise's {row['noise_dn_median']} DN; tick CPU "
                      f"{row['tick_ms_p50']} ms, per period {row['period_cpu_ms']} ms",
                      flush=True)
        if args.json:
            Path(args.json).parent.mkdir(parents=True, exist_ok=True)
            Path(args.json).write_text(json.dumps(out, indent=1))
        return 0
    if args.sensors_only:
        out["sensors"] = bench_sensors(args.repeats or (2 if args.quick else 3),
                                       10.0 if args.quick else 20.0)
        print(f"sensors: physical / ideal8 = {out['sensors']['physical_over_ideal8']}",
              flush=True)
        if args.json:
            Path(args.json).parent.mkdir(parents=True, exist_ok=True)
            Path(args.json).write_text(json.dumps(out, indent=1))
        return 0
    if args.adaptive_only:
        args.pipeline_only = args.no_pipeline = True
    figures = not (args.pipeline_only or args.ceiling_only)   # physics, render, switch rows
    for name in SCENES if figures else ():
        try:
            for integ in sorted(INTEGRATORS):
                sps = bench_physics(name, integ, steps, repeats)
                out["physics"].append({"scene": name, "integrator": integ,
                                       "steps_per_s": round(sps)})
                print(f"physics {name:4s} {integ:13s} {sps:10.0f} steps/s", flush=True)
        except Exception as exc:    # one scene failing still leaves the others' figures
            notes.append(f"physics {name}: {type(exc).__name__}: {exc}")
    jobs = [("nav", {"variant": "indoor"}, "front", 160, ["rgb", "luma", "depth", "seg"]),
            ("nav", {"variant": "outdoor"}, "front", 160, ["rgb"]),
            ("nav", {"variant": "indoor"}, "front", 80, ["luma"]),   # camera luma_scale 0.5
            ("nav", {"variant": "indoor"}, "front", 320, ["rgb"])]
    if not args.quick:
        jobs.append(("nav", {"variant": "indoor"}, "front", 640, ["rgb"]))
    jobs.append(("arm", {}, "wrist", 320, ["rgb"]))      # the arm target
    for name, config, cam, size, kinds in jobs if figures else ():
        try:
            for row in bench_render(name, config, cam, size, kinds, frames, repeats):
                out["render"].append(row)
                print(f"render  {row['scene']:12s} {cam:8s} {row['size']:8s} "
                      f"{row['kind']:6s} {row['fps']:8.1f} fps", flush=True)
        except Exception as exc:
            notes.append(f"render {name} {cam}: {type(exc).__name__}: {exc}")
    for size in (160, 80) if figures else ():   # the camera's RGB and luma sizes
        try:
            row = bench_scene_switch(size, repeats)
            out.setdefault("scene_switch", []).append(row)
            print(f"scene switch {row['size']}: fresh renderer {row['fresh_renderer_ms']} ms, "
                  f"set_model {row['set_model_ms']} ms", flush=True)
        except Exception as exc:
            notes.append(f"scene switch {size}: {type(exc).__name__}: {exc}")
    ceilings = [("indoor", 200.0, 160), ("outdoor", 200.0, 160), ("indoor", 200.0, 80),
                ("indoor", 100.0, 160), ("outdoor", 100.0, 160)]
    # the physical pair's beside them (the shipped topologies' sensors), at the same rates
    ceilings += [(v, hz, size, "physical") for v, hz, size in ceilings[:2]]
    for variant, dvs_hz, luma_size, *sensor in () if args.pipeline_only else ceilings:
        try:
            bench = bench_ceiling_physical if sensor == ["physical"] else bench_ceiling
            row = bench(2.0 if args.quick else 5.0, dvs_hz, luma_size, repeats=repeats,
                        variant=variant)
            out.setdefault("ceiling", []).append(row)
            print(f"ceiling [{row['sensor']}] {row['what']}: {row['cpu_s_per_sim_s_total']} "
                  f"CPU s per sim s {row['cpu_s_per_sim_s']}, at most "
                  f"{row['ceiling_x_on_2_cores']}x real time on 2 cores", flush=True)
        except Exception as exc:
            notes.append(f"ceiling {variant} {sensor or ['ideal8']}, dvs {dvs_hz:g} Hz, "
                         f"luma {luma_size} px: "
                         f"{type(exc).__name__}: {exc}")
    placements = [p.strip() for p in args.placement.split(",") if p.strip()] or [None]
    runs = args.repeats or (1 if args.quick else 3)
    if not (args.no_pipeline or args.ceiling_only):
        try:
            for _ in range(runs):
                for placement in placements:   # alternating: a slow phase hits both
                    row = bench_pipeline(5.0 if args.quick else 20.0, placement=placement)
                    out["pipeline"].append(row)
                    print(f"pipeline [{row['placement']}] {row['topology']}: "
                          f"{row['real_time_factor']}x real time, "
                          f"{row['event_frames']}/{row['ticks']} event frames", flush=True)
            if not args.quick:
                for _ in range(runs if len(placements) > 1 else 1):
                    for placement in placements:
                        row = bench_record(2, 20.0, placement=placement)
                        out["pipeline"].append(row)
                        print(f"pipeline [{row['placement']}] {row['topology']}: "
                              f"{row['real_time_factor']}x real time "
                              f"({row['frames']} frames)", flush=True)
        except Exception as exc:
            notes.append(f"pipeline: {type(exc).__name__}: {exc}")
        if len(placements) > 1:
            out["placement_medians"] = summary = {}
            for row in out["pipeline"]:
                key = f"{row['topology']} [{row['placement']}]"
                summary.setdefault(key, []).append(row["real_time_factor"])
            for key, rates in summary.items():
                summary[key] = {"runs": rates, "median": statistics.median(rates)}
                print(f"median {key}: {summary[key]['median']}x real time "
                      f"(runs {rates})", flush=True)
    if not (args.no_adaptive or args.ceiling_only):
        # beside the fixed-rate pipeline rows: issue 37's adaptive rows (exactly its keys)
        # and what they rest on (sample rates, matched fraction, run spread)
        out["adaptive_detail"] = []
        for scene in ADAPTIVE_SCENES:
            try:
                row, detail = bench_adaptive(scene, args.quick,
                                             args.repeats or (1 if args.quick else 3),
                                             args.adaptive_set)
                out["adaptive"].append(row)
                out["adaptive_detail"].append(detail)
                print(f"adaptive {json.dumps(row)}", flush=True)
            except Exception as exc:
                notes.append(f"adaptive {scene}: {type(exc).__name__}: {exc}")
        if not args.quick:
            try:
                sets = ['camera.luma_sampling="adaptive"',
                        'emulator.overrides={downsample=1.0, lowpass_hold="linear"}',
                        *args.adaptive_set]
                for _ in range(args.repeats or 2):
                    for name, extra in (("fixed", []), ("adaptive", sets)):
                        row = bench_record(2, 20.0, sets=extra)
                        row["luma_sampling"] = name
                        out["pipeline"].append(row)
                        print(f"record [{name}] {row['real_time_factor']}x real time",
                              flush=True)
            except Exception as exc:
                notes.append(f"record adaptive: {type(exc).__name__}: {exc}")
    if notes:
        out["notes"] = notes
        for n in notes:
            print("note:", n, flush=True)
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
