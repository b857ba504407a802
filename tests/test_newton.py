"""Interior-point Newton method on problems with known constrained optima."""

import numpy as np

from drake_estop.planning.backend import python_function
from drake_estop.planning.newton import CONVERGED, INFEASIBLE_START, barrier_newton_for

NO_DATA = np.zeros(1)


def _quadratic_with_bound(data, x, derivatives, jg, jh, g, gg, gh):
    # min (x0 - 2)^2 + (x1 - 1)^2  s.t.  x0 <= 1, x0 + x1 <= 1.5 (both active at the optimum)
    g[0] = 1.0 - x[0]
    g[1] = 1.5 - x[0] - x[1]
    if derivatives:
        jg[0], jg[1] = 2.0 * (x[0] - 2.0), 2.0 * (x[1] - 1.0)
        jh[0, 0], jh[0, 1], jh[1, 0], jh[1, 1] = 2.0, 0.0, 0.0, 2.0
        gg[0, 0], gg[0, 1], gg[1, 0], gg[1, 1] = -1.0, 0.0, -1.0, -1.0
        gh[:, :, :] = 0.0
    return (x[0] - 2.0) * (x[0] - 2.0) + (x[1] - 1.0) * (x[1] - 1.0)


def _linear_on_disc(data, x, derivatives, jg, jh, g, gg, gh):
    # min x0 + x1 on the disc x0^2 + x1^2 <= 1: optimum (-1/sqrt2, -1/sqrt2)
    g[0] = 1.0 - x[0] * x[0] - x[1] * x[1]
    if derivatives:
        jg[0], jg[1] = 1.0, 1.0
        jh[:, :] = 0.0
        gg[0, 0], gg[0, 1] = -2.0 * x[0], -2.0 * x[1]
        gh[0, 0, 0], gh[0, 0, 1], gh[0, 1, 0], gh[0, 1, 1] = -2.0, 0.0, 0.0, -2.0
    return x[0] + x[1]


# the method's source run as Python on these toy problems (a compiled method specialised for them would
# compile on every run: numba cannot cache a function closing over another); the compiled method runs
# in the planner's tests, and tests/test_solver.py checks that it equals the Python one
QUADRATIC = python_function(barrier_newton_for(_quadratic_with_bound))
DISC = python_function(barrier_newton_for(_linear_on_disc))


def test_converges_to_the_active_set_optimum():
    x, _, iterations, status = QUADRATIC(NO_DATA, np.array([0.0, 0.0]), 2, 1.0, 1e-10)
    assert status == CONVERGED
    # KKT: x0 = 1 (bound), and on x0 + x1 = 1.5 -> x1 = 0.5
    np.testing.assert_allclose(x, [1.0, 0.5], atol=1e-6)
    assert iterations < 40


def test_nonlinear_constraint_circle():
    x, _, _, status = DISC(NO_DATA, np.array([0.1, 0.2]), 1, 0.1, 1e-10)
    assert status == CONVERGED
    np.testing.assert_allclose(x, [-1 / np.sqrt(2)] * 2, atol=1e-5)


def test_infeasible_start_rejected():
    x, _, iterations, status = QUADRATIC(NO_DATA, np.array([2.0, 0.0]), 2, 1.0, 1e-8)
    assert status == INFEASIBLE_START and iterations == 0
    np.testing.assert_array_equal(x, [2.0, 0.0])
