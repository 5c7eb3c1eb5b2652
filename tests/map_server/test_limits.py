"""Issue 25: sums stay finite and consistent; per-scout tile quotas and the mission box; `busy` for queries."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from map_server.limits import Limits, default_tile_budget_mib, tile_bytes
from map_server.merge import Merger
from map_server.service import MapService, ServerConfig
from map_server.store import MapStore
from protocol import decode, encode
from protocol.consistency import MAX_STAT, bad_cells
from protocol.errors import ProtocolError
from protocol.keys import delta_key, map_key
from protocol.layers import LAYERS
from protocol.messages import CellDelta, RegionQuery
from protocol.testing import MAP, RES, layer_cells, make_delta
from psrmap_mapcore import TiledMap
from scout_agent.estimators.elevation import plane_moments


def _sample(d: CellDelta) -> tuple[str, bytes]:
    return delta_key(MAP, d.scout), encode(d)


def _tiles(m: Merger) -> dict[str, dict[tuple[int, int], np.ndarray]]:
    return {n: {k: t.copy() for k, t in g.tiles.items()} for n, g in m.map.grids.items()}


def _unchanged(m: Merger, before: dict, version: int) -> None:
    assert m.book.version == version
    for n, g in m.map.grids.items():
        assert set(g.tiles) == set(before[n])
        for k, t in g.tiles.items():
            np.testing.assert_array_equal(t, before[n][k])


def _slip(n: list[float], events: list[float]) -> dict:
    k = len(n)
    return {"ix": np.arange(k, dtype=np.int32), "iy": np.zeros(k, np.int32), "n": np.array(n),
            "events": np.array(events)}  # fmt: skip


# ------------------------------------------------------------------ finite and consistent sums


def test_two_deltas_of_n_1e308_cannot_make_the_count_infinite():
    """Issue 25: two deltas with n = 1e308 made the stored count inf and the value NaN."""
    m = Merger(TiledMap(RES, tile=8), MAP)
    ok = CellDelta(MAP, "s1", 1, 0, 0.0, RES, {"slip": _slip([3.0, 1.0], [1.0, 0.0])})
    assert len(m.ingest([_sample(ok)]).accepted) == 1
    before, version = _tiles(m), m.book.version
    huge = [CellDelta(MAP, "s1", 1, s, 0.0, RES, {"slip": _slip([1e308, 1.0], [0.0, 0.0])}) for s in (1, 2)]
    res = m.ingest([_sample(d) for d in huge])
    assert [r for r, _ in res.rejected] == ["stat_range", "stat_range"]
    assert "n=1e+308" in res.rejected[0][1] and "1e+30" in res.rejected[0][1]
    _unchanged(m, before, version)
    region = m.map.region(0, 0, 1, 0, ("slip",), ("n", "value"))["slip"]
    assert np.isfinite(region["n"]).all() and np.isfinite(region["value"]).all()


def test_any_number_of_deltas_at_the_largest_allowed_magnitude_keeps_every_total_finite():
    """The bound behind stat_range: 1e30 per delta, 2**63 deltas at most -> totals below 1e49; here the
    largest allowed elevation sums, merged many times, stay finite, and so does the plane-fit value."""
    m = Merger(TiledMap(RES, tile=8), MAP)
    z = np.full(1, 1e14)  # sumsq = 1e28, n = 1e2: within MAX_STAT
    mom = plane_moments(np.array([0.1]), np.array([0.05]), z, np.zeros(1), np.zeros(1))
    cells = {k: v * 100.0 for k, v in mom.items()} | {"min": z, "max": z}
    cells = {"ix": np.zeros(1, np.int32), "iy": np.zeros(1, np.int32), **cells}
    for seq in range(50):
        d = CellDelta(MAP, "s1", 1, seq, 0.0, RES, {"elevation": cells})
        assert len(m.ingest([_sample(d)]).accepted) == 1
    out = m.map.region(0, 0, 0, 0, ("elevation",), ("all", "value"))["elevation"]
    assert all(np.isfinite(a).all() for a in out.values())
    assert out["value"][0, 0] == pytest.approx(1e14, rel=1e-6)


def _elevation(**override: float) -> dict:
    """One consistent elevation cell (3 footholds), then the given stats overridden."""
    x, y, z = np.array([0.1, -0.1, 0.05]), np.array([0.0, 0.1, -0.1]), np.array([1.0, 1.2, 0.9])
    mom = plane_moments(x, y, z, np.zeros(3), np.zeros(3))
    cells = {k: np.array([v.sum()]) for k, v in mom.items()} | {
        "min": np.array([0.9]),
        "max": np.array([1.2]),
    }
    for k, v in override.items():
        cells[k] = np.array([v])
    return {"ix": np.zeros(1, np.int32), "iy": np.zeros(1, np.int32), **cells}


@pytest.mark.parametrize(
    "what, override",
    [
        ("negative variance (sumsq < sum²/n)", {"sumsq": 2.0}),
        ("min > max", {"min": 1.3, "max": 1.1}),
        ("mean above max", {"max": 1.0}),
        ("sxy² > sxx·syy", {"sxy": 0.5}),
        ("sxz beyond Cauchy-Schwarz", {"sxz": 5.0}),
        ("n = 0 with a sum", {"n": 0.0}),
        ("elevation sum that would overflow", {"sum": 1e300, "sumsq": 1e300}),
    ],
)
def test_inconsistent_or_overflowing_statistics_reject_the_whole_delta(what, override):
    m = Merger(TiledMap(RES, tile=8), MAP)
    m.ingest([_sample(make_delta(seq=0, scout="s9", cells=((1, 1),)))])
    before, version = _tiles(m), m.book.version
    layers = {"elevation": _elevation(**override), "slip": _slip([2.0], [1.0])}  # the good slip layer too
    d = CellDelta(MAP, "s1", 1, 0, 0.0, RES, layers)
    res = m.ingest([_sample(d)])
    assert len(res.rejected) == 1, what
    assert res.rejected[0][0] == ("stat_range" if "overflow" in what else "inconsistent"), res.rejected
    _unchanged(m, before, version)
    with pytest.raises(ProtocolError):  # the reference decoder agrees
        decode(encode(d), expected_type="cell_delta")


def test_real_sample_sets_pass_the_consistency_checks_within_rounding():
    """Float moments of random and degenerate foothold sets (one point, collinear, equal heights, large
    offsets) are accepted: the checks reject impossible statistics, not rounding."""
    rng = np.random.default_rng(3)
    cols = []
    for k in (1, 2, 3, 5, 40, 400):
        for kind in ("random", "collinear", "flat", "far"):
            x, y = rng.uniform(-0.2, 0.2, k), rng.uniform(-0.2, 0.2, k)
            z = rng.normal(0, 0.05, k) + (1000.0 if kind == "far" else 1.3)
            if kind == "collinear":
                y = 0.5 * x
            if kind == "flat":
                z = np.full(k, 1.3)
            mom = plane_moments(x, y, z, np.zeros(k), np.zeros(k))
            col = {s: float(mom[s].sum()) for s in mom} | {"min": float(z.min()), "max": float(z.max())}
            cols.append([col[s] for s in LAYERS["elevation"].stats])
    block = np.array(cols).T
    assert bad_cells(LAYERS["elevation"], block) == {}
    for name in LAYERS:  # the test builders' statistics are consistent too
        cells = layer_cells(name, np.arange(50), np.zeros(50), np.random.default_rng(1))
        assert bad_cells(LAYERS[name], np.stack([cells[s] for s in LAYERS[name].stats])) == {}
    assert MAX_STAT == 1e30


# ------------------------------------------------------------------ quotas and the mission box


def _spread(scout: str, seq: int, tiles: list[tuple[int, int]], tile: int = 8) -> tuple[str, bytes]:
    cells = tuple((tx * tile, ty * tile) for tx, ty in tiles)
    return _sample(make_delta(seq=seq, scout=scout, cells=cells, layers=("slip",)))


def test_one_scout_cannot_shut_the_others_out_of_new_area():
    """Issue 25: one scout spreading cells over new tiles filled the map (limit_tiles for everyone). Its own
    quota stops it first; another scout's new tiles are still accepted."""
    lim = Limits(max_tiles=64, max_tiles_per_scout=16, max_new_tiles_per_scout_minute=1000)
    m = Merger(TiledMap(RES, tile=8), MAP, limits=lim)
    res = m.ingest([_spread("bad", s, [(100 + 4 * s + k, 0) for k in range(4)]) for s in range(10)])
    reasons = [r for r, _ in res.rejected]
    assert len(res.accepted) == 4 and reasons == ["limit_scout_tiles"] * 6
    assert "max_tiles_per_scout=16" in res.rejected[0][1]
    assert m.book.scout_tiles["bad"] == 16 and len(m.map.gslots) == 16
    good = m.ingest([_spread("good", 0, [(-5, -5), (-6, -5)])])
    assert len(good.accepted) == 1 and m.book.scout_tiles["good"] == 2
    # the bad scout may still add to tiles that exist
    assert len(m.ingest([_spread("bad", 10, [(100, 0)])]).accepted) == 1


