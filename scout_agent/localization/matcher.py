"""`match_track`: the rigid offset (dx, dy, dyaw) of a foothold track that best fits a height reference, with
its covariance, or the reason there is none.

For every candidate offset on a grid (±`window` at `step`, yaw about `pivot`, the scout's position), the
track's points are moved, the reference is read under them, and the vertical datum dz is fitted (a
Huber-weighted mean: the estimate's height and a DEM's bias are unknown); the score is the Huber loss of the
normalised residuals (r − dz)/σ, σ from the reference (its stated error, or the map cell's scatter), points
the reference does not cover costing ½, what a well-fitting point costs on average (E[u²/2] = ½): neither
covering more of another scout's track nor leaving it pays in itself, so a partial overlap (a crossing) is
not pulled onto or off the others' data. From the best grid point a
Nelder–Mead search refines the offset off the grid (a map's peak is narrower than a grid step), and a
quadratic fitted to the scores on a stencil of half steps around it gives the Hessian; score ≈ ½χ², so the
Laplace covariance is H⁻¹, inflated by the footholds per independent reference cell (a DEM pixel's error is
shared by every foothold in it).

Refused (`MatchResult.ok` False, `reason` says which):
- "few": fewer than `min_points` footholds on the reference, or under `min_coverage` of them;
- "flat" (checked first): no offset in the window scores `min_separation_chi2` worse than the best;
- "ambiguous": another place, farther than `exclusion_sigma` of the best's own σ (Mahalanobis, in the
  searched x, y, yaw; and 3 steps), scores within `min_separation_chi2` of it (a periodic or repeated relief);
- "edge": the best lies on the window's border (the true offset may lie outside);
- "flat": the offset's σ along its worst direction exceeds `max_sigma_m` (the terrain does not constrain it),
  or the score has no minimum there.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import numpy as np
from scipy.optimize import minimize

from .reference import HeightReference

__all__ = ["HeightFix", "MatchConfig", "MatchResult", "match_height", "match_track"]


@dataclass(frozen=True)
class MatchConfig:
    window_m: float = 1.0  # search half-width in x and y [m]
    step_m: float = 0.1  # grid step [m]
    yaw_window_deg: float = 1.0  # search half-width in yaw [deg] (0: position only)
    yaw_step_deg: float = 0.5
    huber_k: float = 2.0  # Huber loss: quadratic within k σ
    min_points: int = 40
    min_coverage: float = 0.6
    max_sigma_m: float = 0.5
    min_separation_chi2: float = 9.0  # a second place within Δχ² 9 (3σ) of the best: ambiguous
    exclusion_sigma: float = 3.0  # "another place": farther than this many σ (and 3 grid steps)
    # "laplace": the best offset refined off the grid, covariance from the score's curvature there (a sharp,
    # single peak: the shared map's 0.4 m cells). "moments": the likelihood exp(−½Δχ²) over the whole grid,
    # its mean and covariance (a DEM's 5 m pixels with 0.3 m noise: a broad, rough likelihood whose best
    # grid point is a noise minimum as often as not, and whose curvature there says nothing of its width)
    method: str = "laplace"
    edge_mass: float = 0.05  # moments: refused ("edge") when this much likelihood lies on the window's rim
    # at most this many footholds, evenly along the track (0: all): a DEM's information is per 5 m pixel, not
    # per foothold (the footholds per pixel temper the likelihood either way), and the cost is per foothold
    max_points: int = 0


@dataclass(frozen=True)
class MatchResult:
    ok: bool
    reason: str  # "ok", or why not: few, edge, flat, ambiguous
    dx: float = 0.0  # [m] add to the track's x to put it where the reference says it is
    dy: float = 0.0
    dz: float = 0.0  # vertical datum: reference minus track [m]
    dyaw: float = 0.0  # [rad], about `pivot`
    cov: np.ndarray | None = None  # (4, 4) over (dx, dy, dz, dyaw)
    sigma_max_m: float = float("nan")  # σ of (dx, dy) along its worst direction [m]
    separation_chi2: float = float("nan")  # Δχ² from the best to the best other place
    points: int = 0
    inflation: float = 1.0  # footholds per independent reference cell
    pivot: tuple[float, float] = (0.0, 0.0)


def _huber(u: np.ndarray, k: float) -> np.ndarray:
    a = np.abs(u)
    return np.where(a <= k, 0.5 * u * u, k * a - 0.5 * k * k)


def _scores(
    pts: np.ndarray, ref: HeightReference, cand: np.ndarray, pivot: np.ndarray, k: float, chunk: int = 256
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Score, datum dz and covered share of every candidate offset cand (m, 3) = (dx, dy, dyaw)."""
    m, n = len(cand), len(pts)
    S, DZ, COV = np.empty(m), np.empty(m), np.empty(m)
    rel = pts[:, :2] - pivot
    cap = 0.5  # an uncovered point: the expected cost of a covered one that fits
    for o in range(0, m, chunk):
        cd = cand[o : o + chunk]
        c, s = np.cos(cd[:, 2:3]), np.sin(cd[:, 2:3])
        X = pivot[0] + c * rel[None, :, 0] - s * rel[None, :, 1] + cd[:, 0:1]
        Y = pivot[1] + s * rel[None, :, 0] + c * rel[None, :, 1] + cd[:, 1:2]
        h, sig = ref.heights(X, Y)
        ok = np.isfinite(h) & np.isfinite(sig) & (sig > 0)
        w = np.where(ok, 1.0 / np.where(ok, sig, 1.0) ** 2, 0.0)
        r = np.where(ok, h - pts[None, :, 2], 0.0)  # reference minus track
        dz = (w * r).sum(-1) / np.maximum(w.sum(-1), 1e-12)
        for _ in range(2):  # Huber IRLS on the datum
            u = (r - dz[:, None]) * np.sqrt(w)
            hw = np.where(np.abs(u) <= k, 1.0, k / np.maximum(np.abs(u), 1e-12)) * w
            dz = (hw * r).sum(-1) / np.maximum(hw.sum(-1), 1e-12)
        u = (r - dz[:, None]) * np.sqrt(w)
        S[o : o + chunk] = np.where(ok, _huber(u, k), cap).sum(-1)
        DZ[o : o + chunk] = dz
        COV[o : o + chunk] = ok.sum(-1) / n
    return S, DZ, COV


