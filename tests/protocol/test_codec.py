from __future__ import annotations

import numpy as np
import pytest

from protocol import Ack, MapRegion, ProtocolError, ScoutStatus, Status, decode, encode
from protocol.keys import ack_key, delta_key
from protocol.messages import CellDelta
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


@pytest.mark.parametrize("reason", DECODE_REASONS)
def test_batch_decode_agrees_with_single_decode(reason):
    from protocol.batch import decode_delta_batch

    key, bad, kw = broken(reason)
    good = [(delta_key(MAP, SCOUT), encode(make_delta(seq=i, seed=i))) for i in range(3)]
    opts = {k: v for k, v in kw.items() if k != "key"}
    batch = decode_delta_batch([good[0], (key, bad), good[1], good[2]], **opts)
    err = batch.results[1]
    assert isinstance(err, ProtocolError) and err.reason == reason
    with pytest.raises(ProtocolError) as info:
        decode(bad, **kw)
    assert str(err) == str(info.value)
    if reason != "oversize":  # with a tiny max_bytes every delta is oversize
        for i, j in ((0, 0), (2, 1), (3, 2)):
            single = decode(good[j][1])
            for name, cells in single.layers.items():
                for s, a in cells.items():
                    np.testing.assert_array_equal(batch.results[i].layers[name][s], a)
        assert sum(c.ix.size for c in batch.columns.values()) == 3 * 2 * 3


def _variants():
    """Payloads that probe each check of the batch fast path (some valid, most not)."""
    import copy

    import msgpack

    base = msgpack.unpackb(encode(make_delta(seq=5, seed=5)), raw=False)
    out = []

    def v(fn):
        d = copy.deepcopy(base)
        fn(d)
        out.append(msgpack.packb(d, use_bin_type=True))

    v(lambda d: d.update(v=True))  # bool, not int
    v(lambda d: d.update(t=3))  # int t: valid (single path converts)
    v(lambda d: d.update(t=float("nan")))
    v(lambda d: d.update(res=1))  # int res equal? no: 1 != 0.4
    v(lambda d: d.update(epoch=True))
    v(lambda d: d.update(seq=2**63))
    v(lambda d: d.update(extra="ignored"))  # extra top-level field: accepted by both paths
    v(lambda d: d["layers"].update(slip="notamap"))
    v(lambda d: d["layers"]["slip"].update(ix="text"))  # str instead of bytes
    v(lambda d: d["layers"]["slip"].update(n=5))  # int instead of bytes
    v(lambda d: d["layers"]["slip"].update(events=d["layers"]["slip"]["events"][:8]))
    v(lambda d: d["layers"]["slip"].update(iy=d["layers"]["slip"]["iy"][:4]))
    v(lambda d: d["layers"]["slip"].pop("events"))
    v(lambda d: d["layers"]["slip"].update(ix=b"", iy=b"", n=b"", events=b""))  # empty layer: valid
    v(lambda d: d["layers"].clear())  # no layers: valid
    v(lambda d: d["layers"].update({7: {}}))  # non-str layer name
    v(lambda d: d["layers"]["elevation"].update(n=np.array([1.0, -1.0, 2.0]).tobytes()))
    v(lambda d: d["layers"]["elevation"].update(ix=np.array([0, 0, 0], np.int32).tobytes()))  # dup
    v(lambda d: d["layers"]["elevation"].update(ix=np.array([0, 2**30 + 1, 3], np.int32).tobytes()))
    v(lambda d: d["layers"]["elevation"].update(sum=np.array([0.0, np.inf, 3.0]).tobytes()))
    return out


@pytest.mark.parametrize("key", [delta_key(MAP, SCOUT), None, "psr/m1/delta/other", "bad key"])
def test_batch_fast_path_accepts_and_rejects_exactly_like_single_decode(key):
    from protocol.batch import decode_delta_batch

    good = [(delta_key(MAP, SCOUT), encode(make_delta(seq=i, seed=i))) for i in range(2)]
    variants = _variants()
    samples = [good[0], *((key, p) for p in variants), good[1]]
    batch = decode_delta_batch(samples, res=RES)
    n_cells = 0
    for (k, p), got in zip(samples, batch.results, strict=True):
        try:
            want = decode(p, expected_type="cell_delta", key=k, res=RES)
        except ProtocolError as exc:
            assert isinstance(got, ProtocolError) and (got.reason, str(got)) == (exc.reason, str(exc))
            continue
        assert isinstance(got, CellDelta), got
        assert (got.map, got.scout, got.epoch, got.seq, got.t, got.res) == (
            want.map, want.scout, want.epoch, want.seq, want.t, want.res,
        )  # fmt: skip
        assert set(got.layers) == set(want.layers)
        for name, cells in want.layers.items():
            n_cells += cells["ix"].size
            for s, a in cells.items():
                np.testing.assert_array_equal(got.layers[name][s], a)
    assert sum(c.ix.size for c in batch.columns.values()) == n_cells


