"""Issue 12: fuzzed messages (structure-aware mutations of valid deltas) never crash the decoder or the merge,
are each counted once, and never leave a partial merge — in process and against a live server.
(`python benchmarks/fuzz.py` runs the same with 10⁶ messages.)"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

BENCH = Path(__file__).resolve().parents[2] / "benchmarks" / "fuzz.py"


def test_fuzzed_messages_are_rejected_whole_and_counted():
    res = subprocess.run(
        [sys.executable, str(BENCH), "--messages", "4000", "--live", "600", "--seed", "3"],
        check=True,
        capture_output=True,
        text=True,
        timeout=300,
    )
    out = json.loads(res.stdout.strip().splitlines()[-1])
    assert out["crashes"] == 0 and out["every_message_counted"] and out["totals_exact"]
    assert out["merged"] > 100 and len(out["rejected_by_reason"]) >= 8
    live = out["live"]
    assert live["still_answers_status"] and live["same_as_in_process"] and live["worker"] == "ok"


def test_a_truncated_message_on_the_fast_path_is_rejected_not_a_crash():
    """Found by the fuzzer: a delta cut inside its `t` field made the batch decoder's learnt-header path raise
    struct.error, which stopped the merge worker."""
    from map_server.merge import Merger
    from protocol import encode
    from protocol.keys import delta_key
    from protocol.testing import MAP, RES, make_delta
    from psrmap_mapcore import TiledMap

    m = Merger(TiledMap(RES), MAP)
    key = delta_key(MAP, "s1")
    seq = 0
    for cut in range(20, 120):  # every truncation point through the header, each in a batch of good deltas
        good = [(key, encode(make_delta(seq=seq + k, scout="s1", epoch=1, seed=k))) for k in range(3)]
        bad = encode(make_delta(seq=seq + 3, scout="s1", epoch=1))[:cut]
        res = m.ingest([good[0], good[1], (key, bad), good[2]])
        assert len(res.accepted) == 3 and [r for r, _ in res.rejected] == ["decode"]
        seq += 4
    assert m.book.merged == 300


def _msgpack_values():
    from hypothesis import strategies as st

    scalars = st.one_of(
        st.none(),
        st.booleans(),
        st.integers(-(2**64), 2**64),
        st.floats(allow_nan=True),
        st.text(max_size=12),
        st.binary(max_size=64),
    )
    return st.recursive(
        scalars,
        lambda kids: st.one_of(
            st.lists(kids, max_size=4), st.dictionaries(st.text(max_size=8), kids, max_size=5)
        ),
        max_leaves=20,
    )


def test_hypothesis_arbitrary_msgpack_and_field_swaps_never_crash_the_merge():
    import msgpack
    from hypothesis import HealthCheck, given, settings
    from hypothesis import strategies as st

    from map_server.merge import Merger
    from protocol import encode
    from protocol.keys import delta_key
    from protocol.testing import MAP, RES, make_delta
    from psrmap_mapcore import TiledMap

    valid = msgpack.unpackb(encode(make_delta(seq=0, scout="s1")), raw=False)
    fields = sorted(valid)

    @settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
    @given(field=st.sampled_from(fields), value=_msgpack_values(), raw=st.binary(max_size=256))
    def check(field, value, raw):
        m = Merger(TiledMap(RES), MAP)
        d = dict(valid)
        d[field] = value
        key = delta_key(MAP, "s1")
        try:
            swapped = msgpack.packb(d, use_bin_type=True)
        except (TypeError, ValueError, OverflowError):
            swapped = raw
        res = m.ingest([(key, swapped), (key, raw)])
        assert len(res.accepted) + res.duplicates + len(res.rejected) == 2
        if not res.accepted:
            assert m.map.cells == 0 and m.book.merged == 0  # nothing half-merged

    check()
