"""The server's batch decoder (msgspec + numpy) against the contract's reference decoder, codec.decode."""

from __future__ import annotations

import numpy as np
import pytest

from map_server.decode import DeltaDecoder
from protocol import ProtocolError, decode, encode
from protocol.keys import delta_key
from protocol.messages import CellDelta
from protocol.testing import DECODE_REASONS, MAP, RES, SCOUT, broken, make_delta


@pytest.mark.parametrize("reason", DECODE_REASONS)
def test_batch_decode_agrees_with_single_decode(reason):
    key, bad, kw = broken(reason)
    good = [(delta_key(MAP, SCOUT), encode(make_delta(seq=i, seed=i))) for i in range(3)]
    opts = {k: v for k, v in kw.items() if k != "key"}
    batch = DeltaDecoder(**opts).decode([good[0], (key, bad), good[1], good[2]], views=True)
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
    good = [(delta_key(MAP, SCOUT), encode(make_delta(seq=i, seed=i))) for i in range(2)]
    variants = _variants()
    samples = [good[0], *((key, p) for p in variants), good[1]]
    batch = DeltaDecoder(res=RES).decode(samples, views=True)
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


def test_batch_path_agrees_with_single_decode_byte_for_byte():
    """Payloads edited byte by byte (renamed keys, other int widths, nil, v=2, a broken frame, NaN, a
    duplicate cell) decide in the batch exactly as in the reference decoder."""
    import msgpack

    key = delta_key(MAP, SCOUT)
    good = encode(make_delta(seq=0, seed=0))
    decoder = DeltaDecoder(res=RES)

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
        batch = decoder.decode(samples, views=True)
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


def test_batch_agrees_with_single_decode_under_byte_flips():
    """Every single-byte change anywhere in a payload, and every seq width, decides in the batch as the
    reference decoder does (same reason and message, same numbers)."""
    key = delta_key(MAP, SCOUT)
    rng = np.random.default_rng(11)
    seqs = [2, 127, 128, 255, 256, 65535, 65536, 2**32 - 1, 2**32, 2**63 - 1]
    samples = [(key, encode(make_delta(seq=s, seed=1))) for s in seqs]
    base = encode(make_delta(seq=7, seed=2))
    for _ in range(300):
        b = bytearray(base)
        b[int(rng.integers(len(b)))] = int(rng.integers(256))
        samples.append((key, bytes(b)))
    batch = DeltaDecoder(res=RES).decode(samples, views=True)
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


def test_views_false_gives_headers_and_columns_only():
    samples = [(delta_key(MAP, SCOUT), encode(make_delta(seq=i, seed=i))) for i in range(4)]
    batch = DeltaDecoder(res=RES).decode(samples)
    assert [r.seq for r in batch.results] == [0, 1, 2, 3]
    assert all(r.layers == {} for r in batch.results)
    for name, c in batch.columns.items():
        want = np.concatenate([decode(p).layers[name]["ix"] for _, p in samples])
        np.testing.assert_array_equal(np.sort(c.ix), np.sort(want))
        assert c.vals.shape == (len(c.layer.stats), c.ix.size)


def test_the_key_cache_is_the_instance_s_and_bounded():
    a, b = DeltaDecoder(res=RES), DeltaDecoder(res=RES)
    for i in range(DeltaDecoder._MAX_KEYS + 10):
        a.decode([(delta_key(MAP, f"s{i}"), encode(make_delta(seq=0, scout=f"s{i}")))])
    assert len(a._ids) <= DeltaDecoder._MAX_KEYS and b._ids == {}


@pytest.mark.parametrize("layers", [("slip",), ("elevation", "slip"), ("cot", "giam"), ("contacts",)])
def test_every_shape_decodes_on_the_shaped_path_like_the_reference(layers):
    # the second delta of a scout with the same length and shape takes the shape-typed decoder
    decoder = DeltaDecoder(res=RES)
    key = delta_key(MAP, SCOUT)
    first = encode(make_delta(seq=1, seed=1, layers=layers))
    second = encode(make_delta(seq=2, seed=2, layers=layers))
    assert len(first) == len(second)
    decoder.decode([(key, first)])
    assert decoder._templates  # learnt
    batch = decoder.decode([(key, second)], views=True)
    want = decode(second)
    got = batch.results[0]
    assert isinstance(got, CellDelta) and got.seq == 2
    for name, cells in want.layers.items():
        for s, a in cells.items():
            np.testing.assert_array_equal(got.layers[name][s], a)


def test_a_known_shape_in_another_key_order_is_still_decoded_exactly():
    # same length and shape as a learnt delta, but the elevation stats in another order: the raw-layer
    # fast path sees bytes that are not msgspec's own layout and hands the delta to the typed path
    import msgpack

    decoder = DeltaDecoder(res=RES)
    key = delta_key(MAP, SCOUT)
    decoder.decode([(key, encode(make_delta(seq=0, seed=0)))])  # learns the shape
    d = msgpack.unpackb(encode(make_delta(seq=1, seed=1)), raw=False)
    elev = d["layers"]["elevation"]
    d["layers"]["elevation"] = {
        k: elev[k] for k in ("ix", "iy", *reversed([s for s in elev if s not in ("ix", "iy")]))
    }
    swapped = msgpack.packb(d, use_bin_type=True)
    plain = encode(make_delta(seq=2, seed=2))
    assert len(swapped) == len(plain)
    batch = decoder.decode([(key, swapped), (key, plain)], views=True)
    for payload, got in zip((swapped, plain), batch.results, strict=True):
        want = decode(payload)
        assert isinstance(got, CellDelta)
        for name, cells in want.layers.items():
            for s, a in cells.items():
                np.testing.assert_array_equal(got.layers[name][s], a)
