"""The four-phase emergency-stop planner (paper Sections II-IV).

``plan_stop(pattern, signal_time, params)`` returns a :class:`StopPlan` that
starts from the nominal pattern's state at the servo tick of the signal and
brings the COG to rest, exactly, at the midpoint between the feet:

* single support (III.A): landing time, transition end and slowdown end from
  J_ss (eq. 24) by a barrier Newton method (eq. 25-26, :mod:`drake_estop.planning.solver`);
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

Modules: :mod:`~drake_estop.planning.plan` (parameters, the plan), :mod:`~drake_estop.planning.problems`
(the phase-parameter problems), :mod:`~drake_estop.planning.solver` (their solver, on
:mod:`~drake_estop.planning.stop_condition` and :mod:`~drake_estop.planning.newton`),
:mod:`~drake_estop.planning.halt` (eq. 27-28), :mod:`~drake_estop.planning.assembly` (the stop
from one state: the signal's support phase, the lateral plane), :mod:`~drake_estop.planning.landing`
(the landing's limits), :mod:`~drake_estop.planning.zmp_check` (the ZMP margin check),
:mod:`~drake_estop.planning.replan` (re-plans from a measured state); this one searches: the
signal's tick, then the marginal case.
"""

from __future__ import annotations

import math
import time
from dataclasses import replace

import numpy as np

from drake_estop.planning import lipm
from drake_estop.planning.assembly import plan_from, stop_problem, with_compute_time
from drake_estop.planning.gait import NominalPattern, PatternState
from drake_estop.planning.halt import prepare_halts
from drake_estop.planning.plan import PHASES, InfeasibleStop, StopParameters, StopPlan, snap_to_tick
from drake_estop.planning.replan import check_solve_bound, replan_stop
from drake_estop.planning.solver import infeasible_reason

__all__ = [  # the planner's interface: the stop's entry points and the plan types they take and return
    "MAX_LATCH_SOLVES", "PHASES", "InfeasibleStop", "StopParameters", "StopPlan", "first_stop", "one_step_feasible",
    "plan_stop", "replan_stop", "snap_to_tick", "warm_up",
]


def _trivial_plan(pattern, state, params, signal_time, case):
    """Standing still: hold the current state. Final shift: the nominal walk already stops."""
    end = state.time if case == "standing" else pattern.end_time
    feet = pattern.feet_at(end)[0]
    yaw = pattern.feet_yaw_at(end)[0]
    axes = (None, None)
    if case == "standing":
        axes = tuple(lipm.LipmTrajectory.from_zmp(end, [1.0], [lipm.pad([state.com[a]])], state.com[a], 0.0,
                                                  pattern.w, rest_tail=True) for a in (0, 1))
    return StopPlan(
        signal_time=signal_time, start_time=end, case=case, support=pattern.support_at(signal_time)[0],
        start_support="standing", landing_time=end, transition_end=end, slowdown_end=end, halt_end=end,
        step_length=None, zmp_max=None, landing_foot=None, landing_position=None,
        final_feet={k: v[:2].copy() for k, v in feet.items()}, x=axes[0], y=axes[1], pattern=pattern,
        params=params, start_state=state, cost=0.0, final_yaw=dict(yaw),
    )


def warm_up(pattern: NominalPattern, params: StopParameters | None = None) -> float:
    """Plan once (lift-off, mid and late single support, double support), name the limits of an
    infeasible attempt once and compute every halt duration's basis, so the compiled solver is loaded
    and the caches are filled before the robot walks: the first call in a process loads numba's cache
    (~0.5 s; 20-30 s to compile after an install or an edit of the solver), which must not land on the
    servo tick of a real stop. The time objective (planning/brake.py) falls back to the compiled solver
    where its own search finds no stop, so it is warmed up too. Returns the seconds it took."""
    wall = time.perf_counter()
    start, end = pattern.stride()
    params = params or StopParameters()
    prepare_halts(pattern.w, params)  # every halt duration's basis, not only those of the plans below
    for variant in (params, replace(params, objective="paper")) if params.objective != "paper" else (params,):
        # lift-off (the lateral rounds' own functions), mid single support, its last ticks (where the
        # marginal case's tries run) and double support
        for fraction in (0.0, 0.3, 0.79, 0.9):
            try:
                plan_stop(pattern, start + fraction * (end - start), variant)
            except InfeasibleStop:
                pass
    # the message of a failed attempt names its limits by a scan of its own (loaded once here)
    try:
        problem, kind, _ = stop_problem(pattern, pattern.state(start), replace(params, max_step_length=1e-3,
                                                                               min_step_length=0.0))
        infeasible_reason(problem, kind)
    except (InfeasibleStop, ValueError):
        pass
    return time.perf_counter() - wall


