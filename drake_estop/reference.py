"""Reference solve of the stop-parameter problem with a generic solver (scipy SLSQP).

Uses the paper's own parametrisation: decision variables are the phase
durations (t_i, t_ii, t_iii) and the step length / ZMP_max is the explicit
function of eq. 22 / 29, with the limits as general nonlinear constraints.
The planner's Newton method instead eliminates the slowdown duration, so the
two solves share only the stop condition and the cost. Multi-start from a
grid, best feasible result kept. For tests and benchmarks, not for real time.
"""

from __future__ import annotations

import itertools

import numpy as np
from scipy.optimize import minimize

from drake_estop.stop_condition import target_zmp


def reference_solve(problem, kind, *, starts_per_axis: int = 3, margin: float = 0.0):
    """Returns ``(cost, durations (3,), target)`` of the best feasible SLSQP optimum, or None.

    ``margin`` > 0 solves a tightened problem: every constraint kept ``margin``
    inside its limit (metres or seconds), durations ``margin`` inside their bounds.
    """
    p = problem.params
    bounds = problem.bounds()
    duration_bounds = [(bounds[0, 0] + margin, bounds[0, 1] - margin), (bounds[1, 0] + margin, bounds[1, 1] - margin),
                       (p.min_slowdown_time + margin, p.max_slowdown_time - margin)]
    if kind == "double":
        duration_bounds[0] = (0.0, 0.0)
    free = [0, 1, 2] if kind == "single" else [1, 2]

    def full(x):
        d = np.zeros(3)
        d[free] = x
        return d

    def target(x):
        d = full(x)
        return target_zmp(problem.start, problem.w, d[0], d[1], d[2], derivatives=False)

    def cost(x):
        d = full(x)
        return float(problem.cost_grid([d[0], d[1], target(x)], d[2]))

    def constraints(x):
        d = full(x)
        z = target(x)
        values = [z - bounds[2, 0], bounds[2, 1] - z]
        values += list(np.atleast_1d(problem.extra_constraints([d[0], d[1], z])[0]))
        return np.array(values, float) - margin

    best = None
    grids = [np.linspace(lo + 0.1 * (hi - lo), hi - 0.1 * (hi - lo), starts_per_axis)
             for lo, hi in (duration_bounds[k] for k in free)]
    for x0 in itertools.product(*grids):
        result = minimize(cost, np.array(x0), method="SLSQP", bounds=[duration_bounds[k] for k in free],
                          constraints=[{"type": "ineq", "fun": constraints}],
                          options={"ftol": 1e-12, "maxiter": 300})
        # keep every feasible end point: SLSQP often stops with "positive directional
        # derivative in line search" at the optimum of these problems
        x = np.clip(result.x, [b[0] for b in (duration_bounds[k] for k in free)],
                    [b[1] for b in (duration_bounds[k] for k in free)])
        if not np.all(np.isfinite(x)) or not np.isfinite(cost(x)) or np.any(constraints(x) < -1e-7):
            continue
        result.x, result.fun = x, cost(x)
        if best is None or result.fun < best[0]:
            best = (float(result.fun), full(result.x), float(target(result.x)))
    return best
