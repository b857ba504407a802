"""The four-phase emergency-stop planner (paper Sections II-IV), pure numpy.

``plan_stop(pattern, signal_time, params)`` returns a :class:`StopPlan` that
starts from the nominal pattern's state at the servo tick of the signal and
brings the COG to rest, exactly, at the midpoint between the feet:

* single support (III.A): landing time, transition end and slowdown end from
  J_ss (eq. 24) by a barrier Newton method (eq. 25-26, :mod:`drake_estop.planning.newton`);
  the step length from the stop condition (eq. 22);
* double support (III.B): transition end and slowdown end from J_ds (eq. 30-31);
  ZMP_max from the stop condition (eq. 29);
* marginal case (III.C): no feasible one-step plan -> the robot finishes the
  nominal step and stops at the next support phase;
* halt (eq. 27-28): a two-point boundary-value ZMP segment, duration chosen so
  the ZMP stays inside the support polygon;
* lateral plane: the sagittal phase times;
* crouch (IV.A) and upper-body halt (IV.B, eq. 32-33).

Servo-cycle quantisation: every phase boundary falls on a servo tick. After
snapping the durations to the grid the planner re-solves the ZMP value (step
length or ZMP_max) from the stop condition with the snapped times, so the COG
velocity at the end of the slowdown is zero to rounding (the paper's Fig. 12
overshoot came from rounding the times alone; ``quantisation="round"``
reproduces that for comparison).
"""

from __future__ import annotations

import functools
import math
import os
import time
from dataclasses import dataclass, field, replace

import numpy as np

from drake_estop.planning import lipm
from drake_estop.planning.capture import capture_landing_y
from drake_estop.planning.gait import ARM_NEUTRAL, NominalPattern, PatternState
from drake_estop.planning.geometry import SupportPolygon
from drake_estop.planning.newton import barrier_newton
from drake_estop.planning.stop_condition import (
    StopStart,
    _rest_from_grid_terms,
    _slowdown_from_grid_terms,
    _target_from_grid_terms,
    _terms_grid,
    slowdown_time,
    slowdown_time_grid,
    stop_point,
    target_zmp,
)

try:  # compiled solver core (numba); the pure-Python path below stays the reference
    from drake_estop.planning import fastcore as _fastcore
except ImportError:  # numba missing or broken: pure Python
    _fastcore = None

COMPILED = _fastcore is not None and not os.environ.get("DRAKE_ESTOP_PURE_PYTHON")
"""Use :mod:`drake_estop.planning.fastcore` for grid start, Newton and quantisation (same
algorithm, results equal to rounding). Off without numba or with the environment
variable ``DRAKE_ESTOP_PURE_PYTHON`` set; tests flip it to compare the paths."""

PHASES = ("walking", "landing", "transition", "slowdown", "halt", "stopped")
"""Phase labels; the planner's ``phase`` output port is an index into this tuple."""


