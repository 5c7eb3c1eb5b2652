"""Localization against a map: the scout's recent footholds matched to an orbital DEM and to the shared map.

Feet are height probes. `FootholdTrack` (track.py) keeps where the estimate put the recent footholds;
`match_track` (matcher.py) searches a small window of (dx, dy, dyaw) offsets of that track against a
`HeightReference` (reference.py: a DEM, or the shared map's elevation with its per-cell spread and counts),
scores each by a robust, uncertainty-weighted height residual (the vertical datum fitted per offset), and
returns the best offset with its covariance from the score's curvature (Laplace), or says why it cannot:
flat ground, an ambiguous second peak, the best on the window's edge; against an orbital DEM, `match_trail`
(trail.py) reads the footholds walked since the last fix (averaged per metre, the datum a line along the
trail, yaw matched) against the filter's own prior and returns what they add to it, each foothold once.
`Localizer` (localizer.py) runs them
every few metres walked and fuses an accepted match into the state estimate as a pose measurement
(`state_estimation.pose_update`), behind a χ² gate against the estimate's own covariance.
"""

from __future__ import annotations

from .localizer import LOCALIZE_MODES, Localizer, LocalizerConfig, LocalizerReport
from .matcher import MatchConfig, MatchResult, match_track
from .reference import DemReference, GridReference, HeightReference, height_datum, map_reference
from .track import FootholdTrack
from .trail import TrailConfig, TrailFix, match_trail

__all__ = [
    "LOCALIZE_MODES",
    "DemReference",
    "FootholdTrack",
    "GridReference",
    "HeightReference",
    "Localizer",
    "LocalizerConfig",
    "LocalizerReport",
    "MatchConfig",
    "MatchResult",
    "TrailConfig",
    "TrailFix",
    "map_reference",
    "height_datum",
    "match_track",
    "match_trail",
]
