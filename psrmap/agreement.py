"""How far the scouts' own maps disagree where they overlap: each scout maps elevation in its own estimated
frame, so where two scouts stood on the same cell the difference of their elevations is the relative drift of
their state estimates (plus the cell's real roughness), measured without any ground truth."""

from __future__ import annotations

from itertools import combinations
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from protocol.layers import LAYERS, map_height
from psrmap_mapcore import LayerGrid, read_npz

if TYPE_CHECKING:  # the terrain type only: scout_agent.sim is not imported to score a map
    from scout_agent.sim.terrain import Terrain


def grid_height(grid: LayerGrid) -> np.ndarray | None:
    """The map's height per cell (`protocol.layers.map_height`: σ-weighted where the footholds stated their
    vertical σ, else the elevation layer's value); None without an elevation layer. From raw statistics where
    the grid has them, else the elevation layer's `value`."""
    if "elevation" not in grid.layers:
        return None
    raw = {k: grid.layers[k] for k in ("elevation", "height") if _has_raw(grid, k)}
    if "elevation" not in raw:  # a reply with values only: the elevation layer's value
        return grid.value("elevation")
    return map_height(raw)


def _has_raw(grid: LayerGrid, layer: str) -> bool:
    """The grid holds the statistics the layer's height fit reads (its sums; extremes and σ sums aside)."""
    stats = grid.layers.get(layer)
    need = [s for s in LAYERS[layer].stats if s not in ("min", "max", "min_sigma", "var")]
    return stats is not None and all(s in stats for s in need)


def _elevation_by_cell(path: Path) -> dict[tuple[int, int], float]:
    grid = read_npz(path)
    values = grid_height(grid)
    if values is None:
        return {}
    ok = grid.layers["elevation"]["n"] > 0
    ix0, iy0, w = grid.ix0, grid.iy0, grid.w
    idx = np.flatnonzero(ok.ravel() & np.isfinite(values.ravel()))
    return {(ix0 + int(k % w), iy0 + int(k // w)): float(values.ravel()[k]) for k in idx}


def elevation_agreement(local_maps: dict[str, Path], min_cells: int = 3) -> dict[str, Any]:
    """Per pair of scouts whose local maps (`--save-map` .npz) share ≥ `min_cells` elevation cells: the number of
    shared cells, the mean difference (first − second) and the RMS difference [m]."""
    cells = {sid: _elevation_by_cell(p) for sid, p in local_maps.items() if Path(p).is_file()}
    out: dict[str, Any] = {}
    for a, b in combinations(sorted(cells), 2):
        shared = cells[a].keys() & cells[b].keys()
        if len(shared) < min_cells:
            continue
        d = np.array([cells[a][k] - cells[b][k] for k in shared])
        out[f"{a}-{b}"] = {
            "cells": len(shared),
            "mean_diff_m": round(float(d.mean()), 4),
            "rms_diff_m": round(float(np.sqrt(np.mean(d**2))), 4),
        }
    return out


def cross_scout_rms(agreement: dict[str, Any]) -> float | None:
    """`map_cross_scout_rms_m`: the scouts' own maps' elevation disagreement, RMS over every shared cell of
    every pair (the pairs of `elevation_agreement` pooled by their cell counts); None without overlap."""
    cells = sum(p["cells"] for p in agreement.values())
    if not cells:
        return None
    return round(
        float(np.sqrt(sum(p["cells"] * p["rms_diff_m"] ** 2 for p in agreement.values()) / cells)), 4
    )


def map_elevation_rmse(grid: LayerGrid, terrain: Terrain) -> tuple[float | None, int]:
    """`map_elevation_rmse_m`: the map's height (`grid_height`: the plane-fit height at each cell's centre,
    weighted by the footholds' vertical σ where they stated it) against the exact terrain height there, RMS
    over the cells with data; and that cell count. `grid`: a `mapcore.LayerGrid` of the map with raw
    statistics (a region reply with `stats=all`, a saved map); `terrain`: the mission's
    `scout_agent.sim.terrain.Terrain`."""
    elev = grid.layers.get("elevation")
    values = grid_height(grid)
    if elev is None or values is None:
        return None, 0
    ok = (np.nan_to_num(elev["n"]) > 0) & np.isfinite(values)
    if not ok.any():
        return None, 0
    iy, ix = np.nonzero(ok)
    cx = grid.x0 + (grid.ix0 + ix + 0.5) * grid.res
    cy = grid.y0 + (grid.iy0 + iy + 0.5) * grid.res
    err = values[iy, ix] - terrain.height(cx, cy)
    return round(float(np.sqrt(np.mean(err**2))), 4), int(ok.sum())


__all__ = ["cross_scout_rms", "elevation_agreement", "grid_height", "map_elevation_rmse"]
