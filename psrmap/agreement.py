"""How far the scouts' own maps disagree where they overlap: each scout maps elevation in its own estimated
frame, so where two scouts stood on the same cell the difference of their elevations is the relative drift of
their state estimates (plus the cell's real roughness), measured without any ground truth."""

from __future__ import annotations

from itertools import combinations
from pathlib import Path
from typing import Any

import numpy as np

from mapcore import read_npz
from protocol.layers import layer_value


def _elevation_by_cell(path: Path) -> dict[tuple[int, int], float]:
    grid = read_npz(path)
    elev = grid.layers.get("elevation")
    if elev is None:
        return {}
    n = elev["n"]
    ok = n > 0
    values = layer_value("elevation", elev)
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


__all__ = ["elevation_agreement"]
