"""Map layers: which sufficient statistics each carries, how they merge, and how a value follows from them.

A scout sends per-cell *statistics*; the server adds them (`merge_op`); any reader turns totals into a
value with `layer_value`. All functions are vectorised over cells: every statistic is an array of the
same shape, and cells with `n == 0` give NaN.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Literal

import numpy as np

from protocol.errors import ProtocolError

__all__ = [
    "HAZARD_REASONS",
    "LAYERS",
    "MIN_COT_DIST_M",
    "MIN_PLANE_SPREAD_M",
    "Layer",
    "DATUM_CLASH_SIGMAS",
    "cell_center",
    "cell_index",
    "pack_pair",
    "unpack_pair",
    "unpack_pairs",
    "derived_names",
    "elevation_slope_deg",
    "plane_fit",
    "empty_value",
    "get_layer",
    "layer_derived",
    "layer_value",
    "datum_clash",
    "map_height",
    "map_slope_deg",
    "plane_residual_rms",
    "merge_op",
]

MergeOp = Literal["add", "min", "max"]

MIN_COT_DIST_M = 0.05  # cot is NaN where less distance than this was walked in the cell [m]
MIN_PLANE_SPREAD_M = 0.03  # plane fit along a direction needs footholds spread (std) at least this much [m]
# a cell's footholds clash (two datums) when they scatter about their plane as two groups this many σ apart would
DATUM_CLASH_SIGMAS = 3.0


@dataclass(frozen=True)
class Layer:
    """One map layer: `stats` are the sufficient statistics on the wire, in canonical order.

    `counts` are statistics that may never be negative (rejected as `negative_count`).
    """

    name: str
    stats: tuple[str, ...]
    unit: str
    doc: str
    counts: tuple[str, ...] = ("n",)


LAYERS: dict[str, Layer] = {
    layer.name: layer
    for layer in (
        Layer(
            "elevation",
            ("n", "sum", "sumsq", "sx", "sy", "sxx", "syy", "sxy", "sxz", "syz", "min", "max"),
            "m",
            "terrain height from non-slipping stance footholds; value = plane-fit height at the cell centre "
            "when the fit is well conditioned, else the mean; x, y of the fit sums are relative to the cell "
            "centre",
            counts=("n", "sumsq", "sxx", "syy"),
        ),
        Layer(
            "slip",
            ("n", "events"),
            "1",
            "slip of stance feet; n = stance phases seen, events = slip events; value = events / n",
            counts=("n", "events"),
        ),
        Layer(
            "cot",
            ("work", "dist", "n"),
            "1",
            "cost of transport; work = sum E/(m g) [m], dist = sum of distance [m]; value = work / dist, "
            f"NaN where dist < {MIN_COT_DIST_M} m",
            counts=("n", "dist"),
        ),
        Layer(
            "giim",
            ("n", "sum", "sumsq", "min"),
            "rad",
            "gravito-inertial instability margin at the CoM projection; value = mean, worst = min",
            counts=("n", "sumsq"),
        ),
        Layer(
            "giam",
            ("n", "sum", "sumsq", "min"),
            "m/s^2",
            "gravito-inertial acceleration margin at the CoM projection; value = mean, worst = min",
            counts=("n", "sumsq"),
        ),
        Layer(
            "contacts",
            ("n", "nonfoot"),
            "1",
            "non-foot body contacts at the CoM cell; n = samples, nonfoot = samples with a non-foot "
            "contact; value = nonfoot / n",
            counts=("n", "nonfoot"),
        ),
        Layer(
            "hazard",
            ("n", "slip", "margin", "contact", "attitude"),
            "1",
            "ground a scout could not hold and stopped on (its hazard reflex, contract extension of issue 24); "
            "n = hazard reports in the cell, slip / margin / contact / attitude = how many of them each "
            "trigger raised (repeated slips, GIIM or GIAM below the reflex margin, a non-foot contact, trunk "
            "attitude beyond the limit; one report may count several); value = n",
            counts=("n", "slip", "margin", "contact", "attitude"),
        ),
        Layer(
            "placement",
            ("n", "var", "max"),
            "m",
            "how well the cell's data is placed (contract extension of issue 23): per elevation foothold the "
            "scout's horizontal position uncertainty σ (the larger axis of its estimate's covariance); "
            "n = footholds, var = sum of σ² [m²], max = the largest σ [m]; value = sqrt(var / n), the RMS σ",
            counts=("n", "var"),
        ),
        Layer(
            "height",
            ("n", "w", "wz", "wx", "wy", "wxx", "wyy", "wxy", "wxz", "wyz", "var", "min_sigma"),
            "m",
            "how well the cell's height is known, and the height weighted by it (contract extension of issue "
            "23): per elevation foothold the scout's vertical σ (its filter's height σ when it placed the "
            "foothold, after any later fix it was corrected by, with a floor for the foot's sinkage); "
            "n = footholds, w = Σ 1/σ² [1/m²], wz, wx, wy, wxx, wyy, wxy, wxz, wyz = the elevation layer's plane-"
            "fit moments each weighted by 1/σ² (x, y relative to the cell centre), var = Σ σ² [m²], "
            "min_sigma = the smallest σ [m]; value = the inverse-variance weighted plane-fit height at the "
            "cell centre [m] (a well-datumed scout is not pulled toward a poorly datumed one); sigma = "
            "sqrt(var / n), the RMS σ; best = min_sigma",
            counts=("n", "w", "var", "wxx", "wyy"),
        ),
    )
}

HAZARD_REASONS = ("slip", "margin", "contact", "attitude")  # the hazard layer's per-trigger counts


def get_layer(name: str) -> Layer:
    """The layer called `name`, or ProtocolError('unknown_layer') naming the known layers."""
    layer = LAYERS.get(name)
    if layer is None:
        raise ProtocolError("unknown_layer", f"no layer {name!r}; layers: {', '.join(LAYERS)}")
    return layer


def merge_op(stat: str) -> MergeOp:
    """The generic merge rule: `min`/`min_*` by min, `max`/`max_*` by max, every other stat adds."""
    if stat == "min" or stat.startswith("min_"):
        return "min"
    if stat == "max" or stat.startswith("max_"):
        return "max"
    return "add"


def empty_value(stat: str) -> float:
    """The identity of a stat's merge: 0 for sums, +inf for min, -inf for max."""
    return {"add": 0.0, "min": np.inf, "max": -np.inf}[merge_op(stat)]