def test_the_tile_rate_refills_with_time_and_is_per_scout():
    now = [0.0]
    lim = Limits(max_new_tiles_per_scout_minute=6, max_new_tiles_per_delta=4)
    m = Merger(TiledMap(RES, tile=8), MAP, limits=lim, clock=lambda: now[0])
    first = m.ingest(
        [_spread("a", 0, [(k, 0) for k in range(4)]), _spread("a", 1, [(k, 1) for k in range(4)])]
    )
    assert len(first.accepted) == 1 and [r for r, _ in first.rejected] == ["limit_scout_tile_rate"]
    assert "max_new_tiles_per_scout_minute=6" in first.rejected[0][1]
    assert len(m.ingest([_spread("b", 0, [(k, 2) for k in range(4)])]).accepted) == 1  # b has its own
    now[0] = 20.0  # + 2 tiles: 4 in the bucket
    assert len(m.ingest([_spread("a", 1, [(k, 1) for k in range(4)])]).accepted) == 1  # the resend passes


def test_deltas_outside_the_mission_box_are_rejected_naming_it():
    m = Merger(TiledMap(RES, tile=8), MAP, bbox=(-10, -10, 10, 10))
    res = m.ingest([_spread("a", 0, [(0, 0)]), _spread("a", 1, [(0, 0), (2, 0)])])
    assert len(res.accepted) == 1 and res.rejected[0][0] == "outside_bbox"
    assert "(16, 0)" in res.rejected[0][1] and "x -10..10" in res.rejected[0][1]


