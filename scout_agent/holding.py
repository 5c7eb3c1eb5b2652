"""Publish after correcting: a scout holds what it maps until the next pose fix, and the fix's correction is
spread back over the held track before anything leaves.

Between two fixes a scout's height (and place) drifts; a fix corrects the estimate *now*, and without this
module every cell published before it kept the drift. `HeldSamples` sits between the estimators' per-tick
record (`estimators.record`) and the `CellAccumulator` that turns samples into deltas: it keeps each tick's
samples with the tick's filter variances and distance walked, and

- at a pose fix (`PoseFix`: the change of the estimate a localizer update made and the filter's variance just
  before and after it) moves every held sample by the part of the correction that belongs to its tick. The
  back-correction is the Rauch–Tung–Striebel smoother of a random walk, per axis: the error at a tick t before
  the fix at T has covariance P(t) with the error at T, so the smoothed correction is Δ·P(t)/P⁻(T) and the
  smoothed variance P(t) − (P(t)/P⁻(T))²·(P⁻(T) − P⁺(T)). A tick just before the fix takes (almost) all of
  it, the launch's datum error (in P from the start) its share, drift grown since the last fix none of the
  previous one's. Then everything held is released, corrected;
- a fix that states its datum along the walk (`PoseFix.height_profile`) sets each held foothold's height to
  where that datum puts it (its height as placed, plus every correction since, plus the datum at its distance
  walked): the whole-walk DEM fix revises the older part of the walk too, which the smoother's gain, built
  for a fix that only adds the newest evidence, would leave as the previous fix had it; and sets each held
  foothold's vertical σ to that datum's posterior σ there (`PoseFix.height_profile_var`: hindsight, with the
  walk's evidence on both sides; replayed on three recorded 100 m walks it is 0.08–0.15 m where the footholds
  err 0.05–0.08 m RMS, against the filter's 0.16–0.26 m stated before; docs/results.md, "Honest heights"). Such a fix releases only
  what is `hold_m` behind (`mapping.Mapper.fix`), so the next one revises the rest with more of the walk behind it;
- releases samples older than `hold_m` walked without a fix as they are (the localizer refused or was not
  due), and everything when the mapper closes.

Samples leave in the chunks they were gathered in (one per delta period), so the mapper sends as many
deltas as without holding, each stamped with its newest sample's time.

Released footholds become the `elevation` layer's moments (computed from the corrected heights), the
`placement` layer's horizontal σ and the `height` layer's vertical σ (both the smoothed ones). Samples leave
the scout only through the mapper's deltas, so exactly-once delivery and the outbox are untouched; what is
held is not yet in any delta (a scout that dies loses at most its held samples, as it loses the statistics
of its last 0.2 s without holding).
"""

from __future__ import annotations

import math
from bisect import bisect_left
from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from protocol.layers import LAYERS, cell_center, cell_index
from scout_agent.cells import CellAccumulator
from scout_agent.errors import ScoutConfigError

__all__ = ["HEIGHT_FLOOR_M", "HoldConfig", "HeldSamples", "PoseFix", "height_rows"]

# a foothold's height is never known better than the foot's sinkage and the regolith under it [m]
HEIGHT_FLOOR_M = 0.02


@dataclass(frozen=True)
class HoldConfig:
    """hold_m: a sample waits for a pose fix at most this far walked (the estimate's horizontal path) [m];
    0 publishes at once, as before. A fix that adds only the newest evidence releases everything held; a
    whole-walk DEM fix (`PoseFix.height_profile`, every 25 m from 30 m) only what is hold_m behind, so each
    foothold is revised by two or three of them: 60 m (the 100 m mission, seed 33: scout3's own map 0.127 ->
    0.094 m on the same walk against one revision; docs/results.md, "The map's heights from the whole walk")."""

    hold_m: float = 60.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.hold_m) and self.hold_m >= 0):
            raise ScoutConfigError(f"hold_m = {self.hold_m}: need a finite distance ≥ 0 [m]")


class PoseFix(NamedTuple):
    """A pose correction a localizer fused into the estimate: the change of the base position (x, y, z) [m]
    and the filter's variance of x, y, z just before and just after it [m²] (x, y: the larger axis); with
    `height_profile`, the fix's datum along the walk behind it (distance walked before now, ≤ 0 [m] -> the
    reference's height minus the estimate's there [m], in the frame before the correction): a fix from the
    whole walk (localization/height_track.py) revises the heights it already corrected, the launch's too."""

    correction: np.ndarray  # (3,)
    var_before: np.ndarray  # (3,) as (xy, xy, z)
    var_after: np.ndarray  # (3,)
    height_profile: Callable[[np.ndarray], np.ndarray] | None = None
    # with `height_profile`: its posterior variance along the walk (same argument) [m²], which becomes the held
    # footholds' vertical variance (the `height` layer's σ): a foothold with the walk's evidence on both sides
    # knows its datum better than the filter knew its height when it stood there or when the fix came
    height_profile_var: Callable[[np.ndarray], np.ndarray] | None = None


