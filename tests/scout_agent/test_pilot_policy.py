"""The pilot's stop policy (it scales with the route, a stop after progress counts anew) and its standstill
stances (four planted feet for seconds: their ΔP is the base velocity's error, not a slip), as units."""

from __future__ import annotations

import math

import numpy as np
import pytest

from scout_agent.control.controller import RobotState, TrotController
from scout_agent.control.detour import plan_detour
from scout_agent.control.pilot import Pilot, PilotConfig
from scout_agent.control.reflex import Felt, ReflexConfig
from scout_agent.estimators import TickEstimates
from scout_agent.estimators.slip import SlipTick
from scout_agent.signals import BaseState, ProprioSample

Z3 = np.zeros(3)
BOUNDS = (-5.0, -5.0, 200.0, 5.0)


def _sample(t: float, x: float, planted=(True,) * 4, y: float = 0.0) -> ProprioSample:
    base = BaseState(np.array([x, y, 0.33]), np.array([1.0, 0.0, 0.0, 0.0]), Z3, Z3)
    z12, z4 = np.zeros(12), np.zeros(4)
    return ProprioSample(
        t, z12, z12, z12, np.array(planted), z4, 0.0, np.array([0.0, 0.0, 1.62]), Z3, base,
        np.zeros((4, 3)), np.zeros((4, 3)), np.array(planted), z4,
    )  # fmt: skip


def _est(t: float, event=(), end=(), dp=0.0) -> TickEstimates:
    f = lambda idx: tuple(i in idx for i in range(4))  # noqa: E731
    slip = SlipTick(f(()), f(event), f(end), f(event), (True,) * 4, (0.0,) * 4, (dp,) * 4, 1.0)
    xy = np.array([[float(i), 0.0] for i in sorted(event)]).reshape(-1, 2)
    e2 = np.zeros((0, 2))
    return TickEstimates(t, (0.0, 0.0), 0.0, 0.0, 0.3, 1.0, False, slip, e2, xy, np.zeros((0, 3)), False, 0.0,
                         np.zeros((4, 3)))  # fmt: skip


def _pilot(route_m: float, **kw) -> Pilot:
    controller = TrotController()
    controller.reset(RobotState(0.0, np.array([0.0, 0.0, 0.33]), np.eye(3), Z3, Z3, np.zeros(12), np.zeros(12),
                                np.ones(4, bool)))  # fmt: skip
    return Pilot(np.array([[0.0, 0.0], [route_m, 0.0]]), controller, BOUNDS, PilotConfig(**kw))


def test_the_stop_budget_scales_with_the_route_and_short_routes_keep_three():
    assert _pilot(25.0).stop_budget == 3  # the 20 m field's routes: as before
    assert _pilot(10.0).stop_budget == 3  # a ramp walk
    assert _pilot(137.0).stop_budget == math.ceil(137.0 * 0.08) == 11  # the 100 m field corner to corner


def _stop_and_go_around(p: Pilot, t: float, x: float, y: float = 0.0) -> None:
    p._stop(Felt(t, x + 0.3, y, ("slip",), 3), x, y)
    p._go_around(np.array([x - 5.0, y]), t + 1.0)  # backed off 5 m


