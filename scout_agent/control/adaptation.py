"""The adaptive gait: slower and lower where the ground grips little for its slope, from what the scout feels.

The margin the ground leaves is m = μ̂ − tan θ̂: μ̂ the friction estimate of the area under the feet
(`friction_estimate.FrictionEstimate.area_mu`), θ̂ the slope of the controller's own foothold plane (the
last four footholds, `TrotController.plane`). Where m ≥ `margin_full` the gait is untouched (so on ground that
grips, the adaptive control changes nothing and costs nothing); below it the commanded speed scales down
linearly to `min_speed_scale` at m ≤ 0 and the trunk lowers by up to `max_lower_m` (a lower CoM shortens the
lever of the inertial forces the feet must hold). The stance QP's cone uses `qp_share` · μ̂ of each foot whose estimate fell below the QP's old
constant; once a foot lost its hold anywhere (the area's estimate below the constant), each foot that has not
lost its own gets the larger of `qp_share` · the area's μ̂ and what it proved it holds
(`FrictionEstimate.proven`), not the constant (`qp_proven`, off by default), and the trunk controller's
horizontal acceleration is limited to what the felt margin holds (`accel_share`, off by default). With `qp_area` (off by default) every foot's cone uses the area's estimate,
the smallest of the four, on the idea that the feet stand on the same ground (per foot, the QP asked the
unslipped feet for ratios up to 0.5 on a μ 0.23 lunar patch as the scout braked; they slid 0.15–0.3 m and it
fell): it also takes the grip of the rear feet that still stand on good ground, and on a 20° ramp with an
unholdable patch the back-off then slid down the whole patch and fell in 2 of 2 seeds (0 of 2 without it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from scout_agent.robot import constants as C

__all__ = ["GaitAdaptation", "GaitAdaptationConfig", "GaitSetting"]


@dataclass(frozen=True)
class GaitAdaptationConfig:
    margin_full: float = 0.15  # μ̂ − tan θ̂ at and above which the gait is unchanged
    min_speed_scale: float = 0.4  # speed share at no margin
    max_lower_m: float = 0.03  # trunk lowered by up to this much [m]
    qp_share: float = 0.85  # the stance QP's cone: this share of each foot's estimate
    qp_mu_max: float = 0.6  # ... never above the controller's old constant
    qp_area: bool = False  # every foot's cone from the area's estimate (the smallest), not its own
    # where a foot lost its hold, the others' cones from the area's estimate or what each proved it holds, not
    # the constant: the feet that have felt nothing yet may stand on the same ground (lunar seed 4 west). Off:
    # with `accel_share` 0.7 the lunar matrix fell 5 of 30 (7 by default) but the ramps' seed 0 13 of 21 (3 of
    # 25): hind feet on good ground that must push the back-off up a ramp proved less than it needs
    # (docs/results.md, "What the feet can hold")
    qp_proven: bool = False
    # where a foot lost its hold, the trunk controller asks for at most this horizontal acceleration:
    # g · (accel_share · μ̂_area − tan θ̂), never below accel_floor_mps2 (None: no limit). A stop's step in the
    # speed command asked for ≈ 2 m/s² (kd · Δv), 5–10× what a patch holds at lunar g; on a trot's diagonal pair
    # the braking force's pitch moment is balanced by the normal forces of one front and one hind foot on
    # opposite sides, whose roll moment needs sideways friction too: the trunk rolled 15° within 0.2 s of the
    # stop (lunar seed 6 east). Off (None) by default: see qp_proven
    accel_share: float | None = None
    accel_floor_mps2: float = 0.15


@dataclass(frozen=True)
class GaitSetting:
    speed_scale: float  # share of the commanded speed
    height_offset_m: float  # trunk height change [m]
    qp_mu: np.ndarray  # (4,) friction per foot for the stance QP
    accel_limit_mps2: float  # the trunk's horizontal acceleration limit [m/s²] (inf: none)
    margin: float  # μ̂ − tan θ̂


class GaitAdaptation:
    def __init__(self, config: GaitAdaptationConfig = GaitAdaptationConfig()) -> None:
        self.config = config
        self._last: tuple[tuple[float, ...], GaitSetting] | None = None

    def setting(
        self, mu_feet: np.ndarray, plane_grad: np.ndarray, proven: np.ndarray | None = None
    ) -> GaitSetting:
        """The gait for these friction estimates, foothold plane and (optionally) the ratios each foot proved
        it holds (`FrictionEstimate.proven`, NaN: none); the same object again while none changed (the
        estimate moves at stance ends, the plane when a foot lands: most ticks change nothing)."""
        mu = np.asarray(mu_feet, dtype=float)
        key = (*mu.tolist(), float(plane_grad[0]), float(plane_grad[1]))
        if proven is not None and self.config.qp_proven and float(np.min(mu)) < self.config.qp_mu_max:
            key += tuple(proven.tolist())
        if self._last is None or self._last[0] != key:
            self._last = (key, self._setting(mu, plane_grad, proven))
        return self._last[1]

    def _setting(self, mu: np.ndarray, plane_grad: np.ndarray, proven: np.ndarray | None) -> GaitSetting:
        c = self.config
        tan_slope = float(np.hypot(plane_grad[0], plane_grad[1]))
        area = float(np.min(mu))
        margin = area - tan_slope
        u = min(1.0, max(0.0, margin / c.margin_full))  # 1: full margin, 0: none
        cone = np.full(4, area) if c.qp_area else mu
        qp_mu = np.where(cone >= c.qp_mu_max, c.qp_mu_max, c.qp_share * cone)
        if c.qp_proven and proven is not None and area < c.qp_mu_max:
            # the feet that felt nothing: the area's estimate, or what each proved it holds where it stands
            held = np.fmax(c.qp_share * area, np.asarray(proven, dtype=float))
            qp_mu = np.minimum(qp_mu, held)
        accel = math.inf
        if c.accel_share is not None and area < c.qp_mu_max:
            accel = max(c.accel_floor_mps2, C.LUNAR_G * (c.accel_share * area - tan_slope))
        return GaitSetting(
            speed_scale=c.min_speed_scale + (1.0 - c.min_speed_scale) * u,
            height_offset_m=-c.max_lower_m * (1.0 - u),
            qp_mu=qp_mu,
            accel_limit_mps2=accel,
            margin=margin,
        )