def plan_stop(pattern: NominalPattern, signal_time: float, params: StopParameters | None = None, *,
              measured=None, max_solves: int | None = None) -> StopPlan:
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
    max_solves : int, optional
        Most stop solves of the search (default None: every tick of the
        next two steps, up to a few hundred where no stop exists). A
        real-time caller bounds its tick's work with it; the search then
        raises :class:`InfeasibleStop` once that many tries found no stop.

    Returns
    -------
    StopPlan
        The four-phase stop; the COG ends at rest between the feet.

    Raises
    ------
    InfeasibleStop
        If no stop within two steps (or ``max_solves`` tries) meets the
        limits (names the limit).
    ValueError
        If ``signal_time`` or ``measured`` is not finite, or ``max_solves``
        is not a positive integer.
    """
    return _search(pattern, signal_time, params, measured, first_only=False,
                   max_solves=check_solve_bound(max_solves))


def one_step_feasible(pattern: NominalPattern, signal_time: float, params: StopParameters | None = None, *,
                      measured=None) -> bool:
    """Whether a stop signal at ``signal_time`` would stop within one step.

    The answer is ``plan_stop(pattern, signal_time, params,
    measured=measured).case == "one-step"``: this runs :func:`plan_stop`'s own
    search and ends it at its first attempt (the signal tick's support phase,
    III.A or III.B), so it agrees with the planner by construction and costs
    that one attempt (a failed attempt skips the marginal case's later tries,
    III.C).

    Parameters
    ----------
    pattern : NominalPattern
        The walk the stop would interrupt.
    signal_time : float
        Time of the stop signal [s] on the pattern's clock (snapped to the next
        servo tick, as by :func:`plan_stop`).
    params : StopParameters, optional
        Weights and limits (default: the paper's).
    measured : tuple of array_like, optional
        ``(com_xy [m], com_vel_xy [m/s])`` to plan from, as for :func:`plan_stop`.

    Returns
    -------
    bool
        True for a "one-step" stop; False for "next-step" (III.C),
        "standing", "already-stopping" and where no stop exists at all.

    Raises
    ------
    ValueError
        If ``signal_time`` or ``measured`` is not finite (as :func:`plan_stop`).
    """
    plan = first_stop(pattern, signal_time, params, measured=measured)
    return plan is not None and plan.case == "one-step"


def first_stop(pattern: NominalPattern, signal_time: float, params: StopParameters | None = None, *,
               measured=None) -> StopPlan | None:
    """:func:`plan_stop`'s plan where its search ends at its first attempt (the signal tick's support
    phase, III.A or III.B, or a standing walk), else None (the search would go on to the next phase,
    III.C). The same arguments and errors as :func:`plan_stop`; where it returns a plan, :func:`plan_stop`
    returns the same plan."""
    return _search(pattern, signal_time, params, measured, first_only=True)


def _search(pattern, signal_time, params, measured, first_only, max_solves=None):
    """:func:`plan_stop`; with ``first_only``, None instead of trying past the first failed attempt; at
    most ``max_solves`` tries (None: no bound)."""
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
    while t <= horizon and (max_solves is None or len(reasons) < max_solves):
        support, index, _ = pattern.support_at(t)
        state = pattern.state(t)
        if measured is not None:
            state = _with_deviation(state, pattern, t0, measured)
        if support == "standing" and t == t0:
            return with_compute_time(_trivial_plan(pattern, state, params, t0, "standing"), wall)
        if support == "standing" or index >= len(pattern.steps):
            return with_compute_time(_trivial_plan(pattern, state, params, t0, "already-stopping"), wall)
        if support == "single" and params.landing == "nominal":
            # "finish the step": land where and when the pattern would, stop on that foothold
            t = max(snap_to_tick(pattern.steps[index]["touchdown"], dt), t + dt)
            continue
        try:
            return with_compute_time(plan_from(pattern, state, params, t0, case), wall)
        except InfeasibleStop as error:
            if first_only:
                return None
            reasons.append(error)  # its message is read only if the search ends without a stop
            t = _next_try(pattern, t, dt, support, index, first=case == "one-step")
            case = "next-step"
    detail = f"; at the signal: {reasons[0]}; last try: {reasons[-1]}" if reasons else ""
    if t <= horizon:  # the bound ended the search
        raise InfeasibleStop(f"no feasible stop in the first {max_solves} tries after t={t0:.3f} s{detail}")
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


#: Stop solves the online controller's latch may spend searching from the measured state (``StopPlannerSystem``'s
#: ``max_latch_solves``; :func:`plan_stop`'s ``max_solves``): the signal's support phase and the first three ticks
#: of the next one (III.C), about 2 ms. Measured (the 153 runs of the 500-run campaign whose push
#: starts before the signal): 4 latched from the measured state; the one that found a stop found it at its first
#: try, the three that found none tried 202-268 times (60-100 ms in that tick) before the reference fallback.
MAX_LATCH_SOLVES = 4


def _next_try(pattern, t, dt, support, index, first):
    """Marginal case (III.C): after the signal's own phase fails, jump to the
    next support phase, then advance tick by tick."""
    if not first:
        return t + dt
    step = pattern.steps[index]
    boundary = step["touchdown"] if support == "single" else step["liftoff"]
    return max(snap_to_tick(boundary, dt), t + dt)
