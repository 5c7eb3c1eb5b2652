"""The pilot's stop policy (it scales with the route, a stop after progress counts anew) and its standstill
stances (four planted feet for seconds: their ΔP is the base velocity's error, not a slip), as units."""

from __future__ import annotations

import math

import numpy as np

from scout_agent.control.controller import RobotState, TrotController
from scout_agent.control.pilot import Pilot, PilotConfig
from scout_agent.control.reflex import Felt
from scout_agent.estimators import TickEstimates
from scout_agent.estimators.slip import SlipTick
from scout_agent.signals import BaseState, ProprioSample

Z3 = np.zeros(3)
BOUNDS = (-5.0, -5.0, 200.0, 5.0)


def _sample(t: float, x: float, planted=(True,) * 4) -> ProprioSample:
    base = BaseState(np.array([x, 0.0, 0.33]), np.array([1.0, 0.0, 0.0, 0.0]), Z3, Z3)
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


def _stop_and_go_around(p: Pilot, t: float, x: float) -> None:
    p._stop(Felt(t, x + 0.3, 0.0, ("slip",), 3), x, 0.0)
    p._go_around(np.array([x - 1.0, 0.0]), t + 1.0)


def _walk(p: Pilot, t: float, x0: float, x1: float) -> float:
    """Feed the pilot a walk from x0 to x1 along y = 0 (no estimates: nothing fires); the time after it."""
    for x in np.arange(x0, x1, 0.1):
        p.feel(_sample(t, float(x)), None)
        t += 0.25
    return t


def test_three_stops_in_a_row_give_up_but_a_stop_after_progress_counts_anew():
    p = _pilot(137.0)
    t = _walk(p, 0.0, 0.0, 5.0)
    for k in range(2):  # two stops, 2 m apart, then a third: the same place, three in a row
        _stop_and_go_around(p, t, 5.0 + 2 * k)
        assert p.mode == "walk" and p.gave_up is None
        t = _walk(p, t + 2.0, 5.0 + 2 * k, 7.0 + 2 * k)
    _stop_and_go_around(p, t, 9.0)
    assert p.mode == "stopped" and "3 hazard stops in a row" in (p.gave_up or "")

    # the same three stops, but 12 m walked after each: the detour got it past, each stop counts 1
    p = _pilot(137.0)
    t, x = 0.0, 0.0
    for _ in range(p.stop_budget - 1):
        t = _walk(p, t, x, x + 12.0)
        x += 12.0
        _stop_and_go_around(p, t, x)
        assert p.gave_up is None and p.stops_in_a_row == 1
    # ... until the route's budget is spent
    t = _walk(p, t, x, x + 12.0)
    _stop_and_go_around(p, t, x + 12.0)
    assert p.mode == "stopped" and "the route's budget (11 for 137 m" in (p.gave_up or "")


def test_a_short_route_still_gives_up_after_three_stops_whatever_it_walked():
    p = _pilot(25.0)
    t, x = 0.0, 0.0
    for _ in range(3):
        t = _walk(p, t, x, x + 11.0)
        x += 11.0
        _stop_and_go_around(p, t, x)
    assert p.mode == "stopped" and p.stops_in_a_row == 1 and len(p.stops) == 3
    assert "the route's budget (3 for 25 m" in (p.gave_up or "")


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
