"""Friction maps, and the simulator applying them to the feet."""

from __future__ import annotations

import numpy as np
import pytest

from scout_agent.loop import SimulatedScout
from scout_agent.robot.constants import FOOT_GEOMS
from scout_agent.sim.friction import (
    FrictionMap,
    Patch,
    RegolithFriction,
    lunar_slippery_patches,
    ramp_slippery_patch,
    unholdable,
)
from scout_agent.sim.terrain import (
    LUNAR_ROUTES,
    LunarConfig,
    RampConfig,
    _polyline_distance,
    make_lunar,
    make_ramps,
)


def test_default_and_patches_later_override():
    fm = FrictionMap(0.7, (Patch(0, 0, 2, 2, 0.3), Patch(1, 1, 3, 3, 0.2)))
    np.testing.assert_allclose(fm.at([-1, 0.5, 1.5, 2.5], [0, 0.5, 1.5, 2.5]), [0.7, 0.3, 0.2, 0.2])
    assert fm.at(5.0, 5.0) == pytest.approx(0.7)


def test_patch_parse_and_validation():
    assert Patch.parse("1,2,3,4,0.25") == Patch(1, 2, 3, 4, 0.25)
    with pytest.raises(ValueError, match="x0,y0,x1,y1,MU"):
        Patch.parse("1,2,3")
    with pytest.raises(ValueError, match="x0 < x1"):
        Patch(3, 0, 1, 1, 0.3)


def test_ramp_patch_covers_the_middle_of_the_down_ramp():
    t = make_ramps(RampConfig(slope_deg=10.0))
    p = ramp_slippery_patch(t, 0.25)
    a, b = t.info["segments"]["down"]
    assert a < p.x0 < p.x1 < b and p.mu == 0.25
    assert (p.x0 + p.x1) / 2 == pytest.approx((a + b) / 2)


def test_lunar_patches_with_the_old_floor_are_seeded_slippery_walkable_and_on_routes():
    t = make_lunar(LunarConfig(seed=1))
    ps = lunar_slippery_patches(t, 6, seed=1, holdable=True)
    assert len(ps) == 6 and ps == lunar_slippery_patches(t, 6, seed=1, holdable=True)
    assert all(0.2 <= p.mu <= 0.35 for p in ps)
    for p in ps:  # never below what the steepest ground inside needs
        xs, ys = np.meshgrid(np.linspace(p.x0, p.x1, 17), np.linspace(p.y0, p.y1, 17))
        assert p.mu >= np.tan(np.radians(t.slope_deg(xs, ys).max()))
    for route in LUNAR_ROUTES.values():  # every route gets patches
        centres = np.array([((p.x0 + p.x1) / 2, (p.y0 + p.y1) / 2) for p in ps])
        d = min(_polyline_distance(centres[:, 0], centres[:, 1], route))
        assert d < 0.01


def test_lunar_patches_by_default_follow_the_regolith_distribution_holdable_or_not():
    reg = RegolithFriction()
    lo, hi = np.tan(np.radians([reg.min_deg, reg.max_deg]))
    mus, unholdable_patches = [], 0
    for seed in range(4):
        t = make_lunar(LunarConfig(seed=seed))
        ps = lunar_slippery_patches(t, 6, seed=seed)
        assert ps == lunar_slippery_patches(t, 6, seed=seed)
        for p in ps:
            xs, ys = np.meshgrid(np.linspace(p.x0, p.x1, 17), np.linspace(p.y0, p.y1, 17))
            unholdable_patches += bool(unholdable(p.mu, t.slope_deg(xs, ys)).any())
            mus.append(p.mu)
    assert all(lo <= m <= hi for m in mus)
    # the draw ignores the slope: some patches hold nowhere a robot would need, some fail somewhere
    assert unholdable_patches > 0 and np.median(mus) == pytest.approx(
        np.tan(np.radians(reg.mean_deg)), abs=0.06
    )


def test_unholdable_is_friction_below_the_slope_tangent():
    np.testing.assert_array_equal(unholdable([0.3, 0.3, 0.08], [15.0, 17.0, 5.0]), [False, True, True])


def test_feet_take_friction_from_the_map():
    t = make_ramps(RampConfig(slope_deg=0.0))
    fm = FrictionMap(0.7, (Patch(0.0, -2.0, 0.6, 2.0, 0.25),))  # under the rear feet only
    sim = SimulatedScout(t, fm)
    for _ in range(5):
        _, truth = sim.step(0.0, 0.0)
    ids = [sim.hardware.model.geom(n).id for n in FOOT_GEOMS]
    mu = sim.hardware.model.geom_friction[ids, 0]
    np.testing.assert_allclose(mu, [0.7, 0.7, 0.25, 0.25])
    np.testing.assert_allclose(truth.friction_at_feet, mu)
    assert (
        sim.hardware.model.geom_priority[ids].min()
        > sim.hardware.model.geom_priority[sim.hardware.model.geom("terrain").id]
    )
