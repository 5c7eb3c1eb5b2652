"""Rerun logging of the cost grid and routes (the only module of consumer_planner that imports rerun).

Entities: `map/cost` (GridMap, 8-bit: 0 = cheapest passable cell, 254 = dearest, 255 = impassable),
`plans/<name>/path` (the route at z = 0 in the map frame) and `plans/<name>/breakdown` (its figures as
a JSON text document). One explicit `rr.RecordingStream` is passed in; the global one is never used.
"""

from __future__ import annotations

import json
from collections.abc import Sequence

import numpy as np
import rerun as rr

from consumer_planner.compare import Route
from consumer_planner.costs import CostMap
from consumer_planner.grid import LayerGrid
from protocol.recording import APP_ID, recording_id

__all__ = ["cost_image", "log_plan"]


def open_recording(path: str) -> rr.RecordingStream:
    """A recording saved to `path`, in the mission's recording (`PSRMAP_RECORDING_ID`) if one is set."""
    rec = rr.RecordingStream(APP_ID, recording_id=recording_id())
    rec.save(path)
    return rec


def cost_image(costs: CostMap) -> np.ndarray:
    """(h, w) uint8: passable costs scaled to 0..254, impassable 255."""
    c = costs.cost
    ok = np.isfinite(c)
    out = np.full(c.shape, 255, np.uint8)
    if ok.any():
        lo, hi = float(c[ok].min()), float(c[ok].max())
        out[ok] = np.round(254 * (c[ok] - lo) / (hi - lo if hi > lo else 1.0)).astype(np.uint8)
    return out


def log_plan(rec: rr.RecordingStream, grid: LayerGrid, costs: CostMap, routes: Sequence[Route]) -> None:
    """Log the cost grid and every route with its breakdown to `rec`."""
    img = cost_image(costs)
    xa, ya, _, _ = grid.bounds_m()
    fmt = rr.components.ImageFormat(width=grid.w, height=grid.h, color_model="L", channel_datatype="U8")
    rec.log(
        "map/cost", rr.GridMap(data=img.tobytes(), format=fmt, cell_size=grid.res, translation=[xa, ya, 0.0])
    )
    for route in routes:
        pts = np.column_stack([route.path, np.zeros(len(route.path))])
        rec.log(
            f"plans/{route.name}/path", rr.LineStrips3D([pts], radii=grid.res * 0.15, labels=[route.name])
        )
        text = json.dumps(route.breakdown.as_dict(), indent=1)
        rec.log(f"plans/{route.name}/breakdown", rr.TextDocument(text, media_type="text/markdown"))
