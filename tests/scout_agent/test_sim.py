"""SimulatedScout (the simulated Aliengo and the robot's software, joined): the per-tick records, contact flags and forces, the base state as the robot estimates it, falls."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from scout_agent.loop import SimConfig, SimulatedScout
from scout_agent.robot.constants import FOOT_RADIUS, LUNAR_G, TOTAL_MASS
from scout_agent.signals import GroundTruth, ProprioSample
from scout_agent.sim.terrain import RampConfig, make_ramps


@pytest.fixture(scope="module")
def standing():
    sim = SimulatedScout(make_ramps(RampConfig(slope_deg=0.0)))
    records = [sim.step(0.0, 0.0) for _ in range(int(1.5 / sim.control_dt))]
    return sim, records


def test_records_have_the_fixed_shapes(standing):
    sim, records = standing
    sample, truth = records[-1]
    assert isinstance(sample, ProprioSample) and isinstance(truth, GroundTruth)
    assert sample.q.shape == sample.dq.shape == sample.tau.shape == (12,)
    assert sample.contact.dtype == bool and sample.contact.shape == (4,)
    assert sample.foot_pressure.shape == (4,) and truth.foot_force_world.shape == (4, 3)
    assert sample.foot_pos_des_base.shape == sample.foot_vel_des_base.shape == (4, 3)
    assert sample.phase.shape == (4,) and ((sample.phase >= 0) & (sample.phase < 1)).all()
    assert truth.foot_pos_world.shape == (4, 3)
    assert sim.control_dt == pytest.approx(0.002 * sim.config.decimation)
    assert sim.hardware.model.opt.timestep == 0.002 and sim.hardware.model.opt.impratio == 10


def test_standing_feet_carry_the_lunar_weight(standing):
    _, records = standing
    sample, truth = records[-1]
    window = np.array([g.foot_force_world.sum(axis=0) for _, g in records[-178:]])  # two gait cycles
    assert window[:, 2].mean() == pytest.approx(TOTAL_MASS * LUNAR_G, rel=0.08)
    assert truth.nonfoot_contacts == 0
    # accelerometer reads the specific force: +g up when still
    assert np.linalg.norm(np.mean([s.imu_acc for s, _ in records[-60:]], axis=0)) == pytest.approx(
        LUNAR_G, rel=0.1
    )
    # in contact, the foot centre sits a foot radius above the exact terrain
    c = sample.contact
    assert c.any()
    np.testing.assert_allclose(
        truth.foot_pos_world[c, 2] - truth.terrain_height_at_feet[c], FOOT_RADIUS, atol=4e-3
    )


def test_base_state_is_the_estimate_and_exact_only_on_request(standing):
    sim, records = standing
    est = np.array([s.base.vel for s, _ in records])
    true = np.array([g.base.vel for _, g in records])
    err = est - true
    assert np.abs(err).max() > 1e-4  # an estimate, not the truth
    assert np.sqrt((err[50:] ** 2).mean()) < 0.02  # ... and a good one once the robot stands
    np.testing.assert_array_equal(records[-1][1].base.vel, sim.hardware.data.qvel[:3])
    exact = SimulatedScout(
        make_ramps(RampConfig(slope_deg=0.0)), config=replace(SimConfig(), state_source="exact")
    )
    s, g = exact.step(0.0, 0.0)
    np.testing.assert_array_equal(s.base.vel, g.base.vel)
    with pytest.raises(ValueError, match="estimate, exact"):
        SimConfig(state_source="truth")


def test_contact_flags_follow_the_trot(standing):
    sim = SimulatedScout(make_ramps(RampConfig(slope_deg=0.0)))
    flags, planned, disp = [], [], []
    for _ in range(int(3.0 / sim.control_dt)):
        s, g = sim.step(0.2, 0.0)
        flags.append(s.contact)
        planned.append(s.stance_planned)
        disp.append(g.stance_disp)
    flags, planned = np.array(flags[200:]), np.array(planned[200:])
    assert (flags == planned).mean() > 0.85  # contact sensors agree with the schedule
    assert np.nanmax(np.array(disp[200:])) < 0.02  # no slip on 0.7 friction


def test_falls_are_detected():
    sim = SimulatedScout(make_ramps(RampConfig(slope_deg=0.0)))
    sim.hardware.data.qpos[3:7] = (np.cos(np.pi / 4), np.sin(np.pi / 4), 0.0, 0.0)  # rolled 90°
    for _ in range(50):
        sim.step(0.0, 0.0)
        if sim.fell:
            break
    assert sim.fell and sim.hardware.fall_xy is not None


def test_walking_into_a_hazard_crater_is_a_reported_fall():
    """A fresh bowl across the path: blind (no hazard control) or not, the trot never walks through it. It falls
    there (the fall reported where it happened) or is held in it: which one depends on the estimate's few
    centimetres, and the walk is chaotic (one main fell blind, the next stayed on its feet in the bowl). With the
    hazard control, every stop it makes is placed at the bowl (attitude alone included)."""
    from scout_agent.run import ScoutRunConfig, run_scout
    from scout_agent.sim.terrain import LunarConfig, make_lunar

    crater = max(
        (c for c in make_lunar(LunarConfig(seed=0)).info["craters"] if c["hazard"]), key=lambda c: c["depth"]
    )
    assert crater["depth"] / (2 * crater["r"]) > 0.15  # a fresh bowl (d/D 0.17-0.21, walls to ~33 deg)
    x, y = crater["x"], crater["y"]
    walk = ScoutRunConfig(scene="lunar", seed=0, start=(x - 2.0, y, 0.0), goal=(x + 2.5, y), sim_seconds=25)
    for on in (False, True):
        s = run_scout(replace(walk, hazard_control=on), progress=False)
        assert not s["reached_goal"], on
        end = s["fall_xy"] if s["fell"] else s["final_xy"]  # truth: where it fell, or where it stands
        assert np.hypot(end[0] - x, end[1] - y) < crater["r"] + 0.5, (on, s["fell"], end)
        if not on:
            assert s["hazard_stops"] == []
        for stop in s["hazard_stops"]:  # every stop is placed (map frame, estimated), attitude alone included
            assert np.hypot(stop["x"] - x, stop["y"] - y) < crater["r"] + 1.0, stop


def test_the_controller_runs_on_the_estimate_not_the_truth():
    sim = SimulatedScout(make_ramps(RampConfig(slope_deg=0.0)))
    for _ in range(80):
        s, g = sim.step(0.2, 0.0)
    state = sim.robot.state
    np.testing.assert_array_equal(state.pos, s.base.pos)  # what the controller reads is what the sample says
    np.testing.assert_array_equal(state.q, s.q)
    assert np.abs(state.pos - g.base.pos).max() > 1e-5
    np.testing.assert_array_equal(s.foot_vel_des_base, sim.robot.last_output.foot_vel_des_base)
