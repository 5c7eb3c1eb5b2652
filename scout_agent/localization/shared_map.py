"""`SharedMapSource`: the shared map around the scout as a `GridReference`, followed live.

The scout follows the map through the servers' tile-change notices (`psrmap_common.region.RegionFollower` on its
field): it queries the elevation statistics of the box it needs again only when a notice (or a status resync)
says that part of the map changed, or when it needs a box outside the one it holds. Its own contribution is
taken out, cell by cell, before matching: the elevation statistics are sums, so the other scouts' part is the
shared sums minus the scout's own local map (`scout_agent.cells.LocalMap`, exactly what it published) —
matching its footholds against a map built from those same footholds would only confirm its own estimate. The
`height` layer's Σσ² and count, taken apart the same way, give the others' vertical σ per cell (their datum's
uncertainty, `GridReference.datum_sigma`), which a height fix against their cells adds whole; the `placement`
layer's, their horizontal σ (`GridReference.place_sigma`: where their own estimates put the cells), which a
place fix adds whole — a match against their cells places the scout in *their* frame, no better than they are.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from psrmap_common.errors import QueryError
from psrmap_common.region import RegionFollower, fetch_region
from psrmap_common.trust import Trust
from psrmap_mapcore import LayerGrid
from scout_agent.cells import LocalMap

from .reference import GridReference, map_reference

__all__ = ["SharedMapSource"]

log = logging.getLogger(__name__)

_ADDITIVE = ("n", "sum", "sumsq", "sx", "sy", "sxx", "syy", "sxy", "sxz", "syz")
_SIGMA_ADDITIVE = ("n", "var")  # the height and placement layers' sums their σ reads (Σ 1, Σ σ²)


class SharedMapSource:
    """`source(x, y, radius)` -> the other scouts' elevation around (x, y) as a reference, or None."""

    def __init__(
        self,
        session,
        map_id: str,
        own: LocalMap,
        field_box: tuple[float, float, float, float],
        trusted: Trust | Sequence[str] = (),
        timeout_s: float = 1.0,
        resync_s: float = 10.0,
        min_count: float = 2.0,
    ) -> None:
        self.session, self.map_id, self.own = session, map_id, own
        self.trusted, self.timeout_s, self.min_count = Trust.of(trusted), timeout_s, min_count
        self.follow = RegionFollower(session, map_id, field_box, resync_s, timeout_s, self.trusted)
        self._grid: LayerGrid | None = None
        self._box: tuple[float, float, float, float] | None = None
        self.queries = 0
        self.failures = 0

    def close(self) -> None:
        self.follow.close()

    def __call__(self, x: float, y: float, radius: float) -> GridReference | None:
        box = (x - radius, y - radius, x + radius, y + radius)
        held = self._box
        inside = (
            held is not None
            and held[0] <= box[0]
            and held[1] <= box[1]
            and held[2] >= box[2]
            and held[3] >= box[3]
        )
        if self.follow.due() or not inside:
            statuses = self.follow.statuses()
            ask = (box[0] - radius, box[1] - radius, box[2] + radius, box[3] + radius)  # room to walk on
            try:
                self._grid = fetch_region(self.session, self.map_id, ask, self.timeout_s, trusted=self.trusted,
                                          layers=("elevation", "height", "placement"))  # fmt: skip
                self._box = ask
                self.queries += 1
                self.follow.done(statuses)
            except QueryError as exc:
                self.failures += 1
                log.debug("shared map around (%.1f, %.1f) not available: %s", x, y, exc)
                return None
        return self._others()

    def _others(self) -> GridReference | None:
        g = self._grid
        if g is None or "elevation" not in g.layers or g.h == 0 or g.w == 0:
            return None
        region = self.own.region(g.ix0, g.iy0, g.ix0 + g.w - 1, g.iy0 + g.h - 1)
        stats = _minus(g.layers["elevation"], region.get("elevation", {}), _ADDITIVE)
        n = stats["n"]
        gone = n < self.min_count - 1e-6
        for s in _ADDITIVE:
            stats[s] = np.where(gone, 0.0, stats[s])
        if not (n >= self.min_count - 1e-6).any():
            return None
        ref = map_reference(stats, g.x0 + g.ix0 * g.res, g.y0 + g.iy0 * g.res, g.res, self.min_count)
        return replace(
            ref,
            datum_sigma=self._per_cell_sigma(g, region, "height", gone),
            place_sigma=self._per_cell_sigma(g, region, "placement", gone),
        )

    @staticmethod
    def _per_cell_sigma(g: LayerGrid, region: dict, layer: str, gone: np.ndarray) -> np.ndarray | None:
        """The others' RMS σ per cell from a layer's (Σ1, Σσ²) with the scout's own part taken out: the `height`
        layer's vertical σ (their datum, common to all of a scout's cells nearby, which a height fix cannot
        average away), the `placement` layer's horizontal σ (where their own estimate put the cells); NaN
        where they stated none; None without the layer."""
        if layer not in g.layers:
            return None
        h = _minus(g.layers[layer], region.get(layer, {}), _SIGMA_ADDITIVE)
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(
                (h["n"] >= 1.0 - 1e-6) & ~gone, np.sqrt(np.maximum(h["var"], 0.0) / h["n"]), np.nan
            )


def _minus(shared: dict, mine: dict, names: Sequence[str]) -> dict[str, np.ndarray]:
    """The shared statistics `names` minus the scout's own (its part of the sums), NaN as 0."""
    out = {}
    for s in names:
        a = np.nan_to_num(np.asarray(shared[s], dtype=float))
        b = np.nan_to_num(np.asarray(mine[s], dtype=float)) if s in mine else 0.0
        out[s] = a - b
    return out
