"""The sim actor: MuJoCo physics of one scene, and the topology's clock.

Input  `action`   msg.arrays[scene.command_name]: (command_dim,) float command for tick
                  msg.tick ("action" [v, w] for nav, "pose" [x, y, z, r, p, y] for the arm).
Output `state`    scene.state() arrays (qpos, mocap_pos, mocap_quat, ...), published at
                  render_hz and at every control tick. meta: episode (int), control (bool:
                  True on the sample of a control tick), t_ep (s since the episode start),
                  truth (scene.truth(), control samples only), and on the episode's first
                  sample scene + config (the camera compiles its own model from them: the
                  sim's params are the one source of the scene config). tick = the current
                  control tick (global, counts across episodes); t_sim = simulated seconds
                  since the run started (monotonic across episodes).
Output `proprio`  arrays["proprio"] float32 (D,): the robot's proprioception at each control
                  tick's sample (sebvs/sim/proprio.py: nav odometry [v_forward, v_lateral,
                  yaw_rate], arm the six joint angles and two finger positions; the
                  Gymnasium environments' observation "proprio"), the tick and t_sim of that
                  state sample. meta: names (one per component), episode. Sent only where a
                  topology consumes it (the recorder: observation.state of a dataset).
Output `action`   arrays["action"] float64 (nu,): the scene's scripted command of each control
                  tick (scenes with a script: mjcf, sebvs/sim/mjcf_scene.py), which the sim
                  applies itself when `action` is not wired. Sent at every control tick,
                  the episode's last included, with meta episode, source "scripted"; the
                  tick and t_sim of the tick's state. A recorder records it as the tick's
                  command; a LockstepRecorder passing it back to `action` paces the sim to
                  the recorded chain (topologies/mjcf_reacher.toml). Nav and arm send none.
Output `episode`  meta {event: "start" | "end", episode, seed, reason, scene, config, steps;
                  end also t_ep, outcome: scene.finish()'s result (the arm's grasp of
                  its last command), {} after a divergence or a stop, and health: the
                  episode's {commands, rejected, action_timeouts, deadline_misses}}.
                  health counts the commands for the episode's ticks but its last: the
                  last tick's command drives no step of it and may come after the end.

Clock (DESIGN.md section 3):
  lockstep  after publishing control tick k the sim waits for the action with tick >= k
            before it steps on (bit-for-bit reproducible from the seed). If `action` is not
            wired (camera-only topologies) it free-runs, as fast as it can or capped at
            max_speed_factor x real time (set it when consumers cannot keep up: a PUB
            socket drops at its high-water mark, it does not block).
  realtime  wall-clock pace x realtime_factor; the latest valid action applies on arrival.
            The action for control tick k is due before tick k+1 goes out: the sim counts
            the ticks that missed it and times every action (sebvs/runtime/deadlines.py):
            stats "deadlines", telemetry "deadline_miss" and, per episode, "deadlines".

Execution noise (`command_noise`, off by default): each command the sim applies gets zero-mean
Gaussian noise, std per command dimension, drawn afresh per applied command from the
episode's seed (a stream of its own: lockstep runs stay bit-for-bit reproducible). This is
DART-style recording (Laskey et al. 2017): the robot is pushed off the expert's path and
the recorder keeps the expert's clean command as the label, so a policy can neither read
the label off the robot's own motion (the ego-motion events of the command it is executing)
nor meet states that the expert never left in the data. The noisy command is clipped by the
scene like any other (nav: [-1, 1]).

Scene "mjcf" (your own MJCF file, config path/package/camera/...: sebvs/sim/mjcf_scene.py) is
checked when the topology loads (check_wiring): a file that does not exist, does not compile
or has no such camera is one line naming it before any process starts.

A command with NaN/inf (or the wrong shape) is rejected: error in the log, telemetry
"command_rejected", the last good command stays. Divergence (sebvs.sim.stability) ends the
episode with its reason before the bad state is published: NaN never leaves this actor.
"""
from __future__ import annotations

