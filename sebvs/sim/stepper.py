"""The sim actor's physics without its messaging: one scene stepped episode by episode.

actors/sim.py wires this to the runtime (states out, actions in, the clock), and
sebvs.envs steps it in process (the Gymnasium environments): both run the same code, so an
episode played through either is the same, bit for bit, for the same seed and commands.

    sim = SceneStepper("nav", config, control_hz=10.0, render_hz=100.0, episode_s=30.0)
    info = sim.start_episode(run_seed, k)      # seeded episode_seed(run_seed, k)
    while True:
        if sim.render_due:                     # a state sample (sim.control_due: a tick)
            ...publish scene.state(data), apply the tick's command with sim.apply()...
        reason = sim.advance()                 # one physics step, or why the episode ends
        if reason:
            break
    outcome = sim.finish(reason)

Rates: physics_hz (or timestep) is a whole multiple of render_hz, and the control period a
whole number of render periods. Execution noise (`command_noise`): each applied command
gets zero-mean Gaussian noise, std per dimension, from the episode's own stream
[episode seed, NOISE_STREAM].
"""
from __future__ import annotations

import math

import numpy as np

from . import make_scene  # sets MUJOCO_GL before mujoco is imported
from .randomise import SceneRandomiser
from .stability import StabilityMonitor

import mujoco  # noqa: E402  (after sebvs.sim on purpose)

NOISE_STREAM = 0x6e6f697365   # "noise": the execution noise's seed stream, beside the scene's


def episode_seed(seed: int, episode: int) -> int:
    """The seed of episode `episode` of a run seeded `seed` (stable, reportable)."""
    return int(np.random.SeedSequence([seed, episode]).generate_state(1)[0])