def test_each_scouts_tile_count_survives_a_restart(tmp_path):
    db = str(tmp_path / "m.db")
    lim = Limits(max_tiles_per_scout=3)
    store = MapStore(db, MAP, RES, 8)
    m = Merger(TiledMap(RES, tile=8), MAP, limits=lim)
    res = m.ingest([_spread("a", 0, [(0, 0), (1, 0)])])
    store.commit(res.accepted, m.book, res.touched)
    store.close()
    again = Merger(TiledMap(RES, tile=8), MAP, limits=lim)
    MapStore(db, MAP, RES, 8).load(again)
    assert again.book.scout_tiles["a"] == 2
    assert again.ingest([_spread("a", 1, [(5, 0), (6, 0)])]).rejected[0][0] == "limit_scout_tiles"


def test_default_budget_is_sized_for_the_machine_and_bounds_a_memory_only_map():
    assert default_tile_budget_mib(512 << 20) == 64 and default_tile_budget_mib(64 << 30) == 256
    assert default_tile_budget_mib(2 << 30) == 128
    svc = MapService(ServerConfig(map_id=MAP, res=RES, tile_budget_mib=None))  # no db: the budget caps tiles
    assert svc.merger.limits.max_tiles == int(svc.config.budget_mib * 2**20) // tile_bytes(64)
    with pytest.raises(ValueError, match="tile_budget_mib"):
        ServerConfig(tile_budget_mib=-1)


# ------------------------------------------------------------------ queries never block deltas


