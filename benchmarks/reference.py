"""Reference solve of the stop-parameter problem with a generic solver (scipy SLSQP).

Written from the paper on its own, sharing no function with the planner's solver:

* decision variables are the paper's: the phase durations (t_i, t_ii, t_iii); the ZMP of
  the slowdown (step length ``l_s`` + ``landing_zmp_offset`` in single support, eq. 20;
  ``ZMP_max`` in double support) follows from the stop condition (eq. 17: COG velocity
  zero at the end of the slowdown);
* the stop condition is not the planner's closed form (eq. 22 / 29 in
  :mod:`drake_estop.planning.stop_condition`) but the LIPM's piecewise solution (eq. 6-11 in
  :func:`drake_estop.planning.lipm.chain_end_state`) of phases (i)-(iii); the end velocity is affine
  in the ZMP value, so two end states give it;
* the costs are eq. 24 / 30, the limits are read from :class:`StopParameters` and the
  problem's raw data (start state, feet) and written out here: durations, step length or
  ZMP range on the fore sole, mean swing-ankle speed, fore-leg reach at touchdown,
  rear-leg reach at rest.

Multi-start from a grid, best feasible result kept. For tests and benchmarks, not for
real time.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
from scipy.optimize import minimize

from drake_estop.planning import lipm


def _phases(start, w, kind, t1, t2, t3, z):
    """COG (x, v) relative to the start ZMP after phases (i)-(iii) with slowdown ZMP ``z``."""
    x0 = 0.5 * (start.dcm + start.ccm)
    v0 = 0.5 * w * (start.dcm - start.ccm)
    rate, accel = (0.0, 0.0) if kind == "single" else (start.zmp_rate, start.zmp_accel)
    segments = [lipm.transition_coeffs(0.0, z, t2, rate, accel), lipm.pad([z])]
    durations = [t2, t3]
    if kind == "single":
        segments.insert(0, lipm.pad([0.0]))
        durations.insert(0, t1)
    return lipm.chain_end_state(durations, segments, x0, v0, w)


def stop_zmp(start, w, kind, t1, t2, t3):
    """Slowdown ZMP meeting the stop condition (eq. 17) and the COG position at rest."""
    x_a, v_a = _phases(start, w, kind, t1, t2, t3, 0.0)
    x_b, v_b = _phases(start, w, kind, t1, t2, t3, 1.0)
    z = -v_a / (v_b - v_a)
    return z, x_a + z * (x_b - x_a)


def _limits(problem, kind, d, z, rest, margin):
    """Every limit as ``value >= 0`` (tightened by ``margin``)."""
    p, start, w = problem.params, problem.start, problem.w
    t1 = d[0]
    if kind == "single":
        step = z - p.landing_zmp_offset  # eq. 20: the slowdown ZMP sits offset from the landing ankle
        land_x = problem.support_x + step
        dx, dy = land_x - problem.swing_xy[0], problem.landing_y - problem.swing_xy[1]
        x_touchdown, _ = lipm.chain_end_state([t1], [lipm.pad([0.0])], 0.5 * (start.dcm + start.ccm),
                                              0.5 * w * (start.dcm - start.ccm), w)  # COG after phase (i)
        values = [step - p.min_step_length, p.max_step_length - step,
                  p.max_swing_speed * t1 - math.hypot(dx, dy),
                  p.max_fore_reach - (step - x_touchdown),
                  p.max_rear_reach - rest]  # rear ankle = support ankle = start ZMP
    else:
        values = [z - problem.zmp_low, problem.zmp_high - z,
                  p.max_rear_reach - (rest - problem.rear_ankle)]
    return np.array(values) - margin


def _cost(problem, kind, d, z):
    p = problem.params
    if kind == "single":
        return p.a_ss * ((z - p.landing_zmp_offset) / d[0]) ** 2 + p.b_ss * (d[1] + d[2]) ** 2  # eq. 24
    return p.a_ds * z**2 + p.b_ds * (d[1] + d[2]) ** 2  # eq. 30


def reference_solve(problem, kind, *, starts_per_axis: int = 3, margin: float = 0.0):
    """Returns ``(cost, durations (3,), target)`` of the best feasible SLSQP optimum, or None.

    ``margin`` > 0 solves a tightened problem: every limit kept ``margin`` inside
    (metres or seconds), durations ``margin`` inside their ranges.
    """
    p = problem.params
    # the landing may not come sooner than the swing foot can descend at its joint-speed limits
    earliest = max(p.min_landing_time, getattr(problem, "min_landing", 0.0))
    duration_limits = [(earliest, p.max_landing_time), (p.min_transition_time, p.max_transition_time),
                       (p.min_slowdown_time, p.max_slowdown_time)]
    duration_limits = [(lo + margin, hi - margin) for lo, hi in duration_limits]
    free = [0, 1, 2] if kind == "single" else [1, 2]
    box = [duration_limits[k] for k in free]

    def full(x):
        d = np.zeros(3)
        d[free] = x
        return d

    memo = {}

    def solved(x):  # cost and limits are evaluated at the same points: solve the LIPM once
        key = tuple(np.asarray(x, float).tolist())
        if key not in memo:
            d = full(x)
            memo[key] = (d,) + stop_zmp(problem.start, problem.w, kind, *d)
        return memo[key]

    def cost(x):
        d, z, _ = solved(x)
        return float(_cost(problem, kind, d, z))

    def limits(x):
        d, z, rest = solved(x)
        return _limits(problem, kind, d, z, rest, margin)

    best = None
    grids = [np.linspace(lo + 0.1 * (hi - lo), hi - 0.1 * (hi - lo), starts_per_axis) for lo, hi in box]
    for x0 in itertools.product(*grids):
        result = minimize(cost, np.array(x0), method="SLSQP", bounds=box,
                          constraints=[{"type": "ineq", "fun": limits}],
                          options={"ftol": 1e-14, "maxiter": 500})
        # keep every feasible end point: SLSQP often stops with "positive directional
        # derivative in line search" at the optimum of these problems
        x = np.clip(result.x, [b[0] for b in box], [b[1] for b in box])
        if not np.all(np.isfinite(x)) or not np.isfinite(cost(x)) or np.any(limits(x) < -1e-9):
            continue
        value = cost(x)
        if best is None or value < best[0]:
            d, z, _ = solved(x)
            best = (value, d, float(z))
    return best
