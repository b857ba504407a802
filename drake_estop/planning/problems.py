"""The phase-parameter problems of single support (III.A) and double support (III.B).

Each problem holds the data of one stop: the LIPM start state relative to the start ZMP
(:class:`~drake_estop.planning.stop_condition.StopStart`), the parameters, and in single
support the feet. :attr:`StopProblem.data` packs it into the float vector the solver
(:mod:`drake_estop.planning.solver`) works on; :meth:`StopProblem.evaluate` and
:meth:`StopProblem.values` expose the solver's point evaluator (cost, limits and their
analytic derivatives) for tests and reference solves.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from drake_estop.planning import lipm, solver
from drake_estop.planning.plan import SWING_GRID, StopParameters, snap_to_tick
from drake_estop.planning.stop_condition import StopStart


def descent_time(lift: float, params: StopParameters, lift_rate: float = 0.0, lift_accel: float = 0.0) -> float:
    """Shortest landing duration [s], on the servo grid, whose landing swing comes down no faster than
    ``max_swing_descent_speed``: the swing's vertical quintic Hermite (:func:`~drake_estop.planning.plan.landing_swing`)
    from height ``lift`` [m], vertical velocity ``lift_rate`` [m/s] and acceleration ``lift_accel`` [m/s^2]
    to the floor at rest, checked on the swing's grid. A foot at rest or still rising starts its descent
    from rest, where the quintic peaks at 15/8 of its mean speed (closed form; a rising foot gets the
    landing swing's clearance bump instead of its own rise). A foot already coming down at the nominal
    swing's pace keeps that pace instead of starting again from rest, so the earliest touchdown does not
    move later as the foot descends. Capped one tick below ``max_landing_time`` (very high lifts of custom
    gaits keep a landing window)."""
    dt = params.servo_period
    lift = max(lift, 0.0)
    latest = params.max_landing_time - dt
    if lift_rate >= 0.0:
        return min(snap_to_tick(1.875 * lift / params.max_swing_descent_speed, dt), latest)
    durations = dt * np.arange(1, max(int(round(latest / dt)), 1) + 1)
    T = durations[:, None]
    # vertical speed of the Hermite at the grid points, for every duration (eq. of landing_swing)
    speed = (-lift * _DESCENT_TERMS[0] + lift_rate * T * _DESCENT_TERMS[1] + lift_accel * T**2 * _DESCENT_TERMS[2]) / T
    within = np.flatnonzero(-speed.min(axis=1) <= params.max_swing_descent_speed + 1e-12)
    return float(durations[within[0]]) if len(within) else latest


#: first derivatives of the landing swing's Hermite terms on its check grid (height, velocity, acceleration)
_DESCENT_TERMS = [lipm.poly_eval(c, SWING_GRID, 1) for c in (lipm.SMOOTHSTEP, lipm.HERMITE_D1, lipm.HERMITE_D2)]


class StopProblem:
    """Shared parts of the single- and double-support problems.

    Decision variables ``y = (landing, transition, target)``; ``free`` are the indices of
    the decision variables (the landing duration is fixed at zero in double support).
    """

    kind: str
    free: tuple
    rear_ankle = 0.0  # rear ankle x relative to the start ZMP

    def bounds(self) -> np.ndarray:
        raise NotImplementedError

    def _pack_support(self, d):
        """The support-specific entries of the problem vector."""
        raise NotImplementedError

    @functools.cached_property
    def data(self) -> np.ndarray:
        """The problem as the solver's float64 vector (layout in :mod:`drake_estop.planning.solver`)."""
        p, s = self.params, self.start
        if not (math.isfinite(self.w) and self.w > 0):
            raise ValueError(f"the LIPM frequency w must be positive, got {self.w!r}")
        d = np.zeros(solver.SIZE)
        d[solver.DCM], d[solver.CCM], d[solver.RATE], d[solver.ACCEL] = s.dcm, s.ccm, s.zmp_rate, s.zmp_accel
        d[solver.W] = self.w
        d[solver.MIN_T3], d[solver.MAX_T3] = p.min_slowdown_time, p.max_slowdown_time
        d[solver.REAR_REACH], d[solver.REAR_ANKLE] = p.max_rear_reach, self.rear_ankle
        d[solver.SWING_SPEED], d[solver.FORE_REACH] = p.max_swing_speed, p.max_fore_reach
        d[solver.ZMP_OFFSET] = p.landing_zmp_offset
        d[solver.BOUNDS:solver.BOUNDS + 6] = np.asarray(self.bounds(), float).ravel()
        d[solver.DT], d[solver.COST_TOL] = p.servo_period, p.cost_tolerance
        d[solver.RESOLVE] = 1.0 if p.quantisation == "resolve" else 0.0
        self._pack_support(d)
        if not np.all(np.isfinite(d)):
            raise ValueError(f"stop problem data must be finite, got {d!r}")
        return d

    def evaluate(self, x):
        """Cost, constraints and their analytic derivatives over the free variables ``x``:
        ``(J, grad J, hess J, g (m,), grad g (m, n), hess g (m, n, n))``. Constraint order:
        lower/upper bound of each free variable, slowdown duration above its minimum and below
        its maximum, then the extras (:func:`drake_estop.planning.solver.limits`)."""
        x = np.ascontiguousarray(x, dtype=float)
        n, m, _ = solver.dims(self.data)
        out = np.zeros(n), np.zeros((n, n)), np.zeros(m), np.zeros((m, n)), np.zeros((m, n, n))
        cost = solver.point(self.data, x, True, *out)
        return (float(cost), *out)

    def values(self, x):
        """Cost and constraint values only (``inf`` and ``-1`` where no slowdown stops the COG)."""
        x = np.ascontiguousarray(x, dtype=float)
        n, m, _ = solver.dims(self.data)
        g = np.zeros(m)
        cost = solver.point(self.data, x, False, np.zeros(n), np.zeros((n, n)), g, np.zeros((m, n)),
                            np.zeros((m, n, n)))
        return float(cost), g

    def full(self, x):
        y = np.zeros(3)
        y[list(self.free)] = x
        return y


@dataclass
class SingleSupportProblem(StopProblem):
    start: StopStart
    w: float
    params: StopParameters
    support_x: float  # sagittal ZMP at the start (support ankle)
    swing_xy: np.ndarray  # current swing ankle
    landing_y: float  # lateral landing (nominal step width)
    free: tuple = (0, 1, 2)
    min_landing: float = 0.0  # shortest landing from the swing foot's height (:func:`descent_time`)
    nominal_landing: float = math.nan  # time left to the nominal touchdown [s] (stepping in place keeps it)
    kind = "single"

    def bounds(self):
        """Durations, and the slowdown ZMP = step length + landing_zmp_offset (eq. 20)."""
        p = self.params
        offset = p.landing_zmp_offset
        return np.array([[max(p.min_landing_time, self.min_landing), p.max_landing_time],
                         [p.min_transition_time, p.max_transition_time],
                         [p.min_step_length + offset, p.max_step_length + offset]])

    def step_length(self, target):
        return target - self.params.landing_zmp_offset

    def _pack_support(self, d):
        d[solver.KIND] = 0.0
        d[solver.A_W], d[solver.B_W] = self.params.a_ss, self.params.b_ss
        d[solver.SUPPORT_X] = self.support_x
        d[solver.SWING_X], d[solver.SWING_Y] = self.swing_xy[0], self.swing_xy[1]
        d[solver.LANDING_Y] = self.landing_y


@dataclass
class DoubleSupportProblem(StopProblem):
    start: StopStart
    w: float
    params: StopParameters
    zmp_low: float  # allowed range of Z, relative to the start ZMP
    zmp_high: float
    rear_ankle: float = 0.0  # rear ankle x relative to the start ZMP
    free: tuple = (1, 2)
    kind = "double"

    def bounds(self):
        p = self.params
        return np.array([[0.0, 0.0],
                         [p.min_transition_time, p.max_transition_time],
                         [self.zmp_low, self.zmp_high]])

    def _pack_support(self, d):
        d[solver.KIND] = 1.0
        d[solver.A_W], d[solver.B_W] = self.params.a_ds, self.params.b_ds
