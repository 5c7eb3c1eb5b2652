"""Fleet ties (scout_agent/localization/fleet_ties.py): the other scouts' cells under the stretch a scout still
holds measure its datum there, with the others' own datum error in the variance, and the whole-walk fit takes
them in."""

from __future__ import annotations

from functools import partial
from types import SimpleNamespace

import numpy as np
import pytest

from scout_agent.dem_reader import DemGrid
from scout_agent.errors import ScoutConfigError
from scout_agent.localization import DemReference, GridReference, Localizer, LocalizerConfig
from scout_agent.localization.fleet_ties import FleetTieConfig, fleet_ties
from scout_agent.run import _localize_and_report
from scout_agent.state_estimation import ErrorStateEKF, NoiseConfig

RES = 0.4


def _walk(length_m: float, per_m: int = 8, heading: float = 0.7, origin=(20.0, 20.0)):
    """Footholds (n, 2) along a straight line, two feet 0.3 m apart, and the distance walked at each."""
    s = np.linspace(0.0, length_m, int(length_m * per_m))
    u = np.array([np.cos(heading), np.sin(heading)])
    side = np.where(np.arange(len(s)) % 2, 0.15, -0.15)
    return np.array(origin) + s[:, None] * u + side[:, None] * np.array([-u[1], u[0]]), s


def _ground(x, y):
    """The true ground: a tilted, wavy surface (m)."""
    return 0.05 * x - 0.03 * y + 0.2 * np.sin(0.3 * x) * np.cos(0.2 * y)


def _others(
    datum_m: float, datum_sigma: float, place_sigma: float = 0.1, box=(0.0, 0.0, 120.0, 120.0), seed: int = 0
) -> GridReference:
    """The other scouts' cells over `box`: the ground + their datum error `datum_m`, cm scatter, their stated
    vertical σ `datum_sigma` and horizontal σ `place_sigma`."""
    x0, y0, x1, y1 = box
    nx, ny = int((x1 - x0) / RES), int((y1 - y0) / RES)
    cx = x0 + (np.arange(nx) + 0.5) * RES
    cy = y0 + (np.arange(ny) + 0.5) * RES
    X, Y = np.meshgrid(cx, cy)
    e = 1e-3
    z = _ground(X, Y) + datum_m + np.random.default_rng(seed).normal(0, 0.01, X.shape)
    gx = (_ground(X + e, Y) - _ground(X - e, Y)) / (2 * e)
    gy = (_ground(X, Y + e) - _ground(X, Y - e)) / (2 * e)
    full = lambda v: np.full(X.shape, v)  # noqa: E731
    return GridReference(z, full(0.02), x0, y0, RES, gx, gy, datum_sigma=full(datum_sigma),
                         place_sigma=full(place_sigma))  # fmt: skip


def test_each_held_piece_on_the_others_cells_measures_the_datum_with_their_sigma_added() -> None:
    """The estimate's footholds 0.25 m above the ground, the others' cells true to 0.01 m (their datum +0.01,
    stated σ 0.08): every complete piece within the span gives dz ≈ −0.24 within its σ, whose variance holds
    the others' datum variance counted datum_corr_m / piece_m times; pieces tied already are skipped."""
    xy, s = _walk(95.0)
    pts = np.column_stack([xy, _ground(xy[:, 0], xy[:, 1]) + 0.25])
    others = _others(0.01, 0.08)
    cfg = FleetTieConfig()
    ties = fleet_ties(pts, s, float(s[-1]), lambda x, y, r: others, 0.2, cfg)
    # complete pieces within 60 m of 95 m: 3 (30–40 m) … 8 (80–90 m)
    assert [t.piece for t in ties] == [3, 4, 5, 6, 7, 8]
    for t in ties:
        assert abs(t.dz_m - (-0.24)) < 3 * np.sqrt(t.var_m2), t
        assert abs(t.dz_m - (-0.24)) < 0.03, t
        assert t.var_m2 >= 0.08**2 * cfg.datum_corr_m / cfg.piece_m
        assert cfg.piece_m * t.piece <= t.walked_m <= cfg.piece_m * (t.piece + 1)
    again = fleet_ties(pts, s, float(s[-1]), lambda x, y, r: others, 0.2, cfg, skip={3, 5}.__contains__)
    assert [t.piece for t in again] == [4, 6, 7, 8]


def test_no_tie_where_the_others_have_no_cells_or_too_few_footholds_land_on_them() -> None:
    xy, s = _walk(95.0)
    pts = np.column_stack([xy, _ground(xy[:, 0], xy[:, 1])])
    elsewhere = _others(0.0, 0.05, box=(200.0, 200.0, 240.0, 240.0))
    assert fleet_ties(pts, s, float(s[-1]), lambda x, y, r: elsewhere, 0.2) == []
    assert fleet_ties(pts, s, float(s[-1]), lambda x, y, r: None, 0.2) == []
    # the others' cells cover the walk up to 42 m: piece 3 (30–40 m) whole, piece 4 (40–50 m) a fifth
    part = _others(0.0, 0.05, box=(0.0, 0.0, 20.0 + 42 * np.cos(0.7), 120.0))
    assert [t.piece for t in fleet_ties(pts, s, float(s[-1]), lambda x, y, r: part, 0.2)] == [3]


