"""The planner's cost configuration: term weights, hard limits, the unknown policy and `CostMap`, the result.

`CostConfig` is frozen: the CLI and the mission override it once with `dataclasses.replace`;
`parse_weights("cot=2,slip=1")` reads the CLI's weights. What the terms mean: `costs`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import Literal

import numpy as np

from consumer_planner.errors import PlannerError

__all__ = ["HAZARD_POLICIES", "METRICS", "TERMS", "UNKNOWN_POLICIES", "CostConfig", "CostMap", "Limits", "UnknownPolicy", "Weights",
           "parse_weights"]  # fmt: skip


UNKNOWN_POLICIES = ("forbid", "penalty", "infer")
HAZARD_POLICIES = ("forbid", "penalty")


UnknownPolicy = Literal["forbid", "penalty", "infer"]
HazardPolicy = Literal["forbid", "penalty"]


METRICS = ("cot", "slip_rate", "giim", "giam", "slope_deg")  # per-cell values the terms read


@dataclass(frozen=True)
class Weights:
    """Weight of each cost term (>= 0); names are the CLI's `--weights name=value` keys."""

    distance: float = 1.0
    cot: float = 1.0
    slip: float = 2.0  # slips are the hazard the paper maps first; every entry point plans with these
    giim: float = 1.0
    giam: float = 0.5
    slope: float = 1.0
    confidence: float = 0.5


TERMS = tuple(f.name for f in fields(Weights))


@dataclass(frozen=True)
class Limits:
    """Hard limits: a cell beyond any of them is impassable (NaN metrics never trip a limit)."""

    max_slope_deg: float = (
        30.0  # what a trot crosses (measured: 33 deg craters barely, 39 deg fall; docs/physics.md)
    )
    min_giim_rad: float = 0.087  # 5 deg: four-foothold GIIM fell below this 0.5-1 s before falls
    min_giam: float = -math.inf  # [m/s^2]
    max_slip_rate: float = math.inf  # slip events per stance


@dataclass(frozen=True)
class CostConfig:
    weights: Weights = field(default_factory=Weights)
    limits: Limits = field(default_factory=Limits)
    unknown: UnknownPolicy = "penalty"
    unknown_penalty: float = 4.0  # [1/m] added to the distance term on unknown cells (policy penalty)
    infer_sigma_cells: float = 2.0  # Gaussian sigma of the fill (eq. 17) [cells]
    stances_per_m: float = 28.0  # stance phases per metre: 4 feet x 1.4 Hz trot / 0.2 m/s
    giim_ref_rad: float = 0.6  # GIIM at or above this costs nothing (flat static Aliengo ~0.6 rad)
    giam_ref: float = 0.9  # [m/s^2], ditto (flat static ~0.9 m/s^2)
    slope_ref_deg: float = 30.0  # slope term = 1 at this slope
    confidence_n: float = 10.0  # samples at which the confidence term halves
    # [m] the slip term of a cell reads the largest slip rate within this radius (0 = the raw layer);
    # 0.8 m = half a slippery patch: in the map-utility experiment this made planned routes avoid patches
    slip_spread_m: float = 0.8
    # cells within `hazard_spread_m` of a scout's hazard report (the `hazard` layer: ground a scout felt it
    # could not hold and stopped on): `forbid` = impassable, `penalty` = + `hazard_penalty` [1/m]
    hazard: HazardPolicy = "forbid"
    hazard_penalty: float = 50.0
    hazard_spread_m: float = 0.8  # a report marks where the scout stopped, not the whole patch

    def __post_init__(self) -> None:
        if self.unknown not in UNKNOWN_POLICIES:
            raise PlannerError(f"no unknown policy {self.unknown!r}; policies: {', '.join(UNKNOWN_POLICIES)}")
        if self.hazard not in HAZARD_POLICIES:
            raise PlannerError(f"no hazard policy {self.hazard!r}; policies: {', '.join(HAZARD_POLICIES)}")
        if not (self.hazard_spread_m >= 0 and math.isfinite(self.hazard_spread_m)):
            raise PlannerError(f"hazard_spread_m={self.hazard_spread_m} must be a finite radius >= 0 m")
        if not (self.hazard_penalty >= 0 and math.isfinite(self.hazard_penalty)):
            raise PlannerError(f"hazard_penalty={self.hazard_penalty} must be finite and >= 0 [1/m]")
        if not (self.slip_spread_m >= 0 and math.isfinite(self.slip_spread_m)):
            raise PlannerError(f"slip_spread_m={self.slip_spread_m} must be a finite radius >= 0 m (0 = off)")
        bad = [f"{t}={getattr(self.weights, t)}" for t in TERMS if not getattr(self.weights, t) >= 0]
        if bad:
            raise PlannerError(f"weights must be finite and >= 0: {', '.join(bad)}")


def parse_weights(text: str, base: Weights | None = None) -> Weights:
    """`cot=1,slip=2` -> Weights (unnamed terms keep `base`); PlannerError naming the valid terms."""
    values: dict[str, float] = {}
    for part in (p.strip() for p in text.split(",")):
        if not part:
            continue
        name, sep, num = part.partition("=")
        name = name.strip()
        if not sep or name not in TERMS:
            raise PlannerError(f"bad weight {part!r}; give name=value with name in: {', '.join(TERMS)}")
        try:
            values[name] = float(num)
        except ValueError:
            raise PlannerError(f"weight {name}={num!r} is not a number") from None
        if not (values[name] >= 0 and math.isfinite(values[name])):
            raise PlannerError(f"weight {name}={num} must be finite and >= 0")
    return Weights(**{**(base or Weights()).__dict__, **values})


@dataclass(frozen=True, eq=False)
class CostMap:
    """Everything a route breakdown needs, all (h, w): `cost` [1/m] (+inf impassable), the weighted
    `terms` (summing to `cost` on passable cells; `unknown` = the penalty, `hazard` its penalty), the `metrics` the terms read
    (filled where inferred), and the masks `known`, `inferred`, `impassable` and `datum_clash` (cells whose
    footholds' datums clash: their slope is unknown, `costs`; None = not computed)."""

    cost: np.ndarray
    terms: dict[str, np.ndarray]
    metrics: dict[str, np.ndarray]
    known: np.ndarray
    inferred: np.ndarray
    impassable: np.ndarray
    config: CostConfig
    datum_clash: np.ndarray | None = None
