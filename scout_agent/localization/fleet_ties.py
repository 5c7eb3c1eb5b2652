"""Fleet ties: the other scouts' cells under the stretch of walk a scout still holds, as measurements of its
height datum along that stretch.

A scout publishes its footholds `hold_m` behind the newest (`holding.py`), revised by each whole-walk DEM fix
(`HeightTrack`, `PoseFix.height_profile`). The DEM is the only absolute reference, and its evidence for a
stretch of walk thins toward the walk's newest end (no evidence beyond it) — where the mission's routes end on
or cross the ground another scout walked and published earlier (scout1 of the 100 m mission ends where scout2
started: its last 40 m erred −0.05 … −0.18 m where scout2's cells there err +0.02; docs/results.md,
"Fleet ties"). The localizer's height fix against the shared map (`match_height`, "map_height") reads only the
newest `track_m` = 10 m at most once per 20 m, and only where the place match failed; most of a held stretch
is never compared with the fleet's cells.

`fleet_ties` cuts the held stretch into `piece_m` pieces by distance walked and, for each piece on the others'
cells, reads their height under its footholds (`match_height` at the estimated place, the datum's change over
the places the two estimates allow added: the others' placement σ and the scout's own, as for the map height
fix). Each tie is a point measurement of the datum (the others' height minus the estimate's) at the piece's
middle (`HeightTrack.add_point`), so the next whole-walk fit weighs it against the DEM and the random walk and
revises the held footholds with it. Its variance: the match's (scatter, placement) plus the others' own
vertical σ (their datum error, which a tie cannot average away), counted `datum_corr_m` / `piece_m` times
(their datum error holds over a stretch of their walk: neighbouring pieces on their cells read one draw of it,
as the DEM relief's bins do in `HeightTrack`). Only the scout's own heights move: the others' published cells
are theirs (they revise their own held stretch against ours in turn).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np

from scout_agent.errors import ScoutConfigError

from .matcher import MatchConfig, match_height
from .reference import GridReference, HeightReference

__all__ = ["FleetTie", "FleetTieConfig", "fleet_ties"]


@dataclass(frozen=True)
class FleetTieConfig:
    """piece_m: footholds per tie, by distance walked [m]; span_m: only pieces within this much of the newest
    foothold (what the scout still holds: `HoldConfig.hold_m`) [m]; datum_corr_m: the walk over which the
    others' datum error stays one draw (their DEM fixes are 25 m apart) [m]; min_points: covered footholds a
    piece needs."""

    piece_m: float = 10.0
    span_m: float = 60.0
    datum_corr_m: float = 25.0
    min_points: int = 40

    def __post_init__(self) -> None:
        for name in ("piece_m", "span_m", "datum_corr_m"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ScoutConfigError(f"fleet tie {name} = {v}: need a finite distance > 0 [m]")
        if self.min_points < 1:
            raise ScoutConfigError(f"fleet tie min_points = {self.min_points}: need ≥ 1")


class FleetTie(NamedTuple):
    piece: int  # index of the piece: floor(walked / piece_m)
    walked_m: float  # the datum's place: the piece's footholds' mean distance walked [m]
    dz_m: float  # the others' height minus the estimate's under the piece [m]
    var_m2: float  # its variance [m²]
    points: int  # footholds on the others' cells


# the others' cells around (x, y) within radius [m], as the localizer's map source gives them
Source = Callable[[float, float, float], "HeightReference | None"]


def fleet_ties(
    pts: np.ndarray,
    walked: np.ndarray,
    now_m: float,
    source: Source,
    sigma_xy_m: float,
    config: FleetTieConfig = FleetTieConfig(),
    match: MatchConfig | None = None,
    skip: Callable[[int], bool] = lambda piece: False,
) -> list[FleetTie]:
    """Ties of the complete pieces of footholds `pts` (n, 3) placed at distances walked `walked` (n,) within
    `config.span_m` of `now_m`, each against `source` (the others' cells); `sigma_xy_m`: the scout's own
    horizontal σ now (the footholds moved with every fix: they are placed as well as the estimate is); pieces
    for which `skip(piece)` is true are left out (tied already). A piece without enough footholds on the
    others' cells gives no tie. `match`: the height match's settings (its Huber k, search step; default
    `MatchConfig()`), its `min_points` replaced by the config's."""
    c = config
    out: list[FleetTie] = []
    pts = np.asarray(pts, dtype=float)
    walked = np.asarray(walked, dtype=float)
    if len(pts) == 0:
        return out
    piece = np.floor(walked / c.piece_m).astype(np.int64)
    first = int(np.floor(max(now_m - c.span_m, 0.0) / c.piece_m))
    last = int(np.floor(now_m / c.piece_m)) - 1  # complete pieces only
    cfg = replace(match or MatchConfig(), min_points=c.min_points)
    for k in range(first, last + 1):
        if skip(k):
            continue
        sel = piece == k
        if int(sel.sum()) < c.min_points:
            continue
        p = pts[sel]
        lo, hi = p[:, :2].min(0), p[:, :2].max(0)
        mid = (lo + hi) / 2
        ref = source(float(mid[0]), float(mid[1]), float(np.hypot(*(hi - lo)) / 2 + 2.0))
        if ref is None:
            continue
        place = ref.place_var(p[:, 0], p[:, 1]) if isinstance(ref, GridReference) else 0.0
        datum = ref.datum_var(p[:, 0], p[:, 1]) if isinstance(ref, GridReference) else 0.0
        fix = match_height(p, ref, float(np.sqrt(sigma_xy_m**2 + place)), cfg)
        if fix is None or not (np.isfinite(fix.dz) and np.isfinite(fix.var_m2)):
            continue
        var = fix.var_m2 + datum * max(1.0, c.datum_corr_m / c.piece_m)
        out.append(FleetTie(k, float(walked[sel].mean()), float(fix.dz), float(var), fix.points))
    return out
