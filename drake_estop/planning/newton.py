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
analytic (:mod:`drake_estop.planning.stop_condition`).

The problems are tiny (n <= 3 unknowns, m <= 11 constraints), so the loop works
on plain Python floats and lists: numpy's per-call overhead (microseconds) is
larger than the arithmetic. Evaluators may return numpy arrays or lists, and a
constraint Hessian may be ``None`` for a linear constraint.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from operator import gt, mul

import numpy as np


@dataclass
class NewtonResult:
    x: np.ndarray
    cost: float
    iterations: int
    converged: bool


Evaluator = Callable[[np.ndarray], tuple]
"""x -> (J, grad J, hess J, g (m,), grad g (m, n), hess g (m, n, n)); arrays or nested
lists, a ``None`` constraint Hessian meaning zero."""


def _floats(value):
    """Nested lists of floats from an array or a (nested) list."""
    return value.tolist() if isinstance(value, np.ndarray) else value


def _as_lists(point):
    j, jg, jh, g, gg, gh = point
    if isinstance(gh, np.ndarray):
        gh = gh.tolist()
    return j, _floats(jg), _floats(jh), _floats(g), _floats(gg), gh


def _cholesky_solve(matrix, rhs):
    """Solve a small symmetric positive-definite system (nested lists; None if not PD).

    numpy.linalg costs microseconds per call on 2x2 / 3x3 systems; this is the
    planner's inner loop.
    """
    n = len(rhs)
    a = _floats(matrix)
    low = [[0.0] * n for _ in range(n)]
    for i in range(n):
        row = low[i]
        for j in range(i + 1):
            other = low[j]
            dot = 0.0
            for k in range(j):
                dot += row[k] * other[k]
            acc = a[i][j] - dot
            if i == j:
                if acc <= 0.0:
                    return None
                row[i] = acc**0.5
            else:
                row[j] = acc / other[j]
    b = _floats(rhs)
    y = [0.0] * n
    for i in range(n):  # forward: L y = b
        dot = 0.0
        for k in range(i):
            dot += low[i][k] * y[k]
        y[i] = (b[i] - dot) / low[i][i]
    x = [0.0] * n
    for i in reversed(range(n)):  # backward: L^T x = y
        dot = 0.0
        for k in range(i + 1, n):
            dot += low[k][i] * x[k]
        x[i] = (y[i] - dot) / low[i][i]
    return x


def _newton_direction(hess, rhs):
    """Newton step (list); the Hessian is shifted until positive definite (descent direction)."""
    n = len(rhs)
    scale = max(1e-12, max(abs(hess[i][i]) for i in range(n)))
    shift = 0.0
    for _ in range(40):
        shifted = hess if not shift else [[h + shift if i == j else h for j, h in enumerate(row)]
                                          for i, row in enumerate(hess)]
        step = _cholesky_solve(shifted, rhs)
        if step is not None:
            return step
        shift = max(2.0 * shift, 1e-8 * scale)
    return [r / scale for r in rhs]


def _kkt_system(jg, jh, g, cols, gh, lam, mu):
    """Newton system of the perturbed KKT conditions (eq. 26 with the Lagrangian Hessian):
    ``hess J - sum lam_k hess g_k + sum (lam_k/g_k) grad g_k grad g_k^T`` and
    ``-(grad J - sum (mu/g_k) grad g_k)``; also returns lam_k/g_k. ``cols[i]``: the
    constraint gradients' i-th components."""
    n = len(jg)
    ratio = [lk / gk for lk, gk in zip(lam, g)]
    curvature = [row[:] for row in jh]  # hess J - sum lam_k hess g_k
    for lk, hk in zip(lam, gh):
        if hk is not None:
            for i in range(n):
                out, h = curvature[i], hk[i]
                for j in range(i, n):
                    out[j] -= lk * h[j]
    hess = [[0.0] * n for _ in range(n)]
    for i in range(n):
        weighted = list(map(mul, cols[i], ratio))
        for j in range(i, n):
            hess[i][j] = hess[j][i] = curvature[i][j] + sum(map(mul, weighted, cols[j]))
    barrier = [mu / gk for gk in g]
    rhs = [-(jg[i] - sum(map(mul, barrier, cols[i]))) for i in range(n)]
    return hess, rhs, ratio


def _max_step(lam, dlam):
    """Largest step <= 1 keeping the multipliers positive (fraction to the boundary 0.995)."""
    limits = [-0.995 * lk / dk for lk, dk in zip(lam, dlam) if dk < 0]
    return min(1.0, min(limits)) if limits else 1.0


def barrier_newton(evaluate: Evaluator, x0: np.ndarray, *, mu0: float, mu_final: float,
                   values: Callable | None = None, sigma: float = 0.1, max_iterations: int = 100,
                   grad_tol: float = 1e-8) -> NewtonResult:
    """Minimise J subject to g(x) > 0 from a strictly feasible ``x0``.

    ``values(x) -> (J, g)`` is an optional cheaper evaluator for line-search
    trial points (no derivatives); ``evaluate`` runs once per accepted step.
    Both receive ``x`` as a numpy array.
    """
    values = values or (lambda point: evaluate(point)[::3][:2])
    x = np.array(x0, dtype=float).tolist()
    j, jg, jh, g, gg, gh = _as_lists(evaluate(np.array(x)))
    if not all(gk > 0 for gk in g):
        raise ValueError("barrier_newton needs a strictly feasible start")
    m = len(g)
    lam = [mu0 / gk for gk in g]
    mu = mu0
    grad_scale = max(1.0, max(abs(v) for v in jg))
    for iteration in range(1, max_iterations + 1):
        gap = sum(map(mul, lam, g)) / m
        cols = list(zip(*gg))  # cols[i]: d g_k / d x_i over k
        dual_residual = [jg_i - sum(map(mul, lam, col)) for jg_i, col in zip(jg, cols)]
        if gap <= mu_final and max(map(abs, dual_residual)) <= grad_tol * grad_scale:
            return NewtonResult(np.array(x), j, iteration - 1, True)
        mu = max(min(mu, sigma * gap), 0.1 * mu_final)
        hess, rhs, ratio = _kkt_system(jg, jh, g, cols, gh, lam, mu)
        dx = _newton_direction(hess, rhs)
        dlam = [mu / gk - lk - rk * sum(map(mul, row, dx)) for gk, lk, rk, row in zip(g, lam, ratio, gg)]
        alpha = _max_step(lam, dlam)
        merit = j - mu * sum(map(math.log, g))
        slope = -sum(map(mul, rhs, dx))
        floor = [0.005 * gk for gk in g]  # trial points keep every g_k above 0.5 % of its value
        while alpha > 1e-14:
            trial = [xi + alpha * di for xi, di in zip(x, dx)]
            trial_cost, trial_g = values(np.array(trial))
            trial_g = _floats(trial_g)
            if all(map(gt, trial_g, floor)):
                merit_new = trial_cost - mu * sum(map(math.log, trial_g))
                if merit_new <= merit + 1e-4 * alpha * min(slope, 0.0) + 1e-12 * abs(merit):
                    break
            alpha *= 0.5
        else:
            return NewtonResult(np.array(x), j, iteration, False)
        x = trial
        lam = [max(lk + alpha * dk, 1e-16) for lk, dk in zip(lam, dlam)]
        j, jg, jh, g, gg, gh = _as_lists(evaluate(np.array(x)))
    return NewtonResult(np.array(x), j, max_iterations, False)
