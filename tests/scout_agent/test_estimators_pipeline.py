"""EstimatorPipeline on constructed ticks: footholds at the exact ground height, slip guarding elevation and
GIIM/GIAM, margins over the four most recent footholds, and `record` into the cell statistics."""

from __future__ import annotations

import math

import numpy as np
import pytest

from scout_agent.cells import CellAccumulator
from scout_agent.estimators import EstimatorPipeline, PipelineConfig, margins, record
from scout_agent.robot.constants import HOME_Q, TOTAL_MASS
from scout_agent.robot.kinematics import jacobians
from scout_agent.robot.statics import leg_gravity_torques
from scout_agent.signals import BaseState, ProprioSample

DT = 0.01
G = 1.62
MASS = TOTAL_MASS  # the robot's (the non-foot force comes from its dynamics model)
R_FOOT = 0.0265
GROUND_Z = 0.1
BASE = np.array([0.5, -0.3, 0.45])
HOME_J = jacobians(HOME_Q)  # (4, 3, 3) leg Jacobians the pipeline uses to estimate ground forces from torques
NOMINAL = np.array([[0.24, 0.134], [0.24, -0.134], [-0.24, 0.134], [-0.24, -0.134]])


class FakeFeet:
    """Kinematics double: the test sets the feet directly (relative to the base, base frame)."""

    def __init__(self) -> None:
        self.pos = np.zeros((4, 3))
        self.vel = np.zeros((4, 3))

    def feet_base_and_vel(self, q, dq):
        return self.pos, self.vel


def trot(n_ticks: int, slide_leg: int | None = None, slide_stance: int = 2, slide_v: float = 0.3):
    """A standing trot: diagonal pairs alternate every 0.3 s; stance feet planted on flat ground at GROUND_Z.

    Optionally leg `slide_leg` slides along +x at `slide_v` from 0.1 s to 0.25 s into its `slide_stance`-th
    stance. Yields (sample, feet_world (4, 3), stance index per leg).
    """
    world = np.column_stack([BASE[:2] + NOMINAL, np.full(4, GROUND_Z + R_FOOT)])
    stance_no = [0, 0, 0, 0]
    prev = np.zeros(4, dtype=bool)
    t_start = np.zeros(4)
    for k in range(n_ticks):
        t = k * DT
        pair = int(t / 0.3) % 2
        planned = np.array([pair == 0, pair == 1, pair == 1, pair == 0])
        for i in range(4):
            if planned[i] and not prev[i]:
                stance_no[i] += 1
                t_start[i] = t
                world[i] = [*(BASE[:2] + NOMINAL[i]), GROUND_Z + R_FOOT]
        vel_w = np.zeros((4, 3))
        if slide_leg is not None and planned[slide_leg] and stance_no[slide_leg] == slide_stance:
            tr = t - t_start[slide_leg]
            if 0.1 <= tr < 0.25:
                vel_w[slide_leg, 0] = slide_v
                world[slide_leg, 0] += slide_v * DT
        swing = ~planned
        pos_b = world - BASE
        pos_b[swing, 2] += 0.05  # swing feet lifted
        forces = np.zeros((4, 3))
        forces[planned, 2] = MASS * G / planned.sum()
        # the joint torques that hold those ground forces (base unrotated: world = base frame), τ = −Jᵀf
        tau = -np.einsum("lji,lj->li", HOME_J, forces).reshape(12)
        sample = ProprioSample(
            t=t,
            q=HOME_Q.copy(),
            dq=np.zeros(12),
            tau=tau,
            contact=planned.copy(),
            foot_pressure=forces[:, 2].copy(),
            joint_energy_j=0.0,
            imu_acc=np.array([0.0, 0.0, G]),
            imu_gyro=np.zeros(3),
            base=BaseState(BASE.copy(), np.array([1.0, 0, 0, 0]), np.zeros(3), np.zeros(3)),
            foot_pos_des_base=pos_b.copy(),
            foot_vel_des_base=np.zeros((4, 3)),
            stance_planned=planned,
            phase=np.zeros(4),
        )
        prev = planned
        yield sample, pos_b, vel_w


