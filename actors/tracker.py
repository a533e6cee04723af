"""Closed-loop metrics sinks, from the sim's privileged truth: the paper's Table 4 (nav)
and Table 5 (arm).

Inputs  rgb      from the camera: only meta is read (truth, episode, t_ep, control) of
                 the samples taken at control ticks
        action   from the policy or expert: meta modality (absent for the expert) and
                 inference_ms; the arm tracker also reads arrays["pose"]
        episode  from the sim: start / end with seed, config, reason and outcome
Each finished episode is appended as one JSON line to `path` (so an interrupted evaluation
keeps what it finished). Its "health" is the sim's counters from the end meta (commands,
rejected, action_timeouts, deadline_misses) with the tracker's own over the same ticks
(every tick but the last): actions (ticks with an action) and nonfinite_actions (ticks
whose action held NaN or inf), so a policy that never acted is not read as a result.

NavTracker   metrics over the whole episode and per modality segment (a live modality
             swap splits an episode), the centroid-error trace.
ArmTracker   every tick's predicted pose against the task's pose from truth (the expert's
             rule on the true cube poses, led by `lead_s`), the decision at the end and
             the grasp outcome.
"""
from __future__ import annotations

import asyncio
import json
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated

import numpy as np

from sebvs.metrics import (arm_episode_summary, centre_error_px, episode_duration,
                           nav_truth_metrics)
from sebvs.experts.arm import leading_poses
from sebvs.runtime import Actor, Message, Range

FINALIZE_AFTER_S = 1.0   # frames of an episode may trail its end message (they pass the camera)
SIM_HEALTH = ("commands", "rejected", "action_timeouts", "deadline_misses")   # sim end meta


class EpisodeTracker(Actor):
    """Per-tick rows joined into one JSON line per finished episode; subclasses say what
    the line holds (`summarise`)."""
    inputs = ("rgb", "action", "episode")

    @dataclass
    class Params:
        path: str = ""                        # JSON lines, one per finished episode
        label: dict = field(default_factory=dict)   # copied into every line (condition...)
        # for the trial duration of an episode (a divisor: 1 mHz at the least)
        control_hz: Annotated[float, Range(ge=1e-3)] = 20.0

    async def setup(self) -> None:
        self.frames: dict[int, list] = defaultdict(list)   # episode -> [(tick, truth, t_ep)]
        self.modality_at: dict[int, str] = {}              # tick -> modality that acted
        self.inference_ms: dict[int, float] = {}           # tick -> policy latency
        self.actions: dict[int, np.ndarray] = {}           # tick -> command (when kept)
        self.nonfinite: set[int] = set()                   # ticks of a NaN / inf action
        self.episodes: dict[int, dict] = {}                # episode -> start/end meta
        self.finished: list[dict] = []
        self._timers: dict[int, asyncio.TimerHandle] = {}
        self.last_action_tick: int | None = None

    def keep_action(self, msg: Message) -> np.ndarray | None:
        """The command array to keep per tick (None: only modality and latency)."""
        return None

    def summarise(self, rows: list, segments: dict, info: dict) -> dict:
        """rows [(tick, truth, t_ep)] in tick order -> the episode's record fields."""
        raise NotImplementedError

    async def on_rgb(self, msg: Message) -> None:
        m = msg.meta
        if not m.get("control", True) or not m.get("truth"):
            return
        ep = m.get("episode")
        self.frames[ep].append((msg.tick, m["truth"], float(m.get("t_ep", 0.0))))
        self._finalize_complete()

    def _finalize_complete(self) -> None:
        """Write every ended episode that a later one's frames follow and whose last tick's
        action is in. The action of an episode's last tick comes through the policy, so
        it can arrive after the camera's first frame of the next episode; ticks count up
        over the run and one source's actions arrive in order, so an action of a later
        tick means this episode's are all here. Without an action input only the frames
        count. An action that never comes (a skipped tick) waits for the timer."""
        latest = max((e for e, rows in self.frames.items() if isinstance(e, int) and rows),
                     default=None)
        for ep, info in list(self.episodes.items()):
            if not isinstance(ep, int) or not info.get("ended") or info.get("written") or \
                    latest is None or ep >= latest:
                continue
            rows = self.frames.get(ep)
            last_tick = max(r[0] for r in rows) if rows else None
            if "action" in self.connected and last_tick is not None and (
                    self.last_action_tick is None or self.last_action_tick < last_tick):
                continue
            self._finalize(ep)

    async def on_action(self, msg: Message) -> None:
        if msg.tick is not None and (self.last_action_tick is None or
                                     msg.tick > self.last_action_tick):
            self.last_action_tick = msg.tick
        self.modality_at[msg.tick] = msg.meta.get("modality", "expert")
        if "inference_ms" in msg.meta:
            self.inference_ms[msg.tick] = float(msg.meta["inference_ms"])
        if not _finite(msg.arrays):
            self.nonfinite.add(msg.tick)
        kept = self.keep_action(msg)
        if kept is not None:
            self.actions[msg.tick] = kept
        self._finalize_complete()

    async def on_episode(self, msg: Message) -> None:
        m = msg.meta
        ep = m.get("episode")
        info = self.episodes.setdefault(ep, {})
        if m.get("event") == "start":
            info.update(seed=m.get("seed"), start_tick=msg.tick, config=m.get("config", {}))
        elif m.get("event") == "end":
            info.update(ended=True, reason=m.get("reason", ""), outcome=m.get("outcome", {}),
                        health=m.get("health") or {})
            loop = asyncio.get_running_loop()
            self._timers[ep] = loop.call_later(FINALIZE_AFTER_S, self._finalize, ep)

    def _duration(self, rows: list) -> float:
        # the sim publishes a control sample at both ends of an episode
        return episode_duration([t_ep for _, _, t_ep in rows], self.params.control_hz)

    def _finalize(self, ep: int) -> None:
        info = self.episodes.get(ep)
        if info is None or info.get("written"):
            return
        info["written"] = True
        timer = self._timers.pop(ep, None)
        if timer is not None:
            timer.cancel()
        rows = sorted(self.frames.pop(ep, []), key=lambda r: r[0])
        if not rows:
            self.log.warning("episode %s ended with no control frames", ep)
            return
        segments = defaultdict(list)
        last = None
        for row in rows:
            last = self.modality_at.get(row[0], last)
            segments[last or "none"].append(row)
        record = {**self.params.label, "episode": ep, "seed": info.get("seed"),
                  "reason": info.get("reason", ""), "ticks": len(rows),
                  **self.summarise(rows, segments, info),
                  "inference_ms": [self.inference_ms.pop(k) for k, _, _ in rows
                                   if k in self.inference_ms],
                  "health": self._health(rows, info)}
        for k, _, _ in rows:
            self.modality_at.pop(k, None)
            self.actions.pop(k, None)
            self.nonfinite.discard(k)
        health = record["health"]
        if health["nonfinite_actions"]:
            self.log.warning("episode %s: %d of %d actions not finite", ep,
                             health["nonfinite_actions"], health["actions"])
        self.finished.append(record)
        self.telemetry("episode_metrics", episode=ep, ticks=record["ticks"])
        if self.params.path:
            path = Path(self.params.path)
            path.parent.mkdir(parents=True, exist_ok=True)
            with open(path, "a") as f:
                f.write(json.dumps(record) + "\n")

    def _health(self, rows: list, info: dict) -> dict:
        """The sim's counters and the actions seen, over the ticks but the last (the
        sim's window: the last tick's action drives no step and may come after the run)."""
        ticks = [k for k, _, _ in rows[:-1]]
        sim = info.get("health") or {}
        return {**{k: int(sim.get(k) or 0) for k in SIM_HEALTH},
                "actions": sum(k in self.modality_at for k in ticks),
                "nonfinite_actions": sum(k in self.nonfinite for k in ticks)}

    async def teardown(self) -> None:
        for ep in sorted(self.episodes):
            if self.episodes[ep].get("ended"):
                self._finalize(ep)

    def stats(self) -> dict:
        return {"episodes_finished": len(self.finished),
                "last": self.finished[-1] if self.finished else None}


