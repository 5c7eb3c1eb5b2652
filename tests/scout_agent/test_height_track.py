"""The DEM's height from the whole walk (`localization.height_track`): each DEM pixel's error is counted once
however often the footholds read it, the datum and its drift per metre are fitted together within their stated
σ, one early fix does not set the rate, and the localizer sets its height to the walk's datum without counting
the same footholds twice, handing the mapper the walk's datum with the fix."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
from scipy.ndimage import gaussian_filter, map_coordinates

from scout_agent.dem_reader import DemGrid
from scout_agent.localization import DemReference, Localizer, LocalizerConfig
from scout_agent.localization.height_track import HeightTrack, HeightTrackConfig
from scout_agent.run import _localize_and_report
from scout_agent.state_estimation import ErrorStateEKF, NoiseConfig

N_PIX, PIX, NOISE = 40, 5.0, 0.3


def _dems(seed: int, amp_m: float = 4.0) -> tuple[DemGrid, DemGrid]:
    """A 5 m/px DEM over 200 m with 0.3 m noise per pixel, and the noise-free relief the feet stand on."""
    rng = np.random.default_rng(seed)
    clean = gaussian_filter(np.random.default_rng(1000).normal(0, 1, (N_PIX, N_PIX)), 2.0) * amp_m
    noisy = clean + rng.normal(0, NOISE, clean.shape)
    return DemGrid(noisy, 2.5, 2.5, PIX, NOISE, "test"), DemGrid(clean, 2.5, 2.5, PIX, 0.0, "test")


def _walk(
    length_m: float, per_m: int = 8, heading: float = 0.7, origin=(20.0, 20.0)
) -> tuple[np.ndarray, np.ndarray]:
    """Footholds (n, 2) along a straight line and the distance walked at each."""
    s = np.linspace(0.0, length_m, int(length_m * per_m))
    u = np.array([np.cos(heading), np.sin(heading)])
    side = np.where(np.arange(len(s)) % 2, 0.15, -0.15)
    return np.array(origin) + s[:, None] * u + side[:, None] * np.array([-u[1], u[0]]), s


def _fill(
    track: HeightTrack, xy: np.ndarray, z: np.ndarray, walked: np.ndarray, sigma_xy: float = 0.05
) -> None:
    for k in range(len(walked)):
        track.add(np.array([[xy[k, 0], xy[k, 1], z[k]]]), float(walked[k]), sigma_xy)


def test_footholds_reading_the_same_pixels_again_are_not_new_evidence() -> None:
    """A 20 m stretch walked once, and walked five times over (there and back), the estimate's height off by a
    constant (the drift's line and walk held fixed, so only the datum is fitted): the datum's σ after five
    passes is nearly the σ after one (the DEM's pixel errors limit it, and they are the same pixels), and over
    40 DEM draws the datum lies within that σ (normalised error² ≈ 1) either way. Counting footholds as
    independent would shrink it by √5 and be overconfident."""
    xy1, s1 = _walk(20.0)
    z2 = {1: [], 5: []}
    sig = {1: [], 5: []}
    for seed in range(40):
        dem, clean = _dems(seed)
        for passes in (1, 5):
            xy = np.vstack([xy1 if p % 2 == 0 else xy1[::-1] for p in range(passes)])
            walked = np.arange(len(xy)) * (s1[1] - s1[0])
            true = clean.height(xy[:, 0], xy[:, 1])
            err = 0.4  # the estimate's height 0.4 m above the ground, no drift
            ht = HeightTrack(HeightTrackConfig(rate_sigma=1e-9, walk_sigma=1e-9))
            _fill(ht, xy, true + err, walked)
            fix = ht.fix(dem, 0.05, float(walked[-1]))
            assert fix is not None
            z2[passes].append((fix.dz + err) ** 2 / fix.var_m2)
            sig[passes].append(np.sqrt(fix.var_m2))
    assert np.mean(sig[5]) > 0.9 * np.mean(sig[1]), (np.mean(sig[1]), np.mean(sig[5]))
    for passes in (1, 5):
        assert 0.4 < np.mean(z2[passes]) < 1.8, (passes, np.mean(z2[passes]))
        assert max(z2[passes]) < 10.8  # none beyond p = 0.001


def test_the_walks_datum_and_drift_are_fitted_together_and_one_fix_does_not_set_the_rate() -> None:
    """A 120 m walk whose height is 0.4 m low at launch and drifts up 8 mm per metre walked, fixed at 30, 55,
    80, 105 and 120 m: the datum at each fix lies within its σ over 30 DEM draws (normalised error² ≈ 1), the
    end's σ is smaller than the first's, and the rate after the first 30 m lies within its σ too (normalised
    error² ≈ 1: one short track cannot claim to know it, as the learnt rate did when it locked onto one track's
    slope and a scout ran 1.8 m away)."""
    xy, s = _walk(120.0)
    err = -0.4 + 0.008 * s
    z2, rate_z2, sig_first, sig_end = [], [], [], []
    for seed in range(30):
        dem, clean = _dems(seed)
        true = clean.height(xy[:, 0], xy[:, 1])
        ht = HeightTrack()
        at = 0
        for s_fix in (30.0, 55.0, 80.0, 105.0, 120.0):
            upto = np.searchsorted(s, s_fix, side="right")
            _fill(ht, xy[at:upto], true[at:upto] + err[at:upto], s[at:upto])
            at = upto
            fix = ht.fix(dem, 0.05, float(s[upto - 1]))
            assert fix is not None
            z2.append((fix.dz + err[upto - 1]) ** 2 / fix.var_m2)
            if s_fix == 30.0:
                rate_z2.append((fix.rate + 0.008) ** 2 / ht.rate_var)  # reference minus estimate: −8 mm/m
                sig_first.append(np.sqrt(fix.var_m2))
        sig_end.append(np.sqrt(fix.var_m2))
    assert 0.4 < np.mean(z2) < 1.8, np.mean(z2)
    assert max(z2) < 10.8
    assert np.mean(sig_end) < 0.8 * np.mean(sig_first)
    assert 0.3 < np.mean(rate_z2) < 2.0 and max(rate_z2) < 10.8, rate_z2


def test_relief_below_the_pixel_that_holds_over_metres_is_not_counted_per_bin() -> None:
    """The ground under a 120 m walk carries relief the DEM cannot show (σ 0.2 m, correlated over metres, as a
    degraded crater or a rock field): stated per 1 m bin as white noise, the walk's datum is overconfident
    (normalised error² 2.3 over 30 draws); counted once per DEM pixel of walk (`relief_corr_m`, default the
    pixel), its σ holds the error (≈ 1.5) and the datum is no worse."""
    xy, s = _walk(120.0)
    err = -0.4 + 0.008 * s
    z2: dict[float | None, list[float]] = {1.0: [], None: []}
    e: dict[float | None, list[float]] = {1.0: [], None: []}
    for seed in range(30):
        dem, clean = _dems(seed)
        cells = np.random.default_rng(500 + seed).normal(0, 1, (440, 440))  # 0.5 m cells over 220 m
        relief = gaussian_filter(cells, 5.0)
        relief *= 0.2 / relief.std()
        under = map_coordinates(relief, [xy[:, 1] / 0.5, xy[:, 0] / 0.5], order=1)
        true = clean.height(xy[:, 0], xy[:, 1]) + under
        for corr in (1.0, None):
            ht = HeightTrack(HeightTrackConfig(relief_corr_m=corr))
            _fill(ht, xy, true + err, s)
            fix = ht.fix(dem, 0.2, float(s[-1]))
            assert fix is not None
            z2[corr].append((fix.dz + err[-1]) ** 2 / fix.var_m2)
            e[corr].append(abs(fix.dz + err[-1]))
    assert np.mean(z2[1.0]) > 2.0, np.mean(z2[1.0])  # white: overconfident
    assert 0.5 < np.mean(z2[None]) < 1.8, np.mean(z2[None])
    assert max(z2[None]) < 10.8
    assert np.sqrt(np.mean(np.square(e[None]))) <= 1.02 * np.sqrt(np.mean(np.square(e[1.0])))


def test_the_walks_datum_behind_the_newest_foothold_states_its_own_variance() -> None:
    """The fix's datum along the walk behind it (`last_profile`) and its posterior variance there
    (`last_profile_var`, what the held footholds' vertical σ becomes): over 30 DEM draws of a 120 m walk
    (0.4 m low at launch, drifting 8 mm/m), the profile at every 10 m lies within its σ (normalised error²
    ≈ 1, none beyond p = 0.001); at the newest foothold the variance is the fix's own; in the walk's middle,
    with evidence on both sides, it is smaller than at its ends (what a filter knew when it stood there)."""
    xy, s = _walk(120.0)
    err = -0.4 + 0.008 * s
    at = np.arange(0.0, 121.0, 10.0)
    z2, var_mid, var_end = [], [], []
    for seed in range(30):
        dem, clean = _dems(seed)
        ht = HeightTrack()
        _fill(ht, xy, clean.height(xy[:, 0], xy[:, 1]) + err, s)
        fix = ht.fix(dem, 0.05, float(s[-1]))
        assert fix is not None and ht.last_profile is not None and ht.last_profile_var is not None
        rel = at - float(s[-1])
        var = ht.last_profile_var(rel)
        assert abs(float(var[-1]) - fix.var_m2) < 1e-9 * max(fix.var_m2, 1.0)
        z2.extend((ht.last_profile(rel) + np.interp(at, s, err)) ** 2 / var)
        var_mid.append(float(var[6]))
        var_end.append(max(float(var[0]), float(var[-1])))
    assert 0.4 < np.mean(z2) < 1.8, np.mean(z2)
    assert max(z2) < 10.8
    assert np.mean(var_mid) < 0.7 * np.mean(var_end), (np.mean(var_mid), np.mean(var_end))


def _ekf(sig_z: float) -> ErrorStateEKF:
    e = ErrorStateEKF(np.eye(3), np.zeros(3), np.zeros(3), np.array([0, 0, -1.62]), NoiseConfig())
    e.P[6:8, 6:8] = np.eye(2) * 0.3**2
    e.P[2, 2] = 0.02**2
    e.P[8, 8] = sig_z**2
    return e


def test_the_localizer_takes_the_walks_datum_once_and_keeps_a_shared_map_height() -> None:
    """Through the localizer, on a flat DEM (the place refused): the filter's height and its variance become the
    walk's datum and its variance (+ the DEM's bias); a second attempt with nothing walked since adds nothing
    (refused "dem_height_known", the height unmoved); a height the shared map gave in between stays in the next
    DEM fix (as a point of the same problem), where fusing the DEM's again as independent would pull it back."""
    flat = DemGrid(np.random.default_rng(5).normal(0.0, NOISE, (N_PIX, N_PIX)), 2.5, 2.5, PIX, NOISE, "test")
    xy, s = _walk(60.0)
    e = _ekf(0.5)
    e.p[:] = (*xy[-1], 0.3)
    cfg = LocalizerConfig()
    est = SimpleNamespace(ekf=e, feet=None, position_covariance=e.P[6:9, 6:9].copy)  # a view: P as it is then
    loc = Localizer(est, cfg, dem=DemReference(flat, subpixel_m=0.05))  # type: ignore[arg-type]
    assert loc.heights is not None
    pts = np.column_stack([xy, np.full(len(xy), 0.3)])  # the estimate 0.3 m above the DEM's flat ground
    for k in range(len(s)):
        loc.track.add(pts[k : k + 1], float(s[k]))
        loc.heights.add(pts[k : k + 1], float(s[k]), 0.3)
    loc.walked_m = float(s[-1])
    fix = loc.heights.fix(flat, 0.05, loc.walked_m)
    assert fix is not None
    fixes: list = []
    _localize_and_report(loc, est, lambda: loc.localize("dem"), fixes.append)  # type: ignore[arg-type]
    assert loc.report.fused["dem_height"] == 1, loc.report
    # the mapper gets the fix with the walk's datum behind it (holding.py revises its held heights by it)
    assert len(fixes) == 1 and fixes[0].height_profile is not None
    assert abs(float(fixes[0].height_profile(np.array([0.0]))[0]) - fix.dz) < 1e-9
    # ... and its variance along the walk, the DEM's vertical bias added (the held footholds' vertical σ)
    assert fixes[0].height_profile_var is not None
    v_now = float(fixes[0].height_profile_var(np.array([0.0]))[0])
    assert abs(v_now - (fix.var_m2 + cfg.dem.datum_m**2)) < 1e-9
    assert abs(e.p[2] - (0.3 + fix.dz)) < 1e-6
    assert abs(e.P[8, 8] - (fix.var_m2 + cfg.dem.datum_m**2)) < 1e-9
    z_after, var_after = float(e.p[2]), float(e.P[8, 8])
    loc.localize("dem")
    assert loc.report.refused["dem_height_known"] == 1
    assert e.p[2] == z_after
    # the shared map says the ground is 0.2 m lower than the estimate has it, with σ 0.05 m
    loc.heights.add_point(loc.walked_m, -0.2, 0.05**2)
    e.p[2] -= 0.2  # as its own height fix would have moved the filter
    e.P[8, 8] = 1.0 / (1.0 / var_after + 1.0 / 0.05**2)
    loc.heights.shift(np.r_[e.p[:2], z_after], e.p.copy(), 0.0)
    e.P[8, 8] += 0.1  # walked on: the filter's height less sure again
    loc.localize("dem")
    # the two combined once: the DEM's datum (variance var_after) and the map's (0.05²)
    combined = z_after - 0.2 * var_after / (var_after + 0.05**2)
    assert abs(float(e.p[2]) - combined) < 0.01, (e.p[2], combined)
    assert abs(float(e.P[8, 8]) - 1.0 / (1.0 / var_after + 1.0 / 0.05**2)) < 2e-3
