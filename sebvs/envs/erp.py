"""ERPNav and ERPArm as Gymnasium environments: the lockstep topology's loop in one process.

The settings come from the task's policy topology (topologies/nav_policy.toml,
arm_policy.toml) with the same overrides `sebvs eval` gives a run of the condition and
scenario (both read them from sebvs/conditions.py): the sim, camera, emulator and
accumulator get the very parameters and seeds (Topology.actor_seed) they get there, and
run the same code (sebvs.sim.stepper.SceneStepper, sebvs.sensors.camera.CameraCore,
sebvs.dvs.stream.SensorStream / FrameStream). So `env.reset(seed=s)` plays episode 0 of
`sebvs eval --seed s`'s lockstep run, and every `reset()` after it the next episode of that
run, as the sim actor plays them one after the other (options={"episode": k} jumps).

One env step is one control tick: the action is applied as the sim applies the action of
a tick (execution noise, then the scene's clip), the physics runs to the next control tick,
and every state sample on the way goes through the camera and the event chain (luma at
the camera's dvs rate, an event frame at each tick).
"""
from __future__ import annotations

from collections.abc import Mapping

import gymnasium
import numpy as np
from gymnasium import spaces

from sebvs.conditions import TASKS, control_rate_overrides
from sebvs.runtime.overrides import Overrides, merge
from sebvs.runtime.topology import check_seed
from sebvs.sensor_pairs import DEFAULT_CONDITION, DEFAULT_SENSOR

OBS_KEYS = ("rgb", "events", "proprio")
# the observation's keys as the env's own, or as lerobot-eval reads a Gymnasium env's
OBS_LAYOUTS = ("sebvs", "lerobot")
LEROBOT_KEYS = {"rgb": "pixels", "proprio": "agent_pos"}
TASK_SCENARIO = {name: spec.default_scenario for name, spec in TASKS.items()}


def env_settings(task: str, condition: str = DEFAULT_CONDITION[DEFAULT_SENSOR],
                 scenario: str | None = None, *,
                 sensor: str | None = None, emulator: str | None = None,
                 width: int | None = None, height: int | None = None,
                 control_hz: float | None = None, episode_s: float | None = None,
                 representation: str | None = None, bins: int | None = None,
                 overrides: Overrides = ()) -> dict:
    """The actors' parameters of the task's policy topology as `sebvs eval` runs a
    condition and scenario of it, and the expert's.

    Parameters:
        task: "nav" or "arm".
        condition, scenario: sebvs/conditions.py's (scenario None: the task's first).
        sensor: the camera's ("ideal8" | "physical"; None: the condition's).
        emulator: the emulator preset (None: the condition's, "physical" under the
            physical conditions, the paper's under the 8-bit benchmark's).
        width, height: the image (the event frames follow).
        control_hz: as `sebvs eval --control-hz` (the render and physics rates follow, the
            event window is one control period).
        episode_s: the episode's length.
        representation, bins: the accumulator's (bins alone: a voxel grid).
        overrides: further overrides, applied last: a mapping, or `--set` lines.

    Returns:
        {"topology": Topology, "sim", "camera", "emulator", "accumulator", "tracker",
        "expert": their Params}. ValueError, in one line, for an unknown task, condition
        or scenario.
    """
    from sebvs.runtime.params import build_params
    from sebvs.runtime.topology import load_topology
    if task not in TASKS:
        raise ValueError(f"unknown task {task!r} (one of {', '.join(TASKS)})")
    spec = TASKS[task]
    cond = spec.condition(condition)
    scene = merge(cond.overrides(), spec.scenario(scenario or spec.default_scenario).overrides())
    if control_hz is not None and not (isinstance(control_hz, (int, float))
                                       and 0 < control_hz <= 1000):
        raise ValueError(f"control_hz must be in (0, 1000], got {control_hz!r}")
    # the rates of a run with the event chain wired, as `sebvs eval` sets them
    rate = {} if control_hz is None else \
        control_rate_overrides(spec.policy_sim(), cond, control_hz, events=True)
    mine: dict = {}
    if sensor is not None:
        mine = merge(mine, {"camera": {"sensor": sensor}})
    if emulator is not None:
        mine = merge(mine, {"emulator": {"preset": emulator}})
    if width is not None:
        mine = merge(mine, {"sim": {"config": {"width": int(width)}},
                            "accumulator": {"out_width": int(width)}})
    if height is not None:
        mine = merge(mine, {"sim": {"config": {"height": int(height)}},
                            "accumulator": {"out_height": int(height)}})
    if episode_s is not None:
        mine = merge(mine, {"sim": {"episode_s": float(episode_s)}})
    if bins is not None:
        mine = merge(mine, {"accumulator": {"bins": int(bins)}})
        if representation is None:
            representation = "voxel"
    if representation is not None:
        mine = merge(mine, {"accumulator": {"representation": representation}})
    topo = load_topology(spec.policy_topology,
                         [scene, cond.event_sensor_overrides(), rate, mine,
                          *([overrides] if isinstance(overrides, Mapping) else overrides)])
    out = {"topology": topo}
    for name in ("sim", "camera", "emulator", "accumulator", "tracker"):
        a = topo.actors[name]
        out[name] = build_params(a.cls.Params, a.params, where=name)
    # the expert of `sebvs eval`'s reference row, on the same scene
    expert = load_topology(spec.expert_topology, scene).actors["expert"]
    out["expert"] = build_params(expert.cls.Params, expert.params, where="expert")
    return out


