"""Statistics a real set of samples could have, and magnitudes whose sums stay finite (wire contract v1).

A delta's statistics are sums over samples; the server adds them. Two kinds of cells are rejected here:

- `stat_range`: a statistic with |value| > `MAX_STAT` (1e30). The server merges at most 2**63 deltas, so any
  stored total stays below 1e30 × 2**63 ≈ 1e49 and every product the readers form (plane-fit determinants:
  a product of three moments ≈ 1e147) is finite: no stored statistic and no derived value can overflow,
  whatever the order of arrival. (Physical statistics are far below: 10⁹ footholds of 10³ m give Σz² = 10¹⁵.)
- `inconsistent`: statistics no set of real samples has, beyond rounding:
  * the moment matrix of (1, x, y, z) is positive semi-definite (`n`, `sum`, `sumsq` alone: sumsq ≥ sum²/n,
    a variance ≥ 0; with the plane-fit sums `sx sy sxx syy sxy sxz syz` the whole 4×4 Gram matrix, which also
    forbids sxy² > sxx·syy and a `sum` with n = 0);
  * where n > 0: min ≤ max, and min ≤ mean (= sum/n) ≤ max for the stats a layer has;
  * the `height` layer (weighted moments): the weighted moment matrix of (1, x, y) positive semi-definite; where
    n > 0, w > 0 and 0 < min_sigma with n·min_sigma² ≤ var and w ≤ n / min_sigma² (every σ at least the
    smallest); where n = 0, every sum 0.
  Rounding: the matrix is scaled to unit diagonal and may have eigenvalues down to -k·`GRAM_TOL`; the mean may
  leave [min, max] by `GRAM_TOL` of its scale.

`bad_cells(layer, block)` flags cells (vectorised over a batch), `check_consistent` raises the ProtocolError
of the first problem with a message naming it.
"""

from __future__ import annotations

import numpy as np

from protocol.errors import ProtocolError
from protocol.layers import Layer

__all__ = ["GRAM_TOL", "MAX_STAT", "bad_cells", "check_consistent"]

MAX_STAT = 1e30  # |statistic| of a cell of one delta
GRAM_TOL = 1e-9  # relative rounding allowance of the consistency checks

_PLANE = ("n", "sx", "sy", "sum", "sxx", "sxy", "sxz", "syy", "syz", "sumsq")
# (row, col) of each stat of _PLANE in the Gram matrix of (1, x, y, z)
_PLANE_AT = {
    "n": (0, 0), "sx": (0, 1), "sy": (0, 2), "sum": (0, 3), "sxx": (1, 1), "sxy": (1, 2), "sxz": (1, 3),
    "syy": (2, 2), "syz": (2, 3), "sumsq": (3, 3),
}  # fmt: skip
_MOMENTS = ("n", "sum", "sumsq")
# the height layer's weights: the moment matrix of (1, x, y) weighted by 1/σ² (it carries no Σw·z²)
_WEIGHTED_AT = {"w": (0, 0), "wx": (0, 1), "wy": (0, 2), "wxx": (1, 1), "wxy": (1, 2), "wyy": (2, 2)}
_WEIGHTED_SUMS = ("w", "wz", "wx", "wy", "wxx", "wyy", "wxy", "wxz", "wyz", "var")


def _gram(layer: Layer, block: np.ndarray) -> list[list[np.ndarray]] | None:
    """The cells' moment matrices as a k×k nested list of (N,) arrays (entry [r][c] is shared with [c][r]
    until the elimination writes it), or None when the layer has no moment statistics."""
    idx = {s: r for r, s in enumerate(layer.stats)}
    if all(s in idx for s in _WEIGHTED_AT):
        w: list[list[np.ndarray]] = [[block[idx["w"]]] * 3 for _ in range(3)]
        for s, (r, c) in _WEIGHTED_AT.items():
            w[r][c] = w[c][r] = block[idx[s]]
        return w
    if all(s in idx for s in _PLANE):
        g: list[list[np.ndarray]] = [[block[0]] * 4 for _ in range(4)]
        for s, (r, c) in _PLANE_AT.items():
            g[r][c] = g[c][r] = block[idx[s]]
        return g
    if all(s in idx for s in _MOMENTS):
        n, s1, s2 = (block[idx[s]] for s in _MOMENTS)
        return [[n, s1], [s1, s2]]
    return None


