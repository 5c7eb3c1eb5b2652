"""`match_trail`: what the footholds walked since the last fix say about the scout's horizontal place and
heading against an orbital DEM, as a measurement the filter can take without counting anything twice.

A DEM's 5 m pixels, each the mean of the relief over its footprint, smoothed and with 0.3 m of noise, place a
foothold trail only weakly and roughly: its likelihood over the offset (dx, dy, dyaw) is broad, with noise
minima metres apart (docs/results.md, "DEM place and heading fixes"). So the trail is matched the way the DEM was made and the
result is fused the way a filter can take it:

- footholds are averaged along the trail over `bin_m` of distance walked (the DEM sees nothing finer; it
  also makes the cost per metre, not per foothold); each bin is compared with the DEM bilinear between its
  pixel centres, σ per bin the DEM's stated noise with the sub-pixel relief (`DemReference`), the bins per
  independent DEM sample (`samples_per_bin`) tempering the likelihood;
- the vertical datum is unknown and the estimate's height drifts as it walks, so the datum is fitted per
  candidate as a line a + b·s in the distance walked (b with the prior σ `rate_sigma`), profiled out;
- yaw is a matched parameter (the trail turned about the scout's position, `pivot`): a long trail's shape
  carries the heading;
- only the bins walked since the last fused fix are new evidence: the score is the trail's χ² less that of
  its old part (each profiled on its own), the likelihood of the new footholds given the old ones (which
  the filter has already taken). The old part still fixes the datum line the new part is read against;
- the filter's own Gaussian prior over (x, y, yaw) (mean 0: the estimate) bounds the grid (± `prior_sigmas`
  σ) and breaks the DEM's ambiguity; the posterior's mean and covariance on the grid, divided by the prior,
  are the measurement (its information is what the DEM added; directions it did not inform get none).

Refused (`TrailFix.ok` False, `reason`): "few" (fewer than `min_new_bins` new bins, or off the DEM), "flat"
(the posterior is the prior: information gain below `min_gain_nats`), "ambiguous" (another local peak of the
posterior, separated from the best by a valley deeper than `valley_chi2`, within `min_separation_chi2` of it:
a periodic or repeated relief, or DEM noise that could put the scout at either).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numba import njit
from scipy.ndimage import maximum_filter

from .reference import DemReference

__all__ = ["TrailConfig", "TrailFix", "match_trail"]


@dataclass(frozen=True)
class TrailConfig:
    bin_m: float = 1.0  # footholds averaged along the trail over this much walked [m]
    # bins per independent DEM sample: a foothold bin's DEM height mixes four pixels' noise and the next bins
    # share them. True footholds along the 100 m field's direct route (seeds 31, 33; ten DEM noise draws, a
    # 1.5 m / 2° prior): 4 gave a normalised error² χ²₃ of 2.9 and 4.7 on 130 m trails; a walked trail's shape
    # is not rigid (the heading drifts along it): 8, the conservative side (docs/results.md, "DEM place and heading fixes")
    samples_per_bin: float = 8.0
    rate_sigma: float = 0.03  # prior σ of the datum's slope along the trail (the height drift) [m/m]
    prior_sigmas: float = 3.5  # the grid spans this many of the prior's σ each way
    max_step_m: float = 0.5  # grid step at most [m]
    min_step_m: float = 0.05
    step_sigmas: float = 0.3  # grid step: this share of the prior's smallest position σ
    max_candidates: int = 300_000
    min_new_bins: int = 8
    min_gain_nats: float = 0.05  # "flat": the DEM told the filter less than this
    min_separation_chi2: float = 9.0  # another peak within Δχ² 9 of the best: ambiguous
    valley_chi2: float = 4.0  # ... if a valley this deep parts it from the best (a separate place)


@dataclass(frozen=True)
class TrailFix:
    ok: bool
    reason: str  # "ok", or why not: few, flat, ambiguous
    # the measurement: the estimate's (x, y, yaw) error (truth minus estimate) the new footholds say, with its
    # covariance (directions the DEM did not inform: variance ~1e8 in the prior's units)
    offset: np.ndarray | None = None  # (3,) [m, m, rad]
    cov: np.ndarray | None = None  # (3, 3)
    posterior: np.ndarray | None = None  # (3,) the prior times the likelihood: its mean
    posterior_cov: np.ndarray | None = None
    gain_nats: float = 0.0  # information the match added to the prior
    separation_chi2: float = float("inf")  # Δχ² from the best to the best separate other place
    bins: int = 0
    new_bins: int = 0
    candidates: int = 0


def bin_trail(pts: np.ndarray, walked: np.ndarray, bin_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Footholds (n, 3) placed at distances walked `walked` (n,) averaged per `bin_m` of walking: the bins'
    mean points (k, 3) and mean distances walked (k,)."""
    key = np.floor((walked - walked.min()) / bin_m).astype(np.int64)
    _, inv, cnt = np.unique(key, return_inverse=True, return_counts=True)
    out = np.zeros((len(cnt), 3))
    np.add.at(out, inv, pts)
    s = np.zeros(len(cnt))
    np.add.at(s, inv, walked)
    return out / cnt[:, None], s / cnt