class ERPEnv(gymnasium.Env):
    """One task's closed loop, a control tick per step (see the module docstring).

    Keyword arguments (gymnasium.make passes them on):
      scenario     nav "indoor" | "outdoor"; arm "single" | "multi" (three cubes)
      condition    a condition of `sebvs eval` (sebvs/conditions.py, docs/sim.md; default:
                   the default sensor pair's nominal_physical, the 8-bit pair's is "nominal"):
                   nav nominal, fast, low_light, flicker, blur, fast_flicker,
                   nominal_physical, hdr, dusk, dusk_fast, flicker_100, flicker_120,
                   fast_hdr; arm nominal, moving, fast, low_light, flicker, blur,
                   nominal_physical, fast_physical, hdr, dusk_moving, fast_hdr
      sensor       the camera: "ideal8" | "physical" (None: the condition's)
      emulator     the event sensor's preset: "paper" | "clean" | "noisy" | "physical"
                   (None: the condition's)
      width, height  the image, px (160 x 160); the event frames are the same size
      control_hz   control ticks per second, one per step (None: the topology's 10 Hz)
      episode_s    episode length, s (None: the topology's: nav 30, arm 2)
      obs          the observation's keys, any of "rgb", "events", "proprio"
      obs_layout   "sebvs" (those keys) | "lerobot": the keys lerobot-eval maps, "pixels"
                   ({camera: rgb}, to observation.images.<camera>) and "agent_pos" (the
                   proprio, to observation.state), as `sebvs data export --format lerobot`
                   names them; "events" keeps its name
      bins         event frames as a voxel grid of this many time bins (float32)
      representation  "counts" (default) | "histogram" | "voxel" | "time_surface"
      privileged   info also carries the expert's inputs: "ideal" (the ideal 8-bit
                   render), "state" (the sim's state) and, arm, "depth"
      render_mode  None | "rgb_array" (render() returns the camera's RGB frame)
      seed         the topology seed a first reset() without one plays (0), 0 <= seed < 2**31
                   like every seed of reset(seed=...): one seed, one set of episodes
      overrides    further overrides of the policy topology: a mapping
                   ({"sim": {"command_noise": [0.0, 0.0]}}) or `--set` lines
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}
    task = ""

    def __init__(self, *, scenario: str | None = None,
                 condition: str = DEFAULT_CONDITION[DEFAULT_SENSOR],
                 sensor: str | None = None, emulator: str | None = None,
                 width: int | None = None, height: int | None = None,
                 control_hz: float | None = None, episode_s: float | None = None,
                 obs: tuple | list = OBS_KEYS, bins: int | None = None,
                 representation: str | None = None, privileged: bool = False,
                 render_mode: str | None = None, seed: int = 0,
                 overrides: list | tuple = (), obs_layout: str = "sebvs") -> None:
        from sebvs.dvs.params import preset
        from sebvs.dvs.stream import FrameStream, SensorStream
        from sebvs.sensors.camera import CameraCore
        from sebvs.sim.stepper import SceneStepper
        obs = tuple(obs)
        unknown = [k for k in obs if k not in OBS_KEYS]
        if unknown or not obs or len(set(obs)) != len(obs):
            raise ValueError(f"obs must name some of {', '.join(OBS_KEYS)} once each, "
                             f"got {obs!r}")
        if obs_layout not in OBS_LAYOUTS:
            raise ValueError(f"obs_layout must be one of {', '.join(OBS_LAYOUTS)}, got "
                             f"{obs_layout!r}")
        self.obs_layout = obs_layout
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ValueError(f"render_mode {render_mode!r} is not None or 'rgb_array'")
        self.obs_keys, self.render_mode, self.privileged = obs, render_mode, bool(privileged)
        self.scenario = scenario or TASK_SCENARIO[self.task]
        self.condition = condition
        s = env_settings(self.task, condition, self.scenario, sensor=sensor, emulator=emulator,
                         width=width, height=height, control_hz=control_hz,
                         episode_s=episode_s, representation=representation, bins=bins,
                         overrides=overrides)
        self.settings = s
        self.topology = s["topology"]
        sp, cp, ep, ap = s["sim"], s["camera"], s["emulator"], s["accumulator"]
        self.sim = SceneStepper(sp.scene, sp.config, randomise=sp.randomise,
                                integrator=sp.integrator, physics_hz=sp.physics_hz,
                                timestep=sp.timestep, control_hz=sp.control_hz,
                                render_hz=sp.render_hz, episode_s=sp.episode_s,
                                check_every=sp.check_every, command_noise=sp.command_noise)
        self.metadata = {**self.metadata, "render_fps": sp.control_hz}
        wanted = set()
        if "rgb" in obs or render_mode == "rgb_array":
            wanted.add("rgb")
        if "events" in obs:
            wanted.add("luma")
        if self.privileged:
            wanted |= {"ideal", "depth"} if self.task == "arm" else {"ideal"}
        self.wanted = wanted
        self.camera_params, self.emulator_params = cp, ep
        self._camera_core, self._preset = CameraCore, preset
        self._sensor_stream, self._frame_stream = SensorStream, FrameStream
        self.camera = None
        self.run_seed = check_seed(seed, "seed")
        self.closed = False
        self._build_chain()
        scene = self.sim.scene
        h, w = scene.image_shape()
        self.image_shape = (h, w)
        self.frame_size = (ap.out_height or h, ap.out_width or w)
        spaces_ = {}
        if "rgb" in obs:
            spaces_["rgb"] = spaces.Box(0, 255, (h, w, 3), np.uint8)
        if "events" in obs:
            fh, fw = self.frame_size
            if ap.representation == "voxel":
                big = float(np.finfo(np.float32).max)     # signed sums of events: unbounded
                spaces_["events"] = spaces.Box(-big, big, (ap.bins, fh, fw), np.float32)
            else:
                planes = 2 if ap.representation in ("counts", "time_surface") else 2 * ap.bins
                high = 255 if ap.representation == "time_surface" else ap.clip  # not clipped
                spaces_["events"] = spaces.Box(0, high, (planes, fh, fw), np.uint8)
        if "proprio" in obs:
            lo, hi = self._proprio_bounds()
            spaces_["proprio"] = spaces.Box(lo.astype(np.float32), hi.astype(np.float32),
                                            lo.shape, np.float32)
        # the name `sebvs data export --format lerobot` gives the video feature
        self.camera_name = str(getattr(cp, "camera", "") or scene.cameras[0])
        self.observation_space = spaces.Dict(self._laid_out(spaces_, spaces.Dict))
        self.action_space = self._action_space()
        self.episode = -1
        self.t_offset = 0.0
        self.ended = True
        self._last_rgb = None

    # ------------------------------------------------------------------ subclass hooks
    def _action_space(self) -> spaces.Box:
        raise NotImplementedError

    def _proprio_reader(self):
        """The scene's proprioception for the model the sim runs now.

        Returns:
            sebvs.sim.proprio.ProprioReader: what the sim actor sends the recorder too.
        """
        sim = self.sim
        if getattr(self, "_reader_model", None) is not sim.model:
            from sebvs.sim.proprio import proprio_reader
            self._reader = proprio_reader(sim.scene_name, sim.scene, sim.model)
            self._reader_model = sim.model
        return self._reader

    def _proprio(self) -> np.ndarray:
        return self._proprio_reader().read(self.sim.data)

    def _proprio_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        reader = self._proprio_reader()
        return reader.lo, reader.hi

    def _tick_reward(self, truth: dict) -> float:
        return 0.0

    def _end_reward(self, outcome: dict) -> float:
        return 0.0

    def _terminal(self, reason: str) -> bool:
        """Whether an episode that ended for `reason` is terminated (not truncated)."""
        return reason != "time_limit"

    def _summary(self, outcome: dict, duration_s: float) -> dict:
        raise NotImplementedError

    # ------------------------------------------------------------------ the chain
    def _build_chain(self) -> None:
        """Camera, emulator and accumulator seeded as the topology seeds its actors."""
        topo = self.topology
        topo.seed = self.run_seed
        if self.camera is not None:
            self.camera.close()
        self.camera = self._camera_core(self.camera_params, self.wanted,
                                        seed=topo.actor_seed("camera"))
        ap = self.settings["accumulator"]
        self.sensor = self._sensor_stream(self._preset(
            self.emulator_params.preset,
            **{"seed": topo.actor_seed("emulator"), **self.emulator_params.overrides}))
        self.frames = self._frame_stream(ap.representation, ap.window_s, ap.bins, ap.clip,
                                         ap.out_width, ap.out_height)
        self.sim_seed = topo.actor_seed("sim")

    def _sample(self) -> None:
        """The current state sample through the camera and the event chain (the topology's
        hops in order); on a control tick, the tick's observation parts."""
        sim = self.sim
        data = sim.data
        state = sim.scene.state(data)
        meta = sim.sample_meta(self.episode)
        t_sim = self.t_offset + data.time
        t_state = float(meta["t_ep"])
        for output, arrays, m in self.camera.sample(state, meta, self._alloc):
            if output == "luma":
                # the state's time, or (adaptive luma sampling, between two states) its
                # own, as the camera actor stamps it
                t_out = t_sim if m["t_ep"] == t_state else t_sim + (m["t_ep"] - t_state)
                frame = arrays["luma"]
                events = self.sensor.frame(frame, t_out, m["episode"], m.get("units"))
                self.frames.add(events, m["episode"], self.sensor.geometry_meta(frame))
                if m["control"]:
                    self._parts["events"] = self.frames.frame(t_out)
            else:
                self._parts[output] = arrays[output if output != "ideal" else "rgb"]
        if meta["control"]:
            self.tick += 1
            self._truth = meta["truth"]
            self._t_ep, self._t_sim = float(data.time), t_sim
            self._rows.append((self._truth, float(meta["t_ep"])))
            if self.privileged:
                self._parts["state"] = state

    @staticmethod
    def _alloc(output: str, specs: dict) -> dict:
        return {name: np.empty(shape, dtype) for name, (shape, dtype) in specs.items()}

    def _observation(self) -> dict:
        obs = {}
        if "rgb" in self.obs_keys:
            obs["rgb"] = self._parts["rgb"]
        if "events" in self.obs_keys:
            obs["events"] = self._parts["events"]
        if "proprio" in self.obs_keys:
            obs["proprio"] = self._proprio().astype(np.float32)
        self._last_rgb = self._parts.get("rgb")
        return self._laid_out(obs, dict)

    def _laid_out(self, parts: dict, mapping=dict) -> dict:
        """The observation (or its spaces) under obs_layout's keys: unchanged for "sebvs";
        for "lerobot", rgb as pixels {camera: rgb} (`mapping` builds that inner dict: a
        spaces.Dict for the spaces) and proprio as agent_pos."""
        if self.obs_layout == "sebvs":
            return parts
        out = {}
        for key, value in parts.items():
            if key == "rgb":
                out["pixels"] = mapping({self.camera_name: value})
            else:
                out[LEROBOT_KEYS.get(key, key)] = value
        return out

    def _info(self) -> dict:
        # "episode" is Gymnasium's: RecordEpisodeStatistics (and every trainer reading
        # episode returns through it) writes its statistics under that key
        info = {"episode_index": self.episode, "seed": self.episode_info["seed"],
                "tick": self.tick, "t_ep": self._t_ep, "t_sim": self._t_sim,
                "truth": self._truth, "command": self.sim.command.copy(),
                "rejected": self.rejected}
        if self.privileged:
            info["ideal"] = self._parts["ideal"]
            info["state"] = self._parts["state"]
            if "depth" in self._parts:
                info["depth"] = self._parts["depth"]
        return info

    # ------------------------------------------------------------------ gymnasium
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        self._check_open("reset()")
        if seed is not None:
            # a topology seed, one-to-one with the episodes it plays: one that wrapped
            # around (2**32 + 5) would replay another seed's, a held-out split's among them
            seed = check_seed(seed, "reset(seed=...)")
        super().reset(seed=seed)
        options = options or {}
        if self.episode >= 0 and not self.ended:
            self.t_offset += self.sim.t_ep()     # as the sim's clock runs on over a stop
        if seed is not None:
            self.run_seed = seed
            self._build_chain()
            self.t_offset = 0.0
            self.episode = -1
        k = options.get("episode", self.episode + 1)
        if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 0:
            raise ValueError(f"options['episode'] must be an episode index >= 0, got {k!r}")
        self.episode = int(k)
        self.episode_info = self.sim.start_episode(self.sim_seed, self.episode)
        self.tick = -1
        self._rows: list = []
        self._actions: list = []
        self._parts: dict = {}
        self.rejected = False
        self.ended = False
        self._sample()
        return self._observation(), self._info()

    def _check_open(self, call: str) -> None:
        if self.closed:
            raise gymnasium.error.ClosedEnvironmentError(f"{call} on a closed env: make a "
                                                         f"new one")

    def step(self, action):
        self._check_open("step()")
        if self.ended:
            raise RuntimeError("step() after the episode ended: call reset()")
        sim = self.sim
        cmd = np.asarray(action, dtype=np.float64)
        self.rejected = not sim.check_command(cmd)
        if not self.rejected:
            self.rejected = sim.apply(np.array(cmd)) is not None
        self._actions.append(None if self.rejected else cmd.copy())
        reward = 0.0
        while True:
            reason = sim.advance()
            if reason:
                break
            if sim.render_due:
                self._sample()
                if sim.control_due:
                    reward = self._tick_reward(self._truth)
                    if sim.at_end:
                        reason = sim.advance()      # "time_limit": the sample was the last
                    break
        if reason is None:
            return self._observation(), reward, False, False, self._info()
        return self._end(reason, reward)

    def _end(self, reason: str, reward: float):
        sim = self.sim
        self.ended = True
        t_ep = sim.t_ep()
        outcome = sim.finish(reason)
        self.t_offset += t_ep
        control_hz = self.settings["sim"].control_hz
        from sebvs.metrics import episode_duration
        duration = episode_duration([t for _, t in self._rows], control_hz)
        # the last tick's observation (an episode that ended between ticks has no newer)
        obs = self._observation()
        info = self._info()
        info.update(reason=reason, outcome=outcome,
                    episode_metrics=self._summary(outcome, duration))
        reward += self._end_reward(outcome)
        terminated = self._terminal(reason)
        return obs, reward, terminated, not terminated, info

    def render(self):
        if self.render_mode == "rgb_array":
            return self._last_rgb
        return None

    def close(self) -> None:
        self.closed = True
        if self.camera is not None:
            self.camera.close()
            self.camera = None
        super().close()


