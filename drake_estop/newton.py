"""Newton's method with active limits: a primal-dual interior-point Newton method.

The paper minimises J_ss / J_ds by plain Newton iterations (eq. 26) and checks
the limits afterwards. With the paper's weights the optimum lies *on* the
limits (step length, swing speed, minimum double-support time), so plain
Newton would step outside them. We apply Newton's method to the perturbed KKT
conditions of ``min J(t) s.t. g_k(t) >= 0``::

    grad J - sum_k lam_k grad g_k = 0,      lam_k g_k = mu,

eliminate the multiplier step, and solve (eq. 26 with the Lagrangian Hessian)

    (hess J - sum lam_k hess g_k + sum (lam_k/g_k) grad g_k grad g_k^T) dt
        = -(grad J - sum (mu/g_k) grad g_k).

The barrier parameter follows the complementarity ``mu = sigma * mean(lam g)``,
a backtracking line search on the log-barrier merit keeps every ``g_k > 0``,
and the Hessian is shifted when it is not positive definite. Iterates are
strictly feasible; at convergence ``mean(lam g)`` (the duality gap per
constraint) is below ``mu_final``. Gradients and Hessians of J and the g_k are
analytic (:mod:`drake_estop.stop_condition`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np


@dataclass
class NewtonResult:
    x: np.ndarray
    cost: float
    iterations: int
    converged: bool


Evaluator = Callable[[np.ndarray], tuple]
"""x -> (J, grad J, hess J, g (m,), grad g (m, n), hess g (m, n, n))."""


def _cholesky_solve(matrix, rhs):
    """Solve a small symmetric positive-definite system (plain floats; None if not PD).

    numpy.linalg costs microseconds per call on 2x2 / 3x3 systems; this is the
    planner's inner loop.
    """
    n = len(rhs)
    a = matrix.tolist()
    low = [[0.0] * n for _ in range(n)]
    for i in range(n):
        for j in range(i + 1):
            acc = a[i][j] - sum(low[i][k] * low[j][k] for k in range(j))
            if i == j:
                if acc <= 0.0:
                    return None
                low[i][i] = acc**0.5
            else:
                low[i][j] = acc / low[j][j]
    b = rhs.tolist()
    y = [0.0] * n
    for i in range(n):
        y[i] = (b[i] - sum(low[i][k] * y[k] for k in range(i))) / low[i][i]
    x = [0.0] * n
    for i in reversed(range(n)):
        x[i] = (y[i] - sum(low[k][i] * x[k] for k in range(i + 1, n))) / low[i][i]
    return np.array(x)


def _newton_direction(hess, rhs):
    """Newton step; the Hessian is shifted until positive definite (descent direction)."""
    shift = 0.0
    scale = max(1e-12, float(np.abs(np.diag(hess)).max()))
    eye = np.eye(len(rhs))
    for _ in range(40):
        step = _cholesky_solve(hess + shift * eye if shift else hess, rhs)
        if step is not None:
            return step
        shift = max(2.0 * shift, 1e-8 * scale)
    return rhs / scale


def barrier_newton(evaluate: Evaluator, x0: np.ndarray, *, mu0: float, mu_final: float,
                   values: Callable | None = None, sigma: float = 0.1, max_iterations: int = 100,
                   grad_tol: float = 1e-8) -> NewtonResult:
    """Minimise J subject to g(x) > 0 from a strictly feasible ``x0``.

    ``values(x) -> (J, g)`` is an optional cheaper evaluator for line-search
    trial points (no derivatives); ``evaluate`` runs once per accepted step.
    """
    values = values or (lambda point: evaluate(point)[::3][:2])
    x = np.array(x0, dtype=float)
    j, jg, jh, g, gg, gh = evaluate(x)
    if np.any(g <= 0):
        raise ValueError("barrier_newton needs a strictly feasible start")
    lam = mu0 / g
    mu = mu0
    grad_scale = max(1.0, float(np.abs(jg).max()))
    for iteration in range(1, max_iterations + 1):
        gap = float(np.mean(lam * g))
        dual_residual = jg - lam @ gg
        if gap <= mu_final and np.abs(dual_residual).max() <= grad_tol * grad_scale:
            return NewtonResult(x, j, iteration - 1, True)
        mu = max(min(mu, sigma * gap), 0.1 * mu_final)
        ratio = lam / g
        hess = jh - np.einsum("k,kij->ij", lam, gh) + (gg.T * ratio) @ gg
        rhs = -(jg - (mu / g) @ gg)
        dx = _newton_direction(hess, rhs)
        dlam = mu / g - lam - ratio * (gg @ dx)
        shrinking = dlam < 0
        alpha = min(1.0, float(np.min(-0.995 * lam[shrinking] / dlam[shrinking]))) if np.any(shrinking) else 1.0
        merit = j - mu * np.sum(np.log(g))
        slope = -(rhs @ dx)
        while alpha > 1e-14:
            trial_cost, trial_g = values(x + alpha * dx)
            if np.all(trial_g > 0.005 * g):
                merit_new = trial_cost - mu * np.sum(np.log(trial_g))
                if merit_new <= merit + 1e-4 * alpha * min(slope, 0.0) + 1e-12 * abs(merit):
                    break
            alpha *= 0.5
        else:
            return NewtonResult(x, j, iteration, False)
        x = x + alpha * dx
        lam = np.maximum(lam + alpha * dlam, 1e-16)
        j, jg, jh, g, gg, gh = evaluate(x)
    return NewtonResult(x, j, max_iterations, False)