class SceneStepper:
    """One scene's model and data, its rates, and the episode loop's steps."""

    def __init__(self, scene: str, config: dict | None = None, *, randomise: dict | None = None,
                 integrator: str = "discrete", physics_hz: float = 1000.0,
                 timestep: float | None = None, control_hz: float = 20.0,
                 render_hz: float = 200.0, episode_s: float = 20.0, check_every: int = 1,
                 command_noise: list | tuple = ()) -> None:
        config = dict(config or {})
        physics_hz = 1.0 / timestep if timestep else physics_hz
        for key, v in (("physics_hz", physics_hz), ("control_hz", control_hz),
                       ("render_hz", render_hz), ("episode_s", episode_s)):
            if not v > 0:
                raise ValueError(f"sim: {key} must be positive, got {v!r}")
        self.scene_name = scene
        self.control_hz, self.render_hz, self.episode_s = control_hz, render_hz, episode_s
        self.check_every = check_every
        self.dt = 1.0 / physics_hz
        self.steps_per_control = max(1, round(physics_hz / control_hz))
        self.steps_per_render = max(1, round(physics_hz / render_hz))
        for key, hz, n in (("control_hz", control_hz, self.steps_per_control),
                           ("render_hz", render_hz, self.steps_per_render)):
            if abs(physics_hz / hz - n) > 1e-6 * n:
                raise ValueError(f"sim: {key} {hz:g} must divide physics_hz {physics_hz:g} "
                                 f"(a whole number of physics steps per period)")
        if self.steps_per_control % self.steps_per_render:
            raise ValueError(
                f"sim: control period ({self.steps_per_control} steps) must be a multiple of "
                f"the render period ({self.steps_per_render} steps at physics_hz "
                f"{physics_hz:g}): choose render_hz = n * control_hz")
        for key in ("integrator", "timestep"):
            if key in config:
                raise ValueError(f"sim: set {key!r} as a sim parameter, not inside config")
        self.n_steps = max(1, round(episode_s / self.dt))
        base = {**config, "integrator": integrator, "timestep": self.dt}
        self.randomiser = SceneRandomiser(scene, base, randomise) if randomise else None
        self.config: dict = {}
        self.build(base)
        self.command_noise = list(command_noise)
        self.check_noise(self.command_noise)
        self.noise_rng = np.random.default_rng(0)   # reseeded per episode
        self.command = self.scene.idle_command()    # last good command
        self.noised = 0                             # commands the noise was added to
        self.step = 0
        self.diverged = False

    def build(self, config: dict) -> None:
        """(Re)compile the scene for ``config``; a no-op when it is the current one."""
        if config == self.config:
            return
        self.config = config
        self.scene = make_scene(self.scene_name, **config)
        self.model = self.scene.compile()
        self.data = mujoco.MjData(self.model)
        self.monitor = StabilityMonitor(self.model, self.scene.limits())

    def check_noise(self, std: list) -> None:
        if std and len(std) != self.scene.command_dim:
            raise ValueError(f"sim: command_noise has {len(std)} values, the "
                             f"{self.scene_name} command has {self.scene.command_dim} "
                             f"(one std per dimension)")

    # ------------------------------------------------------------------ episode
    def start_episode(self, run_seed: int, k: int) -> dict:
        """Reset for episode `k` of a run seeded `run_seed`: its scene (a randomised one
        drawn from its seed), the scene's reset, the noise stream, the idle command.
        Returns {"episode", "seed", "scene", "config"}."""
        seed = episode_seed(run_seed, k)
        if self.randomiser:
            self.build(self.randomiser.draw(seed))
        model, data, scene = self.model, self.data, self.scene
        scene.reset(model, data, np.random.default_rng(seed))
        self.noise_rng = np.random.default_rng([seed, NOISE_STREAM])
        self.monitor.reset(data)
        self.command = scene.idle_command()
        scene.apply_command(model, data, self.command)
        self.step = 0
        self.diverged = False
        return {"episode": k, "seed": seed, "scene": self.scene_name, "config": self.config}

    @property
    def render_due(self) -> bool:
        """A state sample is due at the current step."""
        return self.step % self.steps_per_render == 0

    @property
    def control_due(self) -> bool:
        """The current step is a control tick (always a state sample too)."""
        return self.step % self.steps_per_control == 0

    @property
    def at_end(self) -> bool:
        """The episode's time is up: the current sample is its last."""
        return self.step >= self.n_steps

    def sample_meta(self, k: int) -> dict:
        """The state sample's meta at the current step of episode `k`: episode, control,
        t_ep; on a control tick truth and, unless the time is up, t_next_control (the next
        tick's t_ep bit for bit: a frame camera renders that frame's exposure ahead at the
        very times it will have); scene, config, control_hz on the first."""
        control = self.control_due
        meta = {"episode": k, "control": control, "t_ep": self.data.time}
        if control:
            meta["truth"] = self.scene.truth(self.model, self.data)
            if not self.at_end:
                # mj_step adds the timestep to data.time once a step, whatever the integrator
                t, dt = self.data.time, self.model.opt.timestep
                for _ in range(self.steps_per_control):
                    t += dt
                meta["t_next_control"] = t
        if self.step == 0:
            meta["scene"], meta["config"] = self.scene_name, self.config
            meta["control_hz"] = self.control_hz
        return meta

    def advance(self) -> str | None:
        """One physics step (scripted motion first), or why the episode ends instead:
        "time_limit", the scene's done() reason, or a divergence (self.diverged set)."""
        if self.step >= self.n_steps:
            return "time_limit"
        model, data = self.model, self.data
        why = self.scene.done(model, data)
        if why:
            return why
        self.scene.scripted(model, data)
        mujoco.mj_step(model, data)
        self.step += 1
        if self.step % self.check_every == 0:
            why = self.monitor.check(model, data)
            if why:
                self.diverged = True
                return why
        return None

    def t_ep(self) -> float:
        """The episode's time (s), from the step count if the state is not finite."""
        return float(self.data.time) if math.isfinite(self.data.time) else self.step * self.dt

    def finish(self, reason: str) -> dict:
        """The scene's finish() (the arm's grasp of its last command) after an episode that
        ran out its time or ended by the scene; {} after a divergence or a stop."""
        if reason == "stopped" or reason.startswith("diverged"):
            return {}
        return self.scene.finish(self.model, self.data, self.monitor)

    # ------------------------------------------------------------------ commands
    def check_command(self, cmd) -> bool:
        """A command of the scene's shape with finite values."""
        return cmd is not None and np.shape(cmd) == (self.scene.command_dim,) and \
            bool(np.isfinite(cmd).all())

    def executed(self, cmd: np.ndarray) -> np.ndarray:
        """The command as executed: plus the execution noise, when there is any."""
        std = self.command_noise
        if not std:
            return cmd
        self.noised += 1
        return cmd + self.noise_rng.normal(0.0, 1.0, cmd.shape) * np.asarray(std)

    def apply(self, cmd: np.ndarray) -> str | None:
        """Apply a command (float64); None, or why the scene refused it (its ctrl then as
        before, and the last good command stays)."""
        saved = self.data.ctrl.copy()
        try:
            self.scene.apply_command(self.model, self.data, self.executed(cmd))
        except ValueError as exc:
            self.data.ctrl[:] = saved               # a scene must not half-apply a command
            return str(exc)
        self.command = self.scene.clip_command(cmd)     # in force, as the scene takes it
        return None
