"""A discrete PID controller for the experts: derivative on measurement, output limits,
anti-windup.

    u = kp * e + I + D,       e = setpoint - measurement
    I += ki * e * dt          (see anti-windup below)
    D  = -kd * d(measurement)/dt, low-pass filtered with time constant tau_d

Why derivative on measurement: a step of the setpoint (or a detection that jumps, e.g.
the target re-acquired at the other side of the image) would kick an error derivative;
the measurement derivative gives the same damping without the kick.

Anti-windup (while the output sits at a limit the integral must not keep growing, or the
controller overshoots for as long as it takes to unwind it):
  "clamp"     conditional integration: the integral is frozen while the output is saturated
              and the error pushes further into the limit; it also never leaves [i_min, i_max].
  "backcalc"  back-calculation: I += dt * (ki * e + kb * (u_sat - u_raw)); the tracking gain
              kb (1/s) bleeds the integral off at a rate proportional to the saturation.

Units are the caller's: e and measurement in one unit, u in another, dt in seconds.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal


@dataclass
class PIDGains:
    """Gains and limits of one PID axis.

    kp (u/e), ki (u/(e s)), kd (u s/e); out_min/out_max: output limits; i_min/i_max: limits
    of the integral term itself (in output units); tau_d: derivative low-pass time constant
    (s, 0 = unfiltered); anti_windup "clamp" | "backcalc" | "none"; kb: back-calculation
    tracking gain (1/s; 0 = ki/kp when both are set, else 1.0).
    """
    kp: float = 1.0
    ki: float = 0.0
    kd: float = 0.0
    out_min: float = -1.0
    out_max: float = 1.0
    i_min: float = -math.inf
    i_max: float = math.inf
    tau_d: float = 0.0
    anti_windup: Literal["clamp", "backcalc", "none"] = "clamp"
    kb: float = 0.0

    def __post_init__(self) -> None:
        if not self.out_min < self.out_max:
            raise ValueError(f"PID: out_min {self.out_min} must be < out_max {self.out_max}")
        if self.i_min > self.i_max:
            raise ValueError(f"PID: i_min {self.i_min} must be <= i_max {self.i_max}")
        if self.anti_windup not in ("clamp", "backcalc", "none"):
            raise ValueError(f"PID: anti_windup {self.anti_windup!r} is not clamp, backcalc "
                             f"or none")
        if self.tau_d < 0 or self.kb < 0:
            raise ValueError("PID: tau_d and kb must be >= 0")


class PID:
    """One PID axis. `update(setpoint, measurement, dt)` -> saturated output.

    The first update after construction or `reset()` has no derivative (no previous
    measurement). dt <= 0 (a repeated sample) returns the last output unchanged.
    """

    def __init__(self, gains: PIDGains) -> None:
        self.g = gains
        self.reset()

    def reset(self) -> None:
        """Forget the integral, the previous measurement and the derivative filter."""
        self.integral = 0.0          # I term, in output units
        self.d_term = 0.0            # filtered D term, output units
        self.prev_meas: float | None = None
        self.output = 0.0            # last saturated output
        self.raw = 0.0               # last unsaturated output
        self.saturated = False

    def update(self, setpoint: float, measurement: float, dt: float) -> float:
        g = self.g
        if dt <= 0:
            return self.output
        e = setpoint - measurement
        # derivative on measurement, first-order filtered (exact discretisation)
        if self.prev_meas is None or g.kd == 0.0:
            d_raw = 0.0
        else:
            d_raw = -g.kd * (measurement - self.prev_meas) / dt
        if g.tau_d > 0 and self.prev_meas is not None:
            a = 1.0 - math.exp(-dt / g.tau_d)
            self.d_term += a * (d_raw - self.d_term)
        else:
            self.d_term = d_raw
        self.prev_meas = measurement

        p = g.kp * e
        if g.anti_windup == "backcalc":
            # the output uses the integral so far; the integral then takes this step's error
            # and gives back kb * (saturation excess) per second
            raw = p + self.integral + self.d_term
            out = min(max(raw, g.out_min), g.out_max)
            kb = g.kb if g.kb > 0 else (g.ki / g.kp if g.kp and g.ki else 1.0)
            self.integral += dt * (g.ki * e + kb * (out - raw))
            self.integral = min(max(self.integral, g.i_min), g.i_max)
        else:
            # integrate first (the output reacts to this step's error), unless that would
            # push an already saturated output further into its limit
            candidate = min(max(self.integral + g.ki * e * dt, g.i_min), g.i_max)
            raw = p + candidate + self.d_term
            pushing_high = raw > g.out_max and e > 0
            pushing_low = raw < g.out_min and e < 0
            if g.anti_windup == "none" or not (pushing_high or pushing_low):
                self.integral = candidate
            raw = p + self.integral + self.d_term
            out = min(max(raw, g.out_min), g.out_max)
        self.raw, self.output = raw, out
        self.saturated = out != raw
        return out