import asyncio
import time
from dataclasses import dataclass, field
from typing import Annotated, Literal, Optional

import numpy as np

from sebvs.runtime import Actor, Message, Range
from sebvs.runtime.deadlines import DeadlineMonitor
# the physics and the episode loop's steps: sebvs.envs runs the same, in process
from sebvs.sim.stepper import NOISE_STREAM, SceneStepper, episode_seed  # noqa: F401


class Sim(Actor):
    inputs = ("action",)
    outputs = ("state", "proprio", "episode", "action")

    @classmethod
    def check_wiring(cls, params: "Sim.Params", connected: frozenset) -> str | None:
        """What the topology loader refuses before a process starts: an mjcf scene whose
        config cannot be built (sebvs/sim/mjcf_scene.py: no such file, an MJCF that does
        not compile, a camera the model does not have). Nav and arm are built at setup,
        as before.

        Parameters:
            params: the sim's parameters as the topology sets them.
            connected: the names of its wired inputs.

        Returns:
            One line naming what is wrong, or None.
        """
        if params.scene != "mjcf":
            return None
        from sebvs.sim import make_scene
        try:
            make_scene("mjcf", **params.config)
        except (ValueError, TypeError) as exc:
            return f"key 'config': {exc}"
        return None

    @dataclass
    class Params:
        scene: Literal["nav", "arm", "mjcf"] = "nav"
        # scene config: variant, conditions...; mjcf: path, camera, ... (mjcf_scene.py)
        config: dict = field(default_factory=dict)
        # per-episode draws over config keys (sebvs/sim/randomise.py): {} = every episode
        # plays `config` as given
        randomise: dict = field(default_factory=dict)
        # docs/numerics.md: discrete at 1 kHz (the most robust in stiff contacts, and
        # 1 kHz lets render_hz be 200 with 20 Hz control)
        integrator: Literal["euler", "implicitfast", "implicit", "rk4", "discrete"] = \
            "discrete"
        physics_hz: Annotated[float, Range(gt=0)] = 1000.0
        # s; overrides physics_hz when set
        timestep: Optional[Annotated[float, Range(gt=0, le=1)]] = None
        control_hz: Annotated[float, Range(gt=0)] = 20.0
        # state rate: max of the camera's rgb_hz, dvs_hz
        render_hz: Annotated[float, Range(gt=0)] = 200.0
        episode_s: Annotated[float, Range(gt=0)] = 20.0
        episodes: Annotated[int, Range(ge=0)] = 1          # 0: until stopped
        # index of the run's first episode played here: a worker of a fan-out
        # (sebvs/scale) plays episodes [first_episode, first_episode + episodes) of the
        # run, each seeded episode_seed(seed, k) and numbered k as in one process
        first_episode: Annotated[int, Range(ge=0)] = 0
        # realtime clock: sim seconds per wall second (bounded: the pace is waited in ns)
        realtime_factor: Annotated[float, Range(ge=1e-3, le=1000)] = 1.0
        # lockstep without action: 0 = unpaced
        max_speed_factor: Annotated[float, Range(ge=0, le=1000)] = 0.0
        # lockstep: give up waiting, keep last command
        action_timeout_s: Annotated[float, Range(gt=0)] = 10.0
        check_every: Annotated[int, Range(ge=1)] = 1        # stability check period, steps
        # std of the Gaussian noise added to every applied command, one per command
        # dimension (nav: [v, w]); [] = none. For recording only (module docstring)
        command_noise: list[Annotated[float, Range(ge=0, le=10)]] = field(default_factory=list)
        # after the last episode, before ending the run: consumers drain what is queued
        linger_s: Annotated[float, Range(ge=0, le=3600)] = 0.5

    # ------------------------------------------------------------------ setup
    async def setup(self) -> None:
        p = self.params
        if not p.realtime_factor > 0:
            raise ValueError(f"sim: realtime_factor must be positive, got {p.realtime_factor!r}")
        self.core = SceneStepper(p.scene, p.config, randomise=p.randomise,
                                 integrator=p.integrator, physics_hz=p.physics_hz,
                                 timestep=p.timestep, control_hz=p.control_hz,
                                 render_hz=p.render_hz, episode_s=p.episode_s,
                                 check_every=p.check_every, command_noise=p.command_noise)
        if self.core.randomiser:
            self.log.info("sim: each episode draws %s", self.core.randomiser.describe())
        self.lockstep_wait = self.clock == "lockstep" and "action" in self.connected
        self.deadlines = DeadlineMonitor(round(1e9 / (p.control_hz * p.realtime_factor))) \
            if self.clock == "realtime" and "action" in self.connected else None
        self.pending: tuple[int, np.ndarray] | None = None  # lockstep: newest valid action
        self.action_tick = -1
        self.action_event = asyncio.Event()
        self.tick = -1
        self.t_offset = 0.0                 # t_sim at the current episode's start
        self.counts = {"steps": 0, "episodes": 0, "rejected": 0, "action_timeouts": 0,
                       "stale_actions": 0, "diverged": 0, "noised": 0}
        # this episode's: the ticks of the commands checked and of those rejected, and
        # the run's counters at its start (episode end meta "health")
        self.ep_first_tick = 0
        self.ep_checked: list[int] = []
        self.ep_rejected: list[int] = []
        self.ep_start: dict[str, int] = {"action_timeouts": 0, "deadline_misses": 0}
        self.log.info("sim: scene %s %s, integrator %s, dt %g s, %d steps/control, "
                      "%d steps/state, lockstep wait %s", p.scene, p.config, p.integrator,
                      self.dt, self.steps_per_control, self.steps_per_render,
                      self.lockstep_wait)

    # the core's state, by the names the actor always had
    scene = property(lambda self: self.core.scene)
    model = property(lambda self: self.core.model)
    data = property(lambda self: self.core.data)
    config = property(lambda self: self.core.config)
    randomiser = property(lambda self: self.core.randomiser)
    dt = property(lambda self: self.core.dt)
    steps_per_control = property(lambda self: self.core.steps_per_control)
    steps_per_render = property(lambda self: self.core.steps_per_render)
    command = property(lambda self: self.core.command)

    @property
    def noise_rng(self) -> np.random.Generator:
        return self.core.noise_rng

    @noise_rng.setter
    def noise_rng(self, rng: np.random.Generator) -> None:
        self.core.noise_rng = rng

    # ------------------------------------------------------------------ actions
    async def on_action(self, msg: Message) -> None:
        cmd = msg.arrays.get(self.scene.command_name)
        tick = msg.tick if msg.tick is not None else self.tick
        if self.deadlines is not None:
            self.deadlines.action(tick, time.monotonic_ns())
        if self.lockstep_wait and tick < self.tick:
            self.counts["stale_actions"] += 1       # answer to a tick already stepped past
            return
        self.ep_checked.append(tick)
        if not self.core.check_command(cmd):
            self._reject(cmd, tick, "missing, wrong shape or not finite")
        elif self.lockstep_wait:
            self.pending = (tick, np.array(cmd, dtype=np.float64))
        else:
            self._apply(np.array(cmd, dtype=np.float64), tick)
        if tick > self.action_tick:
            self.action_tick = tick                 # a rejected command still answers the tick
            self.action_event.set()

    def _reject(self, cmd, tick: int, why: str) -> None:
        self.counts["rejected"] += 1
        self.ep_rejected.append(tick)
        shown = None if cmd is None else np.asarray(cmd).tolist()
        self.log.error("command rejected at tick %d (%s): %r; keeping %s", tick, why, shown,
                       self.command.tolist())
        self.telemetry("command_rejected", tick=tick, reason=why, command=repr(shown))

    async def control(self, key: str, value) -> dict:
        """`sebvs ctl RUN sim set command_noise=[0.1,0.05]` applies from the next command;
        a list of the wrong length is refused and the running one stays."""
        old = getattr(self.params, key, None)
        result = await super().control(key, value)     # type and Range checked there
        if key == "command_noise":
            try:
                self.core.check_noise(self.params.command_noise)
            except ValueError:
                self.params.command_noise = old
                raise
            self.core.command_noise = list(self.params.command_noise)
        return result

    def _apply(self, cmd: np.ndarray, tick: int) -> None:
        why = self.core.apply(cmd)
        self.counts["noised"] = self.core.noised
        if why is not None:
            self._reject(cmd, tick, why)

    async def _await_action(self, tick: int) -> None:
        """Lockstep: block until the action for `tick` (or a later one) has arrived."""
        if not self.lockstep_wait:
            return
        deadline = time.monotonic() + self.params.action_timeout_s
        while self.action_tick < tick and not self.stopping.is_set():
            left = deadline - time.monotonic()
            if left <= 0:
                self.counts["action_timeouts"] += 1
                self.log.warning("no action for tick %d within %.1f s; keeping %s", tick,
                                 self.params.action_timeout_s, self.command.tolist())
                self.telemetry("action_timeout", tick=tick)
                return
            self.action_event.clear()
            try:    # short waits, so a stop is seen promptly
                await asyncio.wait_for(self.action_event.wait(), min(left, 0.2))
            except asyncio.TimeoutError:
                pass
        if self.pending is not None and self.pending[0] >= tick:
            self._apply(self.pending[1], self.pending[0])
        self.pending = None

    # ------------------------------------------------------------------ loop
    async def run(self) -> None:
        p = self.params
        k = 0
        while not self.stopping.is_set() and (p.episodes <= 0 or k < p.episodes):
            await self._episode(p.first_episode + k)
            k += 1
        if not self.stopping.is_set():
            # The run ends when this source finishes; queued frames downstream would be lost.
            await self.sleep_until(time.monotonic_ns() + int(self.params.linger_s * 1e9))
            self.request_stop(f"{k} episode(s) done")

    def _pace_factor(self) -> float:
        if self.clock == "realtime":
            return self.params.realtime_factor
        if not self.lockstep_wait and self.params.max_speed_factor > 0:
            return self.params.max_speed_factor
        return 0.0

    async def _episode(self, k: int) -> None:
        p, core = self.params, self.core
        info = core.start_episode(self.seed, k)
        seed = info["seed"]
        self.pending = None
        self._open_health()
        await self.emit("episode", meta={"event": "start", "reason": "", **info},
                        t_sim=self.t_offset, tick=self.tick + 1)
        pace = self._pace_factor()
        wall0 = time.monotonic_ns()
        reason = "time_limit"
        while True:
            if core.render_due:
                control = core.control_due
                if control:
                    self.tick += 1
                data = core.data
                await self.emit("state", core.scene.state(data), meta=core.sample_meta(k),
                                t_sim=self.t_offset + data.time, tick=self.tick)
                if control and "proprio" in self.consumed:
                    await self._emit_proprio(k)
                if control and self.script is not None:
                    await self._scripted(k)
                if control and self.deadlines is not None and not core.at_end:
                    self._tick_published()
                if control and not core.at_end:
                    await self._await_action(self.tick)
                if pace > 0:
                    if not await self.sleep_until(wall0 + int(data.time / pace * 1e9)):
                        reason = "stopped"
                        break
                elif not self.lockstep_wait:
                    await asyncio.sleep(0)      # let control and stop through
            if self.stopping.is_set():
                reason = "stopped"
                break
            why = core.advance()
            if why:
                reason = why
                if core.diverged:
                    self.counts["diverged"] += 1
                    self.log.warning("episode %d: %s", k, why)
                break
        step = core.step
        self.counts["steps"] += step
        self.counts["episodes"] += 1
        if self.deadlines is not None:
            self.deadlines.close_episode()
            summary = self.deadlines.summary()
            self.telemetry("deadlines", episode=k, **summary)
            self.log.info("episode %d: %d of %d control ticks missed their deadline (%.0f ms)"
                          "%s", k, summary["misses"], summary["ticks"], summary["period_ms"],
                          f"; action latency p50 {summary['latency_p50_ms']:.1f} ms, p99 "
                          f"{summary['latency_p99_ms']:.1f} ms"
                          if "latency_p50_ms" in summary else "")
        t_ep = core.t_ep()
        # after t_ep is taken: what finish() simulates (a grasp) is not episode time
        outcome = core.finish(reason)
        await self.emit("episode", meta={"event": "end", "reason": reason, "steps": step,
                                         "t_ep": t_ep, "outcome": outcome,
                                         "health": self._episode_health(), **info},
                        t_sim=self.t_offset + t_ep, tick=self.tick)
        self.telemetry("episode_end", episode=k, seed=seed, reason=reason, steps=step,
                       outcome=outcome.get("outcome", ""))
        self.log.info("episode %d (seed %d) ended: %s after %d steps%s", k, seed, reason, step,
                      f"; {outcome['outcome']}" if "outcome" in outcome else "")
        self.t_offset += t_ep

    async def _scripted(self, k: int) -> None:
        """The scene's scripted command of this tick: applied where no actor commands the
        sim, and sent on `action` (the tick's recorded command)."""
        core = self.core
        cmd = np.asarray(self.script(core.model, core.data), dtype=np.float64)
        if "action" not in self.connected and not core.at_end:
            self._apply(cmd, self.tick)
        await self.emit("action", {core.scene.command_name: cmd},
                        meta={"episode": k, "source": "scripted"},
                        t_sim=self.t_offset + core.data.time, tick=self.tick)

    @property
    def script(self):
        """The scene's scripted_command(model, data), or None for a scene without one."""
        return getattr(self.core.scene, "scripted_command", None)

    async def _emit_proprio(self, k: int) -> None:
        """The control sample's proprioception, stamped as its state sample."""
        core = self.core
        if getattr(self, "_proprio_model", None) is not core.model:   # a scene rebuilt
            from sebvs.sim.proprio import proprio_reader
            self._proprio = proprio_reader(core.scene_name, core.scene, core.model)
            self._proprio_model = core.model
        reader = self._proprio
        # float32, as the environments' observation gives it: a row of a recording and the
        # env's observation of that tick are the same numbers
        await self.emit("proprio", {"proprio": reader.read(core.data).astype(np.float32)},
                        meta={"names": list(reader.names), "episode": k, "control": True},
                        t_sim=self.t_offset + core.data.time, tick=self.tick)

    def _open_health(self) -> None:
        self.ep_first_tick = self.tick + 1
        self.ep_checked, self.ep_rejected = [], []
        self.ep_start = {"action_timeouts": self.counts["action_timeouts"],
                         "deadline_misses": self._misses()}

    def _misses(self) -> int:
        return self.deadlines.misses if self.deadlines is not None else 0

    def _episode_health(self) -> dict:
        """The episode's counters, over the commands for its ticks but the last (by tick,
        not arrival: the same counts however late the chain answers)."""
        first, last = self.ep_first_tick, self.tick
        within = lambda ticks: sum(first <= t < last for t in ticks)   # noqa: E731
        return {"commands": within(self.ep_checked), "rejected": within(self.ep_rejected),
                "action_timeouts": self.counts["action_timeouts"]
                - self.ep_start["action_timeouts"],
                "deadline_misses": self._misses() - self.ep_start["deadline_misses"]}

    def _tick_published(self) -> None:
        missed = self.deadlines.published(self.tick, time.monotonic_ns())
        if missed:
            n = self.deadlines.misses
            if n <= 10 or n % 100 == 0:   # the count is in stats; the log stays readable
                self.log.warning("control tick %d: the action for the previous tick missed "
                                 "its deadline (%d missed so far)", self.tick, n)
            self.telemetry("deadline_miss", tick=self.tick - 1, misses=n)

    def stats(self) -> dict:
        out = {**self.counts, "tick": self.tick, "command": self.command.tolist()}
        if self.deadlines is not None:
            out["deadlines"] = self.deadlines.summary()
        return out