def _hessian(f, x0: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Hessian of f at x0 from a quadratic fitted on the 3^d stencil x0 + {-1, 0, 1}·h."""
    d = len(x0)
    grids = np.meshgrid(*[np.array([-1.0, 0.0, 1.0])] * d, indexing="ij")
    U = np.stack([g.ravel() for g in grids], 1) * h
    vals = f(x0 + U)
    iu = np.triu_indices(d)
    A = np.hstack([np.ones((len(U), 1)), U,
                   np.stack([U[:, p] * U[:, q] * (0.5 if p == q else 1.0) for p, q in zip(*iu, strict=True)], 1)])  # fmt: skip
    coef, *_ = np.linalg.lstsq(A, vals, rcond=None)
    H = np.zeros((d, d))
    for cf, p, q in zip(coef[1 + d :], *iu, strict=True):
        H[p, q] = H[q, p] = cf
    return H


def match_track(
    pts: np.ndarray, ref: HeightReference, cfg: MatchConfig = MatchConfig(), pivot: np.ndarray | None = None
) -> MatchResult:
    """Match the footholds `pts` (n, 3, map frame as estimated) against `ref` (see the module's doc)."""
    pts = np.asarray(pts, dtype=float)
    n = len(pts)
    piv = np.asarray(pivot if pivot is not None else pts[-1, :2] if n else (0.0, 0.0), dtype=float)[:2]
    pv = (float(piv[0]), float(piv[1]))
    if n < cfg.min_points:
        return MatchResult(False, "few", points=n, pivot=pv)
    if cfg.max_points and n > cfg.max_points:  # evenly along the track, the newest kept
        pts = pts[np.linspace(0, n - 1, cfg.max_points).round().astype(int)]
        n = len(pts)
    half = int(round(cfg.window_m / cfg.step_m))
    dxs = np.arange(-half, half + 1) * cfg.step_m
    yh = int(round(cfg.yaw_window_deg / cfg.yaw_step_deg)) if cfg.yaw_window_deg > 0 else 0
    ystep = np.radians(cfg.yaw_step_deg)
    dyaws = np.arange(-yh, yh + 1) * ystep
    A, Y, X = np.meshgrid(dyaws, dxs, dxs, indexing="ij")
    cand = np.stack([X.ravel(), Y.ravel(), A.ravel()], 1)
    S, DZS, COVER = _scores(pts, ref, cand, piv, cfg.huber_k)
    b = int(np.argmin(S))
    if COVER[b] < cfg.min_coverage or COVER[b] * n < cfg.min_points:
        return MatchResult(False, "few", points=n, pivot=pv)
    # footholds per independent reference cell, at the best offset
    cell = max(ref.cell_m, 1e-3)
    moved = pts[:, :2] + cand[b, :2]
    h0, _ = ref.heights(moved[:, 0], moved[:, 1])
    covered = np.isfinite(h0)
    cells = np.unique(np.floor(moved[covered] / cell).astype(np.int64), axis=0)
    inflation = max(1.0, covered.sum() / max(len(cells), 1))
    if 2.0 * (float(S.max()) - float(S[b])) / inflation < cfg.min_separation_chi2:
        return MatchResult(False, "flat", separation_chi2=0.0, points=n, inflation=inflation, pivot=pv)
    if cfg.method == "moments":
        return _moments(pts, ref, cfg, cand, S, DZS, piv, inflation, dxs, dyaws, ystep)
    # off the grid: Nelder–Mead in units of one step, yaw only when searched
    scale = np.r_[cfg.step_m, cfg.step_m, ystep][: 3 if yh else 2]

    def f(u: np.ndarray) -> np.ndarray:
        u = np.atleast_2d(u) * scale
        c3 = np.zeros((len(u), 3))
        c3[:, : u.shape[1]] = u
        return _scores(pts, ref, c3, piv, cfg.huber_k)[0]

    x0 = cand[b, : len(scale)] / scale
    opt = minimize(lambda u: float(f(u)[0]), x0, method="Nelder-Mead",
                   options={"xatol": 0.02, "fatol": 1e-3, "maxfev": 150, "initial_simplex": x0 + np.vstack([np.zeros(len(x0)), 0.5 * np.eye(len(x0))])})  # fmt: skip
    best = opt.x if opt.fun <= S[b] else x0
    s_best = min(float(opt.fun), float(S[b]))
    H = _hessian(f, best, np.full(len(best), 0.5)) / np.outer(scale, scale)
    pd = np.linalg.eigvalsh(H).min() > 0
    C = np.linalg.inv(H) * inflation if pd else None
    # another place as good? Farther than `exclusion_sigma` of the best's own (Laplace) σ, in the searched
    # (x, y, yaw), and 3 steps in position, yet within Δχ² `min_separation_chi2` of it: a periodic or repeated
    # relief (checked before the edge: a periodic relief's best is as often on the edge). A broad peak's own
    # slopes are not "another place": on a quadratic bowl a point d σ away scores Δχ² = d².
    far = np.hypot(cand[:, 0] - cand[b, 0], cand[:, 1] - cand[b, 1]) > 3 * cfg.step_m
    if C is not None:
        dv = cand[:, : len(scale)] - best * scale
        far &= np.einsum("ij,jk,ik->i", dv, np.linalg.inv(C), dv) > cfg.exclusion_sigma**2
    sep = 2.0 * (float(S[far].min()) - s_best) / inflation if far.any() else float("inf")
    if sep < cfg.min_separation_chi2:
        return MatchResult(False, "ambiguous", separation_chi2=sep, points=n, inflation=inflation, pivot=pv)
    on_edge = abs(cand[b, 0]) >= dxs[-1] - 1e-9 or abs(cand[b, 1]) >= dxs[-1] - 1e-9
    if on_edge or (yh and abs(cand[b, 2]) >= dyaws[-1] - 1e-12):
        return MatchResult(False, "edge", separation_chi2=sep, points=n, inflation=inflation, pivot=pv)
    if C is None:
        return MatchResult(False, "flat", separation_chi2=sep, points=n, inflation=inflation, pivot=pv)
    sig_xy = float(np.sqrt(np.linalg.eigvalsh(C[:2, :2]).max()))
    if sig_xy > cfg.max_sigma_m:
        return MatchResult(False, "flat", sigma_max_m=sig_xy, separation_chi2=sep, points=n,
                           inflation=inflation, pivot=pv)  # fmt: skip
    off = np.zeros(3)
    off[: len(best)] = best * scale
    _, DZ, _ = _scores(pts, ref, off[None, :], piv, cfg.huber_k)
    dz = float(DZ[0])
    # datum: residual scatter about the fit over the covered footholds, per independent cell
    c, s_ = np.cos(off[2]), np.sin(off[2])
    rel = pts[:, :2] - piv
    q = np.stack(
        [piv[0] + c * rel[:, 0] - s_ * rel[:, 1] + off[0], piv[1] + s_ * rel[:, 0] + c * rel[:, 1] + off[1]],
        1,
    )
    h1, _ = ref.heights(q[:, 0], q[:, 1])
    ok = np.isfinite(h1)
    r = h1[ok] - pts[ok, 2] - dz
    var_dz = float(np.mean(r**2)) * inflation / max(int(ok.sum()), 1)
    return _accepted(off, dz, var_dz, C, bool(yh), sig_xy, sep, n, inflation, pv)


def _moments(
    pts: np.ndarray,
    ref: HeightReference,
    cfg: MatchConfig,
    cand: np.ndarray,
    S: np.ndarray,
    DZS: np.ndarray,
    piv: np.ndarray,
    inflation: float,
    dxs: np.ndarray,
    dyaws: np.ndarray,
    ystep: float,
) -> MatchResult:
    """The likelihood exp(−ΔS / inflation) (= exp(−½Δχ²), footholds per independent cell tempering it) over
    the grid of candidates: its mean is the offset, its covariance (+ the grid's own step²/12) the offset's.
    Refused: "edge" when more than `edge_mass` of it lies on the window's rim (the window cuts it: its
    covariance would be too small), "ambiguous" when its σ exceeds `max_sigma_m` (spread over several places
    or one broad one)."""
    n = len(pts)
    pv = (float(piv[0]), float(piv[1]))
    w = np.exp(-(S - S.min()) / inflation)
    w /= w.sum()
    yawed = len(dyaws) > 1
    use = cand if yawed else cand[:, :2]
    mean = w @ use
    d = use - mean
    C = (w[:, None] * d).T @ d + np.diag(np.r_[cfg.step_m, cfg.step_m, ystep][: use.shape[1]] ** 2 / 12.0)
    rim = (np.abs(cand[:, 0]) >= dxs[-1] - 1e-9) | (np.abs(cand[:, 1]) >= dxs[-1] - 1e-9)
    if yawed:
        rim |= np.abs(cand[:, 2]) >= dyaws[-1] - 1e-12
    sig_xy = float(np.sqrt(np.linalg.eigvalsh(C[:2, :2]).max()))
    b = int(np.argmin(S))
    far = np.hypot(cand[:, 0] - cand[b, 0], cand[:, 1] - cand[b, 1]) > cfg.exclusion_sigma * sig_xy
    sep = 2.0 * (float(S[far].min()) - float(S[b])) / inflation if far.any() else float("inf")
    refuse = partial(MatchResult, False, sigma_max_m=sig_xy, separation_chi2=sep, points=n, inflation=inflation,
                     pivot=pv)  # fmt: skip
    if float(w[rim].sum()) > cfg.edge_mass:
        return refuse("edge")
    if sig_xy > cfg.max_sigma_m:
        return refuse("ambiguous")
    off = np.zeros(3)
    off[: len(mean)] = mean
    _, DZ, _ = _scores(pts, ref, off[None, :], piv, cfg.huber_k)
    dz = float(DZ[0])
    var_dz = float(w @ (DZS - dz) ** 2) + 1e-6  # the datum's spread over the places the likelihood allows
    return _accepted(off, dz, var_dz, C, yawed, sig_xy, sep, n, inflation, pv)


def _accepted(
    off: np.ndarray, dz: float, var_dz: float, C: np.ndarray, yawed: bool, sig_xy: float, sep: float, n: int,
    inflation: float, pivot: tuple[float, float],
) -> MatchResult:  # fmt: skip
    """An accepted match: offset (dx, dy, dyaw) with its covariance C (x, y[, yaw]), the datum dz and its
    variance; the heading row is unbounded (inf) where the search held the heading fixed."""
    cov = np.zeros((4, 4))
    cov[:2, :2] = C[:2, :2]
    cov[2, 2] = var_dz
    if yawed:
        cov[3, 3] = C[2, 2]
        cov[:2, 3] = cov[3, :2] = C[:2, 2]
    else:
        cov[3, 3] = np.inf
    return MatchResult(True, "ok", dx=float(off[0]), dy=float(off[1]), dz=dz, dyaw=float(off[2]), cov=cov,
                       sigma_max_m=sig_xy, separation_chi2=sep, points=n, inflation=inflation, pivot=pivot)  # fmt: skip


@dataclass(frozen=True)
class HeightFix:
    """The vertical datum of a foothold track against a reference where its place is not found: dz (reference
    minus track [m]) at the estimated place, with a variance that holds the horizontal uncertainty too; with
    the footholds' distances walked, dz is the datum at the track's newest end and `rate` its change per metre
    walked (the estimate's height drift the reference sees along the track, [m/m])."""

    dz: float
    var_m2: float
    points: int
    rate: float = 0.0
    # the track's own evidence on `rate` (the line's slope without its prior) and its variance [(m/m)²]; inf
    # where the track does not state one (a mean datum, or all footholds at one distance)
    rate_data: float = 0.0
    rate_data_var: float = float("inf")


def match_height(
    pts: np.ndarray,
    ref: HeightReference,
    sigma_xy_m: float,
    cfg: MatchConfig = MatchConfig(),
    walked_m: np.ndarray | None = None,
    rate_sigma: float = 0.0,
) -> HeightFix | None:
    """The reference's height under the track where the estimate put it, for a track whose horizontal place
    the reference does not constrain (flat, ambiguous): a DEM's 5 m pixels bound the height long before the
    place. dz is the Huber-fitted datum at the estimated place (offset 0); its variance adds (a) the fit's
    residual scatter per independent reference cell and (b) how much the datum changes over the places the
    estimate allows (offsets on a grid of ±2 `sigma_xy_m`, weighted by the estimate's Gaussian). None with
    fewer than `min_points` covered footholds.

    A height estimate that drifts while the scout walks puts the track's old footholds off by less than its
    newest (or more): the track's mean datum lags the estimate's error now. Given each foothold's distance
    walked `walked_m` (n,) and `rate_sigma` > 0 (the prior σ of the drift per metre walked [m/m]), the datum
    is fitted as a line in the distance walked, dz(s) = a + b·(s − s_newest), b with the zero-mean prior
    `rate_sigma` (a Bayesian straight line: a short or noisy track falls back toward the mean), and the fix is
    a, the datum at the newest foothold, with its posterior variance (per independent cell, as above)."""
    pts = np.asarray(pts, dtype=float)
    n = len(pts)
    if n < cfg.min_points:
        return None
    piv = pts[-1, :2]
    span = max(2.0 * sigma_xy_m, cfg.step_m)
    k = max(1, int(np.ceil(span / max(cfg.step_m, span / 8))))
    offs = np.linspace(-span, span, 2 * k + 1)
    X, Y = np.meshgrid(offs, offs)
    cand = np.stack([X.ravel(), Y.ravel(), np.zeros(X.size)], 1)
    _, DZ, COVER = _scores(pts, ref, cand, piv, cfg.huber_k)
    centre = len(cand) // 2
    if COVER[centre] * n < cfg.min_points or not np.isfinite(DZ[centre]):
        return None
    w = np.exp(-0.5 * (X.ravel() ** 2 + Y.ravel() ** 2) / max(sigma_xy_m, 1e-6) ** 2) * (
        COVER * n >= cfg.min_points
    )
    w = w / w.sum()
    var_place = float(np.sum(w * (DZ - np.sum(w * DZ)) ** 2))
    h, _ = ref.heights(pts[:, 0], pts[:, 1])
    ok = np.isfinite(h)
    cell = max(ref.cell_m, 1e-3)
    cells = len(np.unique(np.floor(pts[ok, :2] / cell).astype(np.int64), axis=0))
    inflation = max(1.0, int(ok.sum()) / max(cells, 1))
    if walked_m is not None and rate_sigma > 0:
        s = np.asarray(walked_m, dtype=float)[ok]
        a, b, var_a, b_data, var_b_data = _drift_line(h[ok] - pts[ok, 2], s - s.max(), rate_sigma, cfg.huber_k,
                                                      inflation)  # fmt: skip
        return HeightFix(a, var_a + var_place, int(ok.sum()), b, b_data, var_b_data)
    r = h[ok] - pts[ok, 2] - DZ[centre]
    var_fit = float(np.mean(r**2)) * inflation / max(int(ok.sum()), 1)
    return HeightFix(float(DZ[centre]), var_fit + var_place, int(ok.sum()))


def _drift_line(
    r: np.ndarray, s: np.ndarray, rate_sigma: float, k: float, inflation: float
) -> tuple[float, float, float, float, float]:
    """r ≈ a + b·s (s ≤ 0: distance walked before the newest foothold [m]) by Huber-weighted least squares
    with the prior b ~ N(0, rate_sigma²), each point's σ the residuals' own scatter, counted per independent
    reference cell (× `inflation`). Returns a, b, the posterior variance of a, and b and its variance from the
    data alone (a, b fitted without the prior; inf where the distances do not determine b)."""
    A = np.stack([np.ones_like(s), s], 1)
    prior = np.diag([0.0, 1.0 / rate_sigma**2])
    var_r = max(float(np.var(r)), 1e-6)
    hw = np.ones_like(r)
    for _ in range(4):  # IRLS: the residual scale and the Huber weights
        N = A.T @ (hw[:, None] * A) / (var_r * inflation) + prior
        coef = np.linalg.solve(N, A.T @ (hw * r) / (var_r * inflation))
        res = r - A @ coef
        var_r = max(float(np.mean(res**2)), 1e-6)
        u = np.abs(res) / np.sqrt(var_r)
        hw = np.where(u <= k, 1.0, k / np.maximum(u, 1e-12))
    data = A.T @ (hw[:, None] * A) / (var_r * inflation)
    N = data + prior
    b_data, var_b_data = 0.0, float("inf")
    if np.linalg.det(data) > 1e-12 * max(data[0, 0] * data[1, 1], 1e-300):
        cov_data = np.linalg.inv(data)
        b_data = float((cov_data @ (A.T @ (hw * r) / (var_r * inflation)))[1])
        var_b_data = float(cov_data[1, 1])
    return float(coef[0]), float(coef[1]), float(np.linalg.inv(N)[0, 0]), b_data, var_b_data
