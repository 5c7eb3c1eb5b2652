"""Rerun logging of the cost grid and routes (the only module of consumer_planner that imports rerun).

Entities, all at the plan's mission time on `sim_time` (see `psrmap_common.recording`):
- `map/cost`: the cost grid as an RGBA GridMap — viridis over this plan's cost range (cheapest passable
  cell dark, dearest bright), impassable cells red, cells outside the fetched map transparent. Rerun puts
  the translation at the image's lower-left corner with row 0 drawn at the top, so rows are flipped.
- `plans/<name>/path`: each route draped on the map's own elevation layer (what the planner knows of the
  ground; 0.15 m above it), coloured per route and labelled with its name.
- `plans/breakdown`: every route's figures as one Markdown table.
One explicit `rr.RecordingStream` is passed in; the global one is never used.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import rerun as rr

from consumer_planner.compare import Route
from consumer_planner.costs import CostMap
from psrmap_common.recording import TIMELINE, Scale, colorize, open_stream, scout_color
from psrmap_mapcore import LayerGrid

__all__ = ["breakdown_markdown", "cost_image", "drape", "log_plan", "open_recording"]

PATH_LIFT_M = 0.15  # paths float this far above the mapped ground so the terrain mesh does not hide them
_IMPASSABLE = (220, 30, 30, 230)
_PLANNED = (255, 0, 255)


def open_recording(path: str) -> rr.RecordingStream:
    """A recording saved to `path` (and streamed to the mission's live viewer if there is one), in the
    mission's recording (`PSRMAP_RECORDING_ID`) if one is set."""
    return open_stream(path)


def cost_image(costs: CostMap) -> np.ndarray:
    """(h, w, 4) RGBA, row 0 = southmost: passable costs on viridis over their range, impassable red."""
    c = costs.cost
    ok = np.isfinite(c)
    lo, hi = (float(c[ok].min()), float(c[ok].max())) if ok.any() else (0.0, 1.0)
    img = colorize(np.where(ok, c, np.nan), Scale(lo, hi if hi > lo else lo + 1.0, "cost", "viridis", "cost"))
    img[~ok] = _IMPASSABLE
    return img


def drape(grid: LayerGrid, route: Route) -> np.ndarray:
    """(k, 3) the route's points at the map's elevation (+ PATH_LIFT_M); cells without elevation take the
    nearest mapped cell's along the route (0 if the route crosses no mapped cell)."""
    elev = grid.value("elevation")
    cells = np.asarray(route.cells, dtype=int).reshape(-1, 2)
    z = elev[cells[:, 0], cells[:, 1]] if len(cells) else np.zeros(0)
    known = np.flatnonzero(np.isfinite(z))
    if len(known) == 0:
        z = np.zeros(len(route.path))
    else:
        idx = np.arange(len(z))
        z = np.interp(idx, known, z[known])  # between known cells linear, before/after: the nearest
    return np.column_stack([route.path, z + PATH_LIFT_M])


def breakdown_markdown(routes: Sequence[Route]) -> str:
    """The routes' breakdowns as one Markdown table (NaN / missing shown as —)."""
    cols = [("length [m]", "length_m", "{:.1f}"), ("cost", "cost", "{:.1f}"),
            ("expected slips", "expected_slip_events", "{:.1f}"), ("mean CoT", "mean_cot", "{:.2f}"),
            ("GIIM min / mean [rad]", ("min_giim", "mean_giim"), "{:.2f} / {:.2f}"),
            ("GIAM min / mean [m/s²]", ("min_giam", "mean_giam"), "{:.2f} / {:.2f}"),
            ("max slope [°]", "max_slope_deg", "{:.1f}"), ("unknown", "unknown_fraction", "{:.0%}"),
            ("inferred", "inferred_fraction", "{:.0%}"), ("impassable cells", "impassable_cells", "{}")]  # fmt: skip
    lines = ["| route | " + " | ".join(h for h, _, _ in cols) + " |", "|---" * (len(cols) + 1) + "|"]
    for r in routes:
        b = r.breakdown.as_dict()
        cells = []
        for _, key, fmt in cols:
            vals = [b.get(k) for k in key] if isinstance(key, tuple) else [b.get(key)]
            cells.append("—" if any(v is None for v in vals) else fmt.format(*vals))
        lines.append(f"| **{r.name}** | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _route_color(name: str) -> tuple[int, int, int]:
    return scout_color(name) if any(ch.isdigit() for ch in name) else _PLANNED


def log_plan(
    rec: rr.RecordingStream, grid: LayerGrid, costs: CostMap, routes: Sequence[Route], sim_time: float = 0.0
) -> None:
    """Log the cost grid, every route and the breakdown table to `rec` at `sim_time` [s]."""
    rec.set_time(TIMELINE, duration=sim_time)
    img = np.ascontiguousarray(cost_image(costs)[::-1])
    xa, ya, _, _ = grid.bounds_m()
    fmt = rr.components.ImageFormat(width=grid.w, height=grid.h, color_model="RGBA", channel_datatype="U8")
    rec.log(
        "map/cost",
        rr.GridMap(
            data=img.tobytes(), format=fmt, cell_size=grid.res, translation=[xa, ya, 0.0], opacity=0.95
        ),
    )  # < 1: alpha blended (see map_server.viz)
    for route in routes:
        rec.log(
            f"plans/{route.name}/path",
            rr.LineStrips3D(
                [drape(grid, route)],
                radii=grid.res * 0.12,
                labels=[route.name],
                colors=[_route_color(route.name)],
            ),
        )
    rec.log("plans/breakdown", rr.TextDocument(breakdown_markdown(routes), media_type=rr.MediaType.MARKDOWN))