def test_a_bad_fleet_tie_config_names_what_would_be_valid() -> None:
    with pytest.raises(ScoutConfigError, match="piece_m"):
        FleetTieConfig(piece_m=0.0)
    with pytest.raises(ScoutConfigError, match="span_m"):
        FleetTieConfig(span_m=float("nan"))
    with pytest.raises(ScoutConfigError, match="min_points"):
        FleetTieConfig(min_points=0)


def _localizer(fleet: bool, others: GridReference | None, seed: int):
    """A localizer 95 m into a walk over a flat, noisy DEM (0.3 m per 5 m pixel; its place fixes refused), its
    footholds 0.25 m above the ground all the way; the others' cells (if any) from `others`."""
    rng = np.random.default_rng(seed)
    n_pix = 40
    dem = DemGrid(rng.normal(0.0, 0.3, (n_pix, n_pix)), 2.5, 2.5, 5.0, 0.3, "test")
    xy, s = _walk(95.0)
    # the DEM's ground is flat at 0: the feet stand on it, the estimate 0.25 m above
    pts = np.column_stack([xy, np.full(len(xy), 0.25)])
    e = ErrorStateEKF(np.eye(3), np.zeros(3), np.zeros(3), np.array([0, 0, -1.62]), NoiseConfig())
    e.P[6:8, 6:8] = np.eye(2) * 0.2**2
    e.P[2, 2] = 0.02**2
    e.P[8, 8] = 0.5**2
    e.p[:] = (*xy[-1], 0.25)
    est = SimpleNamespace(ekf=e, feet=None, position_covariance=e.P[6:9, 6:9].copy)
    cfg = LocalizerConfig(fleet_tie=FleetTieConfig() if fleet else None)
    source = (lambda x, y, r: others) if others is not None else None
    loc = Localizer(est, cfg, dem=DemReference(dem, subpixel_m=0.05), map_source=source)  # type: ignore[arg-type]
    assert loc.heights is not None
    for k in range(len(s)):
        loc.track.add(pts[k : k + 1], float(s[k]))
        loc.heights.add(pts[k : k + 1], float(s[k]), 0.2)
    loc.walked_m = loc._tried["map"] = float(s[-1])  # the map source tried just now: only the DEM is due
    return loc, e


def test_the_walks_end_takes_the_others_cells_into_the_held_stretchs_datum() -> None:
    """Over 20 DEM draws: at a DEM attempt or the walk's end the held stretch's datum (the profile the mapper revises the held
    footholds by) from the DEM alone errs by the DEM's noise; with the others' cells (true to 0.02 m, stated σ
    0.05 m) it lies within 3σ of the truth (−0.25 m) at every tied piece, and closer on average."""
    err_alone, err_fleet = [], []
    for seed in range(20):
        ground0 = _others(0.02, 0.05, seed=seed)
        # the same others' cells on the flat ground the DEM describes (z = 0 + their datum)
        others = GridReference(np.full(ground0.z.shape, 0.02) + np.random.default_rng(seed).normal(0, 0.01, ground0.z.shape),
                               ground0.sigma, ground0.x0, ground0.y0, RES, np.zeros_like(ground0.z),
                               np.zeros_like(ground0.z), datum_sigma=ground0.datum_sigma,
                               place_sigma=ground0.place_sigma)  # fmt: skip
        for fleet in (False, True):
            loc, e = _localizer(fleet, others, seed)
            fixes: list = []
            # a DEM attempt during the walk (even draws), the walk's end (odd): both tie the held stretch first
            step = partial(loc.localize, "dem") if seed % 2 == 0 else loc.finish
            _localize_and_report(loc, loc.est, step, fixes.append)  # type: ignore[arg-type]
            assert fixes and fixes[-1].height_profile is not None, loc.report
            held = np.arange(40.0, 90.0, 2.0) - loc.walked_m
            prof = fixes[-1].height_profile(held)
            var = fixes[-1].height_profile_var(held)
            (err_fleet if fleet else err_alone).append(prof + 0.25)
            if fleet:
                assert loc.report.fleet_ties == 6, loc.report
                assert np.all(np.abs(prof + 0.25) < 3 * np.sqrt(var)), (prof, np.sqrt(var))
            else:
                assert loc.report.fleet_ties == 0
    rms = lambda v: float(np.sqrt(np.mean(np.square(v))))  # noqa: E731
    assert rms(err_fleet) < 0.6 * rms(err_alone), (rms(err_fleet), rms(err_alone))


def test_a_map_height_fix_leaves_only_the_pieces_it_read_mostly_untied() -> None:
    """A map height fix over the last 10 m at 127 m walked read 3 m of piece 11 (110–120 m) and 7 m of piece 12:
    only piece 12 is left out of the next fleet ties; without a fleet tie config nothing is marked."""
    loc, _ = _localizer(True, None, 0)
    loc.walked_m = 127.0
    loc._mark_tied(10.0)
    assert loc._tied == {12}
    off, _ = _localizer(False, None, 0)
    off.walked_m = 127.0
    off._mark_tied(10.0)
    assert off._tied == set()