def run(pipe, feet, gen):
    out = []
    for sample, pos_b, vel_w in gen:
        feet.pos = pos_b
        feet.vel = vel_w  # base still and unrotated: world velocity = velocity relative to the base
        out.append(pipe.update(sample))
    return out


def make():
    feet = FakeFeet()
    cfg = PipelineConfig(
        mass_kg=MASS, gravity_mps2=G, foot_radius_m=R_FOOT, paper_margins=True, stance_margins=True
    )
    return EstimatorPipeline(feet, cfg), feet


def test_footholds_are_the_ground_under_the_feet_and_margins_use_four_footholds():
    pipe, feet = make()
    ticks = run(pipe, feet, trot(200))
    fh = np.concatenate([e.footholds for e in ticks if len(e.footholds)])
    assert len(fh) >= 8  # ≈ 2 stances end every 0.3 s
    np.testing.assert_allclose(fh[:, 2], GROUND_Z, atol=1e-12)
    assert not any(any(e.slip.event) for e in ticks)
    last = ticks[-1]
    support = np.column_stack([BASE[:2] + NOMINAL, np.full(4, GROUND_Z)])
    expect = margins(support, BASE, np.array([0.0, 0.0, -G]))
    assert last.giim == pytest.approx(expect[0]) and last.giam == pytest.approx(expect[1])
    assert last.giim > 0
    assert last.giim_stance <= 1e-12  # two stance feet: a line, never a positive margin
    # the paper variant, leg order and |min|, gives the front/rear face (CoM 0.35 m above the ground)
    assert last.giim_paper == pytest.approx(math.atan2(0.24, 0.35), abs=1e-9)


def test_a_slipping_stance_gives_a_slip_event_no_foothold_and_no_stability_sample():
    pipe, feet = make()
    ticks = run(pipe, feet, trot(200, slide_leg=0, slide_stance=2))
    events = [(k, e) for k, e in enumerate(ticks) if e.slip.event[0]]
    assert len(events) == 1
    k_ev, ev = events[0]
    np.testing.assert_allclose(ev.slip_xy, [BASE[:2] + NOMINAL[0]], atol=1e-12)  # at the touchdown foothold
    # FL's second stance runs 0.6–0.9 s: guarded from the event to its end, and it leaves no foothold
    guarded = [k for k, e in enumerate(ticks) if e.stability_guarded]
    assert guarded[0] == k_ev and all(ticks[k].slip.slipped[0] for k in guarded)
    end = next(k for k in range(k_ev, len(ticks)) if ticks[k].slip.stance_end[0])
    assert len(ticks[end].footholds) == 1  # only RR's, not FL's
    acc = CellAccumulator(0.4)
    for e in ticks:
        record(e, acc)
    layers = acc.flush()
    assert layers["slip"]["events"].sum() == 1
    assert layers["slip"]["n"].sum() == sum(len(e.stance_xy) for e in ticks)
    # every unguarded tick maps a margin; at the start two footholds are known: a line, margin ≤ 0 (docs/physics.md)
    assert layers["giim"]["n"].sum() == len(ticks) - len(guarded)
    assert ticks[0].giim == pytest.approx(0.0, abs=1e-12)
    assert layers["elevation"]["n"].sum() == sum(len(e.footholds) for e in ticks)
    assert layers["contacts"]["nonfoot"].sum() == 0