def test_three_stops_at_one_place_give_up_but_stops_along_the_route_do_not():
    p = _pilot(137.0)
    # two stops 1.5 m apart: the second detour keeps twice the radius from both
    _stop_and_go_around(p, 10.0, 20.0, 0.0)
    r = p.config.detour.hazard_radius_m
    _stop_and_go_around(p, 20.0, 21.5, 1.0)
    assert p.mode == "walk" and p.gave_up is None and p.stops_here == 2
    way = p.follower.points
    u = np.linspace(0.0, 1.0, 40)[:, None]
    legs = np.concatenate([a + (b - a) * u for a, b in zip(way[:-1], way[1:], strict=True)])
    for hx, hy in p.hazards:
        assert np.hypot(legs[:, 0] - hx, legs[:, 1] - hy).min() >= 2 * r - p.config.detour.res
    # a third there: the detours did not get it past
    _stop_and_go_around(p, 30.0, 22.0, -1.0)
    assert p.mode == "stopped" and "3 hazard stops at one place" in (p.gave_up or "")

    # stops 12 m apart along the route: each place counts 1, until the route's budget is spent
    p = _pilot(137.0)
    for k in range(p.stop_budget - 1):
        _stop_and_go_around(p, 10.0 * k, 12.0 * (k + 1))
        assert p.gave_up is None and p.stops_here == 1
    _stop_and_go_around(p, 200.0, 12.0 * p.stop_budget)
    assert p.mode == "stopped" and "the route's budget (11 for 137 m" in (p.gave_up or "")


def test_a_short_route_still_gives_up_after_three_stops_anywhere():
    p = _pilot(25.0)
    for k in range(3):
        _stop_and_go_around(p, 10.0 * k, 6.0 * (k + 1))
    assert p.mode == "stopped" and p.stops_here == 1 and len(p.stops) == 3
    assert "the route's budget (3 for 25 m" in (p.gave_up or "")


def test_detour_keeps_each_hazards_own_radius():
    bounds = (0.0, 0.0, 20.0, 10.0)
    wide = plan_detour((1.0, 5.0), (19.0, 5.0), [(10.0, 5.0, 3.0)], bounds)
    assert wide is not None
    u = np.linspace(0.0, 1.0, 60)[:, None]
    legs = np.concatenate([a + (b - a) * u for a, b in zip(wide[:-1], wide[1:], strict=True)])
    assert np.hypot(legs[:, 0] - 10.0, legs[:, 1] - 5.0).min() >= 3.0 - 0.2
    narrow = plan_detour((1.0, 5.0), (19.0, 5.0), [(10.0, 5.0)], bounds)
    assert narrow is not None
    legs = np.concatenate([a + (b - a) * u for a, b in zip(narrow[:-1], narrow[1:], strict=True)])
    assert np.hypot(legs[:, 0] - 10.0, legs[:, 1] - 5.0).min() < 2.0  # the default 1.2 m hugs closer


def test_a_standstills_long_stance_gives_the_reflex_no_slip_and_the_next_stance_does():
    p = _pilot(137.0)
    # standing (the state estimator's standstill): four planted feet whose ΔP grows with the velocity error
    p.controller.hold = True
    out = p._standstill_stances(_sample(1.0, 0.0), _est(1.0, event=(1,), dp=0.05))
    assert not any(out.slip.event) and not any(out.slip.slipped) and len(out.slip_xy) == 0
    assert all(math.isnan(d) for d in out.slip.dp)
    # walking again: those feet's stances go on and still say nothing ...
    p.controller.hold = False
    out = p._standstill_stances(_sample(1.1, 0.0), _est(1.1, event=(2,), dp=0.06))
    assert not any(out.slip.event) and all(math.isnan(d) for d in out.slip.dp)
    # ... until each ends: foot 0 and 3 lift off, their next stance is a walking one and its slip counts
    out = p._standstill_stances(_sample(1.2, 0.0), _est(1.2, end=(0, 3), dp=0.06))
    assert not any(out.slip.slipped)
    lifted = (False, True, True, False)
    p._standstill_stances(_sample(1.3, 0.0, planted=lifted), _est(1.3))
    out = p._standstill_stances(_sample(1.6, 0.0), _est(1.6, event=(0, 1), dp=0.06))
    assert out.slip.event == (True, False, False, False) and out.slip.dp[0] == 0.06
    assert math.isnan(out.slip.dp[1]) and out.slip_xy.tolist() == [[0.0, 0.0]]


