"""The DEM's place and heading fix (`localization.trail.match_trail`): on synthetic 5 m/px DEMs with 0.3 m of
noise it recovers a known offset and a known heading error of a foothold trail within its covariance, refuses a
flat and a periodic DEM, counts each foothold once, and the localizer fuses it into the filter's position and
heading."""

from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from scout_agent.dem_reader import DemGrid
from scout_agent.localization import DemReference, Localizer, LocalizerConfig
from scout_agent.localization.trail import TrailConfig, match_trail
from scout_agent.state_estimation import ErrorStateEKF, NoiseConfig
from scout_agent.state_estimation.pose_update import heading

PIX = 5.0


def _dem(z: np.ndarray, noise_m: float = 0.3) -> DemReference:
    return DemReference(DemGrid(z, PIX / 2, PIX / 2, PIX, noise_m, "test"), subpixel_m=0.05)


def _relief(seed: int, n: int = 40, amp_m: float = 20.0) -> np.ndarray:
    return gaussian_filter(np.random.default_rng(seed).normal(0, 1, (n, n)), 2.0) * amp_m


def _trail(length_m: float = 80.0, heading_rad: float = 0.7, start=(40.0, 40.0), per_m: float = 8.0):
    """Footholds (n, 2) of a trot along a straight line (two lines 0.24 m apart) and the distance walked."""
    s = np.arange(0.0, length_m, 1.0 / per_m)
    u = np.array([np.cos(heading_rad), np.sin(heading_rad)])
    side = np.where(np.arange(len(s)) % 2, 0.12, -0.12)
    return np.asarray(start) + s[:, None] * u + side[:, None] * np.array([-u[1], u[0]]), s


def _misplace(xy: np.ndarray, off: np.ndarray, dyaw: float) -> tuple[np.ndarray, np.ndarray]:
    """The trail as an estimate off by `off` [m] and `dyaw` [rad] at its newest end places it, and that end."""
    pivot = xy[-1]
    c, s = np.cos(-dyaw), np.sin(-dyaw)
    est = pivot - off + (xy - pivot) @ np.array([[c, -s], [s, c]]).T
    return est, pivot - off


PRIOR = np.diag([2.0**2, 2.0**2, np.radians(3.0) ** 2])


def test_a_known_offset_and_heading_are_recovered_within_their_covariance() -> None:
    """Eight DEMs (a strong relief, 0.3 m per-pixel noise drawn anew), a 120 m trail: its (x, y, yaw) error, 1.2 m,
    -0.8 m and 2°, is recovered within the posterior's covariance (normalised error² χ²₃: mean near 3, none
    beyond p = 0.001; the heading within 3σ, σ well under the prior's, a degree off on average); the height
    drifting 1 cm per metre walked and a 0.3 m datum do not move it; the measurement (posterior divided by
    the prior) is no surer than the posterior."""
    truth = np.array([1.2, -0.8, np.radians(2.0)])
    nees, yaw_err = [], []
    for seed in range(8):
        z = _relief(seed)
        noisy = _dem(z + np.random.default_rng(100 + seed).normal(0, 0.3, z.shape))
        xy, s = _trail(120.0, start=(20.0, 20.0))
        h, _ = _dem(z, 0.0).heights(xy[:, 0], xy[:, 1])
        est, pivot = _misplace(xy, truth[:2], truth[2])
        fix = match_trail(np.column_stack([est, h - 0.3 + 0.01 * s]), s, noisy, PRIOR, pivot, new_from_m=0.0)
        assert fix.ok, fix.reason
        assert fix.posterior is not None and fix.posterior_cov is not None and fix.cov is not None
        e = fix.posterior - truth
        nees.append(float(e @ np.linalg.solve(fix.posterior_cov, e)))
        sig_yaw = np.sqrt(fix.posterior_cov[2, 2])
        assert abs(e[2]) < 3.0 * sig_yaw and sig_yaw < 0.6 * np.sqrt(PRIOR[2, 2])
        yaw_err.append(abs(np.degrees(e[2])))
        assert np.all(np.diag(fix.cov) >= np.diag(fix.posterior_cov) - 1e-12)
    assert max(nees) < 16.3 and 0.5 < np.mean(nees) < 6.0, nees
    assert np.mean(yaw_err) < 1.0, yaw_err


def test_a_flat_or_periodic_dem_is_refused() -> None:
    """A flat DEM tells the prior nothing ("flat"); ridges every 15 m across the trail fit as well 15 m along it
    as where it is, inside the prior ("ambiguous"); a trail off the DEM has nothing to match ("few")."""
    xy, s = _trail(60.0, heading_rad=0.0, start=(20.0, 100.0))
    prior = np.diag([6.0**2, 6.0**2, np.radians(2.0) ** 2])
    flat = _dem(np.full((40, 40), 1.0))
    fix = match_trail(np.column_stack([xy, np.zeros(len(s))]), s, flat, prior, xy[-1], 0.0)
    assert not fix.ok and fix.reason == "flat" and fix.gain_nats < 0.05
    xs = PIX / 2 + np.arange(40) * PIX
    ridges = _dem(np.tile(2.0 * np.sin(2 * np.pi * xs / 15.0), (40, 1)), noise_m=0.05)
    h, _ = ridges.heights(xy[:, 0], xy[:, 1])
    est, pivot = _misplace(xy, np.array([0.5, 0.0]), 0.0)
    fix = match_trail(np.column_stack([est, h]), s, ridges, prior, pivot, 0.0)
    assert not fix.ok and fix.reason == "ambiguous" and fix.separation_chi2 < 9.0
    far = np.column_stack([xy + 500.0, np.zeros(len(s))])
    assert match_trail(far, s, flat, prior, xy[-1] + 500.0, 0.0).reason == "few"