@njit(cache=True, nogil=True)
def _trail_chi2(
    bins: np.ndarray,
    s: np.ndarray,
    w: np.ndarray,
    old: np.ndarray,
    Z: np.ndarray,
    x0: float,
    y0: float,
    pix: float,
    cand: np.ndarray,
    px: float,
    py: float,
    rate_prec: float,
    out: np.ndarray,
) -> None:
    """out[i] = (χ² of all bins, χ² of the old bins) for candidate cand[i] = (dx, dy, dyaw): the bins turned
    by dyaw about (px, py) and moved by (dx, dy), DEM Z bilinear under them (clamped to the outer pixel
    centres) less their heights, each set's datum line a + b·s fitted (b's prior precision `rate_prec`) with
    weights w (1/σ² per bin); compiled (tens of thousands of candidates per fix)."""
    ny, nx = Z.shape
    acc = np.zeros((2, 6))
    for i in range(cand.shape[0]):
        c, sn = np.cos(cand[i, 2]), np.sin(cand[i, 2])
        acc[:] = 0.0
        for k in range(bins.shape[0]):
            rx, ry = bins[k, 0] - px, bins[k, 1] - py
            u = (px + c * rx - sn * ry + cand[i, 0] - x0) / pix
            v = (py + sn * rx + c * ry + cand[i, 1] - y0) / pix
            u = min(max(u, 0.0), nx - 1.000001)
            v = min(max(v, 0.0), ny - 1.000001)
            iu, iv = int(u), int(v)
            fu, fv = u - iu, v - iv
            h = (Z[iv, iu] * (1 - fu) + Z[iv, iu + 1] * fu) * (1 - fv) + (
                Z[iv + 1, iu] * (1 - fu) + Z[iv + 1, iu + 1] * fu
            ) * fv
            r = h - bins[k, 2]
            for j in range(2 if old[k] else 1):
                acc[j, 0] += w[k]
                acc[j, 1] += w[k] * s[k]
                acc[j, 2] += w[k] * s[k] * s[k]
                acc[j, 3] += w[k] * r
                acc[j, 4] += w[k] * r * s[k]
                acc[j, 5] += w[k] * r * r
        for j in range(2):
            S0, S1, S2, R0, R1, RR = acc[j, 0], acc[j, 1], acc[j, 2], acc[j, 3], acc[j, 4], acc[j, 5]
            if S0 <= 0.0:
                out[i, j] = 0.0
                continue
            A11 = S2 + rate_prec
            det = S0 * A11 - S1 * S1
            a = (A11 * R0 - S1 * R1) / det
            b = (S0 * R1 - S1 * R0) / det
            out[i, j] = RR - 2 * a * R0 - 2 * b * R1 + a * a * S0 + 2 * a * b * S1 + b * b * A11


def _grid(prior: np.ndarray, extent_m: float, cfg: TrailConfig) -> tuple[np.ndarray, tuple[int, ...], float]:
    """Candidates (m, 3) over ± prior_sigmas σ of the prior, their grid's shape (yaw, y, x) and position step:
    the step a share of the prior's smallest position σ, the yaw step moving the trail's far end (`extent_m`
    from the pivot) by no more than one position step; coarsened while over `max_candidates`."""
    sig = np.sqrt(np.diag(prior))
    step = float(np.clip(cfg.step_sigmas * sig[:2].min(), cfg.min_step_m, cfg.max_step_m))
    while True:
        ystep = min(step / max(extent_m, 1.0), sig[2] / 3.0)
        axes = [np.arange(-n, n + 1) * d for n, d in
                ((int(np.ceil(cfg.prior_sigmas * sig[2] / ystep)), ystep),
                 (int(np.ceil(cfg.prior_sigmas * sig[1] / step)), step),
                 (int(np.ceil(cfg.prior_sigmas * sig[0] / step)), step))]  # fmt: skip
        shape = tuple(len(a) for a in axes)
        if int(np.prod(shape)) <= cfg.max_candidates:
            break
        step *= 1.25
    A, Y, X = np.meshgrid(*axes, indexing="ij")
    return np.stack([X.ravel(), Y.ravel(), A.ravel()], 1), shape, step