def _not_psd(g: list[list[np.ndarray]]) -> np.ndarray:
    """Cells whose matrix is not positive semi-definite beyond rounding: the matrix scaled to unit diagonal
    (a zero diagonal entry is left unscaled: its row must then be zero), then its smallest eigenvalue
    (`numpy.linalg.eigvalsh`, batched over cells) below -GRAM_TOL. Eigenvalues of a symmetric matrix move by
    at most the rounding of its entries (≈ 1e-16 here), whatever its rank: two footholds at the same x make an
    exactly singular moment matrix that an elimination with a tiny pivot would amplify into a false rejection."""
    k = len(g)
    m = np.stack([np.stack(row, axis=-1) for row in g], axis=-2)  # (N, k, k)
    d = np.diagonal(m, axis1=-2, axis2=-1)
    bad = (d < 0).any(axis=-1)
    inv = 1.0 / np.sqrt(np.where(d > 0, d, 1.0))
    scaled = m * inv[:, :, None] * inv[:, None, :]
    if not np.isfinite(scaled).all():
        bad |= ~np.isfinite(scaled).reshape(len(scaled), -1).all(axis=1)
        scaled = np.where(np.isfinite(scaled), scaled, 0.0)
    bad |= np.linalg.eigvalsh(scaled)[:, 0] < -GRAM_TOL * k
    return bad


def bad_cells(layer: Layer, block: np.ndarray) -> dict[str, np.ndarray]:
    """Per problem (`stat_range`, `inconsistent`), a bool mask of the cells of `block` ((S, N) finite
    statistics in `layer.stats` order) that have it; empty when every cell is fine."""
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        return _bad_cells(layer, block)


def _bad_cells(layer: Layer, block: np.ndarray) -> dict[str, np.ndarray]:
    out: dict[str, np.ndarray] = {}
    if not block.size:
        return out
    big = np.abs(block).max(axis=0) > MAX_STAT
    if big.any():
        out["stat_range"] = big
        block = np.where(big, 0.0, block)  # judge the rest of the cells on their own
    bad = np.zeros(block.shape[1], bool)
    g = _gram(layer, block)
    if g is not None:
        bad |= _not_psd(g)
    idx = {s: r for r, s in enumerate(layer.stats)}
    if "n" in idx and ("min" in idx or "max" in idx):
        n = block[idx["n"]]
        pos = n > 0
        lo = block[idx["min"]] if "min" in idx else None
        hi = block[idx["max"]] if "max" in idx else None
        if lo is not None and hi is not None:
            bad |= pos & (lo > hi + GRAM_TOL * np.maximum(np.abs(lo), np.abs(hi)))
        if "sum" in idx:
            mean = block[idx["sum"]] / np.where(pos, n, 1.0)
            tol = GRAM_TOL * np.maximum(1.0, np.abs(mean))
            if lo is not None:
                bad |= pos & (mean < lo - tol)
            if hi is not None:
                bad |= pos & (mean > hi + tol)
    if "min_sigma" in idx and all(s in idx for s in _WEIGHTED_SUMS):
        bad |= _bad_sigmas(block, idx)
    if bad.any():
        out["inconsistent"] = bad
    return out


def _bad_sigmas(block: np.ndarray, idx: dict[str, int]) -> np.ndarray:
    """The height layer's cells whose σ statistics no set of footholds has (module docstring)."""
    n, w, var, smin = (block[idx[s]] for s in ("n", "w", "var", "min_sigma"))
    pos = n > 0
    tol = 1.0 + GRAM_TOL
    floor2 = np.where(pos & (smin > 0), smin * smin, 1.0)
    bad = pos & ~((w > 0) & (smin > 0) & (n * floor2 <= var * tol) & (w * floor2 <= n * tol))
    sums = np.stack([block[idx[s]] for s in _WEIGHTED_SUMS])
    return bad | (~pos & (sums != 0).any(axis=0))


def check_consistent(where: str, layer: Layer, block: np.ndarray) -> None:
    """Raise the ProtocolError of the first problem `bad_cells` finds (stat_range before inconsistent)."""
    got = bad_cells(layer, block)
    if "stat_range" in got:
        k = int(np.flatnonzero(got["stat_range"])[0])
        stats = [s for s, v in zip(layer.stats, block[:, k], strict=True) if abs(v) > MAX_STAT]
        raise ProtocolError(
            "stat_range",
            f"{where} cell {k}: {', '.join(f'{s}={block[layer.stats.index(s), k]:g}' for s in stats)}; "
            f"every statistic must be within ±{MAX_STAT:g} (so stored sums stay finite)",
        )
    if "inconsistent" in got:
        k = int(np.flatnonzero(got["inconsistent"])[0])
        vals = ", ".join(f"{s}={v:g}" for s, v in zip(layer.stats, block[:, k], strict=True))
        raise ProtocolError(
            "inconsistent",
            f"{where} cell {k} ({vals}): no set of samples has these statistics (need sumsq ≥ sum²/n, the "
            "moment matrix of (1, x, y, z) positive semi-definite, min ≤ sum/n ≤ max; height: σ > 0, "
            "n·min_sigma² ≤ var, w ≤ n/min_sigma², all sums 0 where n = 0)",
        )
