"""Path following: pure pursuit over start → via … → goal, and the velocity loop that holds the speed.

The velocity loop (the paper adds one on top of its MPC) integrates the shortfall between the commanded
horizontal speed and the measured one and adds it to the command the trot controller receives, so the
robot holds e.g. 0.2 m/s up slopes where the balance controller alone would lag.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scout_agent.errors import ScoutConfigError


@dataclass(frozen=True)
class FollowerConfig:
    speed: float = 0.2  # commanded horizontal speed [m/s]
    lookahead_m: float = 0.6
    goal_tolerance_m: float = 0.3
    yaw_gain: float = 1.5  # [1/s]
    max_yaw_rate: float = 0.5  # [rad/s]
    ki: float = 0.6  # velocity loop integral gain [1/s]
    max_boost: float = 0.15  # cap on the integral term [m/s]
    slow_heading_err_rad: float = 0.6  # walk slower while turning by more than this


class PathFollower:
    """Pure pursuit over `waypoints`; `reverse=True` walks them backwards (trunk facing away from the
    path: the hazard reflex's back-off along its own trail, no turn on ground that does not hold)."""

    def __init__(self, waypoints, config: FollowerConfig = FollowerConfig(), reverse: bool = False) -> None:
        self.config = config
        self.reverse = reverse
        self.points = np.asarray(waypoints, dtype=float)[:, :2]
        if len(self.points) < 2:
            raise ScoutConfigError("a path needs at least a start and a goal")
        self.segment = 0
        self.integral = 0.0
        self.reached = False

    @property
    def goal(self) -> np.ndarray:
        return self.points[-1]

    def _lookahead(self, p: np.ndarray) -> np.ndarray:
        pts = self.points
        # advance the segment once the robot projects beyond its end
        while self.segment < len(pts) - 2:
            a, b = pts[self.segment], pts[self.segment + 1]
            ab = b - a
            if (p - a) @ ab / (ab @ ab) >= 1.0 or np.hypot(*(p - b)) < self.config.lookahead_m:
                self.segment += 1
            else:
                break
        a, b = pts[self.segment], pts[self.segment + 1]
        ab = b - a
        t = min(1.0, max(0.0, float((p - a) @ ab / (ab @ ab))))
        target = a + ab * t
        remaining = self.config.lookahead_m
        seg = self.segment
        while True:
            end = pts[seg + 1]
            d = float(np.hypot(*(end - target)))
            if d >= remaining or seg == len(pts) - 2:
                return target + (end - target) * min(1.0, remaining / max(d, 1e-9))
            remaining -= d
            target = end
            seg += 1

    def command(self, pos_xy: np.ndarray, yaw: float, vel_xy: np.ndarray, dt: float) -> tuple[float, float]:
        """(forward speed [m/s], yaw rate [rad/s]) for the controller; sets `reached` at the goal."""
        if self.reverse:  # pursue with the tail: the heading is the trunk's reversed, speed is backwards
            v, w = self._forward(pos_xy, yaw + np.pi, vel_xy, dt)
            return -v, w
        return self._forward(pos_xy, yaw, vel_xy, dt)

    def _forward(self, pos_xy: np.ndarray, yaw: float, vel_xy: np.ndarray, dt: float) -> tuple[float, float]:
        c = self.config
        if self.reached or np.hypot(*(self.goal - pos_xy)) < c.goal_tolerance_m:
            self.reached = True
            return 0.0, 0.0
        target = self._lookahead(pos_xy)
        heading = np.arctan2(target[1] - pos_xy[1], target[0] - pos_xy[0])
        err = (heading - yaw + np.pi) % (2 * np.pi) - np.pi
        yaw_rate = min(c.max_yaw_rate, max(-c.max_yaw_rate, float(c.yaw_gain * err)))
        scale = 1.0 if abs(err) < c.slow_heading_err_rad else max(0.0, np.cos(err))
        v_ref = c.speed * scale
        v_meas = float(vel_xy @ np.array([np.cos(yaw), np.sin(yaw)]))
        if scale == 1.0:
            self.integral = min(c.max_boost, max(-0.05, self.integral + c.ki * (v_ref - v_meas) * dt))
        return v_ref + self.integral * scale, yaw_rate
