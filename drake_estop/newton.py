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


def _newton_direction(hess, rhs):
    shift = 0.0
    scale = max(1e-12, float(np.abs(np.diag(hess)).max()))
    eye = np.eye(len(rhs))
    for _ in range(30):
        try:
            chol = np.linalg.cholesky(hess + shift * eye)
            return np.linalg.solve(chol.T, np.linalg.solve(chol, rhs))
        except np.linalg.LinAlgError:
            shift = max(2.0 * shift, 1e-8 * scale)
    return rhs / scale


def barrier_newton(evaluate: Evaluator, x0: np.ndarray, *, mu0: float, mu_final: float,
                   sigma: float = 0.1, max_iterations: int = 100, grad_tol: float = 1e-8) -> NewtonResult:
    """Minimise J subject to g(x) > 0 from a strictly feasible ``x0``."""
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
        hess = jh - np.tensordot(lam, gh, axes=1) + (gg.T * ratio) @ gg
        rhs = -(jg - (mu / g) @ gg)
        dx = _newton_direction(hess, rhs)
        dlam = mu / g - lam - ratio * (gg @ dx)
        shrinking = dlam < 0
        alpha = min(1.0, float(np.min(-0.995 * lam[shrinking] / dlam[shrinking]))) if np.any(shrinking) else 1.0
        merit = j - mu * np.sum(np.log(g))
        slope = -(rhs @ dx)
        while alpha > 1e-14:
            out = evaluate(x + alpha * dx)
            if np.all(out[3] > 0.005 * g):
                merit_new = out[0] - mu * np.sum(np.log(out[3]))
                if merit_new <= merit + 1e-4 * alpha * min(slope, 0.0) + 1e-12 * abs(merit):
                    break
            alpha *= 0.5
        else:
            return NewtonResult(x, j, iteration, False)
        x = x + alpha * dx
        lam = np.maximum(lam + alpha * dlam, 1e-16)
        j, jg, jh, g, gg, gh = out
    return NewtonResult(x, j, max_iterations, False)
