"""C routines called from compiled code (`scout_agent.ccall`) give what their Python bindings give, bit for bit."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
import quadprog

from scout_agent.ccall import c_function, package_library
from scout_agent.control.stance import StanceQP, StanceQPConfig, qp_problem
from scout_agent.lowlevel import LowCmd
from scout_agent.robot import constants as C
from scout_agent.sim.aliengo import SimulatedAliengo, _set_controls
from scout_agent.sim.terrain import RampConfig, make_ramps


def _through_binding(
    qp: StanceQP, stance, feet_w, com, normal, wrench, f_prev, mu4
) -> tuple[np.ndarray, int]:
    """The stance forces as before the compiled call (the problem's arrays, then `quadprog.solve_qp`) and the
    number of constraints active at the solution."""
    c = qp.config
    forces = np.zeros((4, 3))
    k = int(stance.sum())
    if k == 0:
        return forces, 0
    r = feet_w[stance] - com
    G, a, Cm, b = qp_problem(
        r,
        normal,
        wrench,
        f_prev[stance].reshape(-1),
        qp._S,
        mu4[stance].copy(),
        c.f_min,
        c.f_max,
        c.reg,
        c.smooth,
    )
    sol, _, _, _, _, iact = quadprog.solve_qp(G, a, Cm, b, 0)
    forces[stance] = sol.reshape(k, 3)
    return forces, len(iact)


@pytest.mark.parametrize("config", [StanceQPConfig(), StanceQPConfig(mu=0.3, f_max=60.0, smooth=0.0)])
def test_stance_forces_equal_quadprogs_binding_bit_for_bit(config: StanceQPConfig):
    qp = StanceQP(config)
    rng = np.random.default_rng(7)
    active = 0
    for _ in range(3000):
        stance = rng.random(4) < 0.6
        feet_w = rng.normal(size=(4, 3)) * 0.3 + [0.0, 0.0, -0.4]
        com = rng.normal(size=3) * 0.02
        normal = np.array([rng.normal() * 0.2, rng.normal() * 0.2, 1.0])
        normal /= np.linalg.norm(normal)
        wrench = np.concatenate([rng.normal(size=3) * [20, 20, 40] + [0, 0, 34], rng.normal(size=3) * 3])
        f_prev = rng.normal(size=(4, 3)) * 10
        mu4 = rng.uniform(0.05, 0.9, 4)
        want, n_active = _through_binding(qp, stance, feet_w, com, normal, wrench, f_prev, mu4)
        got = qp.solve_feet(stance, feet_w, com, normal, wrench, f_prev, mu4)
        assert np.array_equal(got, want)
        active += n_active > 0
    assert active > 300  # the friction cones or force bounds bind in many of them: the solver's full path


def _tick_through_binding(hw: SimulatedAliengo, cmd: LowCmd) -> float:
    """`SimulatedAliengo.write`'s physics as before the compiled call: the controls, then `mujoco.mj_step` and
    numpy copies of the readings step by step; returns the tick's Σ|τ·q̇|."""
    _set_controls(*cmd, *hw._v_controls)
    blocks = hw._blocks
    for k in range(hw.config.decimation):
        mujoco.mj_step(hw.model, hw.data)
        for block, view in zip(blocks, hw._v_readings, strict=True):
            block[k] = view
    return float(np.abs(hw._blk_tau * hw._blk_dq).sum(axis=1).sum())


def test_the_physics_tick_equals_mujocos_binding_bit_for_bit():
    """A ramp walked down under random joint commands (so the feet slide, lift and land): the compiled tick
    and the binding's steps leave the same MuJoCo state, readings and joint work after every tick."""
    terrain = make_ramps(RampConfig(slope_deg=10.0))
    a, b = SimulatedAliengo(terrain), SimulatedAliengo(terrain)
    rng = np.random.default_rng(3)
    touching = 0
    for tick in range(150):
        cmd = LowCmd(
            C.HOME_Q + rng.normal(size=12) * 0.1,
            rng.normal(size=12) * (tick % 2),  # dq_des zero (the controller's) and not
            np.full(12, 40.0),
            np.full(12, 1.0),
            rng.normal(size=12),
        )
        a.write(cmd)
        work = _tick_through_binding(b, cmd)
        assert np.array_equal(a.data.qpos, b.data.qpos) and np.array_equal(a.data.qvel, b.data.qvel)
        assert np.array_equal(a.data.act, b.data.act) and np.array_equal(
            a.data.qacc_warmstart, b.data.qacc_warmstart
        )
        for x, y in zip(a._blocks, b._blocks, strict=True):
            assert np.array_equal(x, y)
        assert a._energy_tick_j == work * a.dt
        touching += a.data.ncon > 0
    assert touching > 100 and np.abs(a.data.qpos[:2] - a.start[:2]).max() > 0.01  # on the ground, moved


def test_a_missing_library_or_routine_is_named(tmp_path):
    with pytest.raises(RuntimeError, match="no shared library libnothing"):
        package_library(tmp_path, "libnothing")
    with pytest.raises(RuntimeError, match="exports no C function 'no_such_routine'"):
        c_function(quadprog.__file__, "no_such_routine")