def test_only_the_footholds_since_the_last_fix_are_new_evidence() -> None:
    """The trail's old part fixes the datum but adds no evidence: with nothing new the match is "few"; with
    the last 20 m new, the fix is weaker (larger posterior covariance) than the whole trail's as new."""
    z = _relief(3)
    ref = _dem(z + np.random.default_rng(7).normal(0, 0.3, z.shape))
    xy, s = _trail()
    h, _ = _dem(z, 0.0).heights(xy[:, 0], xy[:, 1])
    est, pivot = _misplace(xy, np.array([0.6, 0.4]), np.radians(1.0))
    pts = np.column_stack([est, h])
    assert match_trail(pts, s, ref, PRIOR, pivot, new_from_m=s[-1] + 1.0).reason == "few"
    part = match_trail(pts, s, ref, PRIOR, pivot, new_from_m=60.0)
    whole = match_trail(pts, s, ref, PRIOR, pivot, new_from_m=0.0)
    assert part.ok and whole.ok
    assert part.gain_nats < whole.gain_nats
    assert np.linalg.det(part.posterior_cov) > np.linalg.det(whole.posterior_cov)


def _ekf(sig_pos: float, sig_yaw_deg: float) -> ErrorStateEKF:
    e = ErrorStateEKF(np.eye(3), np.zeros(3), np.zeros(3), np.array([0, 0, -1.62]), NoiseConfig())
    e.P[6:8, 6:8] = np.eye(2) * sig_pos**2
    e.P[2, 2] = np.radians(sig_yaw_deg) ** 2
    return e


@pytest.mark.parametrize("seed", [0, 1])
def test_the_localizer_fuses_the_dem_place_and_heading_once(seed: int) -> None:
    """An estimate 1.2 m and 2° off at the end of a 120 m trail on a strong-relief DEM: the localizer's DEM fix
    moves the position and heading toward the truth, leaves them inside their new 3σ, does not touch the
    height, and a second attempt without new footholds fuses nothing."""
    z = _relief(seed)
    ref = _dem(z + np.random.default_rng(50 + seed).normal(0, 0.3, z.shape))
    xy, s = _trail(120.0, start=(20.0, 20.0))
    h, _ = _dem(z, 0.0).heights(xy[:, 0], xy[:, 1])
    off, dyaw = np.array([1.0, -0.7]), np.radians(2.0)
    est, pivot = _misplace(xy, off, dyaw)
    e = _ekf(2.0, 3.0)
    e.p[:] = (*pivot, 0.0)
    e.R[:, :] = np.array([[np.cos(0.7 - dyaw), -np.sin(0.7 - dyaw), 0],
                          [np.sin(0.7 - dyaw), np.cos(0.7 - dyaw), 0], [0, 0, 1]])  # fmt: skip
    cfg = replace(LocalizerConfig(), dem=replace(LocalizerConfig().dem, height_fix=False))
    loc = Localizer(SimpleNamespace(ekf=e, feet=None), cfg, dem=ref)  # type: ignore[arg-type]
    loc.track.add(np.column_stack([est, h]), 0.0)
    loc.track._s[: len(s)] = s
    loc.walked_m = float(s[-1])
    loc.localize("dem")
    assert loc.report.fused["dem"] == 1, loc.report
    err_xy = e.p[:2] - xy[-1]
    err_yaw = heading(e.R) - 0.7
    assert np.hypot(*err_xy) < np.hypot(*off) and abs(err_yaw) < dyaw
    assert err_xy @ np.linalg.solve(e.P[6:8, 6:8], err_xy) < 13.8
    assert err_yaw**2 / e.heading_variance() < 9.0
    assert e.p[2] == 0.0
    loc.localize("dem")
    assert loc.report.fused["dem"] == 1 and loc.report.refused["dem_few"] == 1


def test_a_coarser_grid_keeps_the_candidates_bounded() -> None:
    """A broad prior (10 m, 10°) on a long trail: the grid coarsens to stay within `max_candidates`."""
    z = _relief(5)
    xy, s = _trail(120.0, start=(20.0, 20.0))
    h, _ = _dem(z, 0.0).heights(xy[:, 0], xy[:, 1])
    cfg = replace(TrailConfig(), max_candidates=20_000)
    fix = match_trail(np.column_stack([xy, h]), s, _dem(z), np.diag([10.0**2, 10.0**2, np.radians(10.0) ** 2]),
                      xy[-1], 0.0, cfg)  # fmt: skip
    assert fix.candidates <= 20_000