def test_template_path_agrees_with_single_decode_byte_for_byte():
    """Once a payload layout is learnt, deltas of that layout skip msgpack; any byte outside the arrays
    that differs, or a header not in canonical form, sends the delta back to the single path."""
    import msgpack

    from protocol import batch as B

    key = delta_key(MAP, SCOUT)
    good = encode(make_delta(seq=0, seed=0))
    B.decode_delta_batch([(key, good)], res=RES)  # learns the layout
    j = good.find(b"\xa6layers")
    assert len(good) - j - 10 in B._TEMPLATES

    def swap(old: bytes, new: bytes) -> bytes:
        assert len(old) == len(new) and good.count(old) >= 1
        return good.replace(old, new, 1)

    d = msgpack.unpackb(good, raw=False)
    nan_first = good.replace(d["layers"]["slip"]["events"], np.array([np.nan, 1, 2]).tobytes(), 1)
    dup = good.replace(
        d["layers"]["slip"]["ix"] + b"\xa2iy" + b"\xc4\x0c" + d["layers"]["slip"]["iy"],
        np.zeros(3, np.int32).tobytes() + b"\xa2iy" + b"\xc4\x0c" + np.zeros(3, np.int32).tobytes(),
        1,
    )
    variants = [
        encode(make_delta(seq=1, seed=1)),  # same layout, other numbers: template path
        encode(make_delta(seq=2**40, seed=2)),  # wider seq: other header length, same layers
        swap(b"\xa6events", b"\xa6evenTs"),  # stat key renamed, same length
        swap(b"\xa4slip", b"\xa4slop"),  # layer renamed
        good[:-1] + b"\x02",  # v = 2
        good.replace(b"\xa3seq\x00", b"\xa3seq\xc0", 1),  # seq = nil (header not canonical ints)
        good.replace(b"\xa1t\xcb", b"\xa1u\xcb", 1),  # header field renamed
        nan_first,
        dup,
        good.replace(b"\xa3seq\x00", b"\xa3seq\xcc", 1)[: len(good)],  # breaks the framing
        good.replace(b"\xa3seq\x00", b"\xa3seq\xcd\x01\x00", 1),  # seq 256 as uint16
        good.replace(b"\xa3seq\x00", b"\xa3seq\xcf\xff\xff\xff\xff\xff\xff\xff\xff", 1),  # 2**64-1
        good.replace(
            b"\xa1t\xcb" + good[good.find(b"\xa1t\xcb") + 3 : good.find(b"\xa1t\xcb") + 11],
            b"\xa1t\xcb" + np.array([np.inf], ">f8").tobytes(),
            1,
        ),
        encode(make_delta(seq=3, epoch=8, seed=3)),  # another epoch: other header bytes
    ]
    samples = [(key, good), *((key, p) for p in variants)]
    for _ in range(2):  # the second time, the scout's header bytes are known too
        batch = B.decode_delta_batch(samples, res=RES)
        for (k, p), got in zip(samples, batch.results, strict=True):
            try:
                want = decode(p, expected_type="cell_delta", key=k, res=RES)
            except ProtocolError as exc:
                assert isinstance(got, ProtocolError), (p, got)
                assert (got.reason, str(got)) == (exc.reason, str(exc))
                continue
            assert isinstance(got, CellDelta), got
            assert (got.seq, got.epoch, got.t) == (want.seq, want.epoch, want.t)
            for name, cells in want.layers.items():
                for s, a in cells.items():
                    np.testing.assert_array_equal(got.layers[name][s], a)
        kinds = [type(r).__name__ for r in batch.results]
        assert kinds[:3] == ["CellDelta"] * 3 and kinds.count("ProtocolError") >= 6
        assert (key, RES) in B._HEADS


def test_known_header_rows_agree_with_single_decode_under_byte_flips():
    """The header checks of a learnt scout run over all deltas of one length at once (numpy): every
    single-byte change anywhere in a payload, and every seq width, decides as the single path does."""
    from protocol import batch as B

    key = delta_key(MAP, SCOUT)
    rng = np.random.default_rng(11)
    B.decode_delta_batch([(key, encode(make_delta(seq=0, seed=0)))], res=RES)  # learns the layout
    B.decode_delta_batch([(key, encode(make_delta(seq=1, seed=0)))], res=RES)  # and the header
    seqs = [2, 127, 128, 255, 256, 65535, 65536, 2**32 - 1, 2**32, 2**63 - 1]
    samples = [(key, encode(make_delta(seq=s, seed=1))) for s in seqs]
    base = encode(make_delta(seq=7, seed=2))
    for _ in range(300):
        b = bytearray(base)
        b[int(rng.integers(len(b)))] = int(rng.integers(256))
        samples.append((key, bytes(b)))
    batch = B.decode_delta_batch(samples, res=RES)
    for (k, p), got in zip(samples, batch.results, strict=True):
        try:
            want = decode(p, expected_type="cell_delta", key=k, res=RES)
        except ProtocolError as exc:
            assert isinstance(got, ProtocolError), (p, got)
            assert (got.reason, str(got)) == (exc.reason, str(exc))
            continue
        assert isinstance(got, CellDelta), (p, got)
        assert (got.map, got.scout, got.epoch, got.seq, got.t, got.res) == (
            want.map, want.scout, want.epoch, want.seq, want.t, want.res,
        )  # fmt: skip
        for name, cells in want.layers.items():
            for s, a in cells.items():
                np.testing.assert_array_equal(got.layers[name][s], a)
