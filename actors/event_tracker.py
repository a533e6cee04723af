"""The event-tracker actor: a non-learned event-only nav driver, in a policy's place.

Input   events   from the accumulator: arrays["frame"] uint8 [2K, H, W] (counts or time
                 bins), tick, t_sim; meta episode and t_ep where the chain carries them
                 (samples with meta control=False are ignored)
        episode  (optional) from the sim: an episode's start resets the driver even when
                 the frames' meta names no episode
Output  action   arrays {"action": float32 [2]} ([v, w] in [-1, 1]), tick = the input tick
                 (parent=msg), meta {"modality": "event_tracker", "mode", "detection",
                 "episode"}

In lockstep the sim waits for the action of every control tick, so every event frame is
answered ([0, 0] while the driver looks). The library code is sebvs.experts.event_tracker
(the event-cluster tracker) and sebvs.experts.event_agent (the look-and-move driver); this
module only wires them. The parameters are the two configs' fields, defaults the same
(tests/test_event_tracker.py checks that they stay so).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Annotated

from sebvs.runtime import Actor, Message, Range

MODALITY = "event_tracker"
Fraction = Annotated[float, Range(gt=0, le=1)]
NonNegative = Annotated[float, Range(ge=0)]
Seconds = Annotated[float, Range(ge=0, le=60)]


class EventTrackerDriver(Actor):
    inputs = ("events", "episode")
    outputs = ("action",)

    @dataclass
    class Params:
        # the tracker (sebvs.experts.event_tracker.EventTrackerConfig; sizes as fractions
        # of the event frame's width)
        burst_active: Fraction = 0.3
        window: Fraction = 0.05
        surround: Annotated[float, Range(gt=1, le=20)] = 3.0
        gate: Fraction = 0.15
        gate_growth: Annotated[float, Range(ge=0, le=10)] = 0.1
        min_events: NonNegative = 12.0
        min_z: NonNegative = 4.0
        acquire_z: NonNegative = 6.0
        shift_iterations: Annotated[int, Range(ge=0, le=20)] = 3
        alpha: Fraction = 0.7
        beta: Annotated[float, Range(ge=0, le=2)] = 0.2
        max_speed: Annotated[float, Range(gt=0, le=100)] = 1.0
        coast_s: Seconds = 1.5
        width_smoothing: Fraction = 0.5
        min_width: Fraction = 0.03
        max_width: Fraction = 0.4
        # the driver (sebvs.experts.event_agent.EventAgentConfig)
        fovy_deg: Annotated[float, Range(ge=1, lt=180)] = 70.0
        w_max: Annotated[float, Range(gt=0, le=100)] = 2.0
        move_s: Annotated[float, Range(gt=0, le=10)] = 0.2
        lead_s: Seconds = 0.3
        settle_s: Seconds = 0.2
        settle_max_s: Seconds = 0.5
        quiet: Annotated[float, Range(gt=0, le=100)] = 1.3
        patience_s: Seconds = 1.5
        search_angle: Annotated[float, Range(ge=0, le=6.3)] = 0.6
        search_w: Fraction = 1.0
        desired_width: Fraction = 0.12
        speed_gain: Annotated[float, Range(ge=0, le=100)] = 4.0
        v_limit: Annotated[float, Range(ge=0, le=1)] = 0.3
        turn_slowdown: Annotated[float, Range(ge=0, le=10)] = 0.8
        # dt of an episode's first tick (then from the frames' times)
        control_hz: Annotated[float, Range(ge=1e-3, le=100_000)] = 10.0

    async def setup(self) -> None:
        from dataclasses import fields
        from sebvs.experts.event_agent import EventAgentConfig, EventTrackerAgent
        from sebvs.experts.event_tracker import EventTrackerConfig
        p = self.params
        tracker = EventTrackerConfig(**{f.name: getattr(p, f.name)
                                        for f in fields(EventTrackerConfig)})
        driver = EventAgentConfig(**{f.name: getattr(p, f.name)
                                     for f in fields(EventAgentConfig)})
        self.agent = EventTrackerAgent(tracker, driver)
        self.episode = None          # from the sim's episode messages, where wired
        self.frame_episode = None    # the episode the last frame belonged to
        self.last_t: float | None = None
        self.counts = {"actions": 0, "held": 0, "not_held": 0}

    async def on_episode(self, msg: Message) -> None:
        if msg.meta.get("event") == "start":
            self.episode = msg.meta.get("episode")

    def _dt(self, episode, t) -> float:
        """s since the previous tick of the same episode (its first: one control period)."""
        if episode != self.frame_episode or self.last_t is None or t is None:
            dt = 1.0 / self.params.control_hz
        else:
            dt = t - self.last_t
            if not dt > 0:
                dt = 1.0 / self.params.control_hz
        self.frame_episode, self.last_t = episode, t
        return dt

    async def on_events(self, msg: Message) -> None:
        if msg.tick is None:
            raise ValueError(f"events message from {msg.source} has no tick")
        if msg.meta.get("control") is False:
            return
        episode = msg.meta.get("episode", self.episode)
        t = msg.meta.get("t_ep")
        if isinstance(t, bool) or not isinstance(t, (int, float)) or not math.isfinite(t):
            t = msg.t_sim
        dt = self._dt(episode, t)
        cmd, det, mode = self.agent.act(msg.arrays["frame"], dt, episode)
        self.counts["actions"] += 1
        self.counts["held" if det is not None else "not_held"] += 1
        await self.emit("action", {"action": cmd}, parent=msg, t_sim=msg.t_sim, tick=msg.tick,
                        meta={"modality": MODALITY, "mode": mode, "episode": episode,
                              "detection": det.as_dict() if det is not None else None})

    def stats(self) -> dict:
        return {**self.counts,
                **{f"tracker_{k}": v for k, v in self.agent.tracker.counts.items()},
                **{f"driver_{k}": v for k, v in self.agent.counts.items()}}