class NavTracker(EpisodeTracker):
    """Table 4: centroid error, bbox width, success within the scaled 200 px radius."""

    def _metrics(self, rows: list) -> dict:
        return nav_truth_metrics([t for _, t, _ in rows], self._duration(rows))

    def summarise(self, rows: list, segments: dict, info: dict) -> dict:
        return {"metrics": self._metrics(rows),
                "by_modality": {mod: self._metrics(r) for mod, r in segments.items()},
                "trace_error_px": [_rounded(centre_error_px(t)) for _, t, _ in rows]}


class ArmTracker(EpisodeTracker):
    """Table 5: each tick's predicted pose against the pose the task asks for (truth's
    expert_pose: the expert's rule on the true cube poses, led by ``lead_s`` as the
    expert that made the labels leads a moving cube), plus the end decision and the grasp
    of the last pose that the sim's finish() ran."""

    @dataclass
    class Params(EpisodeTracker.Params):
        # the expert's lead_s when the policy's labels were recorded (topologies/
        # arm_record.toml): a policy that learned to aim 0.1 s ahead of a moving cube is
        # scored against that aim, not against where the cube is at the tick
        lead_s: Annotated[float, Range(ge=0, le=10)] = 0.0

    def keep_action(self, msg: Message) -> np.ndarray | None:
        pose = msg.arrays.get("pose")
        return None if pose is None else np.asarray(pose, np.float64).reshape(6)

    def summarise(self, rows: list, segments: dict, info: dict) -> dict:
        actions = [self.actions.get(k) for k, _, _ in rows]
        outcome = (info.get("outcome") or {}).get("outcome")
        objects = int((info.get("config") or {}).get("objects", 1))
        reference = leading_poses([t["expert_pose"] for _, t, _ in rows],
                                  [t["mode"] for _, t, _ in rows],
                                  [t_ep for _, _, t_ep in rows], self.params.lead_s)
        summary = arm_episode_summary([t for _, t, _ in rows], reference, actions, outcome,
                                      objects, self.params.lead_s, self._duration(rows))
        missing = sum(a is None for a in actions)
        if missing:
            self.log.warning("episode %s: %d of %d ticks had no pose", info.get("seed"),
                             missing, len(rows))
        return summary


def _finite(arrays: dict) -> bool:
    """Every numeric array of an action holds finite values only."""
    for a in arrays.values():
        a = np.asarray(a)
        if np.issubdtype(a.dtype, np.inexact) and not np.isfinite(a).all():
            return False
    return True


def _rounded(x: float | None) -> float | None:
    return None if x is None else round(x, 2)
