"""The navigation expert (paper's "YOLO+PID"): detector output -> [v, w] command.

Two PID axes on normalised image errors, so the gains hold at any resolution:
  yaw rate  w:  measurement ex = (u - W/2) / (W/2) in [-1, 1] (target right of centre > 0),
                setpoint 0. Positive w turns left (counter-clockwise about +z), so a target
                on the right (ex > 0) gives w < 0.
  forward   v:  measurement width = bbox_w / W, setpoint desired_width (the following
                distance seen as an apparent size): too small -> drive on, too large -> back.
                v is scaled down by (1 - turn_slowdown * |ex|): driving straight on while the
                target sits at the image edge would push it out of view.
Both outputs are clipped to [-1, 1] (the scene scales them to v_max m/s, w_max rad/s).

Lost target (no detection): for `hold_s` the robot stops and waits (a detector miss of a
frame or two should not start a search), then rotates at `search_w` toward the side where the
target was last seen. The PIDs are reset on loss, so a stale integral does not act on
re-acquisition.

Every method takes dt in seconds (the time since the previous control step); a frame rate
change or a dropped frame changes dt, not the behaviour.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .detector import Detection
from .pid import PID, PIDGains


@dataclass
class NavExpertConfig:
    """Gains in normalised units: w per unit ex, v per unit of width fraction."""
    yaw: PIDGains = field(default_factory=lambda: PIDGains(kp=1.6, ki=0.3, kd=0.12,
                                                           i_min=-0.4, i_max=0.4, tau_d=0.05))
    speed: PIDGains = field(default_factory=lambda: PIDGains(kp=8.0, ki=0.5, kd=0.0,
                                                             i_min=-0.3, i_max=0.3))
    desired_width: float = 0.12      # bbox width / image width at the following distance
    turn_slowdown: float = 0.8       # v scale 1 - this * |ex|
    hold_s: float = 0.3              # s without detection before the search starts
    search_w: float = 0.6            # search yaw rate, in [-1, 1] units
    min_confidence: float = 0.0      # detections below this count as none


class NavExpert:
    """Stateful expert for one episode; call `reset()` between episodes."""

    def __init__(self, config: NavExpertConfig | None = None) -> None:
        self.cfg = config or NavExpertConfig()
        self.yaw_pid = PID(self.cfg.yaw)
        self.speed_pid = PID(self.cfg.speed)
        self.reset()

    def reset(self) -> None:
        self.yaw_pid.reset()
        self.speed_pid.reset()
        self.last_side = 1.0         # +1: last seen left of centre (turn left), -1: right
        self.lost_s = 0.0            # seconds since the last detection
        self.mode = "search"         # "track" | "hold" | "search"

    def act(self, det: Detection | None, image_size: tuple[int, int], dt: float) -> np.ndarray:
        """Command [v, w] float32 in [-1, 1] for this frame.

        det: the target detection or None; image_size (width, height) px; dt s (> 0).
        """
        c = self.cfg
        width = float(image_size[0])
        if det is not None and det.confidence >= c.min_confidence:
            ex = (det.centroid[0] - width / 2) / (width / 2)
            wf = det.bbox[2] / width
            self.lost_s = 0.0
            self.mode = "track"
            if ex != 0.0:
                self.last_side = -1.0 if ex > 0 else 1.0
            w = self.yaw_pid.update(0.0, ex, dt)
            v = self.speed_pid.update(c.desired_width, wf, dt)
            v *= max(0.0, 1.0 - c.turn_slowdown * min(1.0, abs(ex)))
        else:
            if self.mode == "track":
                self.yaw_pid.reset()
                self.speed_pid.reset()
            self.lost_s += dt
            if self.lost_s < c.hold_s:
                self.mode = "hold"
                v, w = 0.0, 0.0
            else:
                self.mode = "search"
                v, w = 0.0, c.search_w * self.last_side
        return np.clip(np.array([v, w], dtype=np.float32), -1.0, 1.0)