Stats = Mapping[str, np.ndarray]


def _f(stats: Stats, name: str) -> np.ndarray:
    return np.asarray(stats[name], dtype=np.float64)


def _ratio(num: np.ndarray, den: np.ndarray, ok: np.ndarray) -> np.ndarray:
    out = np.full(np.broadcast(num, den).shape, np.nan)
    np.divide(num, den, out=out, where=ok)
    return out


def plane_fit(
    stats: Stats, min_spread_m: float | None = None, count: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Least-squares plane z = z0 + gx·dx + gy·dy per cell from summed moments -> (z0, gx, gy, rank).

    dx, dy are relative to the cell centre, so z0 is the height at the centre. The gradient is fitted only
    along the principal directions of the footholds' xy spread whose standard deviation is at least
    `min_spread_m` (default `MIN_PLANE_SPREAD_M`), and set to zero across the others (a truncated
    pseudo-inverse). `rank` (0, 1, 2) says how many directions were fitted: 2 is a full plane; 1 is a cell
    crossed by one straight foot track, whose slope is then the slope *along* the track (a lower bound of the
    true slope); 0 leaves z0 = the mean height and no slope. NaN where n == 0.

    Weighted fits (the `height` layer) pass weighted moments, `n` = the sum of the weights, and `count` = the
    footholds behind them (a plane needs at least three; default: `n`).
    """
    spread = MIN_PLANE_SPREAD_M if min_spread_m is None else min_spread_m
    n = _f(stats, "n")
    empty = ~(n > 0)
    nn = np.where(empty, 1.0, n)
    mx, my, mz = _f(stats, "sx") / nn, _f(stats, "sy") / nn, _f(stats, "sum") / nn
    cxx = _f(stats, "sxx") / nn - mx * mx
    cyy = _f(stats, "syy") / nn - my * my
    cxy = _f(stats, "sxy") / nn - mx * my
    cxz = _f(stats, "sxz") / nn - mx * mz
    cyz = _f(stats, "syz") / nn - my * mz
    # closed-form eigen-decomposition of the 2×2 xy covariance (vectorised; np.linalg.eigh per cell is 8× slower)
    half_tr, half_diff = 0.5 * (cxx + cyy), 0.5 * (cxx - cyy)
    root = np.sqrt(half_diff * half_diff + cxy * cxy)
    lam_max, lam_min = half_tr + root, half_tr - root
    theta = 0.5 * np.arctan2(2.0 * cxy, cxx - cyy)  # direction of the largest spread
    vx, vy = np.cos(theta), np.sin(theta)  # unit eigenvector of lam_max; (-vy, vx) is lam_min's
    enough = (n if count is None else np.asarray(count, dtype=np.float64)) >= 3
    keep_max = enough & (lam_max >= spread**2)
    keep_min = enough & (lam_min >= spread**2)
    c_max = np.where(keep_max, (vx * cxz + vy * cyz) / np.where(keep_max, lam_max, 1.0), 0.0)
    c_min = np.where(keep_min, (-vy * cxz + vx * cyz) / np.where(keep_min, lam_min, 1.0), 0.0)
    gx = c_max * vx - c_min * vy
    gy = c_max * vy + c_min * vx
    z0 = mz - gx * mx - gy * my
    nan = np.where(empty, np.nan, 0.0)
    return z0 + nan, gx + nan, gy + nan, keep_max.astype(float) + keep_min + nan


def elevation_slope_deg(stats: Stats) -> np.ndarray:
    """Terrain slope [deg] from the plane fit of elevation stats: along the footholds' spread where they span
    one direction only (a lower bound), NaN where they span none (see `plane_fit`)."""
    return _slope_deg(*plane_fit(stats)[1:])


def _slope_deg(gx: np.ndarray, gy: np.ndarray, rank: np.ndarray) -> np.ndarray:
    with np.errstate(invalid="ignore"):
        return np.where(rank >= 1, np.degrees(np.arctan(np.hypot(gx, gy))), np.nan)


def plane_residual_rms(stats: Stats) -> np.ndarray:
    """RMS [m] of the footholds' heights about the elevation layer's plane fit (`plane_fit`), from the summed
    moments (rss / n = var(z) - g·cov(xy, z) holds for the truncated fit too); NaN where n == 0."""
    n = _f(stats, "n")
    nn = np.where(n > 0, n, 1.0)
    mx, my, mz = _f(stats, "sx") / nn, _f(stats, "sy") / nn, _f(stats, "sum") / nn
    _, gx, gy, _ = plane_fit(stats)
    rss = (
        (_f(stats, "sumsq") / nn - mz * mz)
        - gx * (_f(stats, "sxz") / nn - mx * mz)
        - gy * (_f(stats, "syz") / nn - my * mz)
    )
    return np.sqrt(np.maximum(rss, 0.0))


def _mean(stats: Stats) -> np.ndarray:
    n = _f(stats, "n")
    return _ratio(_f(stats, "sum"), n, n > 0)


def _std(stats: Stats) -> np.ndarray:
    n = _f(stats, "n")
    mean = _mean(stats)
    var = _ratio(_f(stats, "sumsq"), n, n > 0) - mean * mean
    return np.sqrt(np.maximum(var, 0.0))


def _elevation(stats: Stats) -> np.ndarray:
    return plane_fit(stats)[0]


# the height layer's weighted moments under the names `plane_fit` reads
_WEIGHTED = {"n": "w", "sum": "wz", "sx": "wx", "sy": "wy", "sxx": "wxx", "syy": "wyy", "sxy": "wxy",
             "sxz": "wxz", "syz": "wyz"}  # fmt: skip


def _weighted_fit(stats: Stats) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """`plane_fit` of the height layer's 1/σ²-weighted moments; NaN where it has no footholds or no weight."""
    n = _f(stats, "n")
    moments = {k: _f(stats, w) for k, w in _WEIGHTED.items()}
    nan = np.where((n > 0) & (moments["n"] > 0), 0.0, np.nan)
    z0, gx, gy, rank = plane_fit(moments, count=n)
    return z0 + nan, gx + nan, gy + nan, rank + nan


def _weighted_height(stats: Stats) -> np.ndarray:
    return _weighted_fit(stats)[0]


def map_height(layers: Mapping[str, Stats]) -> np.ndarray:
    """The map's height per cell from a reply's (or a map's) layers: the inverse-variance weighted fit of the
    `height` layer where the cell's footholds stated their vertical σ, else the `elevation` layer's value;
    NaN where neither has data. `layers` must hold `elevation` (and may hold `height`) with their raw
    statistics."""
    value = layer_value("elevation", layers["elevation"])
    if "height" not in layers:
        return value
    weighted = layer_value("height", layers["height"])
    return np.where(np.isfinite(weighted), weighted, value)


def map_slope_deg(layers: Mapping[str, Stats]) -> np.ndarray:
    """The map's terrain slope [deg] per cell, the same fit as `map_height`: the gradient of the height layer's
    inverse-variance weighted plane where the cell's footholds stated their vertical σ (and span a direction,
    see `plane_fit`), else the elevation layer's (`elevation_slope_deg`); NaN where neither fits a slope.
    `layers` must hold `elevation` (and may hold `height`) with their raw statistics."""
    value = elevation_slope_deg(layers["elevation"])
    if "height" not in layers:
        return value
    weighted = layer_derived("height", "slope_deg", layers["height"])
    return np.where(np.isfinite(weighted), weighted, value)


def datum_clash(layers: Mapping[str, Stats], sigmas: float = DATUM_CLASH_SIGMAS) -> np.ndarray:
    """Cells whose footholds disagree by far more than their stated vertical σ: bool per cell.

    Within one scout's datum the footholds of a cell lie on its plane to centimetres; the σ they state (the
    height layer's RMS σ) is their datum's uncertainty. Two scouts whose datums differ by d leave the footholds
    scattered about the cell's best plane by about d / 2 (RMS; less where the plane can tilt to absorb it).
    A cell clashes when that scatter `plane_residual_rms` implies two groups more than `sigmas` standard
    deviations of a difference apart: 2 · rms > sigmas · √2 · σ. Its plane (height and slope) is then not the
    terrain but a compromise between datums. False everywhere without the height layer (no σ stated)."""
    shape = np.shape(layers["elevation"]["n"])
    if "height" not in layers:
        return np.zeros(shape, dtype=bool)
    sigma = layer_derived("height", "sigma", layers["height"])
    rms = plane_residual_rms(layers["elevation"])
    with np.errstate(invalid="ignore"):
        return np.asarray(2.0 * rms > sigmas * np.sqrt(2.0) * sigma)


def _worst(stats: Stats) -> np.ndarray:
    return np.where(_f(stats, "n") > 0, _f(stats, "min"), np.nan)


_VALUE = {
    "elevation": _elevation,
    "slip": lambda s: _ratio(_f(s, "events"), _f(s, "n"), _f(s, "n") > 0),
    "cot": lambda s: _ratio(
        _f(s, "work"), _f(s, "dist"), (_f(s, "n") > 0) & (_f(s, "dist") >= MIN_COT_DIST_M)
    ),
    "giim": _mean,
    "giam": _mean,
    "contacts": lambda s: _ratio(_f(s, "nonfoot"), _f(s, "n"), _f(s, "n") > 0),
    "hazard": lambda s: np.where(_f(s, "n") > 0, _f(s, "n"), np.nan),
    "placement": lambda s: np.sqrt(_ratio(_f(s, "var"), _f(s, "n"), _f(s, "n") > 0)),
    "height": _weighted_height,
}

# Named quantities beyond `value` that a reader (or a region query) may ask for.
_DERIVED = {
    "elevation": {
        "mean": _mean,
        "std": _std,
        "slope_deg": elevation_slope_deg,
        "min": _worst,
        "max": lambda s: np.where(_f(s, "n") > 0, _f(s, "max"), np.nan),
    },
    "slip": {
        "events": lambda s: np.where(_f(s, "n") > 0, _f(s, "events"), np.nan),
        "rate": _VALUE["slip"],
    },
    "cot": {},
    "giim": {"mean": _mean, "std": _std, "worst": _worst},
    "giam": {"mean": _mean, "std": _std, "worst": _worst},
    "contacts": {
        "nonfoot": lambda s: np.where(_f(s, "n") > 0, _f(s, "nonfoot"), np.nan),
        "rate": _VALUE["contacts"],
    },
    "hazard": {
        reason: (lambda r: lambda s: np.where(_f(s, "n") > 0, _f(s, r), np.nan))(reason)
        for reason in ("slip", "margin", "contact", "attitude")
    },
    "placement": {"worst": lambda s: np.where(_f(s, "n") > 0, _f(s, "max"), np.nan)},
    "height": {
        "sigma": lambda s: np.sqrt(_ratio(_f(s, "var"), _f(s, "n"), _f(s, "n") > 0)),
        "best": lambda s: np.where(_f(s, "n") > 0, _f(s, "min_sigma"), np.nan),
        "slope_deg": lambda s: _slope_deg(*_weighted_fit(s)[1:]),
    },
}


def layer_value(layer_name: str, stats: Stats) -> np.ndarray:
    """The layer's value per cell from its merged statistics (NaN where `n == 0`).

    elevation: plane-fit height at the cell centre (`plane_fit`: along the directions the footholds span by
    at least `MIN_PLANE_SPREAD_M`; the mean height where they span none) [m];
    slip: events / n; cot: work / dist (NaN where dist < `MIN_COT_DIST_M`); giim, giam: mean;
    contacts: nonfoot / n; hazard: n (hazard reports); placement: sqrt(var / n), the RMS horizontal σ of
    the scout's position when it placed the cell's footholds [m]; height: the plane fit of the footholds
    weighted by 1/σ² of their vertical σ, at the cell centre [m].
    """
    get_layer(layer_name)
    return _VALUE[layer_name](stats)


def derived_names(layer_name: str) -> tuple[str, ...]:
    """Names accepted by `layer_derived` for this layer (besides `value`)."""
    return tuple(_DERIVED[get_layer(layer_name).name])


def layer_derived(layer_name: str, name: str, stats: Stats) -> np.ndarray:
    """A named derived quantity (e.g. `slope_deg`, `std`, `events`, `worst`, `value`); NaN where n == 0."""
    if name == "value":
        return layer_value(layer_name, stats)
    table = _DERIVED[get_layer(layer_name).name]
    if name not in table:
        valid = ", ".join(("value", *table))
        raise ProtocolError("unknown_stat", f"layer {layer_name!r} has no derived {name!r}; derived: {valid}")
    return table[name](stats)


def cell_index(x, y, res: float, x0: float = 0.0, y0: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Map-frame position(s) [m] -> signed cell indices `(ix, iy)` as int32 arrays (floor)."""
    ix = np.floor((np.asarray(x, dtype=np.float64) - x0) / res).astype(np.int32)
    iy = np.floor((np.asarray(y, dtype=np.float64) - y0) / res).astype(np.int32)
    return ix, iy


def cell_center(ix, iy, res: float, x0: float = 0.0, y0: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Cell indices -> map-frame coordinates [m] of the cell centres."""
    x = x0 + (np.asarray(ix, dtype=np.float64) + 0.5) * res
    y = y0 + (np.asarray(iy, dtype=np.float64) + 0.5) * res
    return x, y


def pack_pair(a, b):
    """Two signed 32-bit indices (cell ix, iy or tile tx, ty; ints or arrays) as one int64 key:
    (a << 32) | (b & 0xFFFFFFFF). Keys sort by a, then by b's bit pattern; `unpack_pair` inverts it."""
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return (np.asarray(a, np.int64) << 32) | (np.asarray(b, np.int64) & 0xFFFFFFFF)
    return (int(a) << 32) | (int(b) & 0xFFFFFFFF)


def unpack_pair(key: int) -> tuple[int, int]:
    """The (a, b) that `pack_pair` packed into `key`."""
    key = int(key)
    lo = key & 0xFFFFFFFF
    return key >> 32, lo - (1 << 32) if lo >= 1 << 31 else lo


def unpack_pairs(keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The (a, b) int32 arrays that `pack_pair` packed into the int64 array `keys`."""
    keys = np.asarray(keys, np.int64)
    return (keys >> 32).astype(np.int32), (keys & 0xFFFFFFFF).astype(np.uint32).astype(np.int32)
