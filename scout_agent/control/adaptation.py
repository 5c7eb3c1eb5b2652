"""The adaptive gait: slower and lower where the ground grips little for its slope, from what the scout feels.

The margin the ground leaves is m = μ̂ − tan θ̂: μ̂ the friction estimate of the area under the feet
(`friction_estimate.FrictionEstimate.area_mu`), θ̂ the slope of the controller's own foothold plane (the
last four footholds, `TrotController.plane`). Where m ≥ `margin_full` the gait is untouched (so on ground that
grips, the adaptive control changes nothing and costs nothing); below it the commanded speed scales down
linearly to `min_speed_scale` at m ≤ 0 and the trunk lowers by up to `max_lower_m` (a lower CoM shortens the
lever of the inertial forces the feet must hold). The stance QP's cone uses `qp_share` · μ̂ of each foot whose estimate fell below the QP's old
constant (and the constant elsewhere). With `qp_area` (off by default) every foot's cone uses the area's estimate,
the smallest of the four, on the idea that the feet stand on the same ground (per foot, the QP asked the
unslipped feet for ratios up to 0.5 on a μ 0.23 lunar patch as the scout braked; they slid 0.15–0.3 m and it
fell): it also takes the grip of the rear feet that still stand on good ground, and on a 20° ramp with an
unholdable patch the back-off then slid down the whole patch and fell in 2 of 2 seeds (0 of 2 without it).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["GaitAdaptation", "GaitAdaptationConfig", "GaitSetting"]


@dataclass(frozen=True)
class GaitAdaptationConfig:
    margin_full: float = 0.15  # μ̂ − tan θ̂ at and above which the gait is unchanged
    min_speed_scale: float = 0.4  # speed share at no margin
    max_lower_m: float = 0.03  # trunk lowered by up to this much [m]
    qp_share: float = 0.85  # the stance QP's cone: this share of each foot's estimate
    qp_mu_max: float = 0.6  # ... never above the controller's old constant
    qp_area: bool = False  # every foot's cone from the area's estimate (the smallest), not its own


@dataclass(frozen=True)
class GaitSetting:
    speed_scale: float  # share of the commanded speed
    height_offset_m: float  # trunk height change [m]
    qp_mu: np.ndarray  # (4,) friction per foot for the stance QP
    margin: float  # μ̂ − tan θ̂


class GaitAdaptation:
    def __init__(self, config: GaitAdaptationConfig = GaitAdaptationConfig()) -> None:
        self.config = config
        self._last: tuple[tuple[float, ...], GaitSetting] | None = None

    def setting(self, mu_feet: np.ndarray, plane_grad: np.ndarray) -> GaitSetting:
        """The gait for these friction estimates and foothold plane; the same object again while neither
        changed (the estimate moves at stance ends, the plane when a foot lands: most ticks change nothing)."""
        mu = np.asarray(mu_feet, dtype=float)
        key = (*mu.tolist(), float(plane_grad[0]), float(plane_grad[1]))
        if self._last is None or self._last[0] != key:
            self._last = (key, self._setting(mu, plane_grad))
        return self._last[1]

    def _setting(self, mu: np.ndarray, plane_grad: np.ndarray) -> GaitSetting:
        c = self.config
        tan_slope = float(np.hypot(plane_grad[0], plane_grad[1]))
        margin = float(np.min(mu)) - tan_slope
        u = min(1.0, max(0.0, margin / c.margin_full))  # 1: full margin, 0: none
        cone = np.full(4, float(np.min(mu))) if c.qp_area else mu
        return GaitSetting(
            speed_scale=c.min_speed_scale + (1.0 - c.min_speed_scale) * u,
            height_offset_m=-c.max_lower_m * (1.0 - u),
            qp_mu=np.where(cone >= c.qp_mu_max, c.qp_mu_max, c.qp_share * cone),
            margin=margin,
        )
