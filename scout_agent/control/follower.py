"""Path following: pure pursuit over start → via … → goal, and the velocity loop that holds the speed.

The velocity loop (the paper adds one on top of its MPC) integrates the shortfall between the commanded
horizontal speed and the measured one and adds it to the command the trot controller receives, so the
robot holds e.g. 0.2 m/s up slopes where the balance controller alone would lag.
"""

from __future__ import annotations

import math
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
        self._xy: list[tuple[float, float]] = [(float(x), float(y)) for x, y in self.points]
        self.segment = 0
        self.integral = 0.0
        self.reached = False

    @property
    def goal(self) -> np.ndarray:
        return self.points[-1]

    def _lookahead(self, px: float, py: float) -> tuple[float, float]:
        """The pursuit target `lookahead_m` along the path ahead of the robot's projection on it (scalar
        arithmetic on Python floats: a few 2-vectors a tick, where numpy's per-call cost dominates)."""
        pts, look = self._xy, self.config.lookahead_m
        last = len(pts) - 2
        # advance the segment once the robot projects beyond its end
        while self.segment < last:
            (ax, ay), (bx, by) = pts[self.segment], pts[self.segment + 1]
            abx, aby = bx - ax, by - ay
            if ((px - ax) * abx + (py - ay) * aby) / (abx * abx + aby * aby) >= 1.0 or math.hypot(
                px - bx, py - by
            ) < look:
                self.segment += 1
            else:
                break
        (ax, ay), (bx, by) = pts[self.segment], pts[self.segment + 1]
        abx, aby = bx - ax, by - ay
        t = min(1.0, max(0.0, ((px - ax) * abx + (py - ay) * aby) / (abx * abx + aby * aby)))
        tx, ty = ax + abx * t, ay + aby * t
        remaining = look
        seg = self.segment
        while True:
            ex, ey = pts[seg + 1]
            d = math.hypot(ex - tx, ey - ty)
            if d >= remaining or seg == last:
                f = min(1.0, remaining / max(d, 1e-9))
                return tx + (ex - tx) * f, ty + (ey - ty) * f
            remaining -= d
            tx, ty = ex, ey
            seg += 1

    def command(self, pos_xy: np.ndarray, yaw: float, vel_xy: np.ndarray, dt: float) -> tuple[float, float]:
        """(forward speed [m/s], yaw rate [rad/s]) for the controller; sets `reached` at the goal."""
        px, py = pos_xy.tolist()
        vx, vy = vel_xy.tolist()
        if self.reverse:  # pursue with the tail: the heading is the trunk's reversed, speed is backwards
            v, w = self._forward(px, py, float(yaw) + math.pi, vx, vy, dt)
            return -v, w
        return self._forward(px, py, float(yaw), vx, vy, dt)

    def _forward(
        self, px: float, py: float, yaw: float, vx: float, vy: float, dt: float
    ) -> tuple[float, float]:
        c = self.config
        gx, gy = self._xy[-1]
        if self.reached or math.hypot(gx - px, gy - py) < c.goal_tolerance_m:
            self.reached = True
            return 0.0, 0.0
        tx, ty = self._lookahead(px, py)
        heading = math.atan2(ty - py, tx - px)
        err = (heading - yaw + math.pi) % (2 * math.pi) - math.pi
        yaw_rate = min(c.max_yaw_rate, max(-c.max_yaw_rate, c.yaw_gain * err))
        scale = 1.0 if abs(err) < c.slow_heading_err_rad else max(0.0, math.cos(err))
        v_ref = c.speed * scale
        v_meas = vx * math.cos(yaw) + vy * math.sin(yaw)
        if scale == 1.0:
            self.integral = min(c.max_boost, max(-0.05, self.integral + c.ki * (v_ref - v_meas) * dt))
        return v_ref + self.integral * scale, yaw_rate
