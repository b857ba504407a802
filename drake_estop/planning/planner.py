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
:mod:`~drake_estop.planning.halt` (eq. 27-28); this one plans: the signal's support phase,
the marginal case, the lateral plane, the ZMP margin check, re-plans.
"""

from __future__ import annotations

import math
import time
from dataclasses import replace

import numpy as np

from drake_estop.planning import lipm
from drake_estop.planning.backend import COMPILED
from drake_estop.planning.brake import held_brake, moving_zmp, stop_brake, swing_brake
from drake_estop.planning.capture import MAX_STEP_WIDTH, MIN_STEP_WIDTH, capture_landing_y
from drake_estop.planning.gait import SIDES, NominalPattern, PatternState, rotation
from drake_estop.planning.geometry import SupportPolygon
from drake_estop.planning.halt import choose_halt, prepare_halts
from drake_estop.planning.heading import solve_turned
from drake_estop.planning.plan import (
    PHASES,
    SWING_GRID,
    InfeasibleStop,
    PhaseSolution,
    StopParameters,
    StopPlan,
    landing_swing,
    snap_to_tick,
    soles_polygon,
)
from drake_estop.planning.problems import DoubleSupportProblem, SingleSupportProblem, descent_time
from drake_estop.planning.solver import infeasible_reason, solve_continuous, solve_phases
from drake_estop.planning.stop_condition import StopStart, slowdown_time, target_zmp

__all__ = [  # the planner's interface, including the names other modules import from here
    "COMPILED", "PHASES", "InfeasibleStop", "PhaseSolution", "StopParameters", "StopPlan", "descent_time",
    "REPLAN_TRIES", "ReplanPending", "check_solve_bound", "landing_swing", "one_step_feasible", "plan_stop",
    "replan_stop", "replan_support", "snap_to_tick", "soles_polygon",
    "solve_continuous", "solve_phases", "stop_problem", "swing_braking_time", "warm_up",
]


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
    solution = solve_phases(problem, kind)
    if zmp_region == "polygon":  # a re-plan: the lateral ZMP may use the polygon's width (_lateral_target)
        return problem, kind, feet, solution
    sole, w = pattern.params.sole, pattern.w
    fore_side = feet["swing"] if kind == "single" else feet["fore"]
    fore_y = float(state.next_landing[1]) if kind == "single" else float(state.feet[fore_side][1])
    left_edge, right_edge = sole.lateral_edges(fore_side)
    low = fore_y - right_edge + params.zmp_margin + _LATERAL_SLACK - float(state.zmp[1])
    high = fore_y + left_edge - params.zmp_margin - _LATERAL_SLACK - float(state.zmp[1])
    rate = float(state.zmp_rate[1]) if kind == "double" else 0.0
    accel = float(state.zmp_accel[1]) if kind == "double" else 0.0
    start = StopStart.from_state(state.com[1], state.com_vel[1], state.zmp[1], w, rate, accel)
    limits = {}
    if kind == "single":
        touchdown = _nominal_touchdown(pattern, state)
        dt = params.servo_period
        nominal_landing = max(snap_to_tick(touchdown - state.time, dt), params.min_landing_time + dt)
    solved = {}  # the limits of the last solve: a round that asks for the same limits again has converged
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
        if limits == solved:  # the same problem again (its floor is its own solution): the same answer
            break
        solved = dict(limits)
        try:
            problem, kind, feet = stop_problem(pattern, state, replace(params, **limits), zmp_region)
            solution = solve_phases(problem, kind)
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
    left_edge, right_edge = sole.lateral_edges(fore_side)
    return float(np.clip(wanted, fore_xy[1] - right_edge + margin, fore_xy[1] + left_edge - margin))


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
        touchdown = _nominal_touchdown(pattern, state)
        params = _lateral_reach(pattern, state, params)
        params = _rear_lateral_reach(pattern, state, params)
        params = _landing_shift_limit(state, params, swing)
        if not -(sole.heel - params.zmp_margin) <= params.landing_zmp_offset <= sole.toe - params.zmp_margin:
            raise ValueError(f"landing_zmp_offset {params.landing_zmp_offset} m puts the ZMP outside the fore sole")
        problem = SingleSupportProblem(start, w, params, float(state.zmp[0]),
                                       state.feet[swing][:2].copy(), float(state.next_landing[1]),
                                       min_landing=_earliest_landing(state, params, swing, touchdown),
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
    return DoubleSupportProblem(start, w, params, low, high, rear_ankle), kind, {"fore": fore}


def _nominal_touchdown(pattern: NominalPattern, state: PatternState) -> float:
    """The swing foot's nominal touchdown [s]: the walk's step's, or a recovery step's own."""
    if state.recovery_touchdown is not None:
        return float(state.recovery_touchdown)
    return float(pattern.steps[state.step_index]["touchdown"])


def _nominal_landing_window(pattern: NominalPattern, state: PatternState, params: StopParameters):
    """``params`` whose ``min_landing_time`` admits the nominal touchdown where that is sooner, in single
    support (None elsewhere): the swing foot lands no later than it would have. Late in single support
    the foot is a few millimetres above the floor and lands by the walk's own timing; the stop still
    moves the landing point (eq. 21-22) instead of finishing the step and stopping in the next support
    phase (III.C). Tried only where the limits as given find no stop: where a landing after
    ``min_landing_time`` stops the robot, the paper's optimum stands (at 3.4 s it postpones the
    touchdown and lengthens the step, Section V.A)."""
    if state.support != "single":
        return None
    dt = params.servo_period
    soonest = max(snap_to_tick(_nominal_touchdown(pattern, state) - state.time, dt), dt)
    if soonest >= params.min_landing_time:
        return None
    return replace(params, min_landing_time=soonest)


def _swing_descent_time(state: PatternState, params: StopParameters, swing: str) -> float:
    """:func:`descent_time` of the ``swing`` foot from its height, vertical velocity and acceleration."""
    return descent_time(float(state.feet[swing][2]), params, float(state.feet_vel[swing][2]),
                        float(state.feet_acc[swing][2]))


def _earliest_landing(state: PatternState, params: StopParameters, swing: str, touchdown: float) -> float:
    """Shortest time to touchdown [s]: the swing foot's descent (:func:`descent_time`), and no
    earlier than ``max_early_landing`` before the nominal touchdown (at most ``max_landing_time``)."""
    descent = _swing_descent_time(state, params, swing)
    early = touchdown - state.time - params.max_early_landing
    return max(descent, min(early, params.max_landing_time - params.servo_period))


#: The least landing shift :func:`_landing_shift_limit` allows [m] (a foot already on the floor keeps
#: its landing to the millimetre; the step-length bounds must stay an interval).
MIN_LANDING_SHIFT = 1e-3


def _landing_shift_limit(state: PatternState, params: StopParameters, swing: str) -> StopParameters:
    """``params`` with the step-length bounds narrowed to the nominal step length +- the swing foot's
    height times ``max_landing_shift_per_height``, for a swing foot coming down (unchanged when that
    is inf, and for a foot still rising: a foot leaving the floor gets a clearance bump instead,
    :func:`drake_estop.planning.plan.landing_swing`)."""
    if not math.isfinite(params.max_landing_shift_per_height) or state.feet_vel[swing][2] >= -1e-9:
        return params
    shift = max(float(state.feet[swing][2]) * params.max_landing_shift_per_height, MIN_LANDING_SHIFT)
    nominal = float(state.next_landing[0] - state.zmp[0])
    low, high = max(params.min_step_length, nominal - shift), min(params.max_step_length, nominal + shift)
    if low >= high:  # the nominal step outside the planner's own bounds: those bounds decide
        return params
    return replace(params, min_step_length=low, max_step_length=high)


LATERAL_REACH_ALLOWANCE = 0.02  # [m] lateral COG-to-landing-ankle offset beyond step_width / 2 that
# max_fore_reach already covers: on the straight walk the COG passes 0.110-0.115 m beside the landing
# ankle at touchdown (step width 0.19 m), where max_fore_reach was measured. With 0.03 the outer knee of a
# +15 deg/step turn, landing as soon as the descent limit allows, reached 6.3 rad/s (limit 6)


def _lateral_reach(pattern, state: PatternState, params: StopParameters) -> StopParameters:
    """``params`` with ``max_fore_reach`` shortened where the landing ankle lies further to the side of
    the COG at the nominal touchdown than on the straight walk (the outer foot of a turn, a side-step,
    a slow gait's wider sway): the horizontal COG-to-ankle distance ``hypot(dx, dy)`` then stays within
    the straight walk's ``hypot(max_fore_reach, step_width / 2 + LATERAL_REACH_ALLOWANCE)``, which keeps
    the landing knee bent (at +15 deg per step the outer knee otherwise reached 14 rad/s, limit 6).
    Measured on the walk's nominal footstep and COG: a capture-point landing (planning/capture.py)
    moves the foot by the COG's own deviation, which leaves their lateral offset as it was."""
    if state.recovery_touchdown is not None:  # no walk footstep: the step is aimed from the measured DCM
        return params
    # the walk's own footstep: a capture-point shift follows the COG
    lateral = abs(float(pattern.touchdown_com_offset(state.step_index)[1]))
    allowed = 0.5 * pattern.params.step_width + LATERAL_REACH_ALLOWANCE
    if lateral <= allowed:
        return params
    return replace(params, max_fore_reach=_sideways_reach(params.max_fore_reach, allowed, lateral))


def _sideways_reach(reach: float, allowed: float, lateral: float) -> float:
    """The sagittal reach [m] that keeps ``hypot(reach, allowed)`` with the ankle ``lateral`` [m] to the
    side of the COG instead of ``allowed`` (at least half of ``reach``)."""
    return math.sqrt(max(reach**2 + allowed**2 - lateral**2, 0.25 * reach**2))


def _rear_lateral_reach(pattern, state: PatternState, params: StopParameters) -> StopParameters:
    """``params`` with ``max_rear_reach`` shortened where the walk's own footstep leaves the feet further
    apart sideways than on the straight walk (in the stop's frame: the outer foot of a turn): the COG
    comes to rest between them, so the horizontal COG-to-rear-ankle distance ``hypot(dx, separation / 2)``
    then stays within the straight walk's ``hypot(max_rear_reach, step_width / 2)``. Measured on a
    +15 deg/step turn (feet 0.226 m apart in the stop's frame, 0.19 m on the straight walk): with the full
    sagittal reach the rear knee straightened in the slowdown and the IK drove it at 10.8 rad/s (limit 6).
    The walk's footstep, not a capture-point landing (planning/capture.py): a sideways push that widens the
    step moves the COG with it, and its stops keep the full reach."""
    if state.recovery_touchdown is not None:  # no walk footstep: the step is aimed from the measured DCM
        return params
    separation = float(pattern.steps[state.step_index]["end"][1]) - float(state.feet[state.support_foot][1])
    lateral = 0.5 * abs(separation)
    allowed = 0.5 * pattern.params.step_width
    if lateral <= allowed + 1e-9:
        return params
    return replace(params, max_rear_reach=_sideways_reach(params.max_rear_reach, allowed, lateral))


_MARGIN_ROUNDS = 3  # lateral re-aims of a plan whose transition overshoots into the zmp_margin band


def _plan_from(pattern: NominalPattern, state: PatternState, params: StopParameters, signal_time, case,
               zmp_region: str = "fore"):
    """The stop from ``state``, solved in the heading frame of the foot that carries it
    (:mod:`drake_estop.planning.heading`; the world frame on a straight walk). Where the limits as given
    find no stop, in single support it tries again with the landing also allowed at the nominal touchdown
    where that is sooner than ``min_landing_time`` (:func:`_nominal_landing_window`), then with the slowdown
    ZMP at the landing ankle (the paper's eq. 20, where ``landing_zmp_offset`` is not 0: a walk stepping in
    place has no forward speed for a ZMP ahead of the ankle to stop), without and with that window."""
    def plan(limits):
        return solve_turned(lambda view, local: _plan_local(view, local, limits, signal_time, case, zmp_region),
                            pattern, state)

    try:
        return plan(params)
    except InfeasibleStop as error:
        failure = error
    for limits in _retry_limits(pattern, state, params):
        try:
            found = plan(limits)
        except InfeasibleStop:
            continue
        found.params = params  # the plan's own limits (a re-plan treats it as any other landing)
        return found
    raise failure


def _retry_limits(pattern: NominalPattern, state: PatternState, params: StopParameters):
    """The limits :func:`_plan_from` tries, in order, after the given ones found no stop (single support)."""
    if state.support != "single":
        return
    window = _nominal_landing_window(pattern, state, params)
    if window is not None:
        yield window
    if params.landing_zmp_offset != 0.0:
        yield replace(params, landing_zmp_offset=0.0)
        if window is not None:
            yield replace(window, landing_zmp_offset=0.0)


def _plan_local(pattern: NominalPattern, state: PatternState, params: StopParameters, signal_time, case,
                zmp_region: str = "fore"):
    w = pattern.w
    sole = pattern.params.sole
    t_solve = time.perf_counter()
    if params.objective == "time":  # the soonest rest (planning/brake.py); else the paper's landing below
        plan = _time_plan(pattern, state, params, signal_time, case, t_solve)
        if plan is not None:
            return plan
        if state.support == "single" and moving_zmp(state.zmp_rate, state.zmp_accel):
            # a re-plan while the ZMP moves on the support sole: the paper's landing holds it (eq. 19)
            raise InfeasibleStop("objective time: no stop from the ZMP moving on the support sole")
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
        final_yaw = {support: float(state.feet_yaw[support]), swing: float(state.next_landing_yaw)}
        fore_xy, fore_side = landing_xy, swing
        landing_foot = swing
    else:
        fore_side = feet["fore"]
        fore_xy = state.feet[fore_side][:2].copy()
        step_length = None
        final_feet = {side: state.feet[side][:2].copy() for side in ("left", "right")}
        final_yaw = {side: float(state.feet_yaw[side]) for side in ("left", "right")}
        landing_xy, landing_foot = None, None
    if params.objective == "time" and kind == "single":  # the paper's landing, then the brake
        plan = _time_plan(pattern, state, params, signal_time, case, t_solve,
                          (step_length, solution.landing, solution.iterations, solution.continuous))
        if plan is not None:
            return plan
    solve_time = time.perf_counter() - t_solve

    t0 = state.time
    landing_time = t0 + solution.landing
    transition_end = landing_time + solution.transition
    slowdown_end = transition_end + solution.slowdown
    midpoint = 0.5 * (final_feet["left"] + final_feet["right"])
    sagittal_target = state.zmp[0] + solution.target
    polygon = soles_polygon(sole, tuple((s, float(final_feet[s][0]), float(final_feet[s][1]), final_yaw[s])
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
        halt_durations, halt_coeffs, margin = choose_halt(ends, midpoint, polygon, params, w)
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
            continuous_solution=solution.continuous, final_yaw=final_yaw,
        )
        if landing_foot is not None:
            plan.swing_start = {"pos": state.feet[landing_foot], "vel": state.feet_vel[landing_foot],
                                "acc": state.feet_acc[landing_foot]}
        span = slowdown_end - t0
        plan.upper_body_peak = state.upper_body + state.upper_body_rate * span / 3.0  # eq. 33
        plan.min_zmp_margin = _verify_zmp(plan, final_polygon=polygon)
        if not math.isfinite(plan.min_zmp_margin):  # guard: never hand out a plan with a NaN ZMP
            raise InfeasibleStop("the planned ZMP is not finite")
        if required is None:
            start_zmp = np.array([[plan.x.evaluate_at(t0)[3], plan.y.evaluate_at(t0)[3]]])
            required = min(params.zmp_margin, float(_support_polygon(plan).margin(start_zmp)[0]))
        deficit = required - plan.min_zmp_margin
        if deficit <= 1e-9:
            return plan
        lateral_margin += deficit + 5e-4
    raise InfeasibleStop(f"zmp_margin: the planned ZMP comes {plan.min_zmp_margin * 1e3:.1f} mm from the support "
                         f"polygon's edge (zmp_margin {params.zmp_margin * 1e3:.1f} mm)")


def _time_plan(pattern, state, params, signal_time, case, t_solve, paper_landing=None):
    """The time objective's plan (:mod:`drake_estop.planning.brake`): the soonest rest at the feet's
    midpoint with the ZMP ``zmp_margin`` inside the support polygon. Double support: from ``state``.
    Single support: over the landing choices, or at the paper's ``paper_landing`` = ``(step length,
    touchdown from the start, Newton iterations, continuous solution)`` if given. None where no
    brake fits (the caller falls back)."""
    w = pattern.w
    sole = pattern.params.sole
    zmp = np.asarray(state.zmp[:2], float)
    single = state.support == "single"
    if not single:
        feet = {side: state.feet[side][:2].copy() for side in ("left", "right")}
        yaw = {side: float(state.feet_yaw[side]) for side in ("left", "right")}
        polygon = soles_polygon(sole, tuple((s, float(feet[s][0]), float(feet[s][1]), yaw[s]) for s in feet))
        required = min(params.zmp_margin, float(polygon.margin(zmp)[0]))  # or the walk's own margin at the start
        found = stop_brake(state.com, state.com_vel, zmp, state.zmp_rate, state.zmp_accel,
                           [0.5 * (feet["left"] + feet["right"])], [polygon], params, w, required)
        return None if found is None else _brake_plan(pattern, state, params, signal_time, case, t_solve,
                                                      found[1], feet, yaw, None, polygon, required)
    support = state.support_foot
    swing = "right" if support == "left" else "left"
    yaw = {support: float(state.feet_yaw[support]), swing: float(state.next_landing_yaw)}
    ankle = (support, float(state.feet[support][0]), float(state.feet[support][1]), yaw[support])
    support_polygon = soles_polygon(sole, (ankle,))

    def polygon_for(landing_xy):
        landed = (swing, float(landing_xy[0]), float(landing_xy[1]), yaw[swing])
        return soles_polygon(sole, (ankle, landed) if support == "left" else (landed, ankle))

    required = min(params.zmp_margin, float(support_polygon.margin(zmp)[0]))
    landing_y = float(state.next_landing[1])
    if paper_landing is not None:  # (the paper's solve moved next_landing already if the capture point asked)
        if moving_zmp(state.zmp_rate, state.zmp_accel):
            return None  # the paper's landing phase holds the ZMP (eq. 19): not from a moving one
        landing = np.array([float(zmp[0]) + paper_landing[0], landing_y])
        brake = held_brake(state.com, state.com_vel, zmp, state.feet[support][:2], landing, paper_landing[1],
                           polygon_for(landing), params, w, required)
    else:
        descent = _swing_descent_time(state, params, swing)

        def search(y):
            return swing_brake(state.com, state.com_vel, zmp, state.zmp_rate, state.zmp_accel, state.feet[support][:2],
                               state.feet[swing][:2], y, descent, support_polygon, polygon_for, params, w, required)

        brake = search(landing_y)
        if brake is not None:  # a sideways deviation: land where the lateral capture point goes (planning/capture.py)
            shifted = capture_landing_y(pattern, state, brake.ends[0])
            if shifted is not None and abs(shifted - landing_y) > 1e-9:
                landing_y, brake = shifted, search(shifted)
    if brake is None:
        return None
    landing_xy = np.array([brake.landing_x, landing_y])
    feet = {support: state.feet[support][:2].copy(), swing: landing_xy}
    plan = _brake_plan(pattern, state, params, signal_time, case, t_solve, brake, feet, yaw, swing,
                       polygon_for(landing_xy), required)
    if paper_landing is not None:  # the landing came from the paper's solve (III.A)
        plan.newton_iterations, plan.continuous_solution = paper_landing[2], paper_landing[3]
    return plan


def _brake_plan(pattern, state, params, signal_time, case, t_solve, brake, final_feet, final_yaw, landing_foot,
                polygon, required):
    """The :class:`StopPlan` of a :class:`~drake_estop.planning.brake.Brake` from ``state``."""
    w = pattern.w
    t0 = state.time
    solve_time = time.perf_counter() - t_solve
    midpoint = 0.5 * (final_feet["left"] + final_feet["right"])
    x_traj, y_traj = (
        lipm.LipmTrajectory.from_zmp(t0, brake.durations + [1.0], brake.coeffs[a] + [lipm.pad([midpoint[a]])],
                                     state.com[a], state.com_vel[a], w, rest_tail=True)  # at rest: eq. 27-28
        for a in (0, 1))
    landing, transition, slowdown, halt = (t0 + e for e in brake.ends)
    single = landing_foot is not None
    plan = StopPlan(
        signal_time=signal_time, start_time=t0, case=case, support=pattern.support_at(signal_time)[0],
        start_support=state.support, landing_time=landing, transition_end=transition, slowdown_end=slowdown,
        halt_end=halt, step_length=brake.landing_x - float(state.zmp[0]) if single else None,
        zmp_max=None,
        landing_foot=landing_foot, landing_position=final_feet[landing_foot] if single else None,
        final_feet=final_feet, x=x_traj, y=y_traj, pattern=pattern, params=params, start_state=state,
        solve_time=solve_time, cost=brake.duration,  # the time objective: time to rest from the plan start
        final_yaw=final_yaw,
    )
    if single:
        plan.swing_start = {"pos": state.feet[landing_foot], "vel": state.feet_vel[landing_foot],
                            "acc": state.feet_acc[landing_foot]}
    plan.upper_body_peak = state.upper_body + state.upper_body_rate * (slowdown - t0) / 3.0  # eq. 33
    if not single:  # ZMP_max: the largest sagittal ZMP displacement from the start (eq. 29's role)
        plan.zmp_max = brake.peak - float(state.zmp[0])
    plan.min_zmp_margin = _verify_zmp(plan, final_polygon=polygon)
    if not plan.min_zmp_margin >= required - 1e-9:  # NaN too: never hand out such a plan
        raise InfeasibleStop(f"zmp_margin: the brake's ZMP comes {plan.min_zmp_margin * 1e3:.1f} mm from the "
                             f"support polygon's edge (zmp_margin {params.zmp_margin * 1e3:.1f} mm)")
    return plan


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
    return soles_polygon(plan.pattern.params.sole, ((side, float(xy[0]), float(xy[1]), plan.final_yaw[side]),))


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
    plan = _search(pattern, signal_time, params, measured, first_only=True)
    return plan is not None and plan.case == "one-step"


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


#: A re-plan's tries, in order, by the support it starts in: single support (III.A) holds the plan's ZMP,
#: then the ankle strategy's stance ZMP, its lateral part alone, its sagittal part alone; double support
#: (III.B) holds the plan's ZMP, then takes the recovery step. ``replan_stop(first_try=k)`` starts at the k-th.
REPLAN_TRIES = {"single": ("held", "ankle", "ankle lateral", "ankle sagittal"), "double": ("held", "recovery step")}


class ReplanPending(InfeasibleStop):
    """:func:`replan_stop` used its ``max_solves`` and tries are left: none so far gave a stop.

    ``support`` ("single" or "double") and ``next_try`` (an index into
    ``REPLAN_TRIES[support]``) resume it on a later tick, from that tick's
    measurement: ``replan_stop(..., first_try=next_try)`` while
    :func:`replan_support` still says ``support``.
    """

    def __init__(self, message: str, support: str, next_try: int):
        super().__init__(message)
        self.support = support
        self.next_try = next_try


#: Stop solves a re-plan of the online controller may do in one servo tick (``StopPlannerSystem``'s
#: ``max_replan_solves``): a double-support re-plan (held ZMP, recovery step) and a single-support one's
#: held and ankle ZMP each fit one tick; the rest go on at the next tick (measured on 27 captured re-plans).
MAX_REPLAN_SOLVES = 2

#: Stop solves the online controller's latch may spend searching from the measured state (``StopPlannerSystem``'s
#: ``max_latch_solves``; :func:`plan_stop`'s ``max_solves``): the signal's support phase and the first three ticks
#: of the next one (III.C), about 2 ms. Measured (the 153 runs of the 500-run campaign whose push
#: starts before the signal): 4 latched from the measured state; the one that found a stop found it at its first
#: try, the three that found none tried 202-268 times (60-100 ms in that tick) before the reference fallback.
MAX_LATCH_SOLVES = 4


def check_solve_bound(value, name: str = "max_solves"):
    """``value`` if it bounds a re-plan's solves (a positive integer, or None: no bound); else ``ValueError``
    naming ``name``."""
    if value is not None and (isinstance(value, bool) or not isinstance(value, int) or value < 1):
        raise ValueError(f"{name} must be a positive integer or None, got {value!r}")
    return value


def replan_support(plan: StopPlan, t: float) -> str | None:
    """What :func:`replan_stop` re-plans at ``t``: "single" (the landing can still move), "double" (after
    the landing, before the halt), or None (nothing left to re-plan)."""
    if plan.x is None or t < plan.start_time:
        return None
    if (plan.landing_foot is not None and t < plan.landing_time - plan.params.min_landing_time
            and not plan.recovery_step):  # a recovery step lands as planned (a re-plan hurried it: 2.3 kN)
        return "single"
    return "double" if plan.landing_time <= t < plan.slowdown_end else None


def replan_stop(plan: StopPlan, t: float, com_xy, com_vel_xy, *, feet=None, recovery_step: bool = False,
                first_try: int = 0, max_solves: int | None = None) -> StopPlan | None:
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

    **Ankle strategy.** The paper holds the ZMP still on the support foot until
    the landing (eq. 19). When no landing stops the measured state that way
    (a push towards the support foot's side puts the DCM over its outer edge;
    a forward push needs a step longer than ``max_step_length``), the
    single-support re-plan moves that ZMP, at rest, to :func:`ankle_zmp` (the
    point of the support sole, less ``zmp_margin``, that brings the DCM back to
    the plan's at its landing), then to its lateral part alone, then to its
    sagittal part alone, and keeps the first that gives a stop. The ZMP
    steps there at ``t`` (the COG stays continuous: position and velocity;
    eq. 10-11 hold, eq. 12-13 do not); a physical robot's centre of pressure
    does the same under a push. Measured on the pushed physics benchmark: see
    ``benchmarks/ROBUSTNESS.md``.

    ``feet`` (after the landing only: ``{side: (x, y)}`` [m], either or both
    sides) are measured footholds: the double-support stop is solved on them
    instead of the plan's feet (a pushed swing foot lands centimetres from its
    target; its support polygon is where it stands). Ignored before the landing.

    **Recovery step** (``recovery_step=True``; after the landing only). Where
    no double-support stop exists (a forward push puts the DCM past the fore
    foot's ankle: stopping the COG between the feet then needs a ZMP beyond
    the toe, or stretches the rear leg past ``max_rear_reach``), the re-plan
    steps: the rear foot lifts at ``t`` and lands ahead
    (:func:`_recovery_step`), the stop solved as a single-support stop (III.A,
    eq. 21-26) on the fore foot from the measured COG. A step out of double
    support where a stop would end: the paper's plan has no such step (its
    stop lands once); the field's push recovery (Pratt et al. 2006, IHMC)
    steps towards the capture point. Only forward (the rear foot steps past
    the fore foot), from a DCM at least ``RECOVERY_DCM_AHEAD`` past the fore
    ankle, not heading laterally past the fore sole's inner edge, with the
    rear leg within ``max_rear_reach``; a DCM outside the feet sideways or
    behind is not caught.

    **Bounded work.** The tries (:data:`REPLAN_TRIES`: up to four solves in
    single support, two in double support) run in order until one gives a
    stop. ``max_solves`` (None: no bound) caps the solves of this call: when
    it runs out with tries left, :class:`ReplanPending` says where to go on
    (``first_try``) on a later tick, from that tick's measurement. A try the
    ankle strategy would repeat (its stance ZMP within 1 mm of the plan's)
    is skipped and costs no solve.

    Returns None where nothing is left to re-plan (the halt, a plan that has
    not started yet, a standing plan). Raises :class:`InfeasibleStop` when no
    stop exists from that state (:class:`ReplanPending` when tries are left),
    ``ValueError`` for non-finite ``feet``, a ``first_try`` outside the
    support's tries or a ``max_solves`` below 1.
    """
    footholds = _footholds(feet)
    check_solve_bound(max_solves)
    support = replan_support(plan, t)
    if support is None:
        return None
    tries = REPLAN_TRIES[support]
    if isinstance(first_try, bool) or not isinstance(first_try, int) or not 0 <= first_try < len(tries):
        raise ValueError(f"first_try must be an index into REPLAN_TRIES[{support!r}] (0-{len(tries) - 1}), "
                         f"got {first_try!r}")
    # a push may need the early step, and a landing moved further than a low foot could on its own
    params = replace(plan.params, max_early_landing=math.inf, max_landing_shift_per_height=math.inf)
    double = support == "double"
    start = _ReplanStart(plan, t, com_xy, com_vel_xy, double, params, footholds if double else None)
    # resumed (first_try > 0): what a try that does not apply re-raises (the held ZMP always runs at 0)
    failure = InfeasibleStop(f"re-plan at t={t:.3f} s: the {support}-support tries before "
                             f"{tries[first_try]!r} found no stop on earlier ticks") if first_try else None
    ankle, solves = None, 0
    for index in range(first_try, len(tries)):
        name, stance_zmp = tries[index], None
        if name == "recovery step" and not recovery_step:
            break
        if name.startswith("ankle"):  # the support foot's ZMP moved to take back the DCM deviation
            if ankle is None:
                ankle = _ankle_tries(plan, t, com_xy, com_vel_xy, start.zmp)
            if not ankle:
                break
            stance_zmp = ankle[name]
            if np.max(np.abs(stance_zmp - start.zmp)) < 1e-3:  # the plan's ZMP at t: nothing new to try
                continue
        if max_solves is not None and solves >= max_solves:
            raise ReplanPending(f"{failure}; {len(tries) - index} of the {support}-support tries left "
                                f"from {name!r}", support, index)
        solves += 1
        try:
            if name == "recovery step":
                return _recovery_step(plan, t, com_xy, com_vel_xy, params, footholds, failure)
            return start.solve(stance_zmp=stance_zmp)
        except InfeasibleStop as error:
            failure = error
    raise failure


def _ankle_tries(plan: StopPlan, t: float, com_xy, com_vel_xy, current) -> dict:
    """The ankle strategy's stance ZMPs by try name (:data:`REPLAN_TRIES`): :func:`ankle_zmp`, its lateral
    part and its sagittal part with the rest from ``current`` (the plan's ZMP at ``t``); empty without one."""
    ankle = ankle_zmp(plan, t, com_xy, com_vel_xy)
    if ankle is None:
        return {}
    return {"ankle": ankle, "ankle lateral": np.array([current[0], ankle[1]]),
            "ankle sagittal": np.array([ankle[0], current[1]])}


def ankle_zmp(plan: StopPlan, t: float, com_xy, com_vel_xy):
    """The support foot's ZMP that brings the measured DCM back onto the plan's at the plan's landing.

    With the ZMP held at ``p`` the DCM ``xi = x + x' / omega`` moves as
    ``xi(T) = p + (xi(t) - p) exp(omega (T - t))`` (eq. 6-9); this solves for ``p``
    with ``xi(T)`` the plan's, and clamps it to the support sole less ``zmp_margin``
    (the sole's frame: toe, heel, inner and outer edges). None when the plan has
    no landing ahead or ``p`` is the plan's ZMP (within 1 mm).
    """
    if plan.landing_foot is None or not t < plan.landing_time:
        return None
    w = plan.pattern.w
    grow = math.exp(w * (plan.landing_time - t))
    pos, vel, _, _ = plan.com([plan.landing_time])
    xi_landing = pos[0] + vel[0] / w
    xi_now = np.asarray(com_xy, float)[:2] + np.asarray(com_vel_xy, float)[:2] / w
    wanted = _zmp_to_reach(xi_now, xi_landing, grow)
    support = next(side for side in SIDES if side != plan.landing_foot)
    ankle = np.asarray(plan.feet(t)[support][:2], float)
    turn = rotation(float(plan.feet_yaw(t)[0][support]))
    zmp = _on_sole(plan.pattern.params.sole, support, ankle, turn, turn.T @ (wanted - ankle), plan.params.zmp_margin)
    current = np.array([traj.evaluate_at(float(t))[3] for traj in (plan.x, plan.y)])
    return None if np.max(np.abs(zmp - current)) < 1e-3 else zmp


def _zmp_to_reach(xi_now, xi_target, grow):
    """The ZMP ``p`` that, held while the DCM grows by ``grow = exp(w T)``, takes it from ``xi_now`` to
    ``xi_target``: ``xi(T) = p + (xi_now - p) grow`` (eq. 6-9) solved for ``p``."""
    return (xi_target - xi_now * grow) / (1.0 - grow)


def _on_sole(sole, side: str, ankle, turn, local, margin: float):
    """``local`` (a point in the frame of the ``side`` sole: ankle ``ankle``, rotation ``turn``) clamped to
    the sole less ``margin`` (toe, heel, inner and outer edges), in world axes."""
    left_edge, right_edge = sole.lateral_edges(side)
    local = np.array([np.clip(local[0], -sole.heel + margin, sole.toe - margin),
                      np.clip(local[1], -right_edge + margin, left_edge - margin)])
    return ankle + turn @ local


def _footholds(feet):
    """``replan_stop``'s ``feet`` checked: ``{side: xy array}`` (None for none)."""
    if feet is None:
        return None
    out = {}
    for side, xy in feet.items():
        if side not in SIDES:
            raise ValueError(f"feet: sides are 'left' and 'right', got {side!r}")
        xy = np.asarray(xy, float)[:2]
        if xy.shape != (2,) or not np.all(np.isfinite(xy)):
            raise ValueError(f"feet[{side!r}] must be a finite (x, y), got {feet[side]!r}")
        out[side] = xy
    return out


def swing_braking_time(pos, vel, acc, target_xy, params: StopParameters) -> float:
    """Shortest time to touchdown [s], on the servo grid from ``params.min_landing_time``, in which the
    landing swing (:func:`landing_swing`: quintic Hermite from the ankle's ``pos``, ``vel``, ``acc`` to
    ``target_xy`` at rest) keeps its horizontal acceleration within ``params.max_swing_acceleration``.
    ``params.min_landing_time`` without a limit, or where no duration up to ``params.max_landing_time``
    keeps it (the ankle already accelerates harder than the limit: the swing starts there)."""
    if not math.isfinite(params.max_swing_acceleration):
        return params.min_landing_time
    dt = params.servo_period
    durations = np.arange(params.min_landing_time, params.max_landing_time - dt + 1e-9, dt)
    if len(durations) == 0:
        return params.min_landing_time
    distance = np.asarray(target_xy, float)[:2] - np.asarray(pos, float)[:2]
    vel, acc = np.asarray(vel, float)[:2], np.asarray(acc, float)[:2]
    limit = params.max_swing_acceleration
    # ankle acceleration of the Hermite at s on the grid, for every duration T (eq. of landing_swing):
    # (S''(s) D + H1''(s) v T + H2''(s) a T^2) / T^2
    terms = _BRAKING_TERMS
    for first in range(0, len(durations), _BRAKING_CHUNK):  # the soonest first: most re-plans stop in the first
        chunk = durations[first:first + _BRAKING_CHUNK]
        T = chunk[:, None, None]
        swing = (terms[0][None, :, None] * distance + terms[1][None, :, None] * vel * T
                 + terms[2][None, :, None] * acc * T**2) / T**2
        peak = np.max(np.linalg.norm(swing, axis=2), axis=1)
        within = np.flatnonzero(peak <= limit + 1e-9)
        if len(within):
            return float(chunk[within[0]])
    return params.min_landing_time


#: durations checked at a time by swing_braking_time (each duration's check is its own: the same bits)
_BRAKING_CHUNK = 16
#: second derivatives of the landing swing's Hermite terms on its check grid (position, velocity, acceleration)
_BRAKING_TERMS = [lipm.poly_eval(c, SWING_GRID, 2) for c in (lipm.SMOOTHSTEP, lipm.HERMITE_D1, lipm.HERMITE_D2)]


class _ReplanStart:
    """:func:`replan_stop`'s start: the plan's state at ``t`` with the measured COG, built once and solved
    (:meth:`solve`) as a single- or double-support stop, for each stance ZMP the ankle strategy tries;
    ``footholds`` (``{side: xy}``, double support) replace the plan's feet, at rest. ``zmp``: the plan's
    ZMP at ``t`` (xy)."""

    def __init__(self, plan: StopPlan, t: float, com_xy, com_vel_xy, double: bool, params: StopParameters,
                 footholds=None):
        h = 1e-3
        axes = [traj.evaluate_at(float(t)) for traj in (plan.x, plan.y)]
        zmp, rate, accel = (np.array([a[i] for a in axes]) for i in (3, 4, 5))
        before, now, after = plan.feet(t - h), plan.feet(t), plan.feet(t + h)
        if t - h < plan.start_time:  # the plan's own swing start (continuous with what it started from)
            before = {side: now[side] - h * plan.start_state.feet_vel[side] for side in now}
        feet_vel = {side: (after[side] - before[side]) / (2 * h) for side in now}
        feet_acc = {side: (after[side] - 2 * now[side] + before[side]) / h**2 for side in now}
        for side, xy in (footholds or {}).items():
            now[side] = np.array([xy[0], xy[1], 0.0])
            feet_vel[side], feet_acc[side] = np.zeros(3), np.zeros(3)
        upper, upper_rate = plan.upper_body(t)
        yaw, yaw_rate = plan.feet_yaw(t)
        self.changes = dict(time=float(t), feet_yaw=yaw, feet_yaw_rate=yaw_rate,
                            com=np.asarray(com_xy, float)[:2].copy(), com_vel=np.asarray(com_vel_xy, float)[:2].copy(),
                            zmp=zmp, zmp_rate=rate, zmp_accel=accel, feet=now, feet_vel=feet_vel,
                            feet_acc=feet_acc, upper_body=upper, upper_body_rate=upper_rate)
        if double:
            rear = (next(s for s in now if s != plan.landing_foot) if plan.landing_foot is not None
                    else plan.start_state.rear_foot)
            self.changes.update(support="double", support_foot=None, next_landing=None, rear_foot=rear)
        self.braked = False
        if not double and plan.landing_foot is not None and math.isfinite(params.max_swing_acceleration):
            side = plan.landing_foot  # the landing no sooner than the swing can brake to the plan's landing point
            soonest = swing_braking_time(now[side], feet_vel[side], feet_acc[side], plan.landing_position, params)
            self.braked = soonest > params.min_landing_time + 1e-9  # the limit bounds the landing (braked_swing)
            params = replace(params, min_landing_time=max(params.min_landing_time, soonest))
        self.plan, self.double, self.params, self.zmp = plan, double, params, zmp

    def solve(self, stance_zmp=None) -> StopPlan:
        """The stop from this start; ``stance_zmp`` (xy) replaces the plan's ZMP at ``t``, at rest."""
        plan, changes = self.plan, self.changes
        if stance_zmp is not None:
            changes = dict(changes, zmp=np.asarray(stance_zmp, float)[:2].copy(), zmp_rate=np.zeros(2),
                           zmp_accel=np.zeros(2))
        wall = time.perf_counter()
        new = _plan_from(plan.pattern, replace(plan.start_state, **changes), self.params, plan.signal_time,
                         plan.case, zmp_region="polygon" if self.double else "fore")
        new.braked_swing = self.braked
        new.crouch_window = plan.crouch_window or (plan.start_time, plan.halt_end)
        return _finish(new, wall)


#: ZMP margin [m] of a recovery step's plan (or the plan's own, if smaller). A recovery step is planned
#: where the controller's 3 cm stop has no solution; with 3 cm its halt had none either (30 N s forward
#: push in double support: at most 3.6 mm at the first try; measured before the step's lateral aim, with
#: which 1.5 cm finds it at that first try).
RECOVERY_ZMP_MARGIN = 0.015


#: A recovery step needs the measured DCM at least this far [m] past the fore ankle (sagittally). Measured
#: on the robustness benchmark: steps taken from DCMs 2.5-3.5 cm past the ankle (a left push late in single
#: support, a backward push in double support whose rebound failed a double-support re-plan) failed two
#: runs that held without them; the forward pushes the steps caught had it 6.8-8.2 cm past. Laterally the
#: DCM may lie no further towards the rear foot than the fore sole's inner edge less the margin (the step
#: lifts that foot): in the campaign, steps from DCMs 4.6-9.9 cm towards it (pushes forward-left and left)
#: made a run that passed fall, another fail by 0.4 mm and a third, failing already, fall.
RECOVERY_DCM_AHEAD = 0.05


def _recovery_step(plan: StopPlan, t: float, com_xy, com_vel_xy, params: StopParameters, footholds,
                   failure: InfeasibleStop) -> StopPlan:
    """:func:`replan_stop`'s recovery step out of a double-support stop at ``t`` (re-raises ``failure``
    where it does not apply or has no stop either).

    The state: single support on the fore foot (along the feet's mean heading), the rear foot at rest
    on the floor as the swing foot (lifted from ``t``: the swing's clearance bump), both at ``footholds``
    where given. The ZMP steps, at rest, onto the fore sole less ``zmp_margin``: sagittally under the
    measured DCM (holding it, eq. 6-9; a CoP already on the toe stays there), laterally where it sends the
    DCM to the feet's midline by the soonest touchdown the swing speed allows. The landing keeps the rear
    foot's lateral offset from the fore foot (within the step widths of :mod:`drake_estop.planning.capture`),
    along the fore foot's heading; its length, the landing time and the phases after it are the
    single-support solve's (III.A, eq. 21-26), the nominal touchdown one single-support time after ``t``.
    """
    feet = plan.feet(t)
    now = {side: np.array([*np.asarray((footholds or {}).get(side, feet[side][:2]), float)[:2], 0.0])
           for side in SIDES}
    yaw, _ = plan.feet_yaw(t)
    heading = rotation(0.5 * (yaw["left"] + yaw["right"]))
    along = {side: float((heading.T @ now[side][:2])[0]) for side in SIDES}
    fore = max(SIDES, key=along.get)
    rear = next(side for side in SIDES if side != fore)
    w = plan.pattern.w
    com, vel = np.asarray(com_xy, float)[:2].copy(), np.asarray(com_vel_xy, float)[:2].copy()
    dcm = com + vel / w
    turn = rotation(float(yaw[fore]))
    local = turn.T @ (dcm - now[fore][:2])  # the DCM in the fore sole's frame
    if local[0] < RECOVERY_DCM_AHEAD:
        raise failure  # the DCM is not far past the fore ankle: the stop's own limits failed, not the feet
    if float((turn.T @ (com - now[rear][:2]))[0]) > params.max_rear_reach:
        raise failure  # the rear leg is stretched straight: it drags over the floor instead of lifting
    params = replace(params, zmp_margin=min(params.zmp_margin, RECOVERY_ZMP_MARGIN))
    sole, margin = plan.pattern.params.sole, params.zmp_margin
    lateral = float((turn.T @ (now[rear][:2] - now[fore][:2]))[1])
    lateral = math.copysign(min(max(abs(lateral), MIN_STEP_WIDTH), MAX_STEP_WIDTH), lateral)
    if math.copysign(1.0, lateral) * local[1] > sole.inner - margin:
        raise failure  # the DCM heads for the rear foot's side: lifting that foot drops the robot onto it
    # sagittal: the ZMP under the DCM holds it (eq. 6-9); lateral: the ZMP that brings the DCM to the feet's
    # midline by the soonest touchdown the swing speed allows, xi(T) = p + (xi - p) exp(w T) (as ankle_zmp)
    soonest = max(params.min_landing_time, float((turn.T @ (dcm - now[rear][:2]))[0]) / params.max_swing_speed)
    lateral_zmp = _zmp_to_reach(local[1], 0.5 * lateral, math.exp(w * soonest))
    zmp = _on_sole(sole, fore, now[fore][:2], turn, np.array([local[0], lateral_zmp]), margin)
    gait = plan.pattern.params
    zero = np.zeros(3)
    upper, upper_rate = plan.upper_body(t)
    state = replace(
        plan.start_state, time=float(t), support="single", support_foot=fore, com=com, com_vel=vel, zmp=zmp,
        zmp_rate=np.zeros(2), zmp_accel=np.zeros(2), feet=now, feet_vel={side: zero.copy() for side in SIDES},
        feet_acc={side: zero.copy() for side in SIDES},
        next_landing=now[fore][:2] + turn @ np.array([gait.step_length, lateral]), rear_foot=None,
        upper_body=upper, upper_body_rate=upper_rate, feet_yaw=dict(yaw),
        feet_yaw_rate={side: 0.0 for side in SIDES}, next_landing_yaw=float(yaw[fore]),
        recovery_touchdown=float(t) + gait.single_support_time)
    wall = time.perf_counter()
    try:
        new = _plan_from(plan.pattern, state, params, plan.signal_time, plan.case)
    except InfeasibleStop as error:
        raise InfeasibleStop(f"{failure}; recovery step: {error}") from error
    new.crouch_window = plan.crouch_window or (plan.start_time, plan.halt_end)
    new.recovery_step = True
    new.swing_start = dict(new.swing_start, clearance=plan.pattern.params.lift_height)  # lifted from the floor
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
