"""Interior-point Newton method on problems with known constrained optima."""

import numpy as np
import pytest

from drake_estop.planning.newton import barrier_newton


def _quadratic_with_bound(x):
    # min (x0 - 2)^2 + (x1 - 1)^2  s.t.  x0 <= 1, x0 + x1 <= 1.5 (both active at the optimum)
    cost = (x[0] - 2) ** 2 + (x[1] - 1) ** 2
    grad = np.array([2 * (x[0] - 2), 2 * (x[1] - 1)])
    hess = 2 * np.eye(2)
    g = np.array([1 - x[0], 1.5 - x[0] - x[1]])
    gg = np.array([[-1.0, 0.0], [-1.0, -1.0]])
    gh = np.zeros((2, 2, 2))
    return cost, grad, hess, g, gg, gh


def test_converges_to_the_active_set_optimum():
    result = barrier_newton(_quadratic_with_bound, np.array([0.0, 0.0]), mu0=1.0, mu_final=1e-10)
    assert result.converged
    # KKT: x0 = 1 (bound), and on x0 + x1 = 1.5 -> x1 = 0.5
    np.testing.assert_allclose(result.x, [1.0, 0.5], atol=1e-6)
    assert result.iterations < 40


def test_nonlinear_constraint_circle():
    # min x0 + x1 on the disc x0^2 + x1^2 <= 1: optimum (-1/sqrt2, -1/sqrt2)
    def evaluate(x):
        g = np.array([1 - x @ x])
        return (x[0] + x[1], np.ones(2), np.zeros((2, 2)), g, (-2 * x)[None, :], (-2 * np.eye(2))[None])

    result = barrier_newton(evaluate, np.array([0.1, 0.2]), mu0=0.1, mu_final=1e-10)
    np.testing.assert_allclose(result.x, [-1 / np.sqrt(2)] * 2, atol=1e-5)


def test_infeasible_start_rejected():
    with pytest.raises(ValueError, match="feasible"):
        barrier_newton(_quadratic_with_bound, np.array([2.0, 0.0]), mu0=1.0, mu_final=1e-8)
