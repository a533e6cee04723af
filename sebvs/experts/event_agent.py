"""A non-learned event-only nav driver: look while still, then turn toward what was seen.

    agent = EventTrackerAgent(EventTrackerConfig(), EventAgentConfig())
    cmd, det, mode = agent.act(events, dt, episode)   # events [2K, H, W] -> [v, w] in [-1, 1]

An event camera reports change. A robot that turns or drives makes the whole scene change,
and the floor's edges then outshine a small target (measured in the nav scene indoors,
docs/probe.md: 3,500-7,200 counts outside the target's box against 85-160 inside it while
turning; 600-2,300 against 25-120 while the robot holds still, where only the target
moves). So this driver
alternates, as a saccade does:

  look    command [0, 0]; once the robot has settled (at least `settle_s` still, and the
          frame's share of active pixels back within `quiet` times the quietest still
          frame of the episode, or `settle_max_s` at most) every frame is measured by the
          event-cluster tracker (sebvs/experts/event_tracker.py). A measured target starts
          a move; `patience_s` of looks with none held starts a search.
  move    for `move_s` (the look's tick and the next): the turn that brings the target to
          the image centre (its bearing, `lead_s` ahead on the tracker's velocity, from the
          pinhole model of a camera with vertical field of view `fovy_deg`; the yaw command
          that turns that far in `move_s` at `w_max` rad/s per unit, clipped to [-1, 1]),
          and a forward command from the cluster's apparent width against `desired_width`
          (gain `speed_gain`, at most `v_limit`, scaled by 1 - turn_slowdown * |bearing| /
          half the field of view). The tracker only predicts meanwhile: the
          frames of a turn are blind. Its held position is moved by the image shift the
          commanded turn makes (an efference copy: the robot knows what it commanded),
          so the next look searches where the target will be.
  search  a turn of `search_angle` rad toward the side the target was last seen on (left
          first), at `search_w`, then a look.

A burst frame (the whole image fires: mains flicker) measures nothing; while looking the
robot holds still through it. The driver reads nothing but the event frames, its own
commands and two constants of the robot (field of view, yaw rate per unit command).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .detector import Detection
from .event_tracker import EventTracker, EventTrackerConfig


@dataclass
class EventAgentConfig:
    """The driver's settings (the nav scene's camera and robot as defaults)."""
    fovy_deg: float = 70.0        # the front camera's vertical field of view
    w_max: float = 2.0            # rad/s of a yaw command of 1
    move_s: float = 0.2           # one move's duration
    lead_s: float = 0.3           # aim at the target's position this far ahead
    settle_s: float = 0.2         # still at least this long before a frame is measured
    settle_max_s: float = 0.5     # ... and at most this long waiting for a quiet frame
    quiet: float = 1.3            # quiet: active share <= this x the episode's quietest
    patience_s: float = 1.5       # looking this long with no target held: search
    search_angle: float = 0.6     # rad per search turn
    search_w: float = 1.0         # its yaw command
    desired_width: float = 0.12   # apparent width / image width at the following distance
    speed_gain: float = 4.0       # forward command per unit of width error
    v_limit: float = 0.3          # forward command at most (backing up too)
    turn_slowdown: float = 0.8    # forward scale 1 - this x |bearing / half field of view|

    def __post_init__(self) -> None:
        if not 1 <= self.fovy_deg < 180:
            raise ValueError(f"event agent: fovy_deg must be in [1, 180), got "
                             f"{self.fovy_deg!r}")
        for name in ("w_max", "move_s", "search_w", "quiet"):
            if not getattr(self, name) > 0:
                raise ValueError(f"event agent: {name} must be > 0, got "
                                 f"{getattr(self, name)!r}")
        for name in ("lead_s", "settle_s", "settle_max_s", "patience_s", "search_angle",
                     "desired_width", "speed_gain", "v_limit", "turn_slowdown"):
            if getattr(self, name) < 0:
                raise ValueError(f"event agent: {name} must be >= 0, got "
                                 f"{getattr(self, name)!r}")
        if self.search_w > 1 or self.v_limit > 1:
            raise ValueError("event agent: search_w and v_limit must be <= 1 (commands "
                             "are in [-1, 1])")
        if self.settle_max_s < self.settle_s:
            raise ValueError("event agent: settle_max_s must not be below settle_s")


class EventTrackerAgent:
    """The look-and-move driver over one run's episodes (see the module docstring).

    `act` resets the tracker and the driver when `episode` differs from the last call's.
    `mode` reads "<phase>/<tracker mode>": look/track, look/acquire, move/coast,
    settle/coast, search/acquire, ...; `counts` tallies the phases."""

    def __init__(self, tracker: EventTrackerConfig | None = None,
                 config: EventAgentConfig | None = None) -> None:
        self.cfg = config or EventAgentConfig()
        self.tracker = EventTracker(tracker)
        self.episode = object()
        self.counts = {"look": 0, "settle": 0, "move": 0, "search": 0, "moves": 0,
                       "searches": 0}
        self.reset()

    def reset(self) -> None:
        self.tracker.reset()
        self.phase = "settle"             # the robot may start moving: settle first
        self.remaining_s = 0.0            # of the move
        self.still_s = 0.0                # commanded still since
        self.unseen_s = 0.0               # looking with nothing held since
        self.quietest: float | None = None
        self.cmd = np.zeros(2, np.float32)
        self.side = 1.0                   # +1: last seen left of centre (turn left)

    def act(self, events: np.ndarray, dt: float, episode=None
            ) -> tuple[np.ndarray, Detection | None, str]:
        """One control tick.

        Parameters:
            events: the tick's event frame, [2K, H, W] counts.
            dt: s since the previous tick.
            episode: any value naming the episode; a new one resets the driver.

        Returns:
            (command float32 [2] = [v, w] in [-1, 1], the tracker's Detection or None,
            mode).
        """
        if episode != self.episode:
            self.episode = episode
            self.reset()
        events = np.asarray(events)
        dt = float(dt) if dt and dt > 0 and math.isfinite(dt) else 0.0
        if self.phase in ("move", "search") and self.remaining_s > 1e-9:
            det = self.tracker.step(events, dt, measure=False)
            self.remaining_s -= dt
            return self._done(self.phase, self.cmd, det)
        if self.phase in ("move", "search"):
            self.phase, self.still_s = "settle", 0.0
            self.cmd = np.zeros(2, np.float32)
        self.still_s += dt
        if self.phase == "settle" and not self._settled(events):
            det = self.tracker.step(events, dt, measure=False)
            return self._done("settle", np.zeros(2, np.float32), det)
        self.phase = "look"
        det = self.tracker.step(events, dt)
        # a frame without a single event (an episode's first) says nothing of the noise
        if not self.tracker.burst and self.tracker.active > 0 and (
                self.quietest is None or self.tracker.active < self.quietest):
            self.quietest = self.tracker.active
        if self.tracker.mode == "track":
            self.unseen_s = 0.0
            cmd = self._move(det, events.shape[-1], events.shape[-2])
            self.remaining_s -= dt          # this tick's command is the move's first
            return self._done("look", cmd, det)
        if det is None:
            self.unseen_s += dt
        if self.unseen_s >= self.cfg.patience_s:
            cmd = self._search()
            self.remaining_s -= dt
            return self._done("search", cmd, det)
        return self._done("look", np.zeros(2, np.float32), det)

    def _settled(self, events: np.ndarray) -> bool:
        """Whether this frame, seen still, is quiet enough to measure."""
        c = self.cfg
        if self.still_s + 1e-9 < c.settle_s:
            return False
        if self.still_s + 1e-9 >= c.settle_max_s or self.quietest is None:
            return True
        counts = np.asarray(events).reshape(-1, *events.shape[-2:]).sum(axis=0)
        return np.count_nonzero(counts) / counts.size <= c.quiet * self.quietest

    def _focal(self, height: int) -> float:
        return 0.5 * height / math.tan(math.radians(self.cfg.fovy_deg) / 2)

    def _turn(self, angle: float, width: int, height: int) -> None:
        """Move the tracker's target by the image shift a turn of `angle` rad (left > 0)
        makes: a turn left moves the scene right in the image."""
        if self.tracker.pos is None:
            return
        f = self._focal(height)
        bearing = math.atan((self.tracker.pos[0] - width / 2) / f)
        after = max(-1.45, min(1.45, bearing + angle))
        self.tracker.shift(width / 2 + f * math.tan(after) - self.tracker.pos[0])

    def _move(self, det: Detection, width: int, height: int) -> np.ndarray:
        c = self.cfg
        f = self._focal(height)
        # aim where the target will be when the move is over (its own image velocity: the
        # tracker's, the robot's turns taken out)
        u = det.centroid[0] + self.tracker.vel[0] * c.lead_s
        bearing = math.atan((u - width / 2) / f)
        if bearing:
            self.side = 1.0 if bearing < 0 else -1.0
        # the yaw command that turns the bearing away in move_s, clipped: the turn made
        w_cmd = max(-1.0, min(1.0, -bearing / (c.w_max * c.move_s)))
        self._turn(w_cmd * c.w_max * c.move_s, width, height)
        self.remaining_s = c.move_s
        half_fov = math.atan(0.5 * width / f)
        v = c.speed_gain * (c.desired_width - det.bbox[2] / width)
        v = max(-c.v_limit, min(c.v_limit, v)) * max(0.0, 1 - c.turn_slowdown *
                                                      min(1.0, abs(bearing) / half_fov))
        self.phase = "move"
        self.counts["moves"] += 1
        self.cmd = np.array([v, w_cmd], np.float32)
        return self.cmd

    def _search(self) -> np.ndarray:
        c = self.cfg
        self.unseen_s = 0.0
        self.tracker.reset()
        angle = c.search_angle * self.side
        self.remaining_s = abs(angle) / (c.w_max * c.search_w) if angle else 0.0
        self.phase = "search"
        self.counts["searches"] += 1
        self.cmd = np.array([0.0, math.copysign(c.search_w, angle) if angle else 0.0],
                            np.float32)
        return self.cmd

    def _done(self, phase: str, cmd: np.ndarray, det: Detection | None):
        self.counts[phase] += 1
        return (np.clip(np.asarray(cmd, np.float32), -1.0, 1.0), det,
                f"{phase}/{self.tracker.mode}")
