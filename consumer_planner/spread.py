"""Slip spreading: each cell reads the largest measured value within a radius (a grey dilation over a disc)."""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

__all__ = ["spread_cells", "spread_finite", "spread_max"]


def spread_max(values: np.ndarray, radius_m: float, res: float) -> np.ndarray:
    """Per cell, the largest finite value among the cells whose centres lie within `radius_m` of its
    centre (itself included; a grey dilation over a disc of cells); NaN where none is finite."""
    if spread_cells(radius_m, res) < 1:
        return values.copy()
    return spread_finite(values, np.isfinite(values), radius_m, res)


def spread_cells(radius_m: float, res: float) -> int:
    return int(math.floor(radius_m / res + 1e-9))


def spread_finite(values: np.ndarray, finite: np.ndarray, radius_m: float, res: float) -> np.ndarray:
    """`spread_max` of `values` where `finite` (a radius of >= 1 cell); a new array."""
    r = spread_cells(radius_m, res)
    yy, xx = np.mgrid[-r : r + 1, -r : r + 1]
    disc = (xx**2 + yy**2) * res**2 <= radius_m**2 + 1e-9 * res**2
    lifted = np.where(finite, values, -np.inf)
    out = ndimage.maximum_filter(lifted, footprint=disc, mode="constant", cval=-np.inf)
    out[out == -np.inf] = np.nan  # nothing finite in reach (`lifted` holds no +inf or NaN)
    return out
