from __future__ import annotations

import msgpack
import numpy as np
import pytest

from protocol import Ack, MapRegion, ProtocolError, ScoutStatus, Status, decode, encode
from protocol.keys import ack_key, delta_key
from protocol.testing import DECODE_REASONS, MAP, RES, SCOUT, broken, make_delta, raw_delta


def test_cell_delta_round_trip():
    d = make_delta(seq=3, layers=tuple(["elevation", "slip", "cot", "giim", "giam", "contacts"]))
    back = decode(encode(d), key=delta_key(MAP, SCOUT), res=RES)
    assert (back.map, back.scout, back.epoch, back.seq, back.t, back.res) == (d.map, d.scout, 7, 3, 4.5, RES)
    assert set(back.layers) == set(d.layers)
    for name, cells in d.layers.items():
        for k, v in cells.items():
            np.testing.assert_array_equal(back.layers[name][k], v)
            assert back.layers[name][k].dtype == (np.int32 if k in ("ix", "iy") else np.float64)


def test_empty_delta_round_trip():
    d = make_delta(layers=())
    assert decode(encode(d)).layers == {}


def test_ack_round_trip():
    a = Ack(MAP, SCOUT, 12, 40)
    assert decode(encode(a), expected_type="ack", key=ack_key(MAP, SCOUT)) == a


def test_map_region_round_trip():
    v = np.arange(6, dtype=float).reshape(2, 3)
    r = MapRegion(MAP, RES, -2, 5, 3, 2, 9, {"slip": {"value": v, "n": v * 2}})
    back = decode(encode(r))
    assert (back.ix0, back.iy0, back.w, back.h, back.version) == (-2, 5, 3, 2, 9)
    np.testing.assert_array_equal(back.layers["slip"]["n"], v * 2)


def test_status_round_trip():
    st = Status(MAP, RES, 5, 10, 5, 1, {"wrong_res": 2}, {"s1": ScoutStatus(7, 4, True)})
    assert decode(encode(st), expected_type="status") == st


def test_status_bounds_round_trip_and_give_the_whole_map_box():
    st = Status(MAP, RES, 5, 10, 5, 1, bounds=(-3, 2, 7, 4))
    back = decode(encode(st), expected_type="status")
    assert back == st and back.to_json()["bounds"] == [-3, 2, 7, 4]
    # the box through the corner cells' centres: cell_index of each corner is the corner cell
    assert back.extent_m() == pytest.approx((-2.5 * RES, 2.5 * RES, 7.5 * RES, 4.5 * RES))
    assert Status(MAP, RES, 0, 0, 0, 0).extent_m() is None
    body = msgpack.unpackb(encode(st))
    for bad, reason in (([1, 2, 3], "wrong_type"), ([0, 0, 1.5, 1], "wrong_type"), ([2, 0, 1, 1], "bad_value"),
                        ([0, 0, 2**31, 1], "wrong_type")):  # fmt: skip
        with pytest.raises(ProtocolError) as info:
            decode(msgpack.packb({**body, "bounds": bad}), expected_type="status")
        assert info.value.reason == reason


@pytest.mark.parametrize("reason", DECODE_REASONS)
def test_every_reason_is_rejected_with_that_reason(reason):
    key, payload, kw = broken(reason)
    with pytest.raises(ProtocolError) as info:
        decode(payload, **kw)
    assert info.value.reason == reason
    assert str(info.value).startswith(reason + ":")


def test_messages_name_what_is_valid():
    _, payload, kw = broken("unknown_layer")
    with pytest.raises(ProtocolError, match="layers: elevation, slip, cot, giim, giam, contacts"):
        decode(payload, **kw)
    _, payload, kw = broken("wrong_res")
    with pytest.raises(ProtocolError, match="has res 0.4"):
        decode(payload, **kw)
    _, payload, kw = broken("bad_version")
    with pytest.raises(ProtocolError, match="supported schema versions: 1"):
        decode(payload, **kw)


def test_expected_type_and_key_checks():
    payload = encode(Ack(MAP, SCOUT, 1, 1))
    with pytest.raises(ProtocolError, match="'cell_delta' is expected") as info:
        decode(payload, expected_type="cell_delta")
    assert info.value.reason == "bad_type"
    with pytest.raises(ProtocolError) as info:
        decode(encode(make_delta()), key=delta_key("other", SCOUT))
    assert info.value.reason == "key_mismatch"


def test_missing_stat_of_a_layer_is_missing_field():
    import msgpack

    d = raw_delta()
    del d["layers"]["elevation"]["sxz"]
    with pytest.raises(ProtocolError, match="sxz") as info:
        decode(msgpack.packb(d))
    assert info.value.reason == "missing_field"


def test_protocol_error_rejects_unknown_reason():
    with pytest.raises(ValueError, match="reasons: decode"):
        ProtocolError("nope", "x")