def test_a_second_back_off_retraces_the_detour_and_the_way_in_not_the_first_back_off():
    p = _pilot(137.0)
    t = 0.0
    for x in np.arange(0.0, 6.0, 0.1):  # walk in along y = 0
        p.feel(_sample(t, float(x)), None)
        t += 0.5
    p._stop(Felt(t, 6.2, 0.0, ("slip",), 3), 5.9, 0.0)
    p._start_back(np.array([5.9, 0.0]), t)
    assert p.mode == "back"
    end = p._back.points[-1]
    assert 0.4 <= 5.9 - end[0] <= p.config.backoff_max_m + 0.1
    assert np.allclose(p.trail[-1][1:], end)  # the trail now ends where the back-off does
    # backing off adds nothing to it
    n = len(p.trail)
    p.feel(_sample(t + 1.0, 5.5), None)
    assert len(p.trail) == n
    # the detour turns off the way in along +y from the back-off's end; a second stop there
    p.mode = "walk"
    for y in np.arange(0.1, 1.5, 0.1):
        p.feel(_sample(t, float(end[0]), y=float(y)), None)
        t += 0.5
    p._stop(Felt(t, float(end[0]), 1.7, ("slip",), 3), float(end[0]), 1.4)
    p._start_back(np.array([end[0], 1.4]), t)
    back = p._back.points
    # back along the detour (y falls) and then the way in (x falls): never toward the first hazard
    assert np.all(np.diff(back[:, 1]) <= 1e-9) and np.all(np.diff(back[:, 0]) <= 1e-9)
    assert np.hypot(back[-1][0] - 6.2, back[-1][1]).min() > np.hypot(end[0] - 6.2, 0.0)


def _walk_onto_a_wall(p: Pilot, tan_wall: float) -> None:
    """Three trot steps of 0.1 m with the front feet past a wall's edge at x 0.4 (z falls at `tan_wall`), the rear
    feet on the flat before it: the controller's footholds as its touchdowns would set them."""
    for k in range(3):
        x_front, x_rear = 0.45 + 0.1 * k, 0.0 + 0.1 * k
        p.controller.footholds[:] = [
            [x_front, 0.15, -tan_wall * (x_front - 0.4)],
            [x_front, -0.15, -tan_wall * (x_front - 0.4)],
            [x_rear, 0.15, 0.0],
            [x_rear, -0.15, 0.0],
        ]
        p.feel(_sample(0.1 * k, x_rear + 0.2), _est(0.1 * k))


def test_front_feet_slope_reads_the_wall_the_foothold_plane_averages_away():
    tan20 = math.tan(math.radians(20.0))
    p = _pilot(25.0, senses=ReflexConfig(front_slip_margin=0.12))
    _walk_onto_a_wall(p, tan20)
    assert p.tracks.front_tan() == pytest.approx(tan20, abs=0.01)
    grad, _ = p.controller.plane()
    assert float(np.hypot(*grad)) < 0.7 * tan20  # the four-foot plane: the wall and the flat, averaged


@pytest.mark.parametrize("front_slip_margin", [None, 0.12])
def test_a_front_foot_slip_on_a_wall_steeper_than_the_felt_friction_stops_at_once(front_slip_margin):
    # the scout has felt μ̂ 0.3 (a lost hold); its front feet stand on 20° (tan 0.364: unholdable), its rear feet
    # on the flat: the four-foot plane's margin reads ≈ +0.1, so one front-foot slip stops only with the trigger
    p = _pilot(25.0, senses=ReflexConfig(front_slip_margin=front_slip_margin))
    p.friction.mu[:] = 0.3
    _walk_onto_a_wall(p, math.tan(math.radians(20.0)))
    assert p.mode == "walk" and p.setting is not None and p.setting.margin > ReflexConfig().slip_sure_margin
    felt = p.feel(_sample(0.4, 0.4), _est(0.4, event=(0,)))
    if front_slip_margin is None:
        assert felt is None and p.mode == "walk"
    else:
        assert felt is not None and "slip" in felt.reasons and p.mode == "stop"