def _standing(q: np.ndarray, extra_n: float, n_ticks: int = 60, t0: float = 0.0):
    """Four feet planted, the legs' torques holding the robot's weight (and their own links') plus `extra_n` [N]
    more downward push than the IMU's specific force explains (an external force on something other than the
    feet), at joint angles `q`."""
    J = jacobians(q)
    forces = np.zeros((4, 3))
    forces[:, 2] = (MASS * G + extra_n) / 4
    tau_g = np.zeros(12)
    leg_gravity_torques(q, np.array([0.0, 0.0, -G]), tau_g)
    tau = tau_g - np.einsum("lji,lj->li", J, forces).reshape(12)
    planted = np.ones(4, dtype=bool)
    pos_b = np.column_stack([NOMINAL, np.full(4, GROUND_Z + R_FOOT - BASE[2])])
    for k in range(n_ticks):
        yield (
            ProprioSample(
                t=t0 + k * DT, q=q.copy(), dq=np.zeros(12), tau=tau, contact=planted, foot_pressure=forces[:, 2].copy(),
                joint_energy_j=0.0, imu_acc=np.array([0.0, 0.0, G]), imu_gyro=np.zeros(3),
                base=BaseState(BASE.copy(), np.array([1.0, 0, 0, 0]), np.zeros(3), np.zeros(3)),
                foot_pos_des_base=pos_b, foot_vel_des_base=np.zeros((4, 3)), stance_planned=planted,
                phase=np.zeros(4),
            ),
            pos_b,
            np.zeros((4, 3)),
        )  # fmt: skip


def test_a_force_the_feet_do_not_explain_is_a_non_foot_contact_unless_a_leg_stands_at_a_joint_limit():
    # 30 N the torques show and the IMU does not: flagged after the warm-up
    pipe, feet = make()
    ticks = run(pipe, feet, _standing(HOME_Q, 30.0))
    assert ticks[-1].nonfoot_force_n == pytest.approx(30.0, rel=0.02) and ticks[-1].nonfoot
    # the same with a stance leg's knee at its stop (a hind leg stretched into a hollow): the limit bears torque
    # the motor's current does not show, the foot's force is not known, and nothing is flagged
    q = HOME_Q.copy()
    q[8] = -0.65  # RL calf, range ends at −0.6458
    pipe, feet = make()
    ticks = run(pipe, feet, _standing(q, 30.0))
    assert ticks[-1].nonfoot_force_n == pytest.approx(30.0, rel=0.02)
    assert not any(e.nonfoot for e in ticks)
    # 0.1 rad off the stop the torques are trusted again
    q[8] = -0.75
    pipe, feet = make()
    assert run(pipe, feet, _standing(q, 30.0))[-1].nonfoot


def test_a_joint_limit_reached_before_the_force_rose_still_holds_the_flag_off():
    # a stance knee at its stop while the unexplained force is small, then off the stop as 30 N arrive: the
    # limit's torque may still be in the low-passed force, so nothing is flagged for `nonfoot_limit_hold_s` after
    # the knee left the stop (the limit is watched every tick, not only once the force is above the threshold)
    q = HOME_Q.copy()
    q[8] = -0.65
    pipe, feet = make()
    hold = pipe.config.nonfoot_limit_hold_s
    at_stop = run(pipe, feet, _standing(q, 0.0, n_ticks=40))
    assert not any(e.nonfoot for e in at_stop)
    t_left = 40 * DT
    after = run(pipe, feet, _standing(HOME_Q, 30.0, n_ticks=40, t0=t_left))
    assert after[-1].nonfoot_force_n == pytest.approx(30.0, rel=0.02)
    flagged = [e.t for e in after if e.nonfoot]
    assert flagged and min(flagged) >= t_left - DT + hold - 1e-9  # the last tick at the stop, + hold
    # without the stop the same force is flagged as soon as its low-pass passes 20 N (≈ 0.06 s)
    pipe, feet = make()
    run(pipe, feet, _standing(HOME_Q, 0.0, n_ticks=40))
    flagged = [e.t for e in run(pipe, feet, _standing(HOME_Q, 30.0, n_ticks=40, t0=t_left)) if e.nonfoot]
    assert flagged and min(flagged) < t_left + 0.1