def test_a_full_query_budget_answers_busy_and_deltas_are_still_merged(router, tmp_path):
    import zenoh

    from psrmap_common.query import wait_for_server
    from psrmap_common.session import zenoh_config

    cfg = ServerConfig(
        map_id=MAP, res=RES, db=str(tmp_path / "q.db"), connect=(router,), max_queries_in_flight=2
    )
    with MapService(cfg) as service, zenoh.open(zenoh_config(connect=[router], mode="client")) as client:
        assert wait_for_server(client, MAP)
        gate = threading.Event()
        real = service.region

        def slow(rq: RegionQuery):  # the first queries hold the worker until the test lets go
            gate.wait(10)
            return real(rq)

        service.region = slow  # type: ignore[method-assign]
        sel = f"{map_key(MAP)}?{RegionQuery(0, 0, 4, 4, ('slip',), ('n',)).to_parameters()}"
        handlers = [client.get(sel, timeout=10) for _ in range(6)]
        time.sleep(0.5)
        client.put(delta_key(MAP, "s1"), encode(make_delta(seq=0, scout="s1", layers=("slip",))))
        deadline = time.monotonic() + 10
        while service.merger.book.merged < 1 and time.monotonic() < deadline:
            time.sleep(0.02)
        assert service.merger.book.merged == 1  # merged while the query worker is stuck
        gate.set()
        errs, oks = [], 0
        for h in handlers:
            for r in h:
                if r.ok is not None:
                    oks += 1
                else:
                    errs.append(r.err.payload.to_bytes().decode())
        assert oks == 2 and len(errs) == 4 and all(e.startswith("busy: 2 queries in flight") for e in errs)
        assert service.busy_replies == 4


# ------------------------------------------------------------------ clients bound what they allocate


def _fake_region(ix0: int, iy0: int, w: int = 1, h: int = 1) -> bytes:
    from protocol.messages import MapRegion

    return encode(
        MapRegion(MAP, RES, ix0, iy0, w, h, 1, {"slip": {"n": np.ones((h, w)), "value": np.zeros((h, w))}})
    )


@pytest.mark.parametrize("far", [(-(2**30), 0), (0, 2**30 - 1)])
def test_psrmap_query_refuses_a_reply_far_outside_its_box_without_allocating_it(router, capsys, far):
    """Issue 25: one fake reply holding a cell at ix = -2**30 made `psrmap query` allocate 64 GiB and die with a
    traceback. Two impostor replies (one honest-looking, one far away): an error message, exit 1."""
    import psutil
    import zenoh

    from psrmap.cli import main
    from psrmap_common.session import zenoh_config

    with zenoh.open(zenoh_config(connect=[router], mode="client")) as fake:
        replies = [_fake_region(0, 0), _fake_region(*far)]

        def answer(q):
            for r in replies:
                q.reply(str(q.key_expr), r)

        qa = fake.declare_queryable(map_key(MAP), answer)
        rss = psutil.Process().memory_info().rss
        code = main(["query", "--map", MAP, "--connect", router, "--box", "0,0,2,2", "--timeout", "3"])
        qa.undeclare()
    err = capsys.readouterr().err
    assert code == 1 and "bad reply" in err and "refused (not allocated)" in err, err
    assert str(far[0] if far[0] else far[1]) in err
    assert psutil.Process().memory_info().rss - rss < 256 << 20


def test_stitch_refuses_a_union_box_over_the_client_limit():
    from protocol.messages import MapRegion
    from psrmap_mapcore import MapCoreError, stitch

    a, b = (decode(_fake_region(x, 0)) for x in (0, 5000))
    assert isinstance(a, MapRegion) and isinstance(b, MapRegion)
    with pytest.raises(MapCoreError, match="at most 4000"):
        stitch([a, b], max_cells=4000)
    assert stitch([a, b], max_cells=6000).w == 5001


# ------------------------------------------------------------------ one scout against a default server


