"""Localization against a map: the matcher recovers a known offset of a foothold track on a synthetic map with
a covariance that contains its error, refuses flat and periodic maps, and the EKF's pose update corrects the
estimate, keeps its covariance honest, and gates a wrong place."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from scout_agent.localization import GridReference, MatchConfig, map_reference, match_track
from scout_agent.localization.track import FootholdTrack
from scout_agent.state_estimation import ErrorStateEKF, NoiseConfig
from scout_agent.state_estimation.pose_update import heading, update_pose

RES = 0.1


def _relief(seed: int, scale_cells: float = 8.0, amp_m: float = 3.0) -> np.ndarray:
    return gaussian_filter(np.random.default_rng(seed).normal(0, 1, (300, 300)), scale_cells) * amp_m


def _ref(z: np.ndarray, sigma: float = 0.01) -> GridReference:
    gy, gx = np.gradient(z, RES)  # cell centres at (i + 0.5)·RES - RES/2 = i·RES
    return GridReference(z, np.full(z.shape, sigma), -RES / 2, -RES / 2, RES, gx, gy)


def _track(n: int = 300, length: float = 12.0, heading_rad: float = 0.6435) -> np.ndarray:
    """Footholds (n, 2) of a trot along a straight 12 m line: two tracks 0.3 m apart."""
    s = np.linspace(0, length, n)
    u = np.array([np.cos(heading_rad), np.sin(heading_rad)])
    side = np.where(np.arange(n) % 2, 0.15, -0.15)
    return np.array([5.0, 5.0]) + s[:, None] * u + side[:, None] * np.array([-u[1], u[0]])


@pytest.mark.parametrize("seed, off, dyaw_deg", [(0, (0.33, -0.27), 0.0), (1, (-0.12, 0.41), 0.7)])
def test_a_known_offset_is_recovered_within_its_covariance(seed, off, dyaw_deg) -> None:
    ref = _ref(_relief(seed))
    true_xy = _track()
    pivot = true_xy[-1]
    h, _ = ref.heights(true_xy[:, 0], true_xy[:, 1])
    rng = np.random.default_rng(seed + 10)
    # the estimate placed the track rotated by -dyaw about its end and shifted by -off, 0.1 m low
    a = np.radians(-dyaw_deg)
    rel = true_xy - pivot
    est = pivot + rel @ np.array([[np.cos(a), np.sin(a)], [-np.sin(a), np.cos(a)]]) - np.asarray(off)
    pts = np.column_stack([est, h - 0.1 + rng.normal(0, 0.01, len(h))])
    r = match_track(pts, ref, MatchConfig(window_m=0.8, yaw_window_deg=1.5), pivot=pivot - np.asarray(off))
    assert r.ok, r.reason
    err = np.array([r.dx - off[0], r.dy - off[1]])
    assert np.hypot(*err) < 0.05
    assert err @ np.linalg.solve(r.cov[:2, :2], err) < 13.8  # inside the 3σ ellipse (χ²₂, p = 0.001)
    assert r.dz == pytest.approx(0.1, abs=0.01)
    assert np.degrees(r.dyaw) == pytest.approx(dyaw_deg, abs=0.25)
    assert r.sigma_max_m < 0.05 and r.separation_chi2 > 100


def test_flat_and_periodic_maps_are_refused() -> None:
    pts_xy = _track()
    flat = _ref(np.zeros((300, 300)))
    r = match_track(np.column_stack([pts_xy, np.zeros(len(pts_xy))]), flat, MatchConfig())
    assert not r.ok and r.reason == "flat"
    # ridges every 0.6 m across the track's direction: every 0.6 m along x fits as well
    xs = np.arange(300) * RES
    ridges = np.tile(0.2 * np.sin(2 * np.pi * xs / 0.6), (300, 1))
    per = _ref(ridges)
    h, _ = per.heights(pts_xy[:, 0], pts_xy[:, 1])
    r = match_track(np.column_stack([pts_xy - (0.2, 0.0), h]), per, MatchConfig(window_m=1.0))
    assert not r.ok and r.reason == "ambiguous"
    assert r.separation_chi2 < 9.0


def test_too_few_footholds_or_off_the_map_is_refused() -> None:
    ref = _ref(_relief(2))
    pts = np.column_stack([_track(20), np.zeros(20)])
    assert match_track(pts, ref).reason == "few"
    far = np.column_stack([_track() + 100.0, np.zeros(300)])
    assert match_track(far, ref).reason == "few"


def test_the_map_reference_uses_each_cells_plane_and_scatter() -> None:
    # one cell (0.4 m) with footholds on the plane z = 1 + 0.2 dx - 0.1 dy (dx, dy from the centre)
    rng = np.random.default_rng(3)
    dx, dy = rng.uniform(-0.2, 0.2, (2, 50))
    z = 1.0 + 0.2 * dx - 0.1 * dy + rng.normal(0, 0.02, 50)
    one = lambda v: np.array([[v]])  # noqa: E731
    stats = {"n": one(50.0), "sum": one(z.sum()), "sumsq": one((z**2).sum()), "sx": one(dx.sum()),
             "sy": one(dy.sum()), "sxx": one((dx**2).sum()), "syy": one((dy**2).sum()),
             "sxy": one((dx * dy).sum()), "sxz": one((dx * z).sum()), "syz": one((dy * z).sum()),
             "min": one(z.min()), "max": one(z.max())}  # fmt: skip
    ref = map_reference(stats, x0=2.0, y0=3.0, res=0.4)
    h, s = ref.heights(np.array([2.2 + 0.15, 5.0]), np.array([3.2 - 0.1, 3.2]))
    assert h[0] == pytest.approx(1.0 + 0.2 * 0.15 + 0.1 * 0.1, abs=0.01)
    assert s[0] == pytest.approx(np.hypot(0.02, 0.01), abs=0.006)
    assert np.isnan(h[1]) and np.isnan(s[1])


def _ekf(sig_pos: float = 0.5, sig_yaw: float = 0.02) -> ErrorStateEKF:
    e = ErrorStateEKF(np.eye(3), np.zeros(3), np.zeros(3), np.array([0, 0, -1.62]), NoiseConfig())
    e.P[6:8, 6:8] = np.eye(2) * sig_pos**2
    e.P[2, 2] = sig_yaw**2
    return e


def test_a_pose_measurement_corrects_the_estimate_and_shrinks_its_covariance() -> None:
    e = _ekf()
    cov = np.diag([0.05**2, 0.05**2, 0.02**2, np.radians(0.3) ** 2])
    up = update_pose(e, np.array([0.4, -0.3, 0.05, np.radians(1.0)]), cov, gate_chi2=18.47)
    assert up.accepted and up.dof == 4
    np.testing.assert_allclose(e.p[:2], [0.4 * 0.25 / 0.2525, -0.3 * 0.25 / 0.2525], atol=1e-3)
    assert np.degrees(heading(e.R)) == pytest.approx(
        1.0 * 0.02**2 / (0.02**2 + np.radians(0.3) ** 2), abs=0.02
    )
    assert np.sqrt(e.P[6, 6]) < 0.051 and np.sqrt(e.P[2, 2]) < np.radians(0.3)
    np.testing.assert_allclose(up.correction[:2], e.p[:2], atol=1e-9)


def test_a_wrong_place_is_gated_and_changes_nothing() -> None:
    e = _ekf(sig_pos=0.1)
    P0 = e.P.copy()
    cov = np.diag([0.05**2, 0.05**2, 0.02**2, np.inf])  # no yaw: that row is left out
    up = update_pose(e, np.array([1.5, 0.0, 0.0, 0.0]), cov, gate_chi2=16.27)
    assert not up.accepted and up.dof == 3 and up.d2 > 16.27
    np.testing.assert_array_equal(e.P, P0)
    assert not e.p.any()


def test_the_track_moves_with_a_correction() -> None:
    t = FootholdTrack(keep_m=10.0)
    t.add(np.array([[1.0, 0.0, 0.0], [2.0, 0.0, 0.1]]), walked_m=0.0)
    t.add(np.array([[3.0, 0.0, 0.2]]), walked_m=12.0)  # the first two are now older than 10 m
    assert len(t) == 1
    t.shift(np.array([3.0, 0.0, 0.0]), np.array([3.5, 0.5, 0.1]), np.pi / 2)
    np.testing.assert_allclose(t.window(5.0, 12.0), [[3.5, 0.5, 0.3]])


def test_a_partial_overlap_is_matched_without_being_pulled_onto_the_map() -> None:
    z = _relief(4)
    known = np.zeros(z.shape, bool)
    known[:, :120] = True  # the map holds only x < 12 m: the track leaves it halfway
    ref = GridReference(
        np.where(known, z, np.nan), np.where(known, 0.01, np.nan), -RES / 2, -RES / 2, RES,
        *(np.where(known, g, 0.0) for g in np.gradient(z, RES)[::-1]),
    )  # fmt: skip
    xy = _track(300, 12.0, 0.0) + (3.0, 0.0)  # x from 8 to 20 m along y = 5
    h, _ = _ref(z).heights(xy[:, 0], xy[:, 1])
    off = np.array([0.25, -0.15])
    pts = np.column_stack([xy - off, h + np.random.default_rng(5).normal(0, 0.01, len(h))])
    r = match_track(
        pts, ref, MatchConfig(window_m=0.8, yaw_window_deg=0.0, min_coverage=0.25), pivot=xy[-1] - off
    )
    assert r.ok, r.reason
    assert np.hypot(r.dx - off[0], r.dy - off[1]) < 0.05


def test_where_the_place_is_not_found_the_height_is_and_its_sigma_holds_the_place() -> None:
    """A DEM-like reference (5 m cells, 0.3 m per cell) that cannot place the track still bounds its height:
    `match_height` returns the datum at the estimated place, its variance grows with the slope times the
    horizontal σ (the datum differs between the places the estimate allows)."""
    from scout_agent.localization.matcher import match_height

    pts_xy = _track(600, length=30.0)
    n = 40
    for slope, lo, hi in ((0.0, 0.0, 0.05), (0.1, 0.04, 0.2)):
        z = 0.5 + slope * (np.arange(n) * 5.0)[None, :] + np.zeros((n, n))
        ref = GridReference(
            z, np.full(z.shape, 0.3), -2.5, -2.5, 5.0, np.full(z.shape, slope), np.zeros(z.shape)
        )
        h, _ = ref.heights(pts_xy[:, 0], pts_xy[:, 1])
        fix = match_height(
            np.column_stack([pts_xy, h - 0.4]), ref, sigma_xy_m=1.0, cfg=MatchConfig(step_m=0.5)
        )
        assert fix is not None and fix.dz == pytest.approx(0.4, abs=0.02)
        assert lo <= np.sqrt(fix.var_m2) <= hi, (slope, np.sqrt(fix.var_m2))
    # off the reference: no fix
    far = np.column_stack([pts_xy + 500.0, np.zeros(len(pts_xy))])
    assert match_height(far, ref, 1.0) is None


def test_a_drifting_height_is_fixed_at_the_track_end_within_its_sigma() -> None:
    """A 100 m track whose estimated height drifts up 2 cm per metre walked, from a datum 0.4 m high, against a
    DEM of 5 m pixels with 0.3 m noise (drawn anew each time): fitted as a line in the distance walked, the
    datum at the newest foothold is the estimate's error there (2.4 m high) within its stated σ (normalised
    error² ≈ 1 over the draws), where the track's mean datum lags it by half the track's drift (1 m)."""
    from scout_agent.localization.matcher import match_height

    n_pts, length = 800, 100.0
    pts_xy = _track(n_pts, length=length, heading_rad=0.7)
    walked = np.linspace(0.0, length, n_pts)
    n = 40
    relief = gaussian_filter(np.random.default_rng(3).normal(0, 1, (n, n)), 2.0) * 4.0
    err_end = 0.4 + 0.02 * length
    z2, lag = [], []
    for seed in range(40):
        noisy = relief + np.random.default_rng(seed).normal(0, 0.3, relief.shape)
        ref = GridReference(noisy, np.full(relief.shape, 0.3), -2.5, -2.5, 5.0)
        truth = GridReference(relief, np.full(relief.shape, 0.3), -2.5, -2.5, 5.0)
        h, _ = truth.heights(pts_xy[:, 0], pts_xy[:, 1])
        pts = np.column_stack([pts_xy, h + 0.4 + 0.02 * walked])
        fix = match_height(pts, ref, 0.5, MatchConfig(step_m=0.5), walked, rate_sigma=0.02)
        mean = match_height(pts, ref, 0.5, MatchConfig(step_m=0.5))
        assert fix is not None and mean is not None
        z2.append((fix.dz + err_end) ** 2 / fix.var_m2)
        lag.append(mean.dz + err_end)
        assert fix.rate == pytest.approx(-0.02, abs=0.01)
    assert 0.3 < np.mean(z2) < 2.0, np.mean(z2)
    assert max(z2) < 10.8  # none beyond p = 0.001
    assert np.mean(lag) > 0.8  # the mean datum: ≈ 1 m short of the error at the end


def test_the_localizer_fuses_a_dem_height_where_the_place_is_flat_and_never_moves_the_place() -> None:
    """On a flat DEM (or shared map) the match is refused ("flat") and the position stays where it was; the
    height alone is fused (the estimate 0.5 m low comes up by most of it)."""
    from types import SimpleNamespace

    from scout_agent.localization import Localizer, LocalizerConfig

    n = 40
    flat = GridReference(np.full((n, n), 0.5), np.full((n, n), 0.3), -2.5, -2.5, 5.0, np.zeros((n, n)),
                         np.zeros((n, n)))  # fmt: skip
    for use_dem in (True, False):
        e = _ekf(sig_pos=1.0)
        e.P[8, 8] = 1.0  # height σ 1 m (a declared datum)
        e.p[:] = (20.0, 15.0, 0.0)
        est = SimpleNamespace(ekf=e, feet=None)
        loc = Localizer(est, LocalizerConfig(), dem=flat if use_dem else None,  # type: ignore[arg-type]
                        map_source=None if use_dem else (lambda x, y, r: flat))  # fmt: skip
        pts = np.column_stack([_track(600, length=30.0) + (-5.0, -8.0), np.zeros(600)])
        loc.track.add(pts, 0.0)
        loc.localize("dem" if use_dem else "map")
        name = "dem" if use_dem else "map"
        assert loc.report.refused[f"{name}_flat"] == 1
        np.testing.assert_allclose(e.p[:2], (20.0, 15.0), atol=1e-6)
        assert loc.report.fused[f"{name}_height"] == 1
        assert 0.3 < e.p[2] < 0.55 and np.sqrt(e.P[8, 8]) < 0.5


def test_a_height_against_the_other_scouts_cells_weighs_their_stated_datum() -> None:
    """The shared map's cells, mapped by another scout 0.3 m above where this scout's estimate puts the same
    ground, on a relief that does not place the track (flat): a well-datumed other scout (σ 0.05 m) pulls the
    estimate (σ 0.5 m) up by nearly all of it, a poorly datumed one (σ 1 m) by a fifth; the place never moves;
    the next fix waits for `height_every_m` walked (the other's datum error is common to both)."""
    from dataclasses import replace
    from types import SimpleNamespace

    from scout_agent.localization import Localizer, LocalizerConfig

    n = 200
    for datum_m, lo, hi in ((0.05, 0.25, 0.31), (1.0, 0.03, 0.09)):
        others = GridReference(np.full((n, n), 0.3), np.full((n, n), 0.02), 0.0, 0.0, 0.4, np.zeros((n, n)),
                               np.zeros((n, n)), datum_sigma=np.full((n, n), datum_m))  # fmt: skip
        e = _ekf(sig_pos=0.3)
        e.P[8, 8] = 0.25
        e.p[:] = (20.0, 15.0, 0.0)
        cfg = LocalizerConfig()
        loc = Localizer(SimpleNamespace(ekf=e, feet=None), cfg, map_source=lambda x, y, r, ref=others: ref)  # type: ignore[arg-type]
        pts = np.column_stack([_track(200, length=10.0) + (10.0, 5.0), np.zeros(200)])
        loc.track.add(pts, 0.0)
        loc.walked_m = 10.0
        loc.localize("map")
        assert loc.report.fused["map_height"] == 1, loc.report
        np.testing.assert_allclose(e.p[:2], (20.0, 15.0), atol=1e-6)
        assert lo < e.p[2] < hi, (datum_m, e.p[2])
        loc.walked_m = 10.0 + cfg.map.height_every_m - 1.0
        loc.localize("map")
        assert loc.report.fused["map_height"] == 1  # not yet: within 20 m of the last
    # without a stated datum the cells' scatter alone: as sure as the cells (the old behaviour's weight)
    assert replace(others, datum_sigma=None).datum_var(np.array([1.0]), np.array([1.0])) == 0.0
    assert others.datum_var(np.array([1.0, 500.0]), np.array([1.0, 1.0])) == pytest.approx(1.0)


def _dem_like(
    seed: int, amp_m: float, noise_m: float = 0.3, n: int = 40
) -> tuple[GridReference, GridReference]:
    """A 5 m/px reference over 200 m (bilinear, as DemReference reads a DEM) with `noise_m` per pixel, and the
    noise-free one the footholds stand on."""
    from scout_agent.dem_reader import DemGrid
    from scout_agent.localization import DemReference

    rng = np.random.default_rng(seed)
    clean = gaussian_filter(rng.normal(0, 1, (n, n)), 2.0) * amp_m
    noisy = clean + rng.normal(0, noise_m, (n, n))
    return (DemReference(DemGrid(noisy, 2.5, 2.5, 5.0, noise_m, "test"), subpixel_m=0.05),  # type: ignore[return-value]
            DemReference(DemGrid(clean, 2.5, 2.5, 5.0, 0.0, "test"), subpixel_m=0.05))  # fmt: skip


def test_the_dem_likelihood_moments_hold_the_true_offset_and_refuse_what_the_window_cuts() -> None:
    """method "moments" (the DEM's): over seeds, the recovered (x, y, yaw) offset's error lies inside its
    covariance as a χ²₃ should (mean normalised error² near 3, none beyond p = 0.001); a window too small
    for the likelihood is refused ("edge"), never fused with a cut covariance."""
    nees, refused = [], 0
    for seed in range(8):
        noisy, clean = _dem_like(seed, amp_m=20.0)
        xy = _track(800, length=80.0, heading_rad=0.7) + 40.0
        h, _ = clean.heights(xy[:, 0], xy[:, 1])
        off, a = np.array([1.2, -0.8]), np.radians(2.0)
        pivot = xy[-1]
        rot = np.array([[np.cos(-a), -np.sin(-a)], [np.sin(-a), np.cos(-a)]])
        est = pivot - off + (xy - pivot) @ rot.T
        cfg = MatchConfig(window_m=6.0, step_m=0.5, yaw_window_deg=6.0, yaw_step_deg=0.75, max_sigma_m=2.5,
                          method="moments")  # fmt: skip
        r = match_track(np.column_stack([est, h - 0.3]), noisy, cfg, pivot=pivot - off)
        if not r.ok:
            refused += 1
            continue
        e = np.array([r.dx - off[0], r.dy - off[1], r.dyaw - a])
        C = r.cov[np.ix_([0, 1, 3], [0, 1, 3])]
        nees.append(float(e @ np.linalg.solve(C, e)))
        assert r.dz == pytest.approx(0.3, abs=4 * np.sqrt(r.cov[2, 2]) + 0.05)
    assert refused <= 2 and len(nees) >= 6
    assert max(nees) < 16.3 and 0.5 < np.mean(nees) < 6.0, nees
    # the same track with a window of ±1 m: the likelihood (σ ≈ 0.5-1 m) is cut by it
    cut = match_track(np.column_stack([est, h - 0.3]), noisy, replace_window(cfg, 1.0), pivot=pivot - off)
    assert not cut.ok and cut.reason == "edge"


def replace_window(cfg: MatchConfig, window_m: float) -> MatchConfig:
    from dataclasses import replace

    return replace(cfg, window_m=window_m)


def test_the_shared_map_reference_states_the_other_scouts_vertical_sigma_not_the_scouts_own() -> None:
    """`SharedMapSource` takes the scout's own part out of the shared sums for the height layer as for the
    elevation: a cell both mapped keeps the other scout's footholds and their stated σ (0.2 m), the scout's
    own σ (0.05 m) does not count; a cell only the scout mapped is unknown."""
    from psrmap_mapcore import LayerGrid
    from scout_agent.cells import CellAccumulator, LocalMap
    from scout_agent.holding import elevation_rows, height_rows
    from scout_agent.localization.shared_map import SharedMapSource

    res = 0.4

    def mapped(xs: np.ndarray, z: float, sigma: float) -> LocalMap:
        acc = CellAccumulator(res)
        ys = np.full_like(xs, 0.5)
        zs = np.full_like(xs, z)
        for row in elevation_rows(xs, ys, zs, res).tolist():
            acc.append("elevation", tuple(row))
        for row in height_rows(xs, ys, zs, np.full_like(xs, sigma), res).tolist():
            acc.append("height", tuple(row))
        m = LocalMap(res)
        m.merge(acc.flush())
        return m

    xs = np.repeat(np.arange(0.1, 4.0, 0.4), 3) + np.tile(
        [0.0, 0.1, 0.2], 10
    )  # 3 footholds in each of 10 cells
    own, other = mapped(xs, 1.0, 0.05), mapped(xs[xs < 2.0], 1.3, 0.2)  # the other: the first 5 cells
    shared = LocalMap(res)
    for m in (own, other):
        shared.merge({layer: m.cells(layer) for layer in ("elevation", "height")})
    src = object.__new__(SharedMapSource)
    src.own, src.min_count = own, 2.0
    region = shared.region(0, 0, 9, 2)
    src._grid = LayerGrid("moon", res, 0, 0, 3, 10, {k: region[k] for k in ("elevation", "height")})
    ref = src._others()
    assert ref is not None and ref.datum_sigma is not None
    h, _ = ref.heights(np.array([0.3, 1.5, 2.5, 3.5]), np.array([0.5] * 4))
    np.testing.assert_allclose(h[:2], 1.3, atol=1e-9)  # the other scout's cells, its height
    assert np.isnan(h[2:]).all()  # the scout's own cells alone: unknown
    assert ref.datum_var(np.array([0.3, 1.5]), np.array([0.5, 0.5])) == pytest.approx(0.2**2)


def test_the_walks_end_brings_one_last_fix_for_the_last_stretch() -> None:
    """`Localizer.finish` at the walk's end: a walk of 20 m (shorter than the DEM's first 30 m track) gets
    one height fix; right after an attempt, or after too short a walk, none."""
    from types import SimpleNamespace

    from scout_agent.localization import Localizer, LocalizerConfig

    n = 40
    flat = GridReference(np.full((n, n), 0.5), np.full((n, n), 0.3), -2.5, -2.5, 5.0, np.zeros((n, n)),
                         np.zeros((n, n)))  # fmt: skip
    for walked, attempts in ((20.0, 1), (10.0, 0)):
        e = _ekf(sig_pos=0.3)
        e.P[8, 8] = 0.25
        e.p[:] = (20.0, 15.0, 0.0)
        loc = Localizer(SimpleNamespace(ekf=e, feet=None), LocalizerConfig(), dem=flat)  # type: ignore[arg-type]
        loc.track.add(np.column_stack([_track(400, length=walked) + (5.0, 5.0), np.zeros(400)]), walked)
        loc.walked_m = walked
        loc.finish()
        assert loc.report.attempts == attempts
        assert (loc.report.fused["dem_height"] == 1) == bool(attempts)
        loc.finish()  # nothing walked since: no second attempt
        assert loc.report.attempts == attempts


def test_the_robots_own_height_drift_rate_is_learnt_from_the_dem_fixes() -> None:
    """(Off by default.) A scout whose height drifts up 1.5 cm per metre walked, over a DEM of 5 m pixels with
    0.3 m noise that cannot place it (flat): the DEM height fix's slope along the 100 m track teaches the rate
    (within 3 of its σ, the σ shrunk from the prior's 2 cm/m), with the sign that takes it off the estimate."""
    from types import SimpleNamespace

    from scout_agent.localization import Localizer, LocalizerConfig

    n = 60
    errs = []
    for seed in range(6):
        noisy = np.random.default_rng(seed).normal(0.0, 0.3, (n, n))
        dem = GridReference(noisy, np.full((n, n), 0.3), -2.5, -2.5, 5.0)
        e = _ekf(sig_pos=0.5)
        e.P[8, 8] = 0.25
        e.p[:] = (80.0, 80.0, 0.0)
        loc = Localizer(SimpleNamespace(ekf=e, feet=None), LocalizerConfig(drift_rate_sigma=0.02), dem=dem)  # type: ignore[arg-type]
        walked = np.linspace(0.0, 100.0, 800)
        xy = _track(800, length=100.0, heading_rad=0.7) + (10.0, 10.0)
        loc.track.add(np.column_stack([xy, 0.015 * walked])[:400], 50.0)  # placed halfway ...
        loc.track.add(np.column_stack([xy, 0.015 * walked])[400:], 100.0)  # ... and at the end
        loc.track._s[:800] = walked  # each foothold at its own distance
        loc.walked_m = 100.0
        loc.localize("dem")
        assert loc.report.fused["dem_height"] == 1
        sigma = np.sqrt(loc.drift_rate_var)
        assert sigma < 0.02
        errs.append((loc.drift_rate - 0.015) / sigma)
    assert np.max(np.abs(errs)) < 3.0, errs
    assert abs(np.mean(errs)) < 1.5


def test_only_a_fused_fix_reaches_the_mapper_not_the_learnt_drift_taken_off() -> None:
    """The run loop hands the mapper a `PoseFix` when the localizer fused one, and only then: the learnt
    height drift taken off the estimate every tick is dead reckoning (a fix per tick would release the
    held samples tick by tick), and it is not counted in a fix's correction."""
    from types import SimpleNamespace

    from scout_agent.localization import LocalizerReport
    from scout_agent.run import _localize_and_report

    e = _ekf(sig_pos=0.3)
    est = SimpleNamespace(ekf=e, position_covariance=e.P[6:9, 6:9].copy)  # a view's copy: P as it is then
    loc = SimpleNamespace(report=LocalizerReport(), drift_step_m=0.0)
    got = []

    def drift_only():
        loc.drift_step_m = 0.002
        e.p[2] -= 0.002

    def drift_and_fix():
        drift_only()
        e.p[2] += 0.3
        loc.report.fused["dem_height"] += 1

    _localize_and_report(loc, est, drift_only, got.append)  # type: ignore[arg-type]
    assert got == []
    _localize_and_report(loc, est, drift_and_fix, got.append)  # type: ignore[arg-type]
    assert len(got) == 1 and got[0].correction[2] == pytest.approx(0.3)


def test_a_place_fix_against_the_others_cells_is_no_surer_than_they_were_placed() -> None:
    """A match against the shared map places the scout in the frame the other scouts' estimates drew their
    cells in: the cells' placement σ (their `placement` layer) is added whole to the fix. The same 0.3 m offset
    on the same relief: against cells placed to 1 cm the estimate takes nearly all of it; against cells placed
    to 0.4 m at most two thirds, and it keeps a σ of ≥ 0.3 m, 1.5 times the other's at least; and the
    heading is never made surer than the reference frame's stated heading σ allows."""
    from dataclasses import replace
    from types import SimpleNamespace

    from scout_agent.localization import Localizer, LocalizerConfig

    z = _relief(4)
    off = np.array([0.3, 0.0])
    xy = _track(120, length=3.0, heading_rad=0.6) + (6.0, 6.0)
    h, _ = _ref(z).heights(xy[:, 0], xy[:, 1])
    taken, sigma, sig_yaw = {}, {}, {}
    for place_m in (0.01, 0.4):
        ref = replace(_ref(z), place_sigma=np.full(z.shape, place_m))
        e = _ekf(sig_pos=0.5, sig_yaw=np.radians(5.0))
        e.p[:2] = xy[-1] - off
        loc = Localizer(SimpleNamespace(ekf=e, feet=None), LocalizerConfig(),  # type: ignore[arg-type]
                        map_source=lambda x, y, r, ref=ref: ref)  # fmt: skip
        loc.track.add(np.column_stack([xy - off, h]), 20.0)
        loc.walked_m = 20.0
        loc.localize("map")
        assert loc.report.fused["map"] == 1, loc.report
        taken[place_m] = float((e.p[0] - (xy[-1, 0] - off[0])) / off[0])
        sigma[place_m] = float(np.sqrt(np.linalg.eigvalsh(e.P[6:8, 6:8]).max()))
        sig_yaw[place_m] = float(np.degrees(np.sqrt(e.P[2, 2])))
    assert taken[0.01] > 0.85 and taken[0.4] < 0.67, taken
    assert sigma[0.4] >= 0.3 and sigma[0.4] > 1.5 * sigma[0.01], sigma
    frame = LocalizerConfig().map.frame_yaw_sigma_deg
    assert min(sig_yaw.values()) > 0.9 * frame * 5.0 / np.hypot(frame, 5.0), sig_yaw


def test_a_height_against_the_others_cells_averages_over_where_they_and_the_scout_may_be() -> None:
    """The height from the others' cells on sloping ground, where the place match is refused: the datum is
    read over the places the scout's σ and the others' placement σ allow together, so cells they placed with a
    1.5 m σ pull the height less than the same cells placed to 1 cm, and the stated σ grows with it."""
    from types import SimpleNamespace

    from scout_agent.localization import Localizer, LocalizerConfig

    n = 200
    yy, xx = np.mgrid[0:n, 0:n] * 0.4 + 0.2
    slope = 0.25 * xx + 0.1 * np.sin(yy / 3.0)  # a 14° slope, rolling across
    pulled, sig = {}, {}
    for place_m in (0.01, 1.5):
        others = GridReference(slope + 0.3, np.full((n, n), 0.02), 0.0, 0.0, 0.4, np.full((n, n), 0.25),
                               0.1 / 3.0 * np.cos(yy / 3.0), datum_sigma=np.full((n, n), 0.05),
                               place_sigma=np.full((n, n), place_m))  # fmt: skip
        e = _ekf(sig_pos=0.3)
        e.P[8, 8] = 0.25
        xy = _track(200, length=10.0, heading_rad=np.pi / 2) + (30.0, 20.0)  # along the contour
        h, _ = GridReference(slope, np.full((n, n), 0.02), 0.0, 0.0, 0.4).heights(xy[:, 0], xy[:, 1])
        e.p[:] = (*xy[-1], 0.0)
        cfg = LocalizerConfig()
        loc = Localizer(SimpleNamespace(ekf=e, feet=None), cfg, map_source=lambda x, y, r, ref=others: ref)  # type: ignore[arg-type]
        loc.track.add(np.column_stack([xy, h]), 0.0)
        loc.walked_m = 10.0
        loc.localize("map")
        assert loc.report.fused["map_height"] == 1, loc.report
        pulled[place_m], sig[place_m] = float(e.p[2]), float(np.sqrt(e.P[8, 8]))
    assert pulled[0.01] > 0.25 and pulled[1.5] < 0.8 * pulled[0.01], pulled
    assert sig[1.5] > 1.5 * sig[0.01], sig
