"""Paper eq. 17: a metric at a cell with no estimate, from a Gaussian-weighted average of nearby known cells.

    value(cell) = sum_uv m_uv S_uv N(.) / sum_uv m_uv N(.)    (m: 1 where known, sigma in cells, cut at 3 sigma)

computed only on the bounding box of the cells that need a value, widened by the kernel radius — bit for bit
what the full-grid filter gives there (tests/consumer_planner/test_build_costs_reference.py).
"""

from __future__ import annotations

from concurrent.futures import Future
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

__all__ = ["MIN_WEIGHT", "FillBox", "fill_box", "fill_into", "kernel_radius", "smoothed_mask"]


MIN_WEIGHT = 1e-12  # a cell is filled only where the known cells' Gaussian weight exceeds this


def _smooth(a: np.ndarray, sigma_cells: float, in_place: bool = False) -> np.ndarray:
    """The Gaussian of eq. 17 (cut at 3 sigma, 0 beyond the grid); `in_place`: into `a` (float64),
    as scipy filters each axis line by line from a buffered copy of the line."""
    return ndimage.gaussian_filter(
        a, sigma=sigma_cells, output=a if in_place else None, mode="constant", cval=0.0, truncate=3.0
    )


def smoothed_mask(mask: np.ndarray, sigma_cells: float) -> np.ndarray:
    return _smooth(mask.astype(np.float64), sigma_cells, in_place=True)


def kernel_radius(sigma_cells: float) -> int:
    """Cells `_smooth` reaches from a cell (scipy's kernel radius at truncate=3; 0 where it does not
    filter: scipy skips sigma <= 1e-15)."""
    s = float(sigma_cells)
    return int(3.0 * s + 0.5) if s > 1e-15 else 0


@dataclass(frozen=True)
class FillBox:
    """The bounding box `inner` of the cells to fill, `outer` = it widened by the kernel radius (the
    cells `_smooth` reads for them), `rel` = `inner` within `outer` (all (rows, cols) slices)."""

    inner: tuple[slice, slice]
    outer: tuple[slice, slice]
    rel: tuple[slice, slice]


def fill_box(target: np.ndarray, radius: int) -> FillBox | None:
    rows = np.flatnonzero(target.any(axis=1))
    if rows.size == 0:
        return None
    r0, r1 = int(rows[0]), int(rows[-1]) + 1
    cols = np.flatnonzero(target[r0:r1].any(axis=0))
    c0, c1 = int(cols[0]), int(cols[-1]) + 1
    h, w = target.shape
    o_r0, o_c0 = max(0, r0 - radius), max(0, c0 - radius)
    o_r1, o_c1 = min(h, r1 + radius), min(w, c1 + radius)
    return FillBox(
        inner=(slice(r0, r1), slice(c0, c1)),
        outer=(slice(o_r0, o_r1), slice(o_c0, o_c1)),
        rel=(slice(r0 - o_r0, r1 - o_r0), slice(c0 - o_c0, c1 - o_c0)),
    )


def fill_into(
    out: np.ndarray, mask: np.ndarray, target: np.ndarray, box: FillBox, den: Future, sigma_cells: float
) -> None:
    """Eq. 17 into `out` (in place) on the `target` cells of `box` whose known weight is > 0: `mask`
    (the finite cells, cropped to `box.outer`) weights the values of `out`; `den` = `_smooth(mask)`.

    `_smooth` over `box.outer` gives, on `box.inner`, bit for bit what it gives there over the whole
    grid: each output cell reads only cells within the kernel radius (in `outer`, or beyond the grid's
    edge where both see the constant 0), in the same order."""
    num = _smooth(np.where(mask, out[box.outer], 0.0), sigma_cells, in_place=True)[box.rel]
    weight = den.result()[box.rel]
    reach = target[box.inner] & (weight > MIN_WEIGHT)
    np.divide(num, weight, out=out[box.inner], where=reach)
