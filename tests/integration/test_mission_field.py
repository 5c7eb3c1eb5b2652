"""Mission scale: `[mission] field = L` alone gives default scouts whose routes span the field and cross, a
walking-time limit that follows the routes, and the planner's ends on the field; the summary's map figures
(shared map vs truth, the scouts' own maps' disagreement) are computed as documented."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from psrmap.agreement import cross_scout_rms, map_elevation_rmse
from psrmap.mission.config import load_config, route_seconds
from psrmap_mapcore import LayerGrid
from scout_agent.sim.terrain import Terrain


def _length(route) -> float:
    return sum(math.dist(a, b) for a, b in zip(route[:-1], route[1:], strict=True))


def test_only_the_field_set_gives_crossing_routes_that_span_it(tmp_path) -> None:
    f = tmp_path / "m.toml"
    f.write_text("[mission]\nfield = 100\n")
    cfg = load_config(f)
    assert cfg.field_m == 100.0 and len(cfg.scouts) == 3 and cfg.slippery_patches == 0
    routes = [s.route() for s in cfg.scouts]
    for r in routes:
        pts = np.array(r)
        assert np.all((pts >= 1.0) & (pts <= 99.0))  # on the field
        assert _length(r) > 130.0  # corner to corner
    # scout2 walks scout1's diagonal the other way: they meet, then each walks the other's ground
    assert routes[1] == routes[0][::-1]
    assert cfg.sim_seconds == pytest.approx(route_seconds(cfg.scouts, cfg.speed))
    assert cfg.sim_seconds > 1.5 * max(_length(r) for r in routes) / cfg.speed
    assert cfg.plan_from == (2.0, 2.0) and cfg.plan_to == (98.0, 98.0)
    # the embedded default mission is unchanged
    base = load_config()
    assert base.field_m == 20.0 and base.sim_seconds == 150.0 and base.scouts[0].goal == (18.5, 18.5)


def test_a_bad_field_is_refused_with_the_valid_range(tmp_path) -> None:
    f = tmp_path / "m.toml"
    f.write_text("[mission]\nfield = 2\n")
    with pytest.raises(ValueError, match="5–400"):
        load_config(f)


def test_map_figures() -> None:
    agreement = {"a-b": {"cells": 3, "mean_diff_m": 0.0, "rms_diff_m": 0.02},
                 "a-c": {"cells": 1, "mean_diff_m": 0.0, "rms_diff_m": 0.06}}  # fmt: skip
    assert cross_scout_rms(agreement) == pytest.approx(math.sqrt((3 * 0.02**2 + 0.06**2) / 4), abs=1e-4)
    assert cross_scout_rms({}) is None
    # a plane z = 0.1 x: a map whose cells hold the exact centre height, one cell off by 0.3 m
    t = Terrain(np.tile(0.1 * np.arange(0, 10.01, 0.1), (101, 1)), 0.1, 0.0, 0.0)
    n = np.zeros((5, 5))
    n[1:3, 1:4] = 3
    cx = (np.arange(5) + 0.5) * 0.4
    z = np.tile(0.1 * cx, (5, 1))
    z[2, 3] += 0.3
    # raw statistics, as a map holds them: every cell's footholds at its centre (the plane fit's mean height)
    zeros = np.zeros_like(n)
    moments = {k: zeros for k in ("sx", "sy", "sxx", "syy", "sxy", "sxz", "syz")}
    elevation = {"n": n, "sum": n * z, "sumsq": n * z * z, **moments}
    g = LayerGrid("m", 0.4, 0, 0, 5, 5, {"elevation": elevation})
    rmse, cells = map_elevation_rmse(g, t)
    assert cells == 6 and rmse == pytest.approx(math.sqrt(0.3**2 / 6), abs=1e-3)


def test_each_scout_of_a_mission_draws_its_own_sensor_and_survey_errors() -> None:
    """Robots built and surveyed one by one share no error draw: the mission gives each scout its own sensor
    seed (the first keeps the terrain seed, as a single walk of that seed), so their launch surveys differ,
    and rebuilding the same scout draws the same error again."""
    from psrmap.mission.components import scout_config
    from scout_agent.loop import SimulatedScout
    from scout_agent.run import scout_sim_config
    from scout_agent.sim.terrain import RampConfig, make_ramps

    cfg = load_config()
    runs = [scout_config(cfg, s, "tcp/127.0.0.1:7447", Path("/nonexistent"), None).run for s in cfg.scouts]
    assert runs[0].sensor_seed is None and scout_sim_config(runs[0]).sensors.seed == cfg.seed
    seeds = [scout_sim_config(r).sensors.seed for r in runs]
    assert len(set(seeds)) == len(seeds) == 3
    ramps = make_ramps(RampConfig(slope_deg=0.0))

    def launch_error(run) -> tuple[float, float, float]:
        scout = SimulatedScout(ramps, config=scout_sim_config(run))
        sx, sy, syaw = scout.hardware.start
        return (scout.launch.x - sx, scout.launch.y - sy, scout.launch.yaw - syaw)

    errors = [launch_error(r) for r in runs]
    assert len({tuple(np.round(e, 9)) for e in errors}) == 3  # three different surveys
    assert launch_error(runs[1]) == errors[1]  # the same scout, the same draw
