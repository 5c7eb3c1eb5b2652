"""The height layer (contract extension of issue 23): each foothold carries the scout's vertical σ; the map keeps
weighted plane-fit moments, Σσ² and the smallest σ under the generic merge rule, and its height is the
inverse-variance weighted fit, so a well-datumed scout is not pulled toward a poorly datumed one."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from map_server.decode import DeltaDecoder
from protocol import ProtocolError, decode, encode
from protocol.keys import delta_key
from protocol.layers import LAYERS, layer_derived, layer_value, map_height, merge_op
from protocol.testing import MAP, RES, SCOUT, make_delta
from scout_agent.cells import CellAccumulator, LocalMap
from scout_agent.holding import HEIGHT_FLOOR_M, height_rows


def _scout_delta(z: float, sigma: float, slope: float = 0.0) -> dict:
    """A scout's delta of 12 footholds spread over cell (2, 2) on a plane z + slope·dx, all with σ `sigma`."""
    acc = CellAccumulator(RES)
    rng = np.random.default_rng(5)  # the same footholds for every scout
    x = 0.8 + rng.uniform(0.02, 0.38, 12)
    y = 0.8 + rng.uniform(0.02, 0.38, 12)
    h = z + slope * (x - 1.0)
    for row in height_rows(x, y, h, np.full(12, sigma), RES).tolist():
        acc.append("height", tuple(row))
    for xi, yi, hi in zip(x, y, h, strict=True):
        acc.add_elevation(float(xi), float(yi), float(hi))
    return acc.flush()


def test_height_merges_by_the_generic_rule_and_weights_each_foothold_by_its_sigma() -> None:
    layer = LAYERS["height"]
    assert layer.unit == "m" and "min_sigma" in layer.stats
    assert {s: merge_op(s) for s in layer.stats} == {
        s: "min" if s == "min_sigma" else "add" for s in layer.stats
    }
    local = LocalMap(RES)
    local.merge(_scout_delta(0.0, 0.05, slope=0.2))  # well datumed
    local.merge(_scout_delta(0.5, 0.5, slope=0.2))  # 0.5 m off, and says so
    elev, height = local.cells("elevation"), local.cells("height")
    assert layer_value("elevation", elev)[0] == pytest.approx(0.25, abs=1e-9)  # the plain fit: halfway
    # weights 400 and 4 per foothold: the weighted fit stays by the good scout, (0·400 + 0.5·4) / 404
    assert layer_value("height", height)[0] == pytest.approx(0.5 * 4 / 404, abs=1e-9)
    both = {"elevation": elev, "height": height}
    assert map_height(both)[0] == pytest.approx(layer_value("height", height)[0])
    assert map_height({"elevation": elev})[0] == pytest.approx(0.25, abs=1e-9)  # no σ stated: as before
    assert layer_derived("height", "best", height)[0] == pytest.approx(0.05)
    assert layer_derived("height", "sigma", height)[0] == pytest.approx(np.sqrt((0.05**2 + 0.5**2) / 2))
    empty = {k: np.zeros(1) for k in layer.stats}
    assert np.isnan(layer_value("height", empty)[0]) and np.isnan(layer_derived("height", "sigma", empty)[0])


def test_a_sigma_below_the_floor_counts_as_the_floor() -> None:
    rows = height_rows(np.array([0.1]), np.array([0.1]), np.array([1.0]), np.array([0.0]), RES)
    w = rows[0, 3]
    assert w == pytest.approx(1 / HEIGHT_FLOOR_M**2) and np.isfinite(rows).all()


def _delta_with(change) -> bytes:
    d = make_delta(layers=("height",))
    cells = {k: v.copy() for k, v in d.layers["height"].items()}
    change(cells)
    return encode(dataclasses.replace(d, layers={"height": cells}))


@pytest.mark.parametrize(
    ("change", "reason"),
    [
        (lambda c: c["w"].__setitem__(0, -1.0), "negative_count"),
        (lambda c: c["var"].__setitem__(0, -1.0), "negative_count"),
        (lambda c: c["min_sigma"].__setitem__(0, np.nan), "nonfinite"),
        (lambda c: c["min_sigma"].__setitem__(0, 0.0), "inconsistent"),  # σ must be > 0
        (
            lambda c: c["min_sigma"].__setitem__(0, 10.0),
            "inconsistent",
        ),  # every σ ≥ the smallest: var too small
        (lambda c: c["w"].__setitem__(0, c["w"][0] * 100), "inconsistent"),  # weights above 1/min_sigma²
        (lambda c: c["wxy"].__setitem__(0, 1e6), "inconsistent"),  # weighted moment matrix not PSD
        (
            lambda c: [c["n"].__setitem__(0, 0.0), c["w"].__setitem__(0, 0.0)],
            "inconsistent",
        ),  # sums, no footholds
    ],
)
def test_bad_height_statistics_are_rejected_whole_with_their_reason(change, reason) -> None:
    payload = _delta_with(change)
    with pytest.raises(ProtocolError) as info:
        decode(payload, key=delta_key(MAP, SCOUT), res=RES)
    assert info.value.reason == reason
    good = decode(_delta_with(lambda c: None), key=delta_key(MAP, SCOUT), res=RES)  # the valid one passes
    assert set(good.layers) == {"height"}
    # the server's batch decoder rejects the same delta and keeps the valid one
    samples = [(delta_key(MAP, SCOUT), payload), (delta_key(MAP, SCOUT), _delta_with(lambda c: None))]
    out = DeltaDecoder(res=RES).decode(samples, views=True).results
    assert [o.reason if isinstance(o, ProtocolError) else "ok" for o in out] == [reason, "ok"]


def test_the_missions_height_reader_takes_raw_or_value_only_grids() -> None:
    from psrmap.agreement import grid_height
    from psrmap_mapcore import LayerGrid

    local = LocalMap(RES)
    local.merge(_scout_delta(0.0, 0.05))
    local.merge(_scout_delta(0.5, 0.5))
    region = local.region(2, 2, 2, 2)
    raw = LayerGrid("m", RES, 2, 2, 1, 1, {k: region[k] for k in ("elevation", "height")})
    assert grid_height(raw)[0, 0] == pytest.approx(0.5 * 4 / 404, abs=1e-9)  # the weighted fit
    values = LayerGrid("m", RES, 2, 2, 1, 1, {"elevation": {"n": region["elevation"]["n"],
                                                            "value": region["elevation"]["value"]}})  # fmt: skip
    assert grid_height(values)[0, 0] == pytest.approx(0.25, abs=1e-9)  # a reply with values only
