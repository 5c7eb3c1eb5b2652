"""The scout's map deltas over a real (embedded) Zenoh router to an in-process map server: acks, liveliness,
and the scout's local map equal, cell for cell, to what the server merged from the same run."""

from __future__ import annotations

import json

import numpy as np
import pytest

from protocol.keys import alive_key
from protocol.layers import LAYERS, merge_op
from scout_agent.loop import SimulatedScout
from scout_agent.mapping import Mapper, MapperConfig
from scout_agent.publisher import ScoutPublisher
from scout_agent.sim.terrain import RampConfig, make_ramps

MAP = "testmap"
RES = 0.4


@pytest.fixture(scope="module")
def samples():
    """3 s of a real trot on a 10° ramp (settling included), as the scout would see it."""
    sim = SimulatedScout(make_ramps(RampConfig(slope_deg=10.0)))
    return [sim.step(0.2)[0] for _ in range(int(3.0 / sim.control_dt))]


@pytest.fixture
def server(served_map):
    with served_map(MAP, RES) as pair:
        yield pair


def assert_maps_equal(local, tiled):
    """Cell for cell: integer counts, minima and maxima exactly; sums to the last bits of a float64.

    The server merges a batch of deltas per cell before adding it to the map ((a + b) + c versus a + (b + c)),
    so float sums may differ in their last bit from the scout's delta-by-delta local map."""
    ix0, iy0, ix1, iy1 = local.bounds()
    mine = local.region(ix0, iy0, ix1, iy1)
    theirs = tiled.region(ix0, iy0, ix1, iy1, layers=list(LAYERS), stats=["all"])
    cells = 0
    for name, layer in LAYERS.items():
        for s in layer.stats:
            exact = s in ("n", "events", "nonfoot") or s in ("min", "max") or s.startswith(("min_", "max_"))
            rtol = 0.0 if exact else 1e-12
            np.testing.assert_allclose(
                theirs[name][s], mine[name][s], rtol=rtol, atol=0, err_msg=f"{name}/{s}"
            )
        cells += int((mine[name]["n"] > 0).sum())
    return cells


def test_scout_publishes_its_run_and_the_server_holds_exactly_its_local_map(server, router, samples):
    service, client = server
    with ScoutPublisher(MAP, "scoutA", RES, [router]) as pub:
        assert pub.link.server_up.wait(10)
        alive = list(client.liveliness().get(alive_key(MAP, "scoutA"), timeout=5))
        assert any(r.ok is not None for r in alive)
        mapper = Mapper(MapperConfig(res=RES), publisher=pub)
        for s in samples:
            mapper.update(s)
        summary = mapper.close(ack_timeout_s=15)
    assert summary["all_acked"] and summary["publisher"]["unacked"] == 0
    # 5 Hz: one delta per 0.2 s of scout time, plus the final flush
    assert summary["deltas"] >= int(3.0 / 0.2) - 1
    with service.lock:
        cells = assert_maps_equal(mapper.local, service.map)
    assert cells > 10
    elev = mapper.local.cells("elevation")
    assert elev["n"].sum() > 5  # footholds made it into the map


def test_mapper_without_a_server_keeps_the_same_map(samples):
    a = Mapper(MapperConfig(res=RES))
    for s in samples:
        a.update(s)
    a.close()
    b = Mapper(MapperConfig(res=RES, delta_hz=1.0))  # fewer, larger deltas: same totals
    for s in samples:
        b.update(s)
    b.close()
    for name in ("elevation", "slip", "cot", "giim", "giam", "contacts"):
        ca, cb = a.local.cells(name), b.local.cells(name)
        for s in ca:
            np.testing.assert_allclose(ca[s], cb[s], rtol=1e-9, atol=1e-12, err_msg=f"{name}/{s}")
    assert a.deltas > b.deltas


def test_scout_command_publishes_while_walking(server, router, tmp_path, capsys):
    from psrmap.cli import main

    service, _ = server
    out = tmp_path / "local.npz"
    code = main(
        [
            "scout",
            "--scene",
            "ramps",
            "--slope",
            "5",
            "--sim-seconds",
            "2.5",
            "--quiet",
            "--json",
            "--map",
            MAP,
            "--connect",
            router,
            "--scout-id",
            "cli1",
            "--save-map",
            str(out),
        ]
    )
    assert code == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["map"]["all_acked"] and summary["map"]["saved"] == str(out)
    from psrmap_mapcore import read_npz

    grid = read_npz(out)
    header, layers = {"ix0": grid.ix0, "iy0": grid.iy0, "w": grid.w, "h": grid.h}, grid.layers
    with service.lock:
        theirs = service.map.region(
            header["ix0"],
            header["iy0"],
            header["ix0"] + header["w"] - 1,
            header["iy0"] + header["h"] - 1,
            layers=list(LAYERS),
            stats=["all"],
        )
    # exactly once: counts, minima and maxima equal bit for bit; sums equal to rounding, because the server
    # may add a burst of deltas (the held samples leave together when the walk ends) in another order
    for name, layer in LAYERS.items():
        for s in layer.stats:
            if s == "n" or merge_op(s) != "add":
                np.testing.assert_array_equal(theirs[name][s], layers[name][s], err_msg=f"{name}/{s}")
            else:
                np.testing.assert_allclose(
                    theirs[name][s], layers[name][s], rtol=1e-12, atol=1e-12, err_msg=f"{name}/{s}"
                )


def test_mapping_options_are_checked():
    from psrmap.cli import main

    with pytest.raises(SystemExit):
        main(["scout", "--connect", "tcp/127.0.0.1:1", "--sim-seconds", "1", "--quiet"])
    with pytest.raises(SystemExit):
        main(["scout", "--map", "m1", "--sim-seconds", "1", "--quiet"])
