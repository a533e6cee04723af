"""Seeded scripted trajectories for a target moving in the ground plane.

A `WaypointTrajectory` walks through random waypoints inside a rectangle at a speed that
varies per segment; it turns smoothly (turn rate limited) except at "sudden turns", where
the heading snaps, and sometimes stops for a while. Everything random is drawn from its own
`np.random.Generator`, in the order the segments are used, so the same seed and the same
sequence of `step(dt)` calls give the same path bit for bit.

Units: metres, seconds, radians. Positions are (x, y) in the world frame.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

# Nominal target speeds (m/s) per condition; each segment draws 0.7-1.3x of it.
SPEEDS = {"slow": 0.25, "nominal": 0.5, "fast": 1.0}


@dataclass(frozen=True)
class TrajectoryConfig:
    speed: float = SPEEDS["nominal"]   # m/s, nominal
    bounds: tuple[float, float, float, float] = (-4.0, 4.0, -4.0, 4.0)  # xmin, xmax, ymin, ymax
    hop: tuple[float, float] = (1.0, 3.0)    # distance to the next waypoint, m
    max_turn_rate: float = 1.5               # rad/s, smooth turning
    p_stop: float = 0.2                      # chance to stop at a waypoint
    stop_s: tuple[float, float] = (0.5, 1.5)
    p_sudden: float = 0.2                    # chance the next segment starts with a snap turn
    reach: float = 0.15                      # m: a waypoint counts as reached


class WaypointTrajectory:
    """State of one scripted target path. `step(dt)` advances it and returns (x, y)."""

    def __init__(self, start: np.ndarray, heading: float, cfg: TrajectoryConfig,
                 rng: np.random.Generator) -> None:
        self.cfg = cfg
        self.rng = rng
        self.pos = np.array(start, dtype=np.float64).reshape(2)
        self.heading = float(heading)
        self.stop_left = 0.0
        self.snap = False
        self.n_waypoints = 0
        self._next_waypoint(first=True)

    def _next_waypoint(self, first: bool = False) -> None:
        c, rng = self.cfg, self.rng
        xmin, xmax, ymin, ymax = c.bounds
        # A point at a random bearing and hop distance, clipped into the bounds; drawing the
        # bearing around the current heading (+-120 deg) keeps paths varied but not erratic.
        bearing = self.heading + rng.uniform(-2.1, 2.1)
        dist = rng.uniform(*c.hop)
        wp = self.pos + dist * np.array([np.cos(bearing), np.sin(bearing)])
        self.waypoint = np.array([np.clip(wp[0], xmin, xmax), np.clip(wp[1], ymin, ymax)])
        self.seg_speed = c.speed * rng.uniform(0.7, 1.3)
        stop = rng.uniform() < c.p_stop
        stop_s = rng.uniform(*c.stop_s)
        snap = rng.uniform() < c.p_sudden
        if not first:
            self.stop_left = stop_s if stop else 0.0
            self.snap = snap
        self.n_waypoints += 1

    def step(self, dt: float) -> np.ndarray:
        """Advance by dt seconds; returns a copy of the (x, y) position.

        Plain float math: this runs before every physics step, where numpy's per-call
        overhead on 2-vectors would cost more than the step itself.
        """
        if self.stop_left > 0.0:
            self.stop_left = max(0.0, self.stop_left - dt)
            return self.pos.copy()
        px, py = float(self.pos[0]), float(self.pos[1])
        dx, dy = float(self.waypoint[0]) - px, float(self.waypoint[1]) - py
        dist = math.hypot(dx, dy)
        if dist < self.cfg.reach:
            self._next_waypoint()
            return self.pos.copy()
        want = math.atan2(dy, dx)
        err = (want - self.heading + math.pi) % (2 * math.pi) - math.pi
        if self.snap:                        # sudden turn: face the new waypoint at once
            self.heading, self.snap, err = want, False, 0.0
        else:
            lim = self.cfg.max_turn_rate * dt
            self.heading += min(max(err, -lim), lim)
        # Slow down while the heading is far off, so smooth turns do not orbit the waypoint.
        speed = self.seg_speed * max(0.0, math.cos(err))
        step = min(speed * dt, dist)
        self.pos = np.array([px + step * math.cos(self.heading),
                             py + step * math.sin(self.heading)])
        return self.pos.copy()
