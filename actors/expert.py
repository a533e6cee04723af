"""The expert actor: detector + nav PID follower, or detector + arm pre-grasp pose.

Inputs  rgb    from the camera: arrays["rgb"] uint8 [H, W, 3], tick, t_sim, meta episode,
               t_ep (episode time: dt between ticks), control (samples with control=False,
               between control ticks, are ignored)
        depth  (arm) from the camera: arrays["depth"] float32 [H, W] m, same ticks as rgb
        state  (arm) from the sim: the wrist camera's pose is computed from qpos with the
               expert's own copy of the model (compiled from the first sample's scene +
               config, as the camera does)
Output  action nav: arrays {"action": float32 [2]} ([v, w] in [-1, 1])
               arm: arrays {"pose": float32 [6]} ([x, y, z m, roll, pitch, yaw rad])
        tick and t_sim of the input frame (parent=msg), meta {"detection": dict | None,
        "expert": True, "mode": ..., "episode": ...}.

In lockstep the sim waits for the action of every control tick, so the expert answers
every tick: with the search command (nav) or the HOME pose (arm) when nothing is detected.
The library code is sebvs.experts (detector, pid, nav, arm); this module only wires it.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Annotated, Literal

import numpy as np

from sebvs.runtime import Actor, Message, Range

Byte = Annotated[int, Range(ge=0, le=255)]


@dataclass
class _Pending:
    rgb: np.ndarray | None = None
    depth: np.ndarray | None = None
    msg: Message | None = None


class Expert(Actor):
    inputs = ("rgb", "depth", "state")
    outputs = ("action",)

    @dataclass
    class Params:
        task: Literal["nav", "arm"] = "nav"
        # detector (sebvs.experts.detector.ColorDetector)
        color: list[Annotated[float, Range(ge=0, le=1)]] = \
            field(default_factory=lambda: [0.9, 0.15, 0.1])     # rgb, [0, 1]
        hue_tol: Annotated[float, Range(ge=0, le=360)] = 15.0   # deg (360: any hue)
        s_min: Byte = 90               # saturation, 0..255
        c_min: Byte = 5                # chroma, DN
        min_area: Annotated[int, Range(ge=0)] = 3              # px
        # nav PIDs (sebvs.experts.nav.NavExpertConfig), normalised image units
        yaw_kp: float = 1.6
        yaw_ki: float = 0.3
        yaw_kd: float = 0.12
        speed_kp: float = 8.0
        speed_ki: float = 0.5
        speed_kd: float = 0.0
        anti_windup: Literal["clamp", "backcalc", "none"] = "clamp"
        # bbox width / image width at the following distance
        desired_width: Annotated[float, Range(gt=0, le=1)] = 0.12
        turn_slowdown: float = 0.8
        hold_s: Annotated[float, Range(ge=0)] = 0.3   # s without a detection before searching
        search_w: Annotated[float, Range(ge=-1, le=1)] = 0.6   # search yaw rate, [-1, 1] units
        # dt of the first tick of an episode (then from t_sim)
        control_hz: Annotated[float, Range(ge=1e-3, le=100_000)] = 20.0
        # arm (sebvs.experts.arm.ArmExpertConfig)
        clearance: Annotated[float, Range(ge=0)] = 0.10   # m above the object's top face
        lead_s: Annotated[float, Range(ge=0, le=10)] = 0.0
                                       # s: aim where a moving cube will be this much later
                                       # (the grasp comes one control period after the last
                                       # tick); 0: where it is (sebvs.experts.arm.TargetLead)
        camera: str = ""               # wrist camera name ("" = the scene's first)
        threads: Annotated[int, Range(ge=1, le=256)] = 1
                                       # OpenCV threads: actors share the cores, and a second
                                       # thread waiting on a busy core costs more than it saves

    async def setup(self) -> None:
        import cv2
        from sebvs.experts.agent import ExpertAgent
        p = self.params
        cv2.setNumThreads(max(1, p.threads))
        self.agent = ExpertAgent(p)       # the per-tick logic (sebvs.experts.agent)
        self.counts = {"actions": 0, "detected": 0, "missed": 0, "skipped_ticks": 0}
        self.last_tick: int | None = None
        if p.task == "arm":
            missing = {"rgb", "depth", "state"} - set(self.connected)
            if missing:
                raise ValueError(f"expert: task arm needs inputs {sorted(missing)} wired")
            self.pending: dict[int, _Pending] = {}
            self.states: dict[int, tuple] = {}   # tick -> (ArmCameraModel, state)
        self.log.info("expert: task %s, colour %s", p.task, p.color)

    # the agent's parts, by the names the actor always had
    detector = property(lambda self: self.agent.detector)
    nav = property(lambda self: self.agent.nav)
    lead = property(lambda self: self.agent.lead)
    arm = property(lambda self: self.agent.arm)
    last_t = property(lambda self: self.agent.last_t)

    async def control(self, key: str, value) -> dict:
        """`sebvs ctl RUN expert set yaw_kp=2.0` etc.: gains, detector and search settings
        apply from the next tick (PID state kept); task and camera are fixed at setup."""
        if key in ("task", "camera", "threads"):
            raise ValueError(f"{key!r} cannot change while running")
        old = getattr(self.params, key, None)
        result = await super().control(key, value)
        try:
            self.agent.reconfigure()
        except ValueError:
            setattr(self.params, key, old)      # refused: the running settings stay
            raise
        return result

    # ------------------------------------------------------------------ common
    def _new_tick(self, msg: Message) -> float:
        """Episode bookkeeping; returns dt (s) since the previous control tick."""
        dt = self.agent.new_tick(msg.meta.get("episode"), msg.meta.get("t_ep"), msg.t_sim)
        if self.last_tick is not None and msg.tick is not None and msg.tick > self.last_tick + 1:
            self.counts["skipped_ticks"] += msg.tick - self.last_tick - 1
        self.last_tick = msg.tick
        return dt

    async def _answer(self, msg: Message, name: str, value: np.ndarray, det, mode: str) -> None:
        self.counts["actions"] += 1
        self.counts["detected" if det is not None else "missed"] += 1
        await self.emit("action", {name: value}, parent=msg,
                        meta={"detection": det.as_dict() if det is not None else None,
                              "expert": True, "mode": mode, "episode": msg.meta.get("episode")})

    # ------------------------------------------------------------------ nav
    async def on_rgb(self, msg: Message) -> None:
        if msg.meta.get("control") is False:
            return      # a sample between control ticks (camera rgb_hz > control rate)
        if self.params.task == "nav":
            dt = self._new_tick(msg)
            cmd, det, mode = self.agent.nav_act(msg.arrays["rgb"], dt)
            await self._answer(msg, "action", cmd, det, mode)
        else:
            self._pending(msg).rgb = np.array(msg.arrays["rgb"])
            if self._pending(msg).msg is None:
                self._pending(msg).msg = msg
            await self._arm_ready()

    # ------------------------------------------------------------------ arm
    def _pending(self, msg: Message) -> _Pending:
        return self.pending.setdefault(msg.tick, _Pending())

    async def on_depth(self, msg: Message) -> None:
        if self.params.task != "arm" or msg.meta.get("control") is False:
            return
        self._pending(msg).depth = np.array(msg.arrays["depth"])
        await self._arm_ready()

    async def on_state(self, msg: Message) -> None:
        if self.params.task != "arm":
            return
        meta = msg.meta
        if "config" in meta:
            self.agent.arm_camera(meta["scene"], meta["config"])
        if not meta.get("control"):
            return
        # with the model of its own episode: the next episode's first state (another
        # scene, maybe another number of cubes) can come before this tick's images
        self.states[msg.tick] = (self.arm, {k: np.array(a) for k, a in msg.arrays.items()})
        await self._arm_ready()

    async def _arm_ready(self) -> None:
        """Answer every tick whose rgb, depth and state have all arrived, oldest first."""
        for tick in sorted(self.pending):
            pend = self.pending[tick]
            if pend.rgb is None or pend.depth is None or tick not in self.states or \
                    self.states[tick][0] is None:
                continue
            self._new_tick(pend.msg)
            arm, state = self.states.pop(tick)
            pose, det, mode = self.agent.arm_act(pend.rgb, pend.depth, arm, state)
            del self.pending[tick]
            await self._answer(pend.msg, "pose", pose, det, mode)
        # frames of ticks that can no longer complete (a lost state) must not pile up
        for old in [t for t in self.pending if self.last_tick is not None and
                    t < self.last_tick - 100]:
            del self.pending[old]
        for old in [t for t in self.states if self.last_tick is not None and
                    t < self.last_tick - 100]:
            del self.states[old]

    def stats(self) -> dict:
        return dict(self.counts)