@pytest.mark.serial  # the tile rate refills with wall time: a slower run merges more
def test_one_scout_spreading_cells_over_new_tiles_cannot_exhaust_a_default_server():
    """Issue 25: 256 tiny deltas from one scout, each cell in a new tile, grew the server by 3.5 GiB and shut every
    other scout out of new area. A default `psrmap server` (with --db: paging on) now grows ≤ 256 MiB, says why
    it refused the rest, and still merges another scout's new area (`python benchmarks/scout_flood.py`)."""
    import json
    import subprocess
    import sys
    from pathlib import Path

    bench = Path(__file__).resolve().parents[2] / "benchmarks" / "scout_flood.py"
    res = subprocess.run(
        [sys.executable, str(bench), "--deltas", "64", "--cells", "16"],
        check=True, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    out = json.loads(res.stdout)
    assert out["rss_growth_mib"] <= 256, out
    # 128 tiles a minute, 16 a delta: 8 deltas at once, one more per 7.5 s of refill
    assert 8 <= out["hog_merged"] <= 10 and list(out["hog_rejected"]) == ["limit_scout_tile_rate"], out
    assert out["hog_merged"] + out["hog_rejected"]["limit_scout_tile_rate"] == 64, out
    assert out["other_scout_new_area_merged"], out
    assert out["wal_mib"] < 64, out


@pytest.mark.serial  # ack latency percentiles: the machine to itself
def test_a_thousand_concurrent_queries_do_not_slow_scout_acks():
    """Issue 25: a burst of 1,000 concurrent queries raised scout ack p99 from 9 ms to 4.4 s. Now queries beyond
    the budget are answered `busy` at once, run in the merge worker's gaps within a share of the time, and
    their replies travel below the acks' priority (`python benchmarks/query_load.py`, 1,000 queries)."""
    import json
    import subprocess
    import sys
    from pathlib import Path

    bench = Path(__file__).resolve().parents[2] / "benchmarks" / "query_load.py"
    res = subprocess.run(
        [sys.executable, str(bench), "--queries", "1000", "--seconds", "4", "--rate", "100", "--scouts", "4"],
        check=True, capture_output=True, text=True, timeout=400,
    )  # fmt: skip
    out = json.loads(res.stdout)
    assert out["deltas_unacked"] == 0, out
    q = out["queries"]
    assert q["ok"] > 0 and q["busy"] > 0 and q["no_reply"] == 0 and q["error"] == 0, out
    p99, base = out["ack_ms_with_queries"]["p99"], out["ack_ms_without_queries"]["p99"]
    # goal: ≤ 2× the p99 without queries; 8 helpers share this 2-core machine, so a p99 below 60 ms (the noise
    # of the quiet phase here, against 4.4 s before) also passes
    assert p99 <= 2 * base or p99 <= 60, out


def test_server_flags_for_the_limits_reach_its_config(capsys):
    import argparse

    from map_server.cli import register, server_config

    parser = argparse.ArgumentParser(prog="psrmap")
    register(parser.add_subparsers(dest="command", required=True))
    base = ["server", "--map", "m1", "--connect", "tcp/127.0.0.1:1"]
    args = parser.parse_args(
        [*base, "--bbox=-10,-5,30,40", "--max-queries", "8", "--tile-budget-mib", "0", "--discard-deltas",
         "--limit-max-tiles-per-scout", "7", "--limit-max-new-tiles-per-scout-minute", "3"]
    )  # fmt: skip
    cfg = server_config(args)
    assert cfg.bbox_m == (-10.0, -5.0, 30.0, 40.0) and cfg.bbox_cells == (-25, -13, 75, 100)
    assert (cfg.max_queries_in_flight, cfg.budget_mib, cfg.keep_deltas) == (8, 0.0, False)
    assert (cfg.limits.max_tiles_per_scout, cfg.limits.max_new_tiles_per_scout_minute) == (7, 3)
    assert server_config(parser.parse_args(base)).budget_mib == default_tile_budget_mib()
    for bad in ("1,2,3", "5,0,1,1", "0,0,nan,1"):
        with pytest.raises(SystemExit):
            parser.parse_args([*base, "--bbox", bad])
        assert "--bbox" in capsys.readouterr().err
