"""C routines called from compiled code (`scout_agent.ccall`) give what their Python bindings give, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest
import quadprog

from scout_agent.control.stance import StanceQP, StanceQPConfig, qp_problem


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
