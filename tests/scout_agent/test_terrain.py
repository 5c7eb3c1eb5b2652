"""Terrains: exact heights and slopes, MuJoCo collides with the same triangles, lunar generator caps."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from scout_agent.sim.scene import build_scene
from scout_agent.sim.terrain import (
    LUNAR_ROUTES,
    LunarConfig,
    RampConfig,
    make_lunar,
    make_ramps,
    ramp_profile,
    route_slope_stats,
)


@pytest.fixture(scope="module")
def lunar():
    return make_lunar(LunarConfig(seed=3))


def test_ramp_profile_heights_and_slopes_are_exact():
    cfg = RampConfig(slope_deg=20.0)
    t = make_ramps(cfg)
    xs, zs = ramp_profile(cfg)
    seg = t.info["segments"]
    x = np.linspace(0.01, xs[-1] - 0.01, 500)
    np.testing.assert_allclose(t.height(x, 0.3), np.interp(x, xs, zs), atol=1e-12)
    up = (seg["up"][0] + seg["up"][1]) / 2
    down = (seg["down"][0] + seg["down"][1]) / 2
    assert t.slope_deg(up, 0.0) == pytest.approx(20.0)
    assert t.slope_deg(down, 0.0) == pytest.approx(20.0)
    assert t.slope_deg((seg["platform"][0] + seg["platform"][1]) / 2, 0.0) == pytest.approx(0.0)
    assert t.normal(up, 0.0)[0] < 0  # uphill along +x: the normal leans back


def test_ramp_angle_is_validated():
    with pytest.raises(ValueError, match="0–25"):
        make_ramps(RampConfig(slope_deg=30.0))


def test_mujoco_heightfield_matches_exact_height(lunar):
    m = build_scene(lunar)
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    rng = np.random.default_rng(0)
    gid = np.zeros(1, np.int32)
    for x, y in rng.uniform(0.5, 19.5, (100, 2)):
        dist = mujoco.mj_ray(m, d, np.array([x, y, 10.0]), np.array([0.0, 0.0, -1.0]), None, 1, 1, gid)
        assert 10.0 - dist == pytest.approx(float(lunar.height(x, y)), abs=1e-6)
    # beyond the field the ground goes on at its edge's height (what `height` answers there), 5 m out
    for x, y in ((-4.0, 7.0), (23.5, 12.0), (10.0, 24.0), (-3.0, -3.0), (26.0, 10.0)):
        dist = mujoco.mj_ray(m, d, np.array([x, y, 10.0]), np.array([0.0, 0.0, -1.0]), None, 1, 1, gid)
        if abs(x - 10.0) <= 15.0 and abs(y - 10.0) <= 15.0:
            assert 10.0 - dist == pytest.approx(float(lunar.height(x, y)), abs=1e-6)
        else:
            assert dist == -1.0  # past the skirt: nothing


def test_lunar_is_seeded_and_has_lunar_features(lunar):
    again = make_lunar(LunarConfig(seed=3))
    np.testing.assert_array_equal(lunar.z, again.z)
    assert not np.array_equal(lunar.z, make_lunar(LunarConfig(seed=4)).z)
    assert lunar.extent == (0.0, 0.0, 20.0, 20.0)
    assert len(lunar.info["craters"]) > 20 and len(lunar.info["rocks"]) > 10
    assert max(c["r"] for c in lunar.info["craters"]) <= 1.25  # ≤ 2.5 m wide
    assert max(c["depth"] for c in lunar.info["craters"]) <= 1.0
    assert any(c["hazard"] for c in lunar.info["craters"])


def test_routes_are_capped_and_spawns_flat(lunar):
    stats = route_slope_stats(lunar)
    for name in LUNAR_ROUTES:
        assert stats[name]["max"] <= 26.0 + 0.5, (name, stats[name])  # the corridor cap
        assert stats[name]["p95"] < 23.0, (name, stats[name])
    assert stats["all"]["max"] > 40.0  # hazards remain off the routes
    for route in LUNAR_ROUTES.values():
        for x, y in (route[0], route[-1]):
            xs, ys = np.meshgrid(np.linspace(x - 0.5, x + 0.5, 21), np.linspace(y - 0.5, y + 0.5, 21))
            assert lunar.slope_deg(xs, ys).max() < 5.0
