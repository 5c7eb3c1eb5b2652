"""The map's slope (`map_slope_deg`: the σ-weighted plane of the height layer, else the elevation layer's) and
the datum clash test (`datum_clash`: footholds scattered about their plane far beyond their stated σ), on one
cell holding two scouts' footholds."""

from __future__ import annotations

import numpy as np
import pytest

from protocol.layers import (
    LAYERS,
    datum_clash,
    elevation_slope_deg,
    layer_derived,
    map_height,
    map_slope_deg,
    plane_residual_rms,
)
from scout_agent.holding import elevation_rows, height_rows

RES = 0.4  # cell (0, 0) spans 0 .. 0.4 m in x and y


def cell_layers(
    *scouts: tuple[np.ndarray, np.ndarray, np.ndarray, float],
) -> dict[str, dict[str, np.ndarray]]:
    """The merged elevation and height stats of cell (0, 0) (arrays of shape (1,)) from scouts' footholds
    (x, y, z, σ): each row summed, min/max reduced, as the map server's generic merge leaves them."""
    x = np.concatenate([s[0] for s in scouts])
    y = np.concatenate([s[1] for s in scouts])
    z = np.concatenate([s[2] for s in scouts])
    sigma = np.concatenate([np.full(len(s[0]), s[3]) for s in scouts])
    out: dict[str, dict[str, np.ndarray]] = {}
    for name, rows in (
        ("elevation", elevation_rows(x, y, z, RES)),
        ("height", height_rows(x, y, z, sigma, RES)),
    ):
        stats = {}
        for i, s in enumerate(LAYERS[name].stats):
            col = rows[:, 2 + i]
            stats[s] = np.array(
                [col.min() if s in ("min", "min_sigma") else col.max() if s == "max" else col.sum()]
            )
        out[name] = stats
    return out


def track(along: str, at: float, z0: float, slope_deg: float, sigma: float, rng: np.random.Generator):
    """A scout's 12 footholds along a straight track crossing the cell (x or y fixed near `at`), on the true
    plane z = slope · (x - 0.2) shifted by its datum error `z0`, with 5 mm of foot noise."""
    u = np.linspace(0.03, 0.37, 12)
    v = at + rng.normal(0.0, 0.04, 12)
    x, y = (u, v) if along == "x" else (v, u)
    z = np.tan(np.radians(slope_deg)) * (x - 0.2) + z0 + rng.normal(0.0, 0.005, 12)
    return x, y, z, sigma


def test_two_scouts_a_datum_apart_are_a_clash_and_their_plane_is_no_terrain() -> None:
    rng = np.random.default_rng(3)
    # scout1 crosses along x, scout2 along y 1.2 m higher, each stating σ ≈ 0.16 / 0.24 m (the 100 m mission's cell)
    layers = cell_layers(track("x", 0.1, 0.0, 5.0, 0.16, rng), track("y", 0.3, 1.2, 5.0, 0.24, rng))
    plain = elevation_slope_deg(layers["elevation"])[0]
    weighted = map_slope_deg(layers)[0]
    assert plain > 30.0 and weighted > 30.0  # both fits tilt to bridge the datums: a false steep slope
    assert plane_residual_rms(layers["elevation"])[0] > 0.3  # and still miss half the footholds by decimetres
    assert datum_clash(layers)[0]
    assert not datum_clash({"elevation": layers["elevation"]})[0]  # no σ stated: nothing to test against


def test_the_weighted_slope_follows_the_surer_scout() -> None:
    rng = np.random.default_rng(4)
    # scout1 well datumed on a 10° plane; scout2 0.3 m off and says so (σ 0.5 m)
    layers = cell_layers(track("x", 0.1, 0.0, 10.0, 0.02, rng), track("y", 0.3, 0.3, 10.0, 0.5, rng))
    plain = elevation_slope_deg(layers["elevation"])[0]
    weighted = map_slope_deg(layers)[0]
    assert weighted == pytest.approx(10.0, abs=0.5)
    assert (
        layer_derived("height", "slope_deg", layers["height"])[0] == weighted
    )  # what a query asks the map for
    assert abs(plain - 10.0) > 5.0  # the unweighted fit is pulled by the poorly datumed scout
    assert not datum_clash(layers)[0]  # their disagreement is within what they stated
    assert map_height(layers)[0] == pytest.approx(0.0, abs=0.01)  # the same fit gives the height


def test_one_datum_on_a_steep_slope_is_terrain_not_a_clash() -> None:
    rng = np.random.default_rng(5)
    layers = cell_layers(track("x", 0.1, 0.0, 35.0, 0.1, rng), track("x", 0.3, 0.0, 35.0, 0.1, rng))
    assert map_slope_deg(layers)[0] == pytest.approx(35.0, abs=1.0)
    assert not datum_clash(layers)[0]


def test_fallback_and_empty_cells() -> None:
    rng = np.random.default_rng(6)
    layers = cell_layers(track("x", 0.1, 0.0, 8.0, 0.1, rng), track("y", 0.3, 0.0, 8.0, 0.1, rng))
    no_height = {"elevation": layers["elevation"]}
    assert map_slope_deg(no_height)[0] == pytest.approx(elevation_slope_deg(layers["elevation"])[0])
    empty_height = {k: np.zeros(1) for k in LAYERS["height"].stats}
    assert map_slope_deg({**no_height, "height": empty_height})[0] == pytest.approx(8.0, abs=0.5)
    empty = {k: np.zeros(1) for k in LAYERS["elevation"].stats}
    both_empty = {"elevation": empty, "height": empty_height}
    assert np.isnan(map_slope_deg(both_empty)[0]) and not datum_clash(both_empty)[0]
