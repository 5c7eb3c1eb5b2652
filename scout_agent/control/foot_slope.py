"""The ground's slope under the front feet, from their own footholds.

The controller's foothold plane runs through the four current footholds: where the front feet have walked onto
a crater wall and the rear feet still stand on the flat before it, it reads a mean of both (lunar seed 3 east:
front feet on 20–23°, rear on 3–6°, plane 2–4°, docs/results.md), and a slip trigger that compares the felt
friction with that plane's tangent fires only once the whole body is on the wall. `FootTracks` keeps each foot's
last `keep` touchdown points (the controller's footholds, estimated, map frame) and fits a plane to the front feet's
alone: the left and right tracks give the slope across, each foot's successive footholds the slope along. What it
reads is the robot's own estimate (the footholds come from the estimated pose and the encoders).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["FootTracks", "FootTracksConfig"]

FRONT = (0, 1)  # FL, FR (signals.LEG_NAMES)


@dataclass(frozen=True)
class FootTracksConfig:
    keep: int = 3  # footholds kept per foot (a trot step at 0.2 m/s is ≈ 0.1 m: 3 span ≈ 0.2 m along)
    min_step_m: float = 0.03  # a touchdown closer than this to the foot's previous one replaces it
    min_spread_m: float = 0.04  # the points' smaller xy spread (σ) below which the plane is not fitted


class FootTracks:
    """`update(footholds)` each tick with the controller's (4, 3) footholds; `front_tan()` the front feet's
    plane's steepest tangent (NaN until their footholds span an area)."""

    def __init__(self, config: FootTracksConfig = FootTracksConfig()) -> None:
        self.config = config
        self._last = np.full((4, 3), np.nan)
        self._points: list[list[tuple[float, float, float]]] = [[] for _ in range(4)]
        self._tan = math.nan
        self._dirty = False

    def reset(self) -> None:
        self._points = [[] for _ in range(4)]
        self._last[:] = np.nan
        self._tan = math.nan
        self._dirty = False

    def update(self, footholds: np.ndarray) -> None:
        c = self.config
        for i in FRONT:
            p = footholds[i]
            if p[0] == self._last[i, 0] and p[1] == self._last[i, 1] and p[2] == self._last[i, 2]:
                continue
            self._last[i] = p
            pts = self._points[i]
            q = (float(p[0]), float(p[1]), float(p[2]))
            if pts and math.hypot(q[0] - pts[-1][0], q[1] - pts[-1][1]) < c.min_step_m:
                pts[-1] = q
            else:
                pts.append(q)
                del pts[: -c.keep]
            self._dirty = True

    def front_tan(self) -> float:
        """tan of the steepest slope of the plane through the front feet's kept footholds (NaN: too few)."""
        if not self._dirty:
            return self._tan
        self._dirty = False
        pts = np.array(self._points[FRONT[0]] + self._points[FRONT[1]])
        self._tan = math.nan
        if len(pts) < 4:
            return self._tan
        xy = pts[:, :2] - pts[:, :2].mean(axis=0)
        if np.linalg.eigvalsh(xy.T @ xy / len(pts))[0] < self.config.min_spread_m**2:
            return self._tan
        A = np.column_stack([xy, np.ones(len(pts))])
        (gx, gy, _), *_ = np.linalg.lstsq(A, pts[:, 2], rcond=None)
        self._tan = math.hypot(float(gx), float(gy))
        return self._tan
