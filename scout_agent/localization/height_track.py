"""`HeightTrack`: the estimate's height error along the whole walk, from every foothold since launch against an
orbital DEM, each DEM pixel's error counted once.

Why (docs/results.md, "The map's heights at mission scale"): leg odometry's height error on the 100 m walks is a
datum (the launch read) plus a nearly constant drift per metre walked (a calibration tilt of the legs' velocity:
0.6–0.9 cm/m, 3–4 cm RMS about that line over 120 m on seed 33), while a height fix from one 100 m track every
25 m re-reads the same DEM pixels at each fix: its errors do not average along a walk, and a rate learnt from
one track's slope locked onto that track's pixel noise. Here one least-squares problem holds all of it:

    y_j = d + c·(s_j − s_now) + W(s_j) + Σ_p w_jp·n_p + g_j·δ_k(j) + ε_j

- y_j: the DEM's height minus the estimate's, per `bin_m` of walk (the mean of its footholds; the bilinear
  weights w_jp of the DEM pixels p under them averaged the same way);
- d: the datum now (what the estimate's height lacks at the newest foothold), flat prior; c: its change per
  metre walked (minus the drift rate), prior σ `rate_sigma` (the legs' calibration: one fix cannot set it);
- W: a random walk in the distance walked, zero at the newest foothold, `walk_sigma` m/√m (the drift's
  departures from a line: the IMU's tilt error changing with temperature), knots every `knot_m`;
- n_p: each DEM pixel's own error, prior σ the DEM's stated per-pixel noise: a pixel read by a hundred
  footholds is still one measurement (the footholds are not independent, the pixels are);
- δ_k: where the estimate placed the k-th `segment_m` of footholds against where they were, prior σ the
  filter's horizontal σ when it placed them; g_j the DEM's gradient there (a misplaced foothold reads the
  DEM beside it);
- ε_j: the relief below the DEM's resolution (`DemReference.subpixel_m`), per bin. That relief (a crater a few
  metres across, a rock field) is not white from one 1 m bin to the next: it holds over about a DEM pixel,
  so the bins within `relief_corr_m` of walk see one draw of it, and each bin's variance is the relief's ×
  `relief_corr_m` / `bin_m` (the bins together weigh as many independent reads as there are correlation
  lengths in the walk). Counted per bin as white, the relief can bend the datum's random walk to follow it
  (replayed on six recorded 100 m walks the footholds' height error fell 0.068 -> 0.065 m RMS without it;
  docs/results.md, "A fleet's heights").

The posterior of (d, c) is the fix (`HeightFix`). A fix from it holds all the evidence so far, so the
localizer fuses it as a replacement of what the filter knew of its height from the DEM (localizer.py), not as
one more independent measurement. Point measurements of the datum from elsewhere (the other scouts' cells, a
height fix against the shared map) join the same problem (`add_point`), so a later DEM fix does not undo them.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import partial

import numpy as np
from scipy.linalg import cho_factor, cho_solve

from scout_agent.dem_reader import DemGrid

from .matcher import HeightFix

__all__ = ["HeightTrack", "HeightTrackConfig"]


@dataclass(frozen=True)
class HeightTrackConfig:
    bin_m: float = 1.0  # footholds averaged per this much walked [m]
    rate_sigma: float = (
        0.02  # prior σ of the height drift per metre walked [m/m] (legs' calibration, 1–3 cm/m)
    )
    walk_sigma: float = 0.01  # random walk of the drift about its line [m/√m] (seed 33: 3–4 cm over 120 m)
    knot_m: float = 10.0  # the random walk's knots [m]
    segment_m: float = 10.0  # footholds sharing one horizontal misplacement [m]
    huber_k: float = 3.0  # bins whose residual exceeds k σ are down-weighted (a slip, a fall's last steps)
    min_bins: int = 10  # fewer bins on the DEM: no fix
    # the walk over which the relief below the DEM's resolution stays one draw [m] (None: the DEM's pixel);
    # the true relief under the 100 m field's walks minus the noise-free DEM: 0.11 m per foothold, 0.07 m
    # still in 10 m means (seed 33, scout1; docs/results.md, "A fleet's heights")
    relief_corr_m: float | None = None


class HeightTrack:
    """Footholds since launch in `bin_m` bins of walk (mean position as the estimate holds it now, the
    filter's horizontal σ when placed), and point measurements of the datum; `fix` solves the module's
    problem against a DEM."""

    def __init__(self, config: HeightTrackConfig = HeightTrackConfig(), capacity: int = 512) -> None:
        self.config = config
        self._bins = np.zeros((capacity, 6))  # walked [m], n, x, y, z (means), σ_xy² [m²]
        self._n = 0
        self._points: list[list[float]] = []  # [walked, reference minus estimate, variance]
        self.rate_var = float("nan")  # the last fix's posterior variance of its rate [(m/m)²]
        # the last fix's datum along the walk behind it: distance before the newest foothold (≤ 0) [m] -> the
        # reference's height minus the estimate's there [m], in the frame the fix was computed in
        self.last_profile: Callable[[np.ndarray], np.ndarray] | None = None
        # ... and its posterior variance there [m²] (hindsight: the walk's evidence on both sides of a foothold
        # knows its datum better than the fix knew the datum at the newest one)
        self.last_profile_var: Callable[[np.ndarray], np.ndarray] | None = None

    def __len__(self) -> int:
        return self._n

    def add(self, points: np.ndarray, walked_m: float, sigma_xy_m: float) -> None:
        """Footholds (k, 3) placed at `walked_m` by an estimate of horizontal σ `sigma_xy_m`."""
        k = len(points)
        if k == 0:
            return
        b = self._bins
        if self._n and int(b[self._n - 1, 0] // self.config.bin_m) == int(walked_m // self.config.bin_m):
            row = b[self._n - 1]
            n = row[1] + k
            row[2:5] += (points.sum(0) - k * row[2:5]) / n
            row[1] = n
            row[5] = max(row[5], sigma_xy_m**2)
            return
        if self._n == len(b):
            self._bins = b = np.vstack([b, np.zeros_like(b)])
        b[self._n] = (walked_m, k, *points.mean(0), sigma_xy_m**2)
        self._n += 1

    def add_point(self, walked_m: float, dz_m: float, var_m2: float) -> None:
        """A measurement of the datum at `walked_m`: the reference's height minus the estimate's there."""
        self._points.append([walked_m, dz_m, var_m2])

    def shift(self, pivot_old: np.ndarray, pivot_new: np.ndarray, dyaw: float) -> None:
        """Move every bin as a pose correction moved the scout (`FootholdTrack.shift`); the point measurements
        of the datum change by the height correction."""
        if self._n:
            c, s = np.cos(dyaw), np.sin(dyaw)
            d = self._bins[: self._n, 2:5] - pivot_old
            self._bins[: self._n, 2] = pivot_new[0] + c * d[:, 0] - s * d[:, 1]
            self._bins[: self._n, 3] = pivot_new[1] + s * d[:, 0] + c * d[:, 1]
            self._bins[: self._n, 4] = pivot_new[2] + d[:, 2]
        for p in self._points:
            p[1] -= float(pivot_new[2] - pivot_old[2])

    def fix(self, dem: DemGrid, subpixel_m: float, walked_m: float) -> HeightFix | None:
        """The datum now and its rate along the walk (module docstring), or None with fewer than `min_bins`
        bins on the DEM."""
        got = self._solve(dem, subpixel_m, walked_m)
        if got is None:
            return None
        theta, cov, m, (knot_m, n_knots) = got
        self.rate_var = float(cov[1, 1])
        self.last_profile = partial(_profile, theta[: 2 + n_knots].copy(), knot_m)
        self.last_profile_var = partial(_profile_var, cov, knot_m)
        return HeightFix(float(theta[0]), float(cov[0, 0]), m, rate=float(theta[1]))

    def profile(
        self, dem: DemGrid, subpixel_m: float, walked_m: float, at_m: np.ndarray
    ) -> np.ndarray | None:
        """The datum the whole walk's evidence gives at the distances walked `at_m` (≤ `walked_m`) [m]:
        hindsight (what the map's older heights need: holding.py takes it for the samples it holds)."""
        if self.fix(dem, subpixel_m, walked_m) is None or self.last_profile is None:
            return None
        return self.last_profile(np.asarray(at_m, dtype=float) - walked_m)

    def _solve(
        self, dem: DemGrid, subpixel_m: float, walked_m: float
    ) -> tuple[np.ndarray, np.ndarray, int, tuple[float, int]] | None:
        c = self.config
        b = self._bins[: self._n]
        s, x, y, z, var_xy = b[:, 0], b[:, 2], b[:, 3], b[:, 4], b[:, 5]
        h = dem.height(x, y)
        ok = np.isfinite(h)
        if int(ok.sum()) < c.min_bins:
            return None
        s, x, y, z, var_xy, h = s[ok], x[ok], y[ok], z[ok], var_xy[ok], h[ok]
        m = len(s)
        rel = s - walked_m  # ≤ 0
        # unknowns: d, c, the random walk's increments, the pixels' errors, the segments' misplacements
        n_knots = max(1, int(np.ceil(-rel.min() / c.knot_m + 1e-9)))
        pix, wts = _bilinear(dem, x, y)
        used, inv = np.unique(pix.ravel(), return_inverse=True)
        seg = np.floor((s - s.min()) / c.segment_m).astype(np.int64)
        n_seg = int(seg.max()) + 1
        o_w, o_p = 2, 2 + n_knots
        o_d = o_p + len(used)
        n_u = o_d + 2 * n_seg
        A = np.zeros((m, n_u))
        A[:, 0] = 1.0
        A[:, 1] = rel
        A[:, o_w : o_w + n_knots] = _walk_rows(rel, c.knot_m, n_knots)  # W(s_now) = 0
        np.add.at(A, (np.repeat(np.arange(m), 4), o_p + inv), wts.ravel())
        gx = (dem.height(x + dem.pixel_m, y) - dem.height(x - dem.pixel_m, y)) / (2 * dem.pixel_m)
        gy = (dem.height(x, y + dem.pixel_m) - dem.height(x, y - dem.pixel_m)) / (2 * dem.pixel_m)
        A[np.arange(m), o_d + 2 * seg] = np.nan_to_num(gx)
        A[np.arange(m), o_d + 2 * seg + 1] = np.nan_to_num(gy)
        seg_var = np.zeros(n_seg)
        np.maximum.at(seg_var, seg, var_xy)
        prior = np.r_[
            1e-8,  # d: flat
            1.0 / c.rate_sigma**2,
            np.full(n_knots, 1.0 / (c.walk_sigma**2 * c.knot_m)),
            np.full(len(used), 1.0 / max(dem.noise_m, 1e-3) ** 2),
            np.repeat(1.0 / np.maximum(seg_var, 1e-4), 2),
        ]
        yv = h - z
        corr_m = c.relief_corr_m if c.relief_corr_m is not None else dem.pixel_m
        noise = np.full(m, max(subpixel_m, 1e-3) ** 2 * max(1.0, corr_m / c.bin_m))
        # the point measurements of the datum (rows with d, c and W only)
        if self._points:
            P = np.array(self._points)
            prel = P[:, 0] - walked_m
            rows = np.zeros((len(P), n_u))
            rows[:, 0] = 1.0
            rows[:, 1] = prel
            rows[:, o_w : o_w + n_knots] = _walk_rows(prel, c.knot_m, n_knots)
            A = np.vstack([A, rows])
            yv = np.r_[yv, P[:, 1]]
            noise = np.r_[noise, P[:, 2]]
        # the Huber weights' scale: a bin's spread about the line before the fit (its own noise, its pixels'
        # errors through its weights, its segment's misplacement); the points' own variance
        scale = noise.copy()
        scale[:m] += (
            np.sum(wts**2, axis=1) * dem.noise_m**2
            + (np.nan_to_num(gx) ** 2 + np.nan_to_num(gy) ** 2) * seg_var[seg]
        )
        wr = np.ones(len(yv))
        for _ in range(3):  # Huber IRLS over the residuals
            W = wr / noise
            N = cho_factor(A.T @ (W[:, None] * A) + np.diag(prior))
            theta = cho_solve(N, A.T @ (W * yv))
            u = np.abs(yv - A @ theta) / np.sqrt(scale)
            wr = np.where(u <= c.huber_k, 1.0, c.huber_k / np.maximum(u, 1e-12))
        k = 2 + n_knots
        cov = cho_solve(N, np.eye(n_u)[:, :k])[:k]  # (d, c, W's increments)' covariance
        return theta, 0.5 * (cov + cov.T), m, (c.knot_m, n_knots)


def _profile(theta: np.ndarray, knot_m: float, rel: np.ndarray) -> np.ndarray:
    """d + c·rel + W(rel) at distances `rel` ≤ 0 before the newest foothold (beyond the oldest knot: held)."""
    n_knots = len(theta) - 2
    rel = np.clip(np.asarray(rel, dtype=float), -n_knots * knot_m, 0.0)
    return theta[0] + theta[1] * rel + _walk_rows(rel, knot_m, n_knots) @ theta[2:]


def _profile_var(cov: np.ndarray, knot_m: float, rel: np.ndarray) -> np.ndarray:
    """The posterior variance of `_profile` at distances `rel` ≤ 0 [m²]: aᵀ·cov·a with a = (1, rel, W's rows)."""
    n_knots = len(cov) - 2
    rel = np.clip(np.asarray(rel, dtype=float), -n_knots * knot_m, 0.0)
    a = np.c_[np.ones_like(rel), rel, _walk_rows(rel, knot_m, n_knots)]
    return np.maximum(np.einsum("ij,jk,ik->i", a, cov, a), 0.0)


def _walk_rows(rel: np.ndarray, knot_m: float, n_knots: int) -> np.ndarray:
    """The random walk's design rows (len(rel), n_knots) at distances `rel` ≤ 0 before the newest foothold:
    knots every `knot_m` back from it, linear between them, zero at it."""
    pos = -np.asarray(rel, dtype=float)[:, None] / knot_m
    return np.clip(pos - np.arange(n_knots)[None, :], 0.0, 1.0)


def _bilinear(dem: DemGrid, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The DEM pixels (flat indices, (m, 4)) and bilinear weights (m, 4) `DemGrid.height` reads at (x, y)."""
    ny, nx = dem.z.shape
    u = np.clip((x - dem.x0) / dem.pixel_m, 0, nx - 1)
    v = np.clip((y - dem.y0) / dem.pixel_m, 0, ny - 1)
    i0 = np.minimum(np.floor(u).astype(np.int64), nx - 2)
    j0 = np.minimum(np.floor(v).astype(np.int64), ny - 2)
    fu, fv = u - i0, v - j0
    pix = np.stack([j0 * nx + i0, j0 * nx + i0 + 1, (j0 + 1) * nx + i0, (j0 + 1) * nx + i0 + 1], 1)
    wts = np.stack([(1 - fu) * (1 - fv), fu * (1 - fv), (1 - fu) * fv, fu * fv], 1)
    return pix, wts