class ERPNavEnv(ERPEnv):
    """SEBVS/ERPNav-v1: the four-wheel robot keeps the red cube in view (the paper's
    ERPNav, sebvs/sim/nav.py).

    action    [v, w] in [-1, 1] (float32): forward speed and yaw rate as fractions of the
              scene's v_max (1.5 m/s) and w_max (2 rad/s), what the nav expert and policies
              command; out-of-range values are clipped by the scene, a command that is
              not finite is refused and the last good one stays (info["rejected"])
    proprio   the drive's odometry: [forward m/s, lateral m/s, yaw rate rad/s]
    reward    per step, from the tracking error of the tick the step reached: 1 - e / R
              with e the target centroid's distance from the image centre and R the
              paper's success radius (200 px at 640, scaled), floored at 0; 0 while the
              target is out of view. > 0 exactly on the frames the paper counts as success
    end       truncated when the episode's time is up (episode_s, 30 s), terminated on a
              divergence; the last step's info["episode_metrics"] is the nav tracker's
              Table 4 record of the episode (sebvs.metrics.nav_truth_metrics)
    """

    task = "nav"

    def _action_space(self) -> spaces.Box:
        return spaces.Box(-1.0, 1.0, (2,), np.float32)

    def _tick_reward(self, truth: dict) -> float:
        from sebvs.metrics import centre_error_px, success_radius
        err = centre_error_px(truth)
        if err is None:
            return 0.0
        return max(0.0, 1.0 - err / success_radius(truth["image"][0]))

    def _summary(self, outcome: dict, duration_s: float) -> dict:
        from sebvs.metrics import nav_truth_metrics
        return nav_truth_metrics([t for t, _ in self._rows], duration_s)


