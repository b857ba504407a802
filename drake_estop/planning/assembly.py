"""The stop from one state: the phase-parameter problem, the lateral plane and the plan.

:func:`stop_problem` poses the single- or double-support problem (III.A, eq. 21-26; III.B,
eq. 29-31) from a pattern state; :func:`plan_from` solves it in the heading frame of the foot
that carries the stop and assembles the :class:`~drake_estop.planning.plan.StopPlan`: the
lateral plane on the sagittal phase times (with a slowdown floor where the lateral stop needs
one), the halt (eq. 27-28), the upper-body halt (eq. 33) and the ZMP margin check
(:mod:`~drake_estop.planning.zmp_check`); with ``objective="time"`` the soonest rest
(:mod:`~drake_estop.planning.brake`). The landing's limits come from
:mod:`~drake_estop.planning.landing`. The search of :mod:`~drake_estop.planning.planner` and the
re-plans of :mod:`~drake_estop.planning.replan` call :func:`plan_from`.
"""

from __future__ import annotations

import math
import time
from dataclasses import replace

import numpy as np

from drake_estop.planning import lipm
from drake_estop.planning.brake import held_brake, moving_zmp, rest_points, stop_brake, swing_brake
from drake_estop.planning.capture import capture_landing_y
from drake_estop.planning.gait import NominalPattern, PatternState
from drake_estop.planning.geometry import SupportPolygon
from drake_estop.planning.halt import choose_halt
from drake_estop.planning.heading import solve_turned
from drake_estop.planning.landing import (
    earliest_landing,
    landing_shift_limit,
    lateral_reach,
    nominal_touchdown,
    rear_lateral_reach,
    retry_limits,
    swing_descent_time,
)
from drake_estop.planning.plan import InfeasibleStop, StopParameters, StopPlan, snap_to_tick, soles_polygon
from drake_estop.planning.problems import DoubleSupportProblem, SingleSupportProblem
from drake_estop.planning.solver import solve_phases
from drake_estop.planning.stop_condition import StopStart, slowdown_time, target_zmp
from drake_estop.planning.zmp_check import start_polygon, verify_zmp


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
        touchdown = nominal_touchdown(pattern, state)
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
        touchdown = nominal_touchdown(pattern, state)
        params = lateral_reach(pattern, state, params)
        params = rear_lateral_reach(pattern, state, params)
        params = landing_shift_limit(state, params, swing)
        if not -(sole.heel - params.zmp_margin) <= params.landing_zmp_offset <= sole.toe - params.zmp_margin:
            raise ValueError(f"landing_zmp_offset {params.landing_zmp_offset} m puts the ZMP outside the fore sole")
        problem = SingleSupportProblem(start, w, params, float(state.zmp[0]),
                                       state.feet[swing][:2].copy(), float(state.next_landing[1]),
                                       min_landing=earliest_landing(state, params, swing, touchdown),
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

_MARGIN_ROUNDS = 3  # lateral re-aims of a plan whose transition overshoots into the zmp_margin band


def plan_from(pattern: NominalPattern, state: PatternState, params: StopParameters, signal_time, case,
               zmp_region: str = "fore"):
    """The stop from ``state``, solved in the heading frame of the foot that carries it
    (:mod:`drake_estop.planning.heading`; the world frame on a straight walk). Where the limits as given
    find no stop, in single support it tries again (:func:`~drake_estop.planning.landing.retry_limits`) with
    the landing also allowed at the nominal touchdown where that is sooner than ``min_landing_time``, then
    with the slowdown ZMP at the landing ankle (the paper's eq. 20, where ``landing_zmp_offset`` is not 0: a
    walk stepping in place has no forward speed for a ZMP ahead of the ankle to stop), without and with
    that window; in double support with the paper's J_ds weight (eq. 30) where ``a_ds`` is another."""
    def plan(limits):
        return solve_turned(lambda view, local: _plan_local(view, local, limits, signal_time, case, zmp_region),
                            pattern, state)

    try:
        return plan(params)
    except InfeasibleStop as error:
        failure = error
    for limits in retry_limits(pattern, state, params):
        try:
            found = plan(limits)
        except InfeasibleStop:
            continue
        found.params = params  # the plan's own limits (a re-plan treats it as any other landing)
        return found
    raise failure


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
        landing_y = capture_landing_y(pattern, state, solution.landing, min_width=params.min_step_width,
                                      max_width=params.max_step_width)
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
        plan.min_zmp_margin = verify_zmp(plan, final_polygon=polygon)
        if not math.isfinite(plan.min_zmp_margin):  # guard: never hand out a plan with a NaN ZMP
            raise InfeasibleStop("the planned ZMP is not finite")
        if required is None:
            start_zmp = np.array([[plan.x.evaluate_at(t0)[3], plan.y.evaluate_at(t0)[3]]])
            required = min(params.zmp_margin, float(start_polygon(plan).margin(start_zmp)[0]))
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
        rear, fore = sorted(feet.values(), key=lambda xy: float(xy[0]))
        rests = rest_points(rear, fore, params.max_rear_reach)
        found = stop_brake(state.com, state.com_vel, zmp, state.zmp_rate, state.zmp_accel,
                           rests, [polygon] * len(rests), params, w, required)
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
        descent = swing_descent_time(state, params, swing)

        def search(y):
            return swing_brake(state.com, state.com_vel, zmp, state.zmp_rate, state.zmp_accel, state.feet[support][:2],
                               state.feet[swing][:2], y, descent, support_polygon, polygon_for, params, w, required)

        brake = search(landing_y)
        if brake is not None:  # a sideways deviation: land where the lateral capture point goes (planning/capture.py)
            shifted = capture_landing_y(pattern, state, brake.ends[0], min_width=params.min_step_width,
                                        max_width=params.max_step_width)
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
    x_traj, y_traj = (
        lipm.LipmTrajectory.from_zmp(t0, brake.durations + [1.0], brake.coeffs[a] + [lipm.pad([brake.rest[a]])],
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
    plan.min_zmp_margin = verify_zmp(plan, final_polygon=polygon)
    if not plan.min_zmp_margin >= required - 1e-9:  # NaN too: never hand out such a plan
        raise InfeasibleStop(f"zmp_margin: the brake's ZMP comes {plan.min_zmp_margin * 1e3:.1f} mm from the "
                             f"support polygon's edge (zmp_margin {params.zmp_margin * 1e3:.1f} mm)")
    return plan



def with_compute_time(plan: StopPlan, wall_start: float) -> StopPlan:
    plan.compute_time = time.perf_counter() - wall_start
    return plan