def height_rows(
    x: np.ndarray,
    y: np.ndarray,
    z: np.ndarray,
    sigma_z: np.ndarray,
    res: float,
    x0: float = 0.0,
    y0: float = 0.0,
) -> np.ndarray:
    """The `height` layer's per-foothold rows (x, y, *stats in `LAYERS["height"].stats` order): weight
    1/σ² (σ floored at `HEIGHT_FLOOR_M`), weighted plane-fit moments relative to the cell centre."""
    s = np.maximum(np.asarray(sigma_z, dtype=float), HEIGHT_FLOOR_M)
    w = 1.0 / (s * s)
    ix, iy = cell_index(x, y, res, x0, y0)
    cx, cy = cell_center(ix, iy, res, x0, y0)
    dx, dy = x - cx, y - cy
    one = np.ones_like(w)
    cols = (x, y, one, w, w * z, w * dx, w * dy, w * dx * dx, w * dy * dy, w * dx * dy, w * dx * z, w * dy * z,
            s * s, s)  # fmt: skip
    return np.stack(cols, axis=1)


def elevation_rows(
    x: np.ndarray, y: np.ndarray, z: np.ndarray, res: float, x0: float = 0.0, y0: float = 0.0
) -> np.ndarray:
    """The `elevation` layer's rows for footholds (as `CellAccumulator.add_elevation`, vectorised)."""
    ix, iy = cell_index(x, y, res, x0, y0)
    cx, cy = cell_center(ix, iy, res, x0, y0)
    dx, dy = x - cx, y - cy
    one = np.ones_like(z)
    return np.stack((x, y, one, z, z * z, dx, dy, dx * dx, dy * dy, dx * dy, dx * z, dy * z, z, z), axis=1)