def _separate_peak_chi2(logp: np.ndarray, shape: tuple[int, ...], valley_chi2: float) -> float:
    """Δχ² (2 Δ log p) from the best grid point to the best other local peak of log p that a valley of
    `valley_chi2` parts from it (sampled along the straight line between them); inf if none."""
    L = logp.reshape(shape)
    peaks = np.flatnonzero((maximum_filter(L, size=3, mode="nearest") == L).ravel())
    best = int(np.argmax(logp))
    b = np.array(np.unravel_index(best, shape))
    sep = np.inf
    for p in peaks[np.argsort(-logp[peaks])][:50]:
        if p == best:
            continue
        d = 2.0 * (logp[best] - logp[p])
        if d >= sep:
            break
        q = np.array(np.unravel_index(p, shape))
        n = int(np.abs(q - b).max())
        if n < 2:
            continue
        line = np.rint(b[None, :] + np.linspace(0, 1, n + 1)[:, None] * (q - b)[None, :]).astype(int)
        valley = float(logp[np.ravel_multi_index(line.T, shape)].min())
        if 2.0 * (logp[p] - valley) >= valley_chi2:
            sep = d
    return float(sep)


def match_trail(
    pts: np.ndarray,
    walked: np.ndarray,
    ref: DemReference,
    prior: np.ndarray,
    pivot: np.ndarray,
    new_from_m: float,
    cfg: TrailConfig = TrailConfig(),
) -> TrailFix:
    """Match the footholds `pts` (n, 3, map frame as estimated) placed at distances walked `walked` (n,)
    against the DEM `ref`, the footholds from `new_from_m` walked on being new; `prior` (3, 3): the filter's
    covariance of its (x, y, yaw) [m, m, rad]; `pivot`: the scout's estimated position, about which the trail
    turns (see the module's doc)."""
    pts = np.asarray(pts, dtype=float)
    walked = np.asarray(walked, dtype=float)
    dem = ref.dem
    h0, sig_h = ref.heights(pts[:, 0], pts[:, 1])
    on = np.isfinite(h0) & np.isfinite(sig_h)
    pts, walked, sig_h = pts[on], walked[on], sig_h[on]
    if len(pts) == 0:
        return TrailFix(False, "few")
    bins, s = bin_trail(pts, walked, cfg.bin_m)
    old = s < new_from_m
    n_new = int((~old).sum())
    if n_new < cfg.min_new_bins:
        return TrailFix(False, "few", bins=len(bins), new_bins=n_new)
    piv = np.asarray(pivot, dtype=float)[:2]
    extent = float(np.hypot(*(bins[:, :2] - piv).T).max())
    prior = np.asarray(prior, dtype=float)
    cand, shape, _ = _grid(prior, extent, cfg)
    out = np.empty((len(cand), 2))
    w = np.full(len(bins), 1.0 / (float(np.mean(sig_h**2)) * cfg.samples_per_bin))
    _trail_chi2(bins, s - s.max(), w, old, dem.z, dem.x0, dem.y0, dem.pixel_m, cand, float(piv[0]),
                float(piv[1]), 1.0 / cfg.rate_sigma**2, out)  # fmt: skip
    P_inv = np.linalg.inv(prior)
    logp = -0.5 * (out[:, 0] - out[:, 1]) - 0.5 * np.einsum("ij,jk,ik->i", cand, P_inv, cand)
    wgt = np.exp(logp - logp.max())
    wgt /= wgt.sum()
    mean = wgt @ cand
    d = cand - mean
    post = (wgt[:, None] * d).T @ d
    common: dict[str, Any] = {"bins": len(bins), "new_bins": n_new, "candidates": len(cand)}
    # the measurement: the posterior divided by the prior, in the prior's whitened coordinates
    L = np.linalg.cholesky(prior)
    Li = np.linalg.inv(L)
    post_w = Li @ post @ Li.T
    lam, V = np.linalg.eigh(np.linalg.inv(post_w) - np.eye(3))
    lam = np.clip(lam, 0.0, None)
    gain = 0.5 * float(np.sum(np.log1p(lam)))
    if gain < cfg.min_gain_nats:
        return TrailFix(False, "flat", gain_nats=gain, **common)
    sep = _separate_peak_chi2(logp, shape, cfg.valley_chi2)
    if sep < cfg.min_separation_chi2:
        return TrailFix(False, "ambiguous", gain_nats=gain, separation_chi2=sep, **common)
    J_w = V @ np.diag(lam) @ V.T
    post_info_w = np.eye(3) + J_w
    J_pinv = V @ np.diag(np.where(lam > 1e-9, 1.0 / np.maximum(lam, 1e-9), 0.0)) @ V.T
    m_w = J_pinv @ (post_info_w @ (Li @ mean))
    cov_w = V @ np.diag(1.0 / np.maximum(lam, 1e-8)) @ V.T
    return TrailFix(True, "ok", offset=L @ m_w, cov=L @ cov_w @ L.T, posterior=mean, posterior_cov=post,
                    gain_nats=gain, separation_chi2=sep, **common)  # fmt: skip
