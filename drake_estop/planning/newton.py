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
analytic (:mod:`drake_estop.planning.solver`, :mod:`drake_estop.planning.stop_condition`).

Written in the numba subset (:func:`~drake_estop.planning.backend.jit`), generic over the
problem: ``evaluate(data, x, derivatives, jg, jh, g, gg, gh)`` returns J and writes the
constraint values ``g`` (m,) and, with ``derivatives``, ``grad J`` (n,), ``hess J`` (n, n),
``grad g`` (m, n) and ``hess g`` (m, n, n) into the arrays; ``data`` is the problem's float
vector; :func:`barrier_newton_for` returns the method for one evaluator (compiled, ``evaluate``
must be compiled too).
"""

from __future__ import annotations

import math

import numpy as np

from drake_estop.planning.backend import jit

CONVERGED, NOT_CONVERGED, INFEASIBLE_START = 0, 1, -1
"""Status of :func:`barrier_newton`: converged; stopped (iteration limit, no line-search step, a
constraint at or below zero: the last accepted iterate is returned); the start is not strictly
feasible."""


@jit
def cholesky_solve(a, b, out):
    """Solve a small symmetric positive-definite system into ``out``; False if not positive definite."""
    n = b.shape[0]
    low = np.zeros((n, n))
    for i in range(n):
        for j in range(i + 1):
            dot = 0.0
            for k in range(j):
                dot += low[i, k] * low[j, k]
            acc = a[i, j] - dot
            if i == j:
                if not acc > 0.0:
                    return False
                low[i, i] = math.sqrt(acc)
            else:
                low[i, j] = acc / low[j, j]
    y = np.zeros(n)
    for i in range(n):  # forward: L y = b
        dot = 0.0
        for k in range(i):
            dot += low[i, k] * y[k]
        y[i] = (b[i] - dot) / low[i, i]
    for i in range(n - 1, -1, -1):  # backward: L^T x = y
        dot = 0.0
        for k in range(i + 1, n):
            dot += low[k, i] * out[k]
        out[i] = (y[i] - dot) / low[i, i]
    return True


@jit
def newton_direction(hess, rhs, out):
    """Newton step into ``out``; the Hessian is shifted until positive definite (descent direction)."""
    n = rhs.shape[0]
    scale = 0.0
    for i in range(n):
        v = abs(hess[i, i])
        if i == 0 or v > scale:
            scale = v
    scale = max(1e-12, scale)
    shift = 0.0
    shifted = hess.copy()
    for _ in range(40):
        for i in range(n):
            shifted[i, i] = hess[i, i] + shift if shift else hess[i, i]
        if cholesky_solve(shifted, rhs, out):
            return
        shift = max(2.0 * shift, 1e-8 * scale)
    for i in range(n):
        out[i] = rhs[i] / scale


def barrier_newton_for(evaluate):
    """The method for one problem evaluator: ``barrier_newton(data, x0, m, mu0, mu_final, sigma=0.1,
    max_iterations=100, grad_tol=1e-8)``.

    Compiled, the evaluator is a constant of the returned function (numba caches it; passed as
    an argument instead, it would be a run-time address and nothing could be cached).
    """

    @jit
    def barrier_newton(data, x0, m, mu0, mu_final, sigma=0.1, max_iterations=100, grad_tol=1e-8):
        """Minimise J subject to g(x) > 0 (``m`` constraints) from a strictly feasible ``x0``.

        Returns ``(x, J, iterations, status)`` (:data:`CONVERGED`, :data:`NOT_CONVERGED`,
        :data:`INFEASIBLE_START`). Line-search trial points are evaluated without derivatives;
        ``evaluate`` runs with derivatives once per accepted step.
        """
        n = x0.shape[0]
        x = x0.copy()
        jg = np.zeros(n)
        jh = np.zeros((n, n))
        g = np.zeros(m)
        gg = np.zeros((m, n))
        gh = np.zeros((m, n, n))
        j = evaluate(data, x, True, jg, jh, g, gg, gh)
        for k in range(m):
            if not g[k] > 0:
                return x, j, 0, INFEASIBLE_START
        lam = np.empty(m)
        for k in range(m):
            lam[k] = mu0 / g[k]
        mu = mu0
        grad_scale = 1.0
        for i in range(n):
            grad_scale = max(grad_scale, abs(jg[i]))
        hess = np.zeros((n, n))
        rhs = np.zeros(n)
        ratio = np.zeros(m)
        dx = np.zeros(n)
        dlam = np.zeros(m)
        trial = np.zeros(n)
        trial_g = np.zeros(m)
        scratch_jg, scratch_jh = np.zeros(n), np.zeros((n, n))  # untouched: trial points take no derivatives
        scratch_gg, scratch_gh = np.zeros((m, n)), np.zeros((m, n, n))
        curvature = np.zeros((n, n))
        for iteration in range(1, max_iterations + 1):
            gap = 0.0
            for k in range(m):
                gap += lam[k] * g[k]
            gap = gap / m
            worst = 0.0  # dual residual grad J - sum lam_k grad g_k
            for i in range(n):
                s = 0.0
                for k in range(m):
                    s += lam[k] * gg[k, i]
                r = abs(jg[i] - s)
                if i == 0 or r > worst:
                    worst = r
            if gap <= mu_final and worst <= grad_tol * grad_scale:
                return x, j, iteration - 1, CONVERGED
            for k in range(m):  # an accepted point where a constraint evaluates at or below zero (0/0 cases)
                if not g[k] > 0:
                    return x, j, iteration, NOT_CONVERGED
            mu = max(min(mu, sigma * gap), 0.1 * mu_final)
            # KKT system (eq. 26 with the Lagrangian Hessian)
            for k in range(m):
                ratio[k] = lam[k] / g[k]
            for i in range(n):
                for jj in range(n):
                    curvature[i, jj] = jh[i, jj]
            for k in range(m):  # hess J - sum lam_k hess g_k
                lk = lam[k]
                for i in range(n):
                    for jj in range(i, n):
                        curvature[i, jj] -= lk * gh[k, i, jj]
            for i in range(n):
                for jj in range(i, n):
                    s = 0.0
                    for k in range(m):
                        s += (gg[k, i] * ratio[k]) * gg[k, jj]
                    hess[i, jj] = curvature[i, jj] + s
                    hess[jj, i] = hess[i, jj]
            for i in range(n):
                s = 0.0
                for k in range(m):
                    s += (mu / g[k]) * gg[k, i]
                rhs[i] = -(jg[i] - s)
            newton_direction(hess, rhs, dx)
            for k in range(m):
                s = 0.0
                for i in range(n):
                    s += gg[k, i] * dx[i]
                dlam[k] = mu / g[k] - lam[k] - ratio[k] * s
            alpha = 1.0  # largest step <= 1 keeping the multipliers positive (fraction to the boundary 0.995)
            for k in range(m):
                if dlam[k] < 0:
                    alpha = min(alpha, -0.995 * lam[k] / dlam[k])
            logs = 0.0
            for k in range(m):
                logs += math.log(g[k])
            merit = j - mu * logs
            slope = 0.0
            for i in range(n):
                slope += rhs[i] * dx[i]
            slope = -slope
            accepted = False
            while alpha > 1e-14:
                for i in range(n):
                    trial[i] = x[i] + alpha * dx[i]
                trial_cost = evaluate(data, trial, False, scratch_jg, scratch_jh, trial_g, scratch_gg, scratch_gh)
                inside = True  # trial points keep every g_k above 0.5 % of its value
                for k in range(m):
                    if not trial_g[k] > 0.005 * g[k]:
                        inside = False
                        break
                if inside:
                    logs = 0.0
                    for k in range(m):
                        logs += math.log(trial_g[k])
                    merit_new = trial_cost - mu * logs
                    if merit_new <= merit + 1e-4 * alpha * min(slope, 0.0) + 1e-12 * abs(merit):
                        accepted = True
                        break
                alpha *= 0.5
            if not accepted:
                return x, j, iteration, NOT_CONVERGED
            x[:] = trial
            for k in range(m):
                lam[k] = max(lam[k] + alpha * dlam[k], 1e-16)
            j = evaluate(data, x, True, jg, jh, g, gg, gh)
        return x, j, max_iterations, NOT_CONVERGED

    return barrier_newton