class ERPArmEnv(ERPEnv):
    """SEBVS/ERPArm-v1: the UR5 above the conveyor names a pre-grasp pose from its wrist
    camera each tick; at the end of the episode the sim grasps the last pose (the paper's
    ERPArm, sebvs/sim/arm.py).

    action    [x, y, z m, roll, pitch, yaw rad] (float32), world frame: what the arm
              expert and policies command; the scene clips the position into its reach
              box (+-0.9, +-0.9, -0.2..0.9 m) and wraps the angles; a command that is not
              finite is refused and the last good one stays (info["rejected"])
    proprio   the UR5's six joint angles and the two fingers' positions (the state the
              arm expert places its wrist camera from)
    reward    0 per tick; at the end 1 when the last pose did what the task asked: the
              cube lifted and held, or HOME where nothing was to be grasped
    end       terminated when the episode's time is up (episode_s, 2 s: the grasp ends
              the task) or on a divergence; the last step's info carries the grasp's
              "outcome" and "episode_metrics", the arm tracker's Table 5 record of the
              poses this episode's steps gave (sebvs.metrics.arm_episode_summary)
    """

    task = "arm"

    def _action_space(self) -> spaces.Box:
        lo = np.array([-0.9, -0.9, -0.2, -np.pi, -np.pi, -np.pi], np.float32)
        hi = np.array([0.9, 0.9, 0.9, np.pi, np.pi, np.pi], np.float32)
        return spaces.Box(lo, hi, (6,), np.float32)

    def _terminal(self, reason: str) -> bool:
        return True

    def _end_reward(self, outcome: dict) -> float:
        return 1.0 if outcome.get("outcome") in ("lifted_and_held", "home_correct") else 0.0

    def _summary(self, outcome: dict, duration_s: float) -> dict:
        from sebvs.experts.arm import leading_poses
        from sebvs.metrics import arm_episode_summary
        truths = [t for t, _ in self._rows]
        lead_s = self.settings["tracker"].lead_s
        reference = leading_poses([t["expert_pose"] for t in truths],
                                  [t["mode"] for t in truths], [t for _, t in self._rows],
                                  lead_s)
        actions = self._actions[:len(self._rows)]
        actions += [None] * (len(self._rows) - len(actions))
        return arm_episode_summary(truths, reference, actions, outcome.get("outcome"),
                                   int(self.sim.config.get("objects", 1)), lead_s, duration_s)