class HeldSamples:
    """Duck-types the `CellAccumulator` methods `estimators.record` calls (`append`, `add_elevation`) and
    holds each tick's samples (`tick` first) until a fix corrects them or they are `hold_m` old.

    Samples are held in chunks, one per delta period (`cut`), and leave chunk by chunk (`chunks`), so the
    mapper sends as many deltas, each as large, as it would without holding, only later."""

    def __init__(self, acc: CellAccumulator, config: HoldConfig = HoldConfig()) -> None:
        self.acc = acc
        self.config = config
        # per tick: walked [m], var_xy, var_z [m²] (smoothed in place by each fix); NaN variance = unknown
        self._ticks: list[tuple[float, float, float]] = []
        self.dz_total = 0.0  # the height corrections of every fix so far [m]
        self._tick0 = 0  # absolute index of `_ticks[0]`
        self._chunks: list[tuple[int, float, float]] = []  # (end tick, exclusive; newest t [s]; walked there)
        self._rows: dict[str, list[tuple[float, ...]]] = {name: [] for name in LAYERS}  # (tick, x, y, *stats)
        # (tick, x, y, z, z as placed less the height corrections before it: its height in no fix's frame)
        self._feet: list[tuple[float, ...]] = []
        self._prev_xy: tuple[float, float] | None = None
        self._t = 0.0
        self.walked_m = 0.0
        self.fixes = 0  # fixes that found samples to correct
        self.corrected = 0  # footholds moved by a fix before they left
        # per fix: (its height correction [m], the filter's height σ before and after it [m]), for the summary
        self.fix_log: list[tuple[float, float, float]] = []

    # ------------------------------------------------------------------------------- what record() calls
    def tick(self, t: float, x: float, y: float, var_xy: float | None, var_z: float | None) -> None:
        """A new tick at time t [s] and the estimate's (x, y) [m], with the filter's horizontal (larger axis)
        and vertical position variance [m²] (None: unknown, e.g. on the exact state: its footholds carry no
        σ layers)."""
        if self._prev_xy is not None:
            self.walked_m += math.hypot(x - self._prev_xy[0], y - self._prev_xy[1])
        self._prev_xy = (x, y)
        self._t = t
        nan = math.nan
        self._ticks.append(
            (self.walked_m, nan if var_xy is None else float(var_xy), nan if var_z is None else float(var_z))
        )

    def append(self, layer: str, row: tuple[float, ...]) -> None:
        self._rows[layer].append((self._tick0 + len(self._ticks) - 1, *row))

    def add_elevation(self, x: float, y: float, z: float) -> None:
        self._feet.append((self._tick0 + len(self._ticks) - 1, x, y, z, z - self.dz_total))

    @property
    def pending(self) -> int:
        """Samples held."""
        return len(self._feet) + sum(len(r) for r in self._rows.values())

    # ------------------------------------------------------------------------------------------- chunks
    def cut(self) -> None:
        """End the current chunk (a delta period) at the last tick; nothing happens without new ticks."""
        end = self._tick0 + len(self._ticks)
        if end > (self._chunks[-1][0] if self._chunks else self._tick0):
            self._chunks.append((end, self._t, self.walked_m))

    def due(self):
        """`chunks` of the ticks `hold_m` or more behind (none while the oldest chunk is younger)."""
        if self._chunks and self._chunks[0][2] <= self.walked_m - self.config.hold_m:
            yield from self.chunks(self.walked_m - self.config.hold_m)

    def chunks(self, upto_walked_m: float = math.inf):
        """Yield each releasable chunk's newest time [s] after its samples went into the accumulator (the
        caller flushes one delta per chunk before asking for the next); all chunks by default, the current
        one cut first. Ticks no held sample needs any more are forgotten."""
        if upto_walked_m == math.inf:
            self.cut()
        while self._chunks and self._chunks[0][2] <= upto_walked_m:
            end, t, _ = self._chunks.pop(0)
            for name, rows in self._rows.items():
                k = _split(rows, end)
                if k:
                    for r in rows[:k]:
                        self.acc.append(name, r[1:])
                    del rows[:k]
            k = _split(self._feet, end)
            if k:
                self._release_feet(np.asarray(self._feet[:k], dtype=float))
                del self._feet[:k]
            del self._ticks[: end - self._tick0]
            self._tick0 = end
            yield t

    # ---------------------------------------------------------------------------------------------- fix
    def correct(self, fix: PoseFix) -> None:
        """Spread `fix` back over the held samples (module docstring); the caller then releases them."""
        before = np.asarray(fix.var_before, dtype=float)
        after = np.asarray(fix.var_after, dtype=float)
        self.fix_log.append(
            (
                float(fix.correction[2]),
                float(np.sqrt(max(before[2], 0.0))),
                float(np.sqrt(max(after[2], 0.0))),
            )
        )
        dz_before = self.dz_total
        self.dz_total += float(fix.correction[2])
        if not self._ticks:
            return
        self.fixes += 1
        t = np.asarray(self._ticks, dtype=float)  # (k, 3)
        gain = np.zeros((len(t), 3))
        for col, axes in ((1, (0, 1)), (2, (2,))):  # var_xy moves x and y, var_z moves z
            b = before[axes[0]]
            if b > 0:
                g = np.clip(np.nan_to_num(t[:, col] / b, nan=1.0), 0.0, 1.0)
                gain[:, axes] = g[:, None]
                t[:, col] = np.maximum(t[:, col] - g * g * max(b - after[axes[0]], 0.0), 0.0)
        if fix.height_profile is not None and fix.height_profile_var is not None:
            t[:, 2] = fix.height_profile_var(t[:, 0] - self.walked_m)
        self._ticks = [(float(a), float(b), float(c)) for a, b, c in t.tolist()]
        shift = gain * np.asarray(fix.correction, dtype=float)  # (k, 3) per tick
        if self._feet:
            f = np.asarray(self._feet, dtype=float)
            rel = f[:, 0].astype(np.int64) - self._tick0
            f[:, 1:4] += shift[rel]
            if fix.height_profile is not None:  # where the whole walk's datum puts each, before this fix
                f[:, 3] = f[:, 4] + dz_before + fix.height_profile(t[rel, 0] - self.walked_m)
            self._feet = [(int(r[0]), *r[1:]) for r in f.tolist()]
            self.corrected += len(f)
        for name, rows in self._rows.items():
            if rows:
                r = np.asarray(rows, dtype=float)
                r[:, 1:3] += shift[r[:, 0].astype(np.int64) - self._tick0, :2]
                self._rows[name] = [(int(v[0]), *v[1:]) for v in r.tolist()]

    def _release_feet(self, f: np.ndarray) -> None:
        """Footholds (m, 4) (tick, x, y, z) into the elevation layer, and with their smoothed σ into the
        placement and height layers."""
        acc = self.acc
        x, y, z = f[:, 1], f[:, 2], f[:, 3]
        for row in elevation_rows(x, y, z, acc.res, acc.x0, acc.y0).tolist():
            acc.append("elevation", tuple(row))
        var = np.asarray([self._ticks[int(k) - self._tick0][1:] for k in f[:, 0]], dtype=float)  # (m, 2)
        known = np.isfinite(var).all(axis=1)
        if not known.any():
            return
        s_xy = np.sqrt(var[known, 0])
        for fx, fy, s in zip(x[known].tolist(), y[known].tolist(), s_xy.tolist(), strict=True):
            acc.append("placement", (fx, fy, 1.0, s * s, s))  # n, var, max
        rows = height_rows(x[known], y[known], z[known], np.sqrt(var[known, 1]), acc.res, acc.x0, acc.y0)
        for row in rows.tolist():
            acc.append("height", tuple(row))


def _split(rows: list, end: int) -> int:
    """How many of `rows` (in tick order, the tick first) belong to ticks before `end`."""
    return bisect_left(rows, end, key=lambda r: r[0])
