"""The scout's start: a surveyed launch pose with its stated uncertainty, and the source of its height datum.

A real scout does not know where it stands exactly. The lander surveys its launch point (decimetres, about a
degree of heading), and nobody hands it the ground height under its feet. `initial_pose` makes that start:

- x, y, heading: the true spawn pose plus an error drawn from the run seed with σ `sigma_xy_m` (per axis) and
  `sigma_yaw_deg` (`LaunchSurvey`; defaults 0.15 m and 1°, a lander's survey of its rover, assumed from the
  decimetre/degree class of a lander survey; docs/physics.md); the estimator starts with exactly that covariance;
- the ground height under it (the height datum of everything it maps): the first of `datum_sources` that has a
  value there, each a `HeightDatum` callable returning (height, σ) or None — issue 23's localizer adds the
  orbital DEM and the shared map here. With none, the start height is **declared** 0 with σ
  `declared_sigma_z_m` (2 m), and `LaunchPose.datum` says so.

`LaunchSurvey(mode="exact")` is the comparison option (`--launch exact`): the exact spawn pose and the exact
ground height, as the builds before issue 23 had; it is never the default.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from scout_agent.errors import ScoutConfigError

LAUNCH_MODES = ("survey", "exact")

# (x, y) [m] in the map frame → (ground height [m], its σ [m]), or None where the source has no value
HeightDatum = Callable[[float, float], "tuple[float, float] | None"]


@dataclass(frozen=True)
class LaunchSurvey:
    mode: str = "survey"  # one of LAUNCH_MODES; "exact" is for comparison only
    sigma_xy_m: float = 0.15  # σ of the surveyed x and y [m]
    sigma_yaw_deg: float = 1.0  # σ of the surveyed heading [deg]
    declared_sigma_z_m: float = 2.0  # σ of the declared 0 height when no datum source has a value [m]

    def __post_init__(self) -> None:
        if self.mode not in LAUNCH_MODES:
            raise ScoutConfigError(f"launch mode {self.mode!r} unknown; modes: {', '.join(LAUNCH_MODES)}")
        for name in ("sigma_xy_m", "sigma_yaw_deg", "declared_sigma_z_m"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise ScoutConfigError(f"launch survey {name} = {v}: need a finite value ≥ 0")


@dataclass(frozen=True)
class LaunchPose:
    """Where the scout believes it launches, in the map frame, and how well it knows it."""

    x: float  # [m]
    y: float  # [m]
    yaw: float  # heading [rad]
    ground_z: float  # ground height under the launch point (the map's height datum) [m]
    sigma_xy_m: float = 0.0  # σ of x and y [m]
    sigma_yaw_rad: float = 0.0  # σ of the heading [rad]
    sigma_z_m: float = 0.0  # σ of ground_z [m]
    datum: str = "given"  # where ground_z came from: "exact", "declared", or a datum source's name

    def covariance(self) -> np.ndarray:
        """(4, 4) covariance of (x, y, yaw, ground_z)."""
        return np.diag([self.sigma_xy_m**2, self.sigma_xy_m**2, self.sigma_yaw_rad**2, self.sigma_z_m**2])


def initial_pose(
    true_xy_yaw: tuple[float, float, float],
    survey: LaunchSurvey,
    rng: np.random.Generator,
    datum_sources: Sequence[tuple[str, HeightDatum]] = (),
    exact_ground_z: Callable[[], float] | None = None,
) -> LaunchPose:
    """The launch pose the scout starts from. `true_xy_yaw` is where the lander put it (what the survey
    measures, with error); `datum_sources` are tried in order at the surveyed x, y; `exact_ground_z` is read
    only in the comparison mode "exact"."""
    x, y, yaw = (float(v) for v in true_xy_yaw)
    if survey.mode == "exact":
        if exact_ground_z is None:
            raise ScoutConfigError("launch mode 'exact' needs the exact ground height (comparison runs only)")
        return LaunchPose(x, y, yaw, float(exact_ground_z()), datum="exact")
    ex, ey = rng.normal(0.0, survey.sigma_xy_m, 2) if survey.sigma_xy_m else (0.0, 0.0)
    eyaw = rng.normal(0.0, np.radians(survey.sigma_yaw_deg)) if survey.sigma_yaw_deg else 0.0
    sx, sy, syaw = x + float(ex), y + float(ey), float(yaw + eyaw)
    sig_xy, sig_yaw = survey.sigma_xy_m, float(np.radians(survey.sigma_yaw_deg))
    for name, source in datum_sources:
        got = source(sx, sy)
        if got is not None and np.isfinite(got[0]) and np.isfinite(got[1]):
            return LaunchPose(sx, sy, syaw, float(got[0]), sig_xy, sig_yaw, float(got[1]), datum=name)
    return LaunchPose(sx, sy, syaw, 0.0, sig_xy, sig_yaw, survey.declared_sigma_z_m, datum="declared")


__all__ = ["LAUNCH_MODES", "HeightDatum", "LaunchPose", "LaunchSurvey", "initial_pose"]