@dataclass(frozen=True)
class StopParameters:
    """Weights and limits of the stop planner. Defaults reproduce the paper (V-VI).

    Attributes
    ----------
    a_ss, b_ss : float
        Weights of the mean swing speed [1/(m/s)^2] and the double-support
        time [1/s^2] in J_ss (eq. 24).
    a_ds, b_ds : float
        Weights of the ZMP displacement [1/m^2] and the double-support time
        [1/s^2] in J_ds (eq. 30).
    servo_period : float
        Control period [s]; phase boundaries fall on its ticks (HRP-2: 0.005).
    max_step_length, min_step_length : float
        Landing step from the support ankle, sagittal [m].
    min_landing_time, max_landing_time : float
        Time to touchdown [s].
    min_transition_time, max_transition_time : float
        Double-support ZMP transition [s].
    min_slowdown_time, max_slowdown_time : float
        Slowdown phase [s].
    max_swing_speed : float
        Mean swing-ankle speed to the landing point [m/s].
    max_swing_descent_speed : float
        Fastest descent of the landing foot [m/s].
    zmp_margin : float
        ZMP distance kept from the sole edges [m].
    crouch : bool
        Lower the COG during the stop (IV.A).
    crouch_depth : float
        COG lowering [m].
    halt_durations : tuple of float
        Settle-segment candidates of the halt [s].
    quantisation : str
        "resolve" (re-solve the ZMP after snapping the phase times to ticks)
        or "round" (the paper's rounding).
    landing : str
        "replan" or "nominal" (keep the nominal footstep).
    landing_zmp_offset : float
        Single support: slowdown ZMP ahead of the landing ankle [m].
    max_fore_reach, max_rear_reach : float
        Leg reach from the COG to the landing / rear ankle [m].
    cost_tolerance : float
        Relative suboptimality of the interior-point solution (dimensionless).

    Raises
    ------
    ValueError
        On a non-physical value; the message names the field.
    """

    a_ss: float = 5.0  # weight of the mean swing speed in J_ss (eq. 24)
    b_ss: float = 1000.0  # weight of the double-support time in J_ss
    a_ds: float = 50.0  # weight of the ZMP displacement in J_ds (eq. 30)
    b_ds: float = 1000.0  # weight of the double-support time in J_ds
    servo_period: float = 0.005  # HRP-2 control period [s]
    max_step_length: float = 0.4  # [m] from the support ankle, sagittal
    min_step_length: float = 0.0  # [m] no stepping backwards
    min_landing_time: float = 0.1  # minimum time to touchdown [s]
    max_landing_time: float = 1.0
    min_transition_time: float = 0.1  # minimum double-support ZMP transition [s]
    max_transition_time: float = 0.8
    min_slowdown_time: float = 0.005
    max_slowdown_time: float = 1.5
    # mean swing-ankle speed to the landing point [m/s]; the quintic swing from rest peaks at 15/8
    # of it (2.1 m/s; the nominal swing peaks at 1.76). At 1.2 the hip and ankle pitch of the swing
    # leg went up to 5.2 rad/s against their 5 rad/s limit; 1.12 leaves every joint 4 % under its
    # limit over the stride (benchmarks/bench_joint_velocity.py)
    max_swing_speed: float = 1.12
    # fastest descent of the landing foot [m/s]: landing from swing height h takes at least
    # 15/8 h / this (the quintic's peak speed), so a foot caught high in the swing is not slammed
    # down while the landing leg is nearly straight (knee speed = leg-extension rate / sin(knee)).
    # The nominal swing descends at up to 0.27 m/s (64 h s^3 (1-s)^3 over the single support).
    max_swing_descent_speed: float = 0.30
    zmp_margin: float = 0.01  # ZMP distance kept from the sole edges [m]
    crouch: bool = True
    crouch_depth: float = 0.04  # COG lowering during the stop [m] (IV.A)
    halt_durations: tuple = (0.3, 0.4, 0.5, 0.6, 0.8, 1.0, 1.2, 1.5)  # settle-segment candidates [s]
    quantisation: str = "resolve"  # or "round": snap times, keep the continuous ZMP value
    landing: str = "replan"  # or "nominal": keep the nominal footstep ("finish the step" baseline)
    # single support: slowdown ZMP ahead of the landing ankle [m]; 0 is the paper's eq. 20, up to
    # toe - zmp_margin lets the ZMP use the fore sole as the double-support stop does (III.B)
    landing_zmp_offset: float = 0.0
    # leg reach: horizontal distance from the COG to the landing ankle at touchdown (fore) and to
    # the rear ankle where the COG comes to rest (rear) [m]. Measured with the whole-body IK on
    # models/humanoid.urdf at the walking COG height 0.814 m (0.245 and 0.26; a 4 cm crouch adds
    # about 5 cm); beyond them a knee is stretched straight. Conservative: the crouch is ignored.
    # The fore reach keeps the landing knee bent at touchdown: at 0.22 the knee landed straight,
    # where the knee speed (leg-extension rate / sin(knee)) is unbounded, and the IK drove it at
    # up to 26 rad/s against its 6 rad/s limit; 0.195 lands it bent by 0.4 rad or more.
    max_fore_reach: float = 0.195
    max_rear_reach: float = 0.26
    cost_tolerance: float = 1e-6  # relative suboptimality of the interior-point solution

    def __post_init__(self):
        for name in ("a_ss", "b_ss", "a_ds", "b_ds", "servo_period", "max_step_length",
                     "min_landing_time", "max_landing_time", "min_transition_time",
                     "max_transition_time", "min_slowdown_time", "max_slowdown_time",
                     "max_swing_speed", "cost_tolerance", "max_fore_reach", "max_rear_reach",
                     "max_swing_descent_speed"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive finite number, got {value!r}")
        for low, high in (("min_landing_time", "max_landing_time"),
                          ("min_transition_time", "max_transition_time"),
                          ("min_slowdown_time", "max_slowdown_time"),
                          ("min_step_length", "max_step_length")):
            if getattr(self, low) >= getattr(self, high):
                raise ValueError(f"{low} must be below {high}")
        if self.zmp_margin < 0 or self.crouch_depth < 0:
            raise ValueError("zmp_margin and crouch_depth must be >= 0")
        if self.quantisation not in ("resolve", "round"):
            raise ValueError(f"quantisation must be 'resolve' or 'round', got {self.quantisation!r}")
        if self.landing not in ("replan", "nominal"):
            raise ValueError(f"landing must be 'replan' or 'nominal', got {self.landing!r}")
        if not self.halt_durations or min(self.halt_durations) <= 0:
            raise ValueError("halt_durations must be positive")


@dataclass
class PhaseSolution:
    """Solved durations and ZMP value of phases (i)-(iii)."""

    landing: float
    transition: float
    slowdown: float
    target: float  # Z relative to the start ZMP: step length (single) or ZMP_max (double)
    cost: float
    iterations: int
    continuous: tuple  # durations and target before quantisation


@dataclass
class StopPlan:
    """A planned stop. Times are absolute, in seconds on the pattern's clock.

    Attributes
    ----------
    signal_time : float
        Servo tick of the stop signal [s].
    start_time : float
        Where the stop motion leaves the nominal pattern [s].
    case : str
        "one-step", "next-step" (III.C), "standing" or "already-stopping".
    support : str
        Support at the signal: "single", "double" or "standing".
    landing_time, transition_end, slowdown_end, halt_end : float
        Ends of the four phases [s].
    step_length : float or None
        Single-support stops: the landing step from the support ankle [m].
    zmp_max : float or None
        Double-support stops: the ZMP displacement from the start [m].
    landing_foot : str or None
        "left" or "right".
    final_feet : dict
        Side -> ankle (x, y) at rest [m].
    min_zmp_margin : float
        Smallest ZMP distance inside the support polygon [m].
    compute_time : float
        Wall-clock time of the plan [s].

    Notes
    -----
    ``com(times)`` returns the COG position [m], velocity [m/s],
    acceleration [m/s^2] and ZMP [m] (each (n, 2)); ``phase(t)`` the phase
    label; ``polygon(t)`` the support polygon; ``summary()`` a JSON-ready dict.
    """

    signal_time: float
    start_time: float  # where the stop motion leaves the nominal pattern
    case: str  # "one-step", "next-step", "standing", "already-stopping"
    support: str  # support at the signal: "single", "double" or "standing"
    start_support: str  # support where the planned motion starts
    landing_time: float
    transition_end: float
    slowdown_end: float
    halt_end: float
    step_length: float | None  # single-support stops: sagittal, from the support ankle
    zmp_max: float | None  # double-support stops: ZMP displacement from the start
    landing_foot: str | None
    landing_position: np.ndarray | None
    final_feet: dict
    x: lipm.LipmTrajectory | None
    y: lipm.LipmTrajectory | None
    pattern: NominalPattern
    params: StopParameters
    start_state: PatternState
    newton_iterations: int = 0
    compute_time: float = 0.0
    solve_time: float = 0.0
    cost: float = float("nan")
    min_zmp_margin: float = float("nan")
    upper_body_peak: np.ndarray | None = None  # eq. 33
    swing_start: dict = field(default_factory=dict)
    continuous_solution: tuple | None = None
    crouch_window: tuple | None = None  # (start, end): a re-plan keeps the crouch of the plan it replaces

    @property
    def steps_after_signal(self) -> int:
        """Foot landings between the signal and rest (nominal ones included)."""
        nominal = sum(1 for step in self.pattern.steps
                      if self.signal_time < step["touchdown"] <= self.start_time + 1e-9)
        return nominal + (1 if self.landing_foot is not None else 0)

    # -- evaluation -----------------------------------------------------
    def phase(self, t: float) -> str:
        if t < self.signal_time - 1e-9:
            return "walking"
        if self.case == "standing" or t >= self.halt_end:
            return "stopped"
        if t < self.start_time:
            return "landing"  # finishing the nominal step (marginal case)
        if t < self.landing_time:
            return "landing"
        if t < self.transition_end:
            return "transition"
        if t < self.slowdown_end:
            return "slowdown"
        return "halt"

    def com(self, times):
        """COG xy position, velocity, acceleration and ZMP, (n, 2) each, nominal before the start."""
        times = np.atleast_1d(np.asarray(times, float))
        out = [np.zeros((len(times), 2)) for _ in range(4)]
        before = times < self.start_time
        if np.any(before) or self.x is None:
            nominal = self.pattern.com(times)
            for o, n in zip(out, nominal):
                o[:] = n
        if self.x is not None and np.any(~before):
            for axis, traj in enumerate((self.x, self.y)):
                values = traj.evaluate(times[~before])
                for o, v in zip(out, values):
                    o[~before, axis] = v
        return tuple(out)

    def com_height(self, times):
        """COG height, vertical velocity and acceleration: quintic crouch (IV.A)."""
        times = np.atleast_1d(np.asarray(times, float))
        z0 = self.pattern.params.com_height
        moving = self.x is not None and self.case != "standing"
        depth = self.params.crouch_depth if (self.params.crouch and moving) else 0.0
        if depth == 0.0:
            zeros = np.zeros_like(times)
            return z0 + zeros, zeros, zeros.copy()
        start, end = self.crouch_window or (self.start_time, self.halt_end)
        duration = end - start
        s = np.clip((times - start) / duration, 0.0, 1.0)
        inside = (times > start) & (times < end)
        z = z0 - depth * lipm.poly_eval(lipm.SMOOTHSTEP, s)
        zd = -depth * lipm.poly_eval(lipm.SMOOTHSTEP, s, 1) / duration * inside
        zdd = -depth * lipm.poly_eval(lipm.SMOOTHSTEP, s, 2) / duration**2 * inside
        return z, zd, zdd

    def feet(self, t: float):
        """Ankle (x, y, lift) of each foot at ``t``."""
        if t < self.start_time or self.x is None:
            return self.pattern.feet_at(t)[0]
        feet = {side: np.array([*xy[:2], 0.0]) for side, xy in self.final_feet.items()}
        if self.landing_foot is not None and t < self.landing_time:
            s = self.swing_start
            feet[self.landing_foot] = landing_swing(
                s["pos"], s["vel"], s["acc"], self.landing_position, t - self.start_time,
                self.landing_time - self.start_time, self.pattern.params.lift_height)
        return feet

    def upper_body(self, t: float):
        """Arm joints: cubic slowdown (eq. 32) to ``slowdown_end``, then quintic halt to neutral."""
        if t < self.start_time or self.x is None:
            return self.pattern.upper_body(t)
        q0, qd0 = self.start_state.upper_body, self.start_state.upper_body_rate
        if self.case == "standing":
            return q0.copy(), np.zeros_like(q0)
        span = self.slowdown_end - self.start_time
        if t <= self.slowdown_end:
            tau = t - self.start_time
            q = q0 + qd0 * tau - qd0 / span * tau**2 + qd0 / (3 * span**2) * tau**3  # eq. 32
            qd = qd0 * (1.0 - tau / span) ** 2
            return q, qd
        peak = self.upper_body_peak
        s = min((t - self.slowdown_end) / (self.halt_end - self.slowdown_end), 1.0)
        sigma = float(lipm.poly_eval(lipm.SMOOTHSTEP, s))
        dsigma = float(lipm.poly_eval(lipm.SMOOTHSTEP, s, 1)) / (self.halt_end - self.slowdown_end)
        return peak + (ARM_NEUTRAL - peak) * sigma, (ARM_NEUTRAL - peak) * dsigma

    def support_sides(self, t: float, feet=None) -> list:
        """Feet on the ground at ``t`` ('left'/'right'); ``feet`` from :meth:`feet` if given."""
        feet = self.feet(t) if feet is None else feet
        on_ground = [side for side, p in feet.items() if p[2] <= 1e-9]
        if t < self.start_time:
            support, _, side = self.pattern.support_at(t)
            if support == "single":
                on_ground = [side]
        elif self.landing_foot is not None and t < self.landing_time:
            on_ground = [s for s in feet if s != self.landing_foot]
        return on_ground

    def polygon(self, t: float) -> SupportPolygon:
        """Support polygon at ``t`` (soles on the ground)."""
        feet = self.feet(t)
        return soles_polygon(self.pattern.params.sole,
                             tuple((s, float(feet[s][0]), float(feet[s][1])) for s in self.support_sides(t, feet)))

    def summary(self) -> dict:
        sole = self.pattern.params.sole
        return {
            "estop_time": self.signal_time,
            "support": self.support,
            "case": self.case,
            "steps_after_signal": self.steps_after_signal,
            "plan_start_time": self.start_time,
            "phase_times": {
                "landing_end": self.landing_time,
                "transition_end": self.transition_end,
                "slowdown_end": self.slowdown_end,
                "halt_end": self.halt_end,
            },
            "step_length": self.step_length,
            "zmp_max": self.zmp_max,
            "landing_foot": self.landing_foot,
            "landing_position": None if self.landing_position is None else list(map(float, self.landing_position)),
            "final_feet": {k: [float(v[0]), float(v[1])] for k, v in self.final_feet.items()},
            "sole": {"toe": sole.toe, "heel": sole.heel, "inner": sole.inner, "outer": sole.outer},
            "newton_iterations": self.newton_iterations,
            "plan_compute_time_s": self.compute_time,
            "parameter_solve_time_s": self.solve_time,
            "cost": self.cost,
            "min_zmp_margin_m": self.min_zmp_margin,
            "upper_body_peak_rad": None if self.upper_body_peak is None else list(map(float, self.upper_body_peak)),
            "crouch": bool(self.params.crouch),
            "servo_period": self.params.servo_period,
        }


@functools.lru_cache(maxsize=512)
def soles_polygon(sole, feet: tuple) -> SupportPolygon:
    """Support polygon of the soles ``feet`` = ((side, ankle x, ankle y), ...); cached, since
    the same footholds recur from plan to plan."""
    return SupportPolygon(np.vstack([sole.corners((x, y), side) for side, x, y in feet]))


class InfeasibleStop(Exception):
    """No stop satisfies the planner's limits from this state.

    The message names the limit that made the stop infeasible.
    """


# ---------------------------------------------------------------------------
# swing foot
# ---------------------------------------------------------------------------

def landing_swing(pos, vel, acc, target_xy, elapsed, duration, lift_height):
    """Swing ankle from its current state to the landing point, at rest, over ``duration``.

    Quintic Hermite per axis (zero velocity and acceleration at touchdown); the
    lift gets an extra apex bump when the Hermite part alone would dip below
    the floor, and a clearance bump when the foot is leaving the floor (low and
    not descending). A foot already coming down is not lifted again: that
    re-lift, squeezed into the last 0.1 s before touchdown, drove the landing
    knee at up to 15 rad/s (its limit is 6).
    """
    s = min(max(elapsed / duration, 0.0), 1.0)
    target = np.array([target_xy[0], target_xy[1], 0.0])
    unit = [
        np.eye(6)[0] * pos[i] + (target[i] - pos[i]) * lipm.SMOOTHSTEP
        + vel[i] * duration * lipm.HERMITE_D1 + acc[i] * duration**2 * lipm.HERMITE_D2
        for i in range(3)
    ]
    grid = np.linspace(0, 1, 41)
    lowest = float(np.min(lipm.poly_eval(unit[2], grid)))
    leaving = pos[2] < 0.5 * lift_height and vel[2] >= -1e-9
    apex = max(0.0, min(lift_height, 0.5 * lift_height - lowest)) if leaving else max(0.0, -lowest)
    unit[2] = lipm.pad(unit[2]) + 64.0 * apex * lipm.pad(lipm.BUMP_A)
    return np.array([float(lipm.poly_eval(u, s)) for u in unit])


def descent_time(lift: float, params: StopParameters) -> float:
    """Shortest landing duration from swing height ``lift`` [m], on the servo grid: the quintic
    descent peaks at 15/8 of its mean speed, kept under ``max_swing_descent_speed``. Capped one
    tick below ``max_landing_time`` (very high lifts of custom gaits keep a landing window)."""
    dt = params.servo_period
    shortest = math.ceil(1.875 * max(lift, 0.0) / params.max_swing_descent_speed / dt - 1e-9) * dt
    return min(shortest, params.max_landing_time - dt)


# ---------------------------------------------------------------------------
# phase-parameter solvers
# ---------------------------------------------------------------------------

class _StopProblem:
    """Shared parts of the single- and double-support problems.

    Decision variables ``y = (landing, transition, target)`` (the landing
    duration is fixed at zero in double support). The stop condition (eq. 21)
    is solved for the slowdown duration, ``T3 = f(y)`` (closed form, see
    :func:`slowdown_time`), which makes the step-length and ZMP limits simple
    bounds; it is the same equation the paper solves for ``l_s`` (eq. 22).

    Two evaluation paths: vectorised over broadcastable duration grids
    (``*_grid``, :meth:`target_interval`; grid start and quantisation) and at
    one point in plain floats (:meth:`evaluate`, :meth:`values`; the Newton
    iterations, where numpy's per-call overhead would dominate).
    """

    free: tuple  # indices of y that are decision variables
    rear_ankle = 0.0  # rear ankle x relative to the start ZMP

    def bounds(self) -> np.ndarray:
        raise NotImplementedError

    # -- grids ------------------------------------------------------------
    def grid_terms(self, landing, transition):
        """Closed-form terms on a (landing, transition) grid, shared by the grid evaluations."""
        return _terms_grid(self.start, self.w, landing, transition)

    def slowdown(self, y, terms=None):
        """T3 from the stop condition (eq. 21), vectorised; ``terms`` from :meth:`grid_terms`."""
        if terms is None:
            return slowdown_time_grid(self.start, self.w, y[0], y[1], y[2])
        return _slowdown_from_grid_terms(terms, self.w, np.asarray(y[2], float))

    def constraints_grid(self, y, t3, terms=None):
        p = self.params
        with np.errstate(invalid="ignore"):
            return [np.nan_to_num(t3 - p.min_slowdown_time, nan=-1.0),
                    np.nan_to_num(p.max_slowdown_time - t3, nan=-1.0)] + self.extra_constraints(y, terms)[0]

    def target_interval(self, landing, transition, terms=None):
        """ZMP-target interval meeting the bounds and the slowdown-duration limits (Z falls as
        the slowdown lengthens), vectorised over duration arrays."""
        p = self.params
        bounds = self.bounds()
        terms = self.grid_terms(landing, transition) if terms is None else terms
        long = _target_from_grid_terms(terms, self.w, p.max_slowdown_time)
        short = _target_from_grid_terms(terms, self.w, p.min_slowdown_time)
        return np.maximum(bounds[2, 0], np.minimum(long, short)), np.minimum(bounds[2, 1], np.maximum(long, short))

    def extra_constraints(self, y, terms=None):
        """Rear-leg reach where the COG comes to rest: ``reach - (x_rest - rear) >= 0``.

        Arrays in, arrays out (vectorised); at one point also gradients and Hessians.
        """
        if np.ndim(y[0]) != 0:
            terms = self.grid_terms(y[0], y[1]) if terms is None else terms
            target = np.asarray(y[2], float)
            rest = _rest_from_grid_terms(terms, self.w, target, _slowdown_from_grid_terms(terms, self.w, target))
            return [np.nan_to_num(self.params.max_rear_reach - rest + self.rear_ankle, nan=-1.0)], None, None
        values, grads, hessians = self._extras_point([float(v) for v in y], *self._point(y)[3:])
        return (values, [np.array(gr) for gr in grads],
                [np.zeros((3, 3)) if h is None else np.array(h) for h in hessians])

    # -- one point, plain floats --------------------------------------------
    def _point(self, y):
        """T3 and rest position with derivatives at ``y`` (zeros where infeasible)."""
        t3, tg, th, rest, rg, rh = stop_point(self.start, self.w, float(y[0]), float(y[1]), float(y[2]))
        if tg is None:
            return t3, _ZERO3, _ZERO33, rest, _ZERO3, _ZERO33
        return t3, tg, th, rest, rg, rh

    def _extras_point(self, y, rest, rest_grad=None, rest_hess=None):
        """Extra constraints at one point: values, and with ``rest_grad`` their gradients and
        Hessians in y (nested lists, None = zero)."""
        value = self.params.max_rear_reach - rest + self._floats["rear_ankle"] if math.isfinite(rest) else -1.0
        if rest_grad is None:
            return [value], None, None
        return [value], [[-v for v in rest_grad]], [[[-v for v in row] for row in rest_hess]]

    @functools.cached_property
    def _floats(self):
        """Problem data as plain floats (the solver's scalar arithmetic)."""
        return self._float_data()

    def _float_data(self):
        return {"rear_ankle": float(self.rear_ankle),
                "bounds": [tuple(map(float, self.bounds()[k])) for k in self.free]}

    @functools.cached_property
    def _bound_rows(self):
        """Gradients of the bound constraints (lower, upper per free variable)."""
        n = len(self.free)
        rows = []
        for i in range(n):
            unit = [1.0 if j == i else 0.0 for j in range(n)]
            rows += [unit, [-u for u in unit]]
        return rows

    def _bound_values(self, x):
        return [v for xi, (lo, hi) in zip(x, self._floats["bounds"]) for v in (xi - lo, hi - xi)]

    def _full_point(self, x):
        """Free variables (array or list) -> y as a list of floats."""
        if len(self.free) == 3:
            return list(map(float, x))
        y = [0.0, 0.0, 0.0]
        for k, value in zip(self.free, x):
            y[k] = float(value)
        return y

    def _restrict(self, vector=None, matrix=None):
        """Entries of a 3-vector / 3x3 matrix over the free variables."""
        if len(self.free) == 3:
            return vector if matrix is None else matrix
        idx = self.free
        if matrix is None:
            return [vector[i] for i in idx]
        return [[matrix[i][j] for j in idx] for i in idx]

    def evaluate(self, x):
        """Cost, constraints and their analytic derivatives over the free variables, as
        plain floats and nested lists for :func:`barrier_newton` (``None``: zero Hessian).

        Constraint order: lower/upper bound of each free variable, slowdown
        duration above its minimum and below its maximum, then the extras.
        """
        x = list(map(float, x))
        y = self._full_point(x)
        t3, tg, th, rest, rg, rh = self._point(y)
        cost, cg, ch = self.cost_terms(y, t3, tg, th)
        ev, eg, eh = self._extras_point(y, rest, rg, rh)
        p = self.params
        finite = math.isfinite(t3)
        g = self._bound_values(x) + [t3 - p.min_slowdown_time if finite else -1.0,
                                     p.max_slowdown_time - t3 if finite else -1.0] + ev
        sub = self._restrict
        gg = self._bound_rows + [sub(tg), sub([-v for v in tg])] + [sub(e) for e in eg]
        th_free = sub(matrix=th)
        gh = [None] * len(self._bound_rows) + [th_free, [[-v for v in row] for row in th_free]]
        gh += [None if h is None else sub(matrix=h) for h in eh]
        return cost, sub(cg), sub(matrix=ch), g, gg, gh

    def values(self, x):
        """Cost and constraint values only (line-search trial points)."""
        x = list(map(float, x))
        y = self._full_point(x)
        t3, rest = stop_point(self.start, self.w, y[0], y[1], y[2], derivatives=False)
        g = self._bound_values(x)
        extras = self._extras_point(y, rest)[0]
        if not math.isfinite(t3):
            return math.inf, [-1.0] * (len(g) + 2 + len(extras))
        p = self.params
        g += [t3 - p.min_slowdown_time, p.max_slowdown_time - t3] + extras
        return self.cost_grid(y, t3), g

    def full(self, x):
        y = np.zeros(3)
        y[list(self.free)] = x
        return y


_ZERO3 = [0.0, 0.0, 0.0]
_ZERO33 = [[0.0] * 3 for _ in range(3)]


def _square(value):
    """value ** 2 (same rounding for floats and arrays, no float overflow error)."""
    return value * value


def _outer_plus(u, scale, matrix):
    """``u u^T + scale * matrix`` as nested lists (a Hessian term of the costs)."""
    return [[u[i] * u[j] + scale * matrix[i][j] for j in range(3)] for i in range(3)]


@dataclass
class _SingleSupportProblem(_StopProblem):
    start: StopStart
    w: float
    params: StopParameters
    support_x: float  # sagittal ZMP at the start (support ankle)
    swing_xy: np.ndarray  # current swing ankle
    landing_y: float  # lateral landing (nominal step width)
    free: tuple = (0, 1, 2)
    min_landing: float = 0.0  # shortest landing from the swing foot's height (:func:`descent_time`)
    nominal_landing: float = math.nan  # time left to the nominal touchdown [s] (stepping in place keeps it)

    def bounds(self):
        """Durations, and the slowdown ZMP = step length + landing_zmp_offset (eq. 20)."""
        p = self.params
        offset = p.landing_zmp_offset
        return np.array([[max(p.min_landing_time, self.min_landing), p.max_landing_time],
                         [p.min_transition_time, p.max_transition_time],
                         [p.min_step_length + offset, p.max_step_length + offset]])

    def step_length(self, target):
        return target - self.params.landing_zmp_offset

    def target_interval(self, landing, transition, terms=None):
        """Base interval narrowed by the swing-speed disc and the fore-leg reach at touchdown."""
        p = self.params
        low, high = super().target_interval(landing, transition, terms)
        dy = self.landing_y - self.swing_xy[1]
        radius = np.sqrt(np.maximum((p.max_swing_speed * landing) ** 2 - dy * dy, 0.0))
        offset = p.landing_zmp_offset - self.support_x
        low = np.maximum(low, self.swing_xy[0] - radius + offset)
        high = np.minimum(high, self.swing_xy[0] + radius + offset)
        grow = np.exp(self.w * landing)
        ahead = 0.5 * (self.start.dcm * grow + self.start.ccm / grow)
        return low, np.minimum(high, p.max_fore_reach + ahead + p.landing_zmp_offset)

    def _distance(self, step):
        dx = self.support_x + step - self.swing_xy[0]
        dy = self.landing_y - self.swing_xy[1]
        return np.sqrt(dx * dx + dy * dy), dx, dy

    def extra_constraints(self, y, terms=None):
        """Mean swing-ankle speed to the landing point, ``v_max t_i - distance >= 0``, fore-leg
        reach at touchdown, ``reach - (landing - x_G(t_i)) >= 0`` with the COG of phase (i)
        (constant ZMP, eq. 6): ``x_G - p0 = (xi0 exp(w t_i) + zeta0 exp(-w t_i)) / 2``, and the
        rear-leg reach at rest (support ankle = rear)."""
        if np.ndim(y[0]) == 0:
            return super().extra_constraints(y)
        p = self.params
        step = self.step_length(y[2])
        dist, dx, dy = self._distance(step)
        speed = p.max_swing_speed * y[0] - dist
        grow = np.exp(self.w * y[0])
        ahead = 0.5 * (self.start.dcm * grow + self.start.ccm / grow)
        reach = p.max_fore_reach - step + ahead
        return [speed, reach] + super().extra_constraints(y, terms)[0], None, None

    def _float_data(self):
        data = super()._float_data()
        data.update(support_x=float(self.support_x), swing=tuple(map(float, self.swing_xy[:2])),
                    landing_y=float(self.landing_y))
        return data

    def _extras_point(self, y, rest, rest_grad=None, rest_hess=None):
        """The three extra constraints of :meth:`extra_constraints` at one point (plain floats)."""
        p, f = self.params, self._floats
        step = self.step_length(y[2])
        dx = f["support_x"] + step - f["swing"][0]
        dy = f["landing_y"] - f["swing"][1]
        dist = math.sqrt(dx * dx + dy * dy)
        speed = p.max_swing_speed * y[0] - dist
        grow = math.exp(self.w * y[0])
        ahead = 0.5 * (self.start.dcm * grow + self.start.ccm / grow)
        reach = p.max_fore_reach - step + ahead
        rear, rear_grad, rear_hess = super()._extras_point(y, rest, rest_grad, rest_hess)
        if rest_grad is None:
            return [speed, reach] + rear, None, None
        speed_grad = [p.max_swing_speed, 0.0, -dx / dist]
        speed_hess = [[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, -dy * dy / dist**3]]
        reach_grad = [0.5 * self.w * (self.start.dcm * grow - self.start.ccm / grow), 0.0, -1.0]
        reach_hess = [[self.w * self.w * ahead, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]
        return ([speed, reach] + rear, [speed_grad, reach_grad] + rear_grad,
                [speed_hess, reach_hess] + rear_hess)

    def cost_grid(self, y, t3):
        p = self.params
        return p.a_ss * _square(self.step_length(y[2]) / y[0]) + p.b_ss * _square(y[1] + t3)  # eq. 24

    def cost_terms(self, y, t3, tg, th):
        """J_ss (eq. 24) and its gradient and Hessian in (t_i, t_ii, l_s), nested lists."""
        p = self.params
        t1, t2 = y[0], y[1]
        step = self.step_length(y[2])
        u = step / t1  # mean swing speed term
        t1sq = t1 * t1
        ug = [-step / t1sq, 0.0, 1.0 / t1]
        uh = [[2 * step / t1**3, 0.0, -1.0 / t1sq], [0.0, 0.0, 0.0], [-1.0 / t1sq, 0.0, 0.0]]
        span = t2 + t3  # double support + slowdown
        sg = [tg[0], tg[1] + 1.0, tg[2]]
        cost = p.a_ss * u * u + p.b_ss * span * span
        ku, ks = 2 * p.a_ss * u, 2 * p.b_ss * span
        grad = [ku * ug[i] + ks * sg[i] for i in range(3)]
        hu, hs = _outer_plus(ug, u, uh), _outer_plus(sg, span, th)
        hess = [[2 * p.a_ss * hu[i][j] + 2 * p.b_ss * hs[i][j] for j in range(3)] for i in range(3)]
        return cost, grad, hess


@dataclass
class _DoubleSupportProblem(_StopProblem):
    start: StopStart
    w: float
    params: StopParameters
    zmp_low: float  # allowed range of Z, relative to the start ZMP
    zmp_high: float
    rear_ankle: float = 0.0  # rear ankle x relative to the start ZMP
    free: tuple = (1, 2)

    def bounds(self):
        p = self.params
        return np.array([[0.0, 0.0],
                         [p.min_transition_time, p.max_transition_time],
                         [self.zmp_low, self.zmp_high]])

    def cost_grid(self, y, t3):
        p = self.params
        return p.a_ds * _square(y[2]) + p.b_ds * _square(y[1] + t3)  # eq. 30 (t_i = signal time)

    def cost_terms(self, y, t3, tg, th):
        """J_ds (eq. 30) with ZMP_max = target, in (t_ii, ZMP_max) (eq. 31), nested lists."""
        p = self.params
        span = y[1] + t3
        sg = [tg[0], tg[1] + 1.0, tg[2]]
        zg = [0.0, 0.0, 1.0]
        cost = p.a_ds * _square(y[2]) + p.b_ds * span * span
        kz, ks = 2 * p.a_ds * y[2], 2 * p.b_ds * span
        grad = [kz * zg[i] + ks * sg[i] for i in range(3)]
        hs = _outer_plus(sg, span, th)
        hess = [[2 * p.a_ds * zg[i] * zg[j] + 2 * p.b_ds * hs[i][j] for j in range(3)] for i in range(3)]
        return cost, grad, hess


_GRID = {"single": (16, 4), "double": (1, 10)}
_TARGET_SAMPLES = np.linspace(0.02, 0.98, 12)


@functools.lru_cache(maxsize=64)
def _grid_axes(kind, bounds):
    """Landing and transition grids (include the bounds; cached: they depend on the limits only)."""
    axes = []
    for (lo, hi), count in zip(bounds, _GRID[kind]):
        inset = 1e-3 * (hi - lo)
        inner = np.linspace(lo + inset, hi - inset, count) if count > 1 else np.array([lo])
        axes.append(np.unique(np.concatenate([[lo], inner])) if count > 1 else inner)
    return axes[0][:, None, None], axes[1][None, :, None]


def _grid_start(problem, kind):
    """Cheapest feasible point of a grid (vectorised): ``(y, cost, strict)`` or None.

    Durations on a grid that includes their bounds; the ZMP target sampled
    inside its feasible interval for each pair of durations
    (:meth:`target_interval`), so thin feasible regions bounded by the
    swing-speed and reach limits are not missed. Strictly feasible points are
    preferred (the interior-point method needs one); ``strict=False`` means
    the feasible set has no interior on the grid (a corner of the limits).
    Arrays are (landing, transition, target) axes that broadcast; the closed
    form's quadrature runs once per transition duration.
    """
    bounds = problem.bounds()
    t1, t2 = _grid_axes(kind, tuple(tuple(row) for row in bounds[:2].tolist()))
    terms = problem.grid_terms(t1, t2)  # (landing, transition, 1)
    low, high = problem.target_interval(t1[..., 0], t2[..., 0], tuple(term[..., 0] for term in terms))
    z = low[..., None] + (high - low)[..., None] * _TARGET_SAMPLES
    y = [t1, t2, z]
    t3 = problem.slowdown(y, terms)
    margins = problem.constraints_grid(y, t3, terms)
    margins += [y[k] - bounds[k, 0] for k in problem.free] + [bounds[k, 1] - y[k] for k in problem.free]
    worst = functools.reduce(np.minimum, margins)
    worst = np.where((high >= low)[..., None] & np.isfinite(t3), worst, -np.inf)
    cost = problem.cost_grid(y, np.nan_to_num(t3))
    for strict, threshold in ((True, 1e-9), (False, -1e-12)):
        ok = worst > threshold
        if np.any(ok):
            i = np.unravel_index(np.argmin(np.where(ok, cost, np.inf)), cost.shape)
            return np.array([np.broadcast_to(axis, cost.shape)[i] for axis in y]), float(cost[i]), strict
    return None


def _limit_names(problem, kind):
    """Names of the limits behind :meth:`constraints_grid` (in its order), then the ZMP-target bounds."""
    names = ["min_slowdown_time", "max_slowdown_time"]
    names += ["max_swing_speed", "max_fore_reach", "max_rear_reach"] if kind == "single" else ["max_rear_reach"]
    if kind == "single":
        return names + ["min_step_length", "max_step_length"]
    return names + ["zmp_margin (ZMP_max behind the fore sole's heel)", "zmp_margin (ZMP_max past the fore sole's toe)"]


def _infeasible_reason(problem, kind, samples=41):
    """Why no grid point is feasible, naming the limits (for the InfeasibleStop message).

    Evaluates every limit on the duration grid times ``samples`` ZMP targets across their
    bounds: a limit is named if dropping it alone leaves a feasible point, or else if it is
    violated everywhere; "stop condition" if no non-negative slowdown stops the COG.
    """
    bounds = problem.bounds()
    t1, t2 = _grid_axes(kind, tuple(tuple(row) for row in bounds[:2].tolist()))
    z = np.linspace(bounds[2, 0], bounds[2, 1], samples)[None, None, :]
    y = [t1, t2, z]
    terms = problem.grid_terms(t1, t2)
    t3 = problem.slowdown(y, terms)
    stops = np.isfinite(t3)
    margins = [np.where(stops, g, 0.0) for g in problem.constraints_grid(y, t3, terms)]
    margins += [z - bounds[2, 0] + 0 * t1, bounds[2, 1] - z + 0 * t1]
    names = _limit_names(problem, kind)
    ok = [np.broadcast_to(m >= 0, t3.shape) for m in margins]
    blocking = [name for k, name in enumerate(names)
                if np.any(stops & functools.reduce(np.logical_and, [o for j, o in enumerate(ok) if j != k]))]
    if not np.any(stops):
        blocking = [(f"min_step_length/max_step_length: no step in [{bounds[2, 0]:.3f}, {bounds[2, 1]:.3f}] m "
                     "stops the COG (stop condition, eq. 22)") if kind == "single" else
                    "zmp_margin: no ZMP_max on the fore sole stops the COG (stop condition, eq. 29)"]
    elif not blocking:
        blocking = [name for name, o in zip(names, ok) if not np.any(o & stops)] or ["a combination of limits"]
    return f"no feasible {kind}-support stop from this state: limited by " + ", ".join(blocking)


def solve_continuous(problem, kind):
    """Interior-point Newton optimum before quantisation: ``(y, t3, cost, iterations)``."""
    if COMPILED and _fastcore is not None:
        _, (y0, y1, t3, y2, cost), iterations, status = _fastcore.solve(*_compiled_args(problem, kind), False)
        _compiled_status(status, kind, problem)
        return np.array([y0, y1, y2]), float(t3), float(cost), int(iterations)
    return _solve_continuous_python(problem, kind)


def _compiled_args(problem, kind):
    """Problem vector and grid axes for :mod:`drake_estop.planning.fastcore`."""
    bounds = problem.bounds()
    t1, t2 = _grid_axes(kind, tuple(tuple(row) for row in bounds[:2].tolist()))
    return _fastcore.pack(problem, kind), t1.ravel(), t2.ravel(), _TARGET_SAMPLES


def _compiled_status(status, kind, problem):
    """The Python path's exceptions for the compiled solver's status codes."""
    if status == _fastcore.NO_GRID_START:
        raise InfeasibleStop(_infeasible_reason(problem, kind))
    if status == _fastcore.NO_QUANTISATION:
        raise InfeasibleStop("no servo-tick quantisation of the optimum meets the limits")
    if status == _fastcore.INFEASIBLE_START:
        raise ValueError("barrier_newton needs a strictly feasible start")


def _solve_continuous_python(problem, kind):
    """:func:`solve_continuous` in pure Python (the reference the compiled path follows)."""
    start = _grid_start(problem, kind)
    if start is None:
        raise InfeasibleStop(_infeasible_reason(problem, kind))
    y0, cost0, strict = start
    if not strict:  # no interior: the corner of the limits is the only candidate
        return y0, float(problem.slowdown(y0)), cost0, 0
    free = list(problem.free)
    scale = max(cost0, 1.0)
    m = 2 * len(free) + 2 + (3 if kind == "single" else 1)
    result = barrier_newton(problem.evaluate, y0[free], values=problem.values, mu0=1e-1 * scale / m,
                            mu_final=problem.params.cost_tolerance * scale / m)
    y = problem.full(result.x)
    t3 = float(problem.slowdown(y))
    return y, t3, float(problem.cost_grid(y, t3)), result.iterations


def _at_rest_solution(problem, kind):
    """Phase parameters when the sagittal COG is at rest over a ZMP at rest (stepping in place).

    Then the stop condition holds for every slowdown duration with the ZMP kept where it
    is (Z = 0 in eq. 22 / 29; its closed form is 0/0 in T3), so the slowdown cannot be
    found from Z and the barrier method has no interior: land as early as the swing-speed
    and landing-time limits allow, beside the support foot, with the shortest transition and
    slowdown; :func:`_solve_both_axes` lengthens the slowdown for the lateral plane. The
    touchdown is the nominal one when that is later (the foot lands as it would have; an
    early 0.1 s touchdown from mid-swing slams the foot down). None if the state is not at
    rest or Z = 0 breaks a limit.
    """
    s, p = problem.start, problem.params
    if max(abs(s.dcm), abs(s.ccm), abs(s.zmp_rate), abs(s.zmp_accel)) > _AT_REST:
        return None
    bounds = problem.bounds()
    if not bounds[2, 0] <= 0.0 <= bounds[2, 1]:
        return None
    dt = p.servo_period
    on_tick = lambda t: math.ceil(t / dt - 1e-9) * dt  # noqa: E731
    landing = 0.0
    if kind == "single":
        distance = float(problem._distance(problem.step_length(0.0))[0])
        nominal = problem.nominal_landing if math.isfinite(problem.nominal_landing) else 0.0
        landing = on_tick(max(p.min_landing_time, distance / p.max_swing_speed, min(nominal, p.max_landing_time)))
        if landing > p.max_landing_time + 1e-12:
            return None
    transition, slowdown = on_tick(p.min_transition_time), on_tick(p.min_slowdown_time)
    # the COG stays over the start ZMP: rear reach to it, and in single support the fore reach
    values = [p.max_rear_reach + problem.rear_ankle]
    if kind == "single":
        values.append(p.max_fore_reach - problem.step_length(0.0))
    if min(values) < 0 or transition > p.max_transition_time + 1e-12 or slowdown > p.max_slowdown_time + 1e-12:
        return None
    cost = float(problem.cost_grid([landing, transition, 0.0], slowdown))
    return PhaseSolution(landing, transition, slowdown, 0.0, cost, 0, (landing, transition, slowdown, 0.0))


_AT_REST = 1e-12  # [m], [m/s], [m/s^2]: a sagittal start state this close to rest is at rest


def _solve(problem, kind) -> PhaseSolution:
    at_rest = _at_rest_solution(problem, kind)
    if at_rest is not None:
        return at_rest
    if COMPILED and _fastcore is not None:
        q, cont, iterations, status = _fastcore.solve(*_compiled_args(problem, kind), True)
        _compiled_status(status, kind, problem)
        (t1, t2, t3, z, cost), cont = q.tolist(), cont.tolist()[:4]
        if problem.params.quantisation == "resolve":
            # Z once more with numpy at the chosen ticks: equal to the Python path's to the bit
            # (the compiled quadrature can differ in the last bit, and the halt
            # boundary-value problem downstream amplifies that ~1e7 times)
            z = float(_target_from_grid_terms(problem.grid_terms(np.float64(t1), np.float64(t2)), problem.w,
                                              np.float64(t3)))
            cost = float(problem.cost_grid([t1, t2, z], t3))
        return PhaseSolution(t1, t2, t3, z, cost, int(iterations), tuple(cont))
    y, t3, _, iterations = _solve_continuous_python(problem, kind)
    return _quantise(problem, kind, y, t3, iterations)


def _quantise(problem, kind, y, t3, iterations) -> PhaseSolution:
    """Snap the durations to servo ticks; re-solve Z so eq. 17 holds exactly.

    Tries floor-1 .. ceil+1 ticks of each duration (vectorised) and keeps the
    cheapest combination that meets every limit with the re-solved Z. With
    ``quantisation="round"`` Z keeps its continuous value (the paper's
    behaviour, for comparison): the stop condition then no longer holds.
    """
    dt = problem.params.servo_period
    p = problem.params
    bounds = problem.bounds()
    limits = [bounds[0], bounds[1], (p.min_slowdown_time, p.max_slowdown_time)]
    options = []
    for k, value in enumerate((y[0], y[1], t3)):
        if kind == "double" and k == 0:
            options.append(np.zeros(1))
            continue
        lo = math.ceil(limits[k][0] / dt - 1e-9)
        hi = math.floor(limits[k][1] / dt + 1e-9)
        base = math.floor(value / dt + 1e-9)
        options.append(np.array(sorted({min(max(n, lo), hi) for n in range(base - 1, base + 3)}), float) * dt)
    shape = tuple(len(o) for o in options)
    t1, t2, t3q = options[0][:, None, None], options[1][None, :, None], options[2][None, None, :]
    terms = problem.grid_terms(t1, t2)
    if p.quantisation == "resolve":
        z = _target_from_grid_terms(terms, problem.w, t3q)
    else:
        z = np.full(shape, y[2])
    yq = [t1, t2, z]
    ok = np.ones(shape, bool)
    for k in range(3):
        ok &= (yq[k] >= bounds[k, 0] - 1e-12) & (yq[k] <= bounds[k, 1] + 1e-12)
    for g in problem.constraints_grid(yq, t3q, terms):
        ok &= g >= -1e-12
    if not np.any(ok):
        raise InfeasibleStop("no servo-tick quantisation of the optimum meets the limits")
    cost = np.where(ok, problem.cost_grid(yq, t3q), np.inf)
    i = np.unravel_index(np.argmin(cost), shape)
    return PhaseSolution(float(t1[i[0], 0, 0]), float(t2[0, i[1], 0]), float(t3q[0, 0, i[2]]), float(z[i]),
                         float(cost[i]),
                         iterations, (y[0], y[1], t3, y[2]))


# ---------------------------------------------------------------------------
# planning
# ---------------------------------------------------------------------------

_HALT_PROBE = np.linspace(0.0, 1.0, 41)


def _halt_candidates(params):
    dt = params.servo_period
    ticks = lambda t: max(1, round(t / dt)) * dt  # noqa: E731
    shifts = sorted({ticks(params.min_transition_time), ticks(2 * params.min_transition_time)})
    pairs = [(a, ticks(b)) for a in shifts for b in params.halt_durations]
    return sorted(pairs, key=lambda pair: (pair[0] + pair[1], pair[0]))


@functools.lru_cache(maxsize=256)
def _halt_basis(w: float, shift: float, settle: float):
    """Unit responses of the halt ZMP shapes (cached: they depend on durations only).

    Shapes over the two halt segments: [from the slowdown ZMP, to the target,
    free point q, bump A, bump B]. Returns their ZMP coefficients per segment,
    the COG end state each produces from rest (plain floats), the homogeneous
    transition matrix, ``S^T`` and the normal matrix ``S S^T`` (nested lists)
    of the least-norm boundary-value problem (eq. 27-28; ``S``: weighted
    responses of the unknowns) and the shapes sampled at the probe points.
    """
    zero = lipm.pad(np.zeros(1))
    one = lipm.pad([1.0])
    rise = lipm.pad(lipm.scale_unit_poly(lipm.SMOOTHSTEP, shift))
    settle_rise = lipm.pad(lipm.scale_unit_poly(lipm.SMOOTHSTEP, settle))
    shapes = [
        [one - rise, zero],
        [zero, settle_rise],
        [rise, one - settle_rise],
        [zero, lipm.pad(lipm.scale_unit_poly(lipm.BUMP_A, settle))],
        [zero, lipm.pad(lipm.scale_unit_poly(lipm.BUMP_B, settle))],
    ]
    durations = (shift, settle)
    responses = np.array([lipm.chain_end_state(durations, shape, 0.0, 0.0, w) for shape in shapes])
    total = shift + settle
    ch, sh = math.cosh(w * total), math.sinh(w * total)
    homogeneous = np.array([[ch, sh / w], [w * sh, ch]])
    scaled = responses[2:].T * _HALT_WEIGHTS
    normal = scaled @ scaled.T  # badly conditioned for long settles: solved per call, not inverted
    samples = np.array([np.concatenate([lipm.poly_eval(c, _HALT_PROBE * d) for d, c in zip(durations, shape)])
                        for shape in shapes])
    return np.array(shapes), responses, homogeneous, (np.ascontiguousarray(scaled.T), normal.tolist()), samples


_HALT_WEIGHTS = np.array([10.0, 1.0, 1.0])  # q, bump A, bump B: bumps penalised


def _halt_axis(x3, v3, zmp3, target, shift, settle, w):
    """Halt ZMP of one axis (eq. 27-28): a quick shift from the slowdown ZMP to a
    free point ``q``, then a settle segment from ``q`` to ``target`` with two
    bumps. ``q`` and the bump heights solve Harada's two-point boundary-value
    problem (COG at ``target`` at rest) in the weighted least-norm sense, so
    the ZMP moves as little as the COG allows. Returns (shape weights ``mix``,
    ZMP samples at the probe points); coefficients per segment are
    ``np.tensordot(mix, shapes, axes=1)`` (:func:`_halt_coeffs`)."""
    _, responses, homogeneous, (scaled_t, normal), samples = _halt_basis(w, shift, settle)
    free = homogeneous @ np.array([x3, v3]) + zmp3 * responses[0] + target * responses[1]
    # weighted least norm: u = W S^T (S S^T)^-1 (end state wanted - end state without the unknowns)
    u = _HALT_WEIGHTS * (scaled_t @ np.array(_solve2(normal, (np.array([target, 0.0]) - free).tolist())))
    mix = np.concatenate([[zmp3, target], u])
    return mix, mix @ samples


def _solve2(matrix, rhs):
    """2x2 linear solve by Gaussian elimination with partial pivoting, plain floats; the
    operations of LAPACK's gesv (multiplier by the pivot's reciprocal), so the result
    equals ``np.linalg.solve`` to the bit even on the badly conditioned halt systems."""
    (a, b), (c, d) = matrix
    r0, r1 = rhs
    if abs(c) > abs(a):
        a, b, c, d, r0, r1 = c, d, a, b, r1, r0
    factor = c * (1.0 / a)
    second = (r1 - factor * r0) / (d - factor * b)
    return (r0 - b * second) / a, second


def _halt_coeffs(mix, shift, settle, w):
    """ZMP coefficients per halt segment of the shape weights from :func:`_halt_axis`."""
    return list(np.tensordot(mix, _halt_basis(w, shift, settle)[0], axes=1))


def _choose_halt(ends, midpoint, polygon, params, w):
    """Shortest halt whose ZMP keeps ``zmp_margin`` inside the support polygon;
    else the one with the largest margin. ``ends``: COG position, velocity and
    ZMP per axis at the slowdown end. Returns (durations, coeffs per axis, margin)."""
    best = None
    for shift, settle in _halt_candidates(params):
        axes = [_halt_axis(x3, v3, zmp3, midpoint[a], shift, settle, w) for a, (x3, v3, zmp3) in enumerate(ends)]
        margin = float(polygon.margin(np.stack([axes[0][1], axes[1][1]], axis=1)).min())
        if best is None or margin > best[2]:
            best = ([shift, settle], [axis[0] for axis in axes], margin)
        if margin >= params.zmp_margin:
            break
    (shift, settle), mixes, margin = best
    return best[0], [_halt_coeffs(mix, shift, settle, w) for mix in mixes], margin


def _polygon_y_range(polygon: SupportPolygon, x: float, margin: float):
    """The y interval of ``polygon`` (``margin`` inside) at abscissa ``x``, or None."""
    low, high = -np.inf, np.inf
    for (nx, ny), d in zip(polygon._normals, polygon._offsets):
        bound = d - margin - nx * x
        if ny > 1e-12:
            high = min(high, bound / ny)
        elif ny < -1e-12:
            low = max(low, bound / ny)
        elif bound < 0:
            return None
    return (low, high) if low <= high else None


_LATERAL_ROUNDS = 5  # re-solves that raise the slowdown floor until the lateral stop fits the fore sole
_LATERAL_SLACK = 1e-3  # [m] the floor aims this far inside the lateral ZMP range (tick rounding)


def _solve_both_axes(pattern, state, params, zmp_region="fore"):
    """Solve the sagittal phase parameters (III.A / III.B) so that the lateral plane stops too.

    The paper solves the sagittal plane and reuses its phase times laterally. With short or
    no steps the sagittal stop is easy and its optimum has the shortest transition and
    slowdown, far too short to stop the lateral sway with the ZMP on the fore sole; the halt
    then cannot absorb the lateral velocity left over. So: if the lateral ZMP that stops the
    lateral COG at the slowdown end (same stop condition, eq. 17) lies beyond the fore sole,
    the slowdown duration that brings it onto the sole (closed form, eq. 21) becomes the
    floor of the slowdown time and the sagittal problem is solved again, for a few rounds.
    Returns ``(problem, kind, feet, solution)``.
    """
    problem, kind, feet = stop_problem(pattern, state, params, zmp_region)
    solution = _solve(problem, kind)
    if zmp_region == "polygon":  # a re-plan: the lateral ZMP may use the polygon's width (_lateral_target)
        return problem, kind, feet, solution
    sole, w = pattern.params.sole, pattern.w
    fore_side = feet["swing"] if kind == "single" else feet["fore"]
    fore_y = float(state.next_landing[1]) if kind == "single" else float(state.feet[fore_side][1])
    outer, inner = (sole.outer, sole.inner) if fore_side == "left" else (sole.inner, sole.outer)
    low = fore_y - inner + params.zmp_margin + _LATERAL_SLACK - float(state.zmp[1])
    high = fore_y + outer - params.zmp_margin - _LATERAL_SLACK - float(state.zmp[1])
    rate = float(state.zmp_rate[1]) if kind == "double" else 0.0
    accel = float(state.zmp_accel[1]) if kind == "double" else 0.0
    start = StopStart.from_state(state.com[1], state.com_vel[1], state.zmp[1], w, rate, accel)
    limits = {}
    if kind == "single":
        touchdown = pattern.steps[state.step_index]["touchdown"]
        dt = params.servo_period
        nominal_landing = max(math.ceil((touchdown - state.time) / dt - 1e-9) * dt, params.min_landing_time + dt)
    for _ in range(_LATERAL_ROUNDS):
        wanted = target_zmp(start, w, solution.landing, solution.transition, solution.slowdown, derivatives=False)
        if low - _LATERAL_SLACK <= wanted <= high + _LATERAL_SLACK:
            break
        bound = low if wanted < low else high
        if kind == "single" and solution.landing > nominal_landing + 1e-9 and "max_landing_time" not in limits:
            # first keep the touchdown no later than the nominal one: postponing it lets the lateral
            # COG run out over the support foot's side (the nominal walk bounds that excursion)
            limits["max_landing_time"] = nominal_landing + 1e-9
        else:
            floor = slowdown_time(start, w, solution.landing, solution.transition, bound, derivatives=False)
            if floor > params.min_slowdown_time and floor < params.max_slowdown_time:
                limits["min_slowdown_time"] = max(floor, limits.get("min_slowdown_time", floor))
                if kind == "single":  # a later touchdown would need a longer slowdown again
                    limits["max_landing_time"] = max(solution.landing, params.min_landing_time + params.servo_period,
                                                     ) + 1e-9
            elif kind == "single":
                # the lateral COG runs away while the foot swings: no slowdown is long enough, so
                # land earlier (the latest touchdown from which a slowdown of half the longest fits)
                ceiling = _latest_landing(start, w, solution.transition, 0.5 * params.max_slowdown_time,
                                          bound, wanted < low, params.min_landing_time, solution.landing,
                                          params.servo_period)
                if ceiling is None:
                    break
                limits["max_landing_time"] = ceiling
                limits.pop("min_slowdown_time", None)
            else:
                break
        try:
            problem, kind, feet = stop_problem(pattern, state, replace(params, **limits), zmp_region)
            solution = _solve(problem, kind)
        except (InfeasibleStop, ValueError):
            break
    return problem, kind, feet, solution


def _latest_landing(start, w, transition, slowdown, bound, below, earliest, latest, dt):
    """Latest touchdown on a servo tick in [earliest, latest) whose lateral stop ZMP, for the
    given transition and slowdown, has not passed ``bound`` (from below the range if ``below``),
    so that a slowdown up to that long reaches the fore sole (bisection over ticks), or None."""
    def inside(t1):
        wanted = target_zmp(start, w, t1, transition, slowdown, derivatives=False)
        return wanted >= bound if below else wanted <= bound

    lo, hi = math.ceil(earliest / dt - 1e-9), math.floor(latest / dt + 1e-9) - 1
    if hi < lo or not inside(lo * dt):
        return None
    while lo < hi:
        mid = (lo + hi + 1) // 2
        lo, hi = (mid, hi) if inside(mid * dt) else (lo, mid - 1)
    return max(lo * dt, earliest + 1e-9) if lo * dt <= earliest else lo * dt


def _lateral_target(state, solution, fore_xy, fore_side, kind, w, sole, margin, polygon=None, sagittal=None):
    """Lateral ZMP of phases (ii)-(iii): the sagittal phase times, and the value
    that also zeroes the lateral COG velocity at the slowdown end (same stop
    condition, eq. 17), clipped to the fore sole (or, with ``polygon``, to the
    support polygon's width at the ``sagittal`` target)."""
    rate = float(state.zmp_rate[1]) if kind == "double" else 0.0
    accel = float(state.zmp_accel[1]) if kind == "double" else 0.0
    start = StopStart.from_state(state.com[1], state.com_vel[1], state.zmp[1], w, rate, accel)
    wanted = state.zmp[1] + target_zmp(start, w, solution.landing, solution.transition,
                                       solution.slowdown, derivatives=False)
    if polygon is not None:
        interval = _polygon_y_range(polygon, sagittal, margin)
        if interval is None:
            raise InfeasibleStop("zmp_margin: the sagittal ZMP target leaves the support polygon")
        return float(np.clip(wanted, *interval))
    outer, inner = (sole.outer, sole.inner) if fore_side == "left" else (sole.inner, sole.outer)
    return float(np.clip(wanted, fore_xy[1] - inner + margin, fore_xy[1] + outer - margin))


def _zmp_segments(state, solution, targets, kind):
    """Sagittal and lateral ZMP polynomials of phases (i)-(iii)."""
    segs = []
    for axis in (0, 1):
        p0, end = float(state.zmp[axis]), float(targets[axis])
        if kind == "single":
            coeffs = [lipm.pad([p0]), lipm.transition_coeffs(p0, end, solution.transition), lipm.pad([end])]
            durations = [solution.landing, solution.transition, solution.slowdown]
        else:
            coeffs = [lipm.transition_coeffs(p0, end, solution.transition,
                                             float(state.zmp_rate[axis]), float(state.zmp_accel[axis])),
                      lipm.pad([end])]
            durations = [solution.transition, solution.slowdown]
        segs.append((durations, coeffs))
    return segs


def stop_problem(pattern: NominalPattern, state: PatternState, params: StopParameters, zmp_region: str = "fore"):
    """The phase-parameter problem (III.A or III.B) from ``state``.

    Returns ``(problem, kind, context)`` with ``kind`` "single" or "double";
    ``context`` carries the feet the plan needs. Exposed for reference solves.
    ``zmp_region`` (double support): "fore" keeps ZMP_max on the fore sole
    (III.B: the ZMP moves from the rear to the fore foot); "polygon" allows
    the whole sagittal extent of both soles (re-plans after a push, where the
    COG may have to be stopped over the rear foot).
    """
    w = pattern.w
    sole = pattern.params.sole
    kind = state.support
    start = StopStart.from_state(state.com[0], state.com_vel[0], state.zmp[0], w,
                                 state.zmp_rate[0] if kind == "double" else 0.0,
                                 state.zmp_accel[0] if kind == "double" else 0.0)
    if kind == "single":
        support = state.support_foot
        swing = "right" if support == "left" else "left"
        if not -(sole.heel - params.zmp_margin) <= params.landing_zmp_offset <= sole.toe - params.zmp_margin:
            raise ValueError(f"landing_zmp_offset {params.landing_zmp_offset} m puts the ZMP outside the fore sole")
        touchdown = pattern.steps[state.step_index]["touchdown"]
        problem = _SingleSupportProblem(start, w, params, float(state.zmp[0]),
                                        state.feet[swing][:2].copy(), float(state.next_landing[1]),
                                        min_landing=descent_time(float(state.feet[swing][2]), params),
                                        nominal_landing=float(touchdown - state.time))
        return problem, kind, {"support": support, "swing": swing}
    rear = state.rear_foot or "right"
    fore = "left" if rear == "right" else "right"
    fore_x = state.feet[fore][0]
    low = fore_x - sole.heel + params.zmp_margin - state.zmp[0]
    high = fore_x + sole.toe - params.zmp_margin - state.zmp[0]
    if zmp_region == "polygon":
        low = min(state.feet[rear][0], fore_x) - sole.heel + params.zmp_margin - state.zmp[0]
        high = max(state.feet[rear][0], fore_x) + sole.toe - params.zmp_margin - state.zmp[0]
    elif zmp_region != "fore":
        raise ValueError(f"zmp_region must be 'fore' or 'polygon', got {zmp_region!r}")
    rear_ankle = state.feet[rear][0] - state.zmp[0]
    return _DoubleSupportProblem(start, w, params, low, high, rear_ankle), kind, {"fore": fore}


_MARGIN_ROUNDS = 3  # lateral re-aims of a plan whose transition overshoots into the zmp_margin band


def _plan_from(pattern: NominalPattern, state: PatternState, params: StopParameters, signal_time, case,
               zmp_region: str = "fore"):
    w = pattern.w
    sole = pattern.params.sole
    t_solve = time.perf_counter()
    problem, kind, feet, solution = _solve_both_axes(pattern, state, params, zmp_region)
    if kind == "single":  # a sideways deviation: land where the lateral capture point goes (planning/capture.py)
        landing_y = capture_landing_y(pattern, state, solution.landing)
        if landing_y is not None and abs(landing_y - float(state.next_landing[1])) > 1e-9:
            state = replace(state, next_landing=np.array([float(state.next_landing[0]), landing_y]))
            problem, kind, feet, solution = _solve_both_axes(pattern, state, params, zmp_region)
    if kind == "single":
        support, swing = feet["support"], feet["swing"]
        step_length = problem.step_length(solution.target)
        landing_xy = np.array([state.zmp[0] + step_length, state.next_landing[1]])
        final_feet = {support: state.feet[support][:2].copy(), swing: landing_xy}
        fore_xy, fore_side = landing_xy, swing
        landing_foot = swing
    else:
        fore_side = feet["fore"]
        fore_xy = state.feet[fore_side][:2].copy()
        step_length = None
        final_feet = {side: state.feet[side][:2].copy() for side in ("left", "right")}
        landing_xy, landing_foot = None, None
    solve_time = time.perf_counter() - t_solve

    t0 = state.time
    landing_time = t0 + solution.landing
    transition_end = landing_time + solution.transition
    slowdown_end = transition_end + solution.slowdown
    midpoint = 0.5 * (final_feet["left"] + final_feet["right"])
    sagittal_target = state.zmp[0] + solution.target
    polygon = soles_polygon(sole, tuple((s, float(final_feet[s][0]), float(final_feet[s][1]))
                                        for s in ("left", "right")))
    # A transition that starts with the walk's ZMP rate and acceleration (double support) can overshoot its
    # lateral target: aim further inside until the whole plan keeps zmp_margin (or the start's own margin,
    # if the walk's ZMP at the signal is already closer to an edge).
    required = None
    lateral_margin = params.zmp_margin
    for _ in range(_MARGIN_ROUNDS):
        lateral_target = _lateral_target(state, solution, fore_xy, fore_side, kind, w, sole, lateral_margin,
                                         polygon if zmp_region == "polygon" else None, sagittal_target)
        targets = (sagittal_target, lateral_target)
        segs = _zmp_segments(state, solution, targets, kind)
        # COG state at the slowdown end, per axis (the last ZMP segment is constant at the target)
        ends = [lipm.chain_end_state(d, c, float(state.com[a]), float(state.com_vel[a]), w) + (float(targets[a]),)
                for a, (d, c) in enumerate(segs)]
        halt_durations, halt_coeffs, margin = _choose_halt(ends, midpoint, polygon, params, w)
        if margin < params.zmp_margin - 1e-9:
            raise InfeasibleStop(f"halt ZMP keeps at most {margin * 1e3:.1f} mm from the support polygon's edge "
                                 f"for every halt duration (zmp_margin {params.zmp_margin * 1e3:.1f} mm, "
                                 f"halt_durations up to {max(params.halt_durations)} s)")
        halt = sum(halt_durations)
        x_traj, y_traj = (
            lipm.LipmTrajectory.from_zmp(t0, list(d) + halt_durations + [1.0],
                                         list(c) + list(hc) + [lipm.pad([midpoint[a]])],
                                         state.com[a], state.com_vel[a], w, rest_tail=True)
            for a, ((d, c), hc) in enumerate(zip(segs, halt_coeffs)))
        plan = StopPlan(
            signal_time=signal_time, start_time=t0, case=case, support=pattern.support_at(signal_time)[0],
            start_support=kind, landing_time=landing_time, transition_end=transition_end,
            slowdown_end=slowdown_end, halt_end=slowdown_end + halt,
            step_length=step_length if kind == "single" else None,
            zmp_max=solution.target if kind == "double" else None,
            landing_foot=landing_foot, landing_position=landing_xy, final_feet=final_feet,
            x=x_traj, y=y_traj, pattern=pattern, params=params, start_state=state,
            newton_iterations=solution.iterations, solve_time=solve_time, cost=solution.cost,
            continuous_solution=solution.continuous,
        )
        if landing_foot is not None:
            plan.swing_start = {"pos": state.feet[landing_foot], "vel": state.feet_vel[landing_foot],
                                "acc": state.feet_acc[landing_foot]}
        span = slowdown_end - t0
        plan.upper_body_peak = state.upper_body + state.upper_body_rate * span / 3.0  # eq. 33
        plan.min_zmp_margin = _verify_zmp(plan, final_polygon=polygon)
        if required is None:
            start_zmp = np.array([[plan.x.evaluate_at(t0)[3], plan.y.evaluate_at(t0)[3]]])
            required = min(params.zmp_margin, float(_support_polygon(plan).margin(start_zmp)[0]))
        deficit = required - plan.min_zmp_margin
        if deficit <= 1e-9:
            return plan
        lateral_margin += deficit + 5e-4
    raise InfeasibleStop(f"zmp_margin: the planned ZMP comes {plan.min_zmp_margin * 1e3:.1f} mm from the support "
                         f"polygon's edge (zmp_margin {params.zmp_margin * 1e3:.1f} mm)")


def _verify_zmp(plan: StopPlan, final_polygon: SupportPolygon | None = None) -> float:
    """Smallest ZMP margin to the support polygon over every servo tick of the stop.

    ``final_polygon``: the polygon of both feet at their final positions, if the
    caller has it (else built by :meth:`StopPlan.polygon`).
    """
    dt = plan.params.servo_period
    ticks = plan.start_time + dt * np.arange(int(round((plan.halt_end - plan.start_time) / dt)) + 1)
    zmp = np.stack([_zmp_at(plan.x, ticks), _zmp_at(plan.y, ticks)], axis=1)  # ticks >= start: no nominal part
    worst = np.inf
    split = int(np.searchsorted(ticks, plan.landing_time, side="left"))  # ticks before the landing
    if split > 0:
        worst = min(worst, float(_support_polygon(plan).margin(zmp[:split]).min()))
    if split < len(ticks):
        polygon = final_polygon if final_polygon is not None else plan.polygon(plan.halt_end)
        worst = min(worst, float(polygon.margin(zmp[split:]).min()))
    return worst


def _support_polygon(plan: StopPlan) -> SupportPolygon:
    """:meth:`StopPlan.polygon` at the plan start: before the landing only the support sole."""
    if plan.landing_foot is None:
        return plan.polygon(plan.start_time)
    side = next(s for s in plan.final_feet if s != plan.landing_foot)
    xy = plan.final_feet[side]
    return soles_polygon(plan.pattern.params.sole, ((side, float(xy[0]), float(xy[1])),))


def _zmp_at(traj: lipm.LipmTrajectory, times: np.ndarray) -> np.ndarray:
    """ZMP of a trajectory at sorted times (the ZMP part of :meth:`LipmTrajectory.evaluate`)."""
    k = np.clip(np.searchsorted(traj.breaks, times, side="right") - 1, 0, len(traj.zmp) - 1)
    tau = times - traj.breaks[k]
    coeffs = traj.zmp[k]
    value = coeffs[:, -1].copy()
    for i in range(lipm.N_COEFFS - 2, -1, -1):  # Horner, vectorised over the ticks
        value *= tau
        value += coeffs[:, i]
    return value


def _trivial_plan(pattern, state, params, signal_time, case):
    """Standing still: hold the current state. Final shift: the nominal walk already stops."""
    end = state.time if case == "standing" else pattern.end_time
    feet = pattern.feet_at(end)[0]
    axes = (None, None)
    if case == "standing":
        axes = tuple(lipm.LipmTrajectory.from_zmp(end, [1.0], [lipm.pad([state.com[a]])], state.com[a], 0.0,
                                                  pattern.w, rest_tail=True) for a in (0, 1))
    return StopPlan(
        signal_time=signal_time, start_time=end, case=case, support=pattern.support_at(signal_time)[0],
        start_support="standing", landing_time=end, transition_end=end, slowdown_end=end, halt_end=end,
        step_length=None, zmp_max=None, landing_foot=None, landing_position=None,
        final_feet={k: v[:2].copy() for k, v in feet.items()}, x=axes[0], y=axes[1], pattern=pattern,
        params=params, start_state=state, cost=0.0,
    )


def warm_up(pattern: NominalPattern, params: StopParameters | None = None) -> float:
    """Plan once (single and double support) so the compiled solver is loaded before the
    robot walks: the first call in a process loads numba's cache (~0.3 s; ~17 s to
    compile after an install), which must not land on the servo tick of a real stop.
    Returns the seconds it took."""
    wall = time.perf_counter()
    start, end = pattern.stride()
    for fraction in (0.3, 0.9):
        try:
            plan_stop(pattern, start + fraction * (end - start), params)
        except InfeasibleStop:
            pass
    return time.perf_counter() - wall


def snap_to_tick(t: float, servo_period: float) -> float:
    """The servo tick at or after ``t`` (the stop is sampled by the servo loop)."""
    return math.ceil(t / servo_period - 1e-9) * servo_period


def plan_stop(pattern: NominalPattern, signal_time: float, params: StopParameters | None = None, *,
              measured=None) -> StopPlan:
    """Plan the stop for a signal at ``signal_time`` (snapped to the next servo tick).

    Parameters
    ----------
    pattern : NominalPattern
        The walk the stop interrupts.
    signal_time : float
        Time of the stop signal [s] on the pattern's clock.
    params : StopParameters, optional
        Weights and limits (default: the paper's).
    measured : tuple of array_like, optional
        ``(com_xy [m], com_vel_xy [m/s])`` of the robot at that tick (a state
        estimate); the plan then starts from it, so the continuity conditions
        (eq. 10-11) hold against what the robot is doing, with the ZMP
        continuous with the pattern's (eq. 12-13). A next-step fallback
        (III.C) starts at a later tick from the pattern's state there plus
        the measured deviation propagated by the LIPM.

    Returns
    -------
    StopPlan
        The four-phase stop; the COG ends at rest between the feet.

    Raises
    ------
    InfeasibleStop
        If no stop within two steps meets the limits (names the limit).
    ValueError
        If ``signal_time`` or ``measured`` is not finite.
    """
    params = params or StopParameters()
    if measured is not None:
        measured = tuple(np.asarray(m, float)[:2] for m in measured)
        if len(measured) != 2 or not all(np.all(np.isfinite(m)) for m in measured):
            raise ValueError(f"measured must be finite (com_xy, com_vel_xy), got {measured!r}")
    if not math.isfinite(signal_time):
        raise ValueError(f"estop_time must be finite, got {signal_time!r}")
    wall = time.perf_counter()
    dt = params.servo_period
    t0 = snap_to_tick(signal_time, dt)
    t = t0
    case = "one-step"
    horizon = t0 + 2.0 * pattern.params.step_time
    reasons = []
    while t <= horizon:
        support, index, _ = pattern.support_at(t)
        state = pattern.state(t)
        if measured is not None:
            state = _with_deviation(state, pattern, t0, measured)
        if support == "standing" and t == t0:
            return _finish(_trivial_plan(pattern, state, params, t0, "standing"), wall)
        if support == "standing" or index >= len(pattern.steps):
            return _finish(_trivial_plan(pattern, state, params, t0, "already-stopping"), wall)
        if support == "single" and params.landing == "nominal":
            # "finish the step": land where and when the pattern would, stop on that foothold
            t = max(snap_to_tick(pattern.steps[index]["touchdown"], dt), t + dt)
            continue
        try:
            return _finish(_plan_from(pattern, state, params, t0, case), wall)
        except InfeasibleStop as error:
            reasons.append(str(error))
            t = _next_try(pattern, t, dt, support, index, first=case == "one-step")
            case = "next-step"
    detail = f"; at the signal: {reasons[0]}; last try: {reasons[-1]}" if reasons else ""
    raise InfeasibleStop(f"no feasible stop within two steps of t={t0:.3f} s{detail}")


def _with_deviation(state: PatternState, pattern: NominalPattern, t0: float, measured) -> PatternState:
    """``state`` (the pattern's at ``state.time`` >= ``t0``) with the COG moved by the measured deviation
    at ``t0``, propagated under the pattern's ZMP: the LIPM is linear, so the deviation evolves on its
    own (eq. 6, 9 with a zero ZMP): ``d(t) = d0 cosh(w s) + d0' / w sinh(w s)``."""
    pos, vel, _, _ = pattern.com([t0])
    d0, v0 = measured[0] - pos[0], measured[1] - vel[0]
    w, s = pattern.w, state.time - t0
    ch, sh = math.cosh(w * s), math.sinh(w * s)
    return replace(state, com=state.com + d0 * ch + v0 / w * sh, com_vel=state.com_vel + d0 * w * sh + v0 * ch)


def replan_stop(plan: StopPlan, t: float, com_xy, com_vel_xy) -> StopPlan | None:
    """Re-plan a stop at tick ``t`` from the measured COG (e.g. after a push).

    The new plan starts at ``t`` from the current plan's ZMP (value, rate and
    acceleration: eq. 12-13) and feet, and from the measured COG position and
    velocity (eq. 10-11):

    * landing phase, while the landing can still move (before
      ``landing_time - min_landing_time``): landing time, step length and the
      later phases are solved again (III.A, eq. 21-26);
    * after the landing, in the ZMP transition or the slowdown: the stop is
      solved again as a double-support stop on the landed feet (III.B,
      eq. 29-31).

    Returns None where nothing is left to re-plan (the halt, a plan that has
    not started yet, a standing plan). Raises :class:`InfeasibleStop` when no
    stop exists from that state.
    """
    params = plan.params
    if plan.x is None or t < plan.start_time:
        return None
    single = plan.landing_foot is not None and t < plan.landing_time - params.min_landing_time
    double = plan.landing_time <= t < plan.slowdown_end
    if not (single or double):
        return None
    h = 1e-3
    axes = [traj.evaluate_at(float(t)) for traj in (plan.x, plan.y)]
    zmp, rate, accel = (np.array([a[i] for a in axes]) for i in (3, 4, 5))
    before, now, after = plan.feet(t - h), plan.feet(t), plan.feet(t + h)
    if t - h < plan.start_time:  # the plan's own swing start (continuous with what it started from)
        before = {side: now[side] - h * plan.start_state.feet_vel[side] for side in now}
    feet_vel = {side: (after[side] - before[side]) / (2 * h) for side in now}
    feet_acc = {side: (after[side] - 2 * now[side] + before[side]) / h**2 for side in now}
    upper, upper_rate = plan.upper_body(t)
    changes = dict(time=float(t), com=np.asarray(com_xy, float)[:2].copy(),
                   com_vel=np.asarray(com_vel_xy, float)[:2].copy(), zmp=zmp, zmp_rate=rate, zmp_accel=accel,
                   feet=now, feet_vel=feet_vel, feet_acc=feet_acc, upper_body=upper, upper_body_rate=upper_rate)
    if double:
        rear = (next(s for s in now if s != plan.landing_foot) if plan.landing_foot is not None
                else plan.start_state.rear_foot)
        changes.update(support="double", support_foot=None, next_landing=None, rear_foot=rear)
    wall = time.perf_counter()
    new = _plan_from(plan.pattern, replace(plan.start_state, **changes), params, plan.signal_time, plan.case,
                     zmp_region="polygon" if double else "fore")
    new.crouch_window = plan.crouch_window or (plan.start_time, plan.halt_end)
    return _finish(new, wall)


def _next_try(pattern, t, dt, support, index, first):
    """Marginal case (III.C): after the signal's own phase fails, jump to the
    next support phase, then advance tick by tick."""
    if not first:
        return t + dt
    step = pattern.steps[index]
    boundary = step["touchdown"] if support == "single" else step["liftoff"]
    return max(snap_to_tick(boundary, dt), t + dt)


def _finish(plan: StopPlan, wall_start: float) -> StopPlan:
    plan.compute_time = time.perf_counter() - wall_start
    return plan
