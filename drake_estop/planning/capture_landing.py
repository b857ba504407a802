"""The capture landing: a single-support re-plan that lands sooner and nearer, and the two-step capture.

Where a push sends the divergent component of motion (DCM) past the farthest landing before the plan's
touchdown, :func:`capture_landing` lands as soon as the swing can brake (:func:`capture_setup` chooses the
landing time and the reachable landing points by the DCM's deadline), and where that landing stops nothing
:func:`capture_step` follows it with a recovery step of the old support foot (N-step capture, Koolen et al.
2012). :func:`swing_braking_time` and :func:`swing_reach` bound how soon and where a moving swing foot can
land. :func:`drake_estop.planning.replan.replan_stop` tries the capture landing last in single support;
:mod:`drake_estop.planning.capture` holds the LIPM's capture time and the ankle's share, which this module
plans with.
"""

from __future__ import annotations

import math
import time
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from drake_estop.planning import lipm
from drake_estop.planning.assembly import plan_from, with_compute_time
from drake_estop.planning.capture import capture_time
from drake_estop.planning.gait import SIDES, rotation
from drake_estop.planning.plan import SWING_GRID, InfeasibleStop, StopParameters, StopPlan, snap_to_tick
from drake_estop.planning.problems import descent_time
from drake_estop.planning.recovery import RECOVERY_ZMP_MARGIN, zmp_to_reach
from drake_estop.planning.recovery import recovery_step as recovery_step_plan
from drake_estop.planning.zmp_check import start_polygon

if TYPE_CHECKING:  # the re-plan module calls this one
    from drake_estop.planning.replan import ReplanStart


#: How far [m] past the widest landing ankle (outwards) the lateral DCM may lie at a capture landing's
#: touchdown (:func:`capture_landing`): negative, inside it. Measured on the 29 N s push to the right at
#: 2.95 s: with 0 the plan lands 35 ms later and the robot, whose real lateral DCM runs 2-3 cm ahead of the
#: LIPM's (its body rolls), falls; with -0.03 it stops.
CAPTURE_DCM_PAST_ANKLE = -0.03
SHORTEST_LANDING = StopParameters().min_landing_time
#: How far [m] behind the nearest landing point the support ZMP sends the sagittal DCM by a capture landing's
#: touchdown (:func:`capture_landing`).
CAPTURE_DCM_BEHIND_LANDING = 0.05
#: The least sagittal span [m] of landing points the capture landing's swing must reach by its touchdown.
CAPTURE_LANDING_SPAN = 0.03
#: The fastest descent [m/s] of a capture landing's swing foot (the planner's ``max_swing_descent_speed``, 0.3 m/s,
#: takes 0.29 s down from the 5 cm apex: by then a 0.5 m/s sideways push has the DCM past the widest landing).
CAPTURE_DESCENT_SPEED = 0.6
#: The largest horizontal acceleration [m/s^2] of a capture landing's swing foot (the braked landing's is 15:
#: with 15 the 29 N s push's capture landing reached 1 cm of landing points by its deadline and found no stop).
CAPTURE_SWING_ACCELERATION = 20.0


def capture_landing(start: ReplanStart, setup: tuple, failure: InfeasibleStop, two_steps: bool = False) -> StopPlan:
    """The single-support re-plan's last try: land sooner and nearer, by the lateral DCM's deadline.

    After a sideways push towards the swing foot's side, the lateral DCM diverges from the support ZMP
    (eq. 6-9) and runs past the widest landing (``params.max_step_width``)
    unless the foot comes down in time. The other tries keep the plan's landing point, whose sagittal
    distance the braked swing needs long to cover, and its ``min_landing_time`` (the braking time from
    that re-plan's start). Measured, 29 N s to the right at 2.95 s: the plan landed at 3.49 s, 0.44 s
    after the push, when the DCM was 0.12 m past the landed sole; this try, at 3.145 s, lands at 3.34 s
    and the robot stops (:func:`capture_setup` says how the landing is chosen).

    The stop is solved (III.A, eq. 21-26) from ``setup`` (:func:`capture_setup`'s) with the landing time
    in that tick and the step within the reachable landings. Where it finds none, ``two_steps`` tries the
    landing followed by a recovery step (:func:`capture_step`); :class:`InfeasibleStop` (after
    ``failure``'s message) where that finds none either.
    """
    state, limits, params = setup
    wall = time.perf_counter()
    plan = start.plan
    try:
        new = plan_from(plan.pattern, state, limits, plan.signal_time, plan.case)
    except InfeasibleStop as error:
        failure = InfeasibleStop(f"{failure}; capture landing: {error}")
        if not two_steps:
            raise failure from error
        return capture_step(start, setup, failure)
    new.braked_swing = new.capture_landing = True
    new.params = params  # the re-plan's own limits, with the capture landing's margin (as a recovery step's)
    new.crouch_window = plan.crouch_window or (plan.start_time, plan.halt_end)
    return with_compute_time(new, wall)


#: How far [m] past the landed ankle a two-step capture (:func:`capture_step`) aims the DCM at its touchdown:
#: the recovery step that follows needs it :func:`~drake_estop.planning.recovery.recovery_dcm_ahead` past at
#: least; the forward pushes the recovery steps caught had it 6.8-8.2 cm past.
CAPTURE_STEP_DCM_AHEAD = 0.07
#: How far [m] inside the recovery step's lateral bound (the landed sole's inner edge less its margin) a
#: two-step capture keeps the DCM at its touchdown (the landing's width is chosen for it).
CAPTURE_STEP_INNER_ROOM = 0.005


def capture_step(start: ReplanStart, setup: tuple, failure: InfeasibleStop) -> StopPlan:
    """N-step capture: the capture landing followed by a recovery step, where no landing stops the robot.

    A forward push can send the DCM further than one step reaches in the time the swing needs: the
    stop condition (eq. 22) then asks for a step past ``max_step_length`` at every landing time. Two
    steps catch what one cannot (Koolen et al. 2012): the swing foot lands as soon as it can
    (:func:`capture_setup`'s touchdown, on the servo grid), at the reachable landing point nearest
    :data:`CAPTURE_STEP_DCM_AHEAD` behind the DCM there, the support ZMP held meanwhile (eq. 6-9 give
    the COG at the touchdown); then the old support foot steps ahead out of double support, planned as
    the recovery step (:func:`~drake_estop.planning.recovery.recovery_step`, III.A) from that state. The
    plan returned lands once and follows the recovery step's COG and ZMP after its touchdown;
    :attr:`StopPlan.next_step` holds the recovery step, which the online controller takes there
    (re-planned from the measured state first).

    Raises :class:`InfeasibleStop` (after ``failure``'s message) where the recovery step finds no stop.
    """
    state, limits, params = setup
    plan, wall = start.plan, time.perf_counter()
    swing = plan.landing_foot
    support = next(side for side in SIDES if side != swing)
    w, dt = plan.pattern.w, params.servo_period
    t = float(state.time)
    touchdown = t + snap_to_tick(limits.max_landing_time, dt)
    duration = touchdown - t
    ankle = np.asarray(state.feet[support][:2], float)
    turn = rotation(float(state.feet_yaw[support]))
    zmp = np.asarray(state.zmp, float)[:2]
    # the COG at the touchdown with the support ZMP held (eq. 6-9)
    grow_c, grow_s = math.cosh(w * duration), math.sinh(w * duration)
    offset = np.asarray(state.com, float)[:2] - zmp
    velocity = np.asarray(state.com_vel, float)[:2]
    com = zmp + offset * grow_c + velocity / w * grow_s
    vel = offset * w * grow_s + velocity * grow_c
    dcm_local = turn.T @ (com + vel / w - ankle)
    zmp_local = turn.T @ (zmp - ankle)
    low, high = zmp_local[0] + limits.min_step_length, zmp_local[0] + limits.max_step_length
    lateral = float((turn.T @ (np.asarray(state.next_landing, float)[:2] - ankle))[1])
    # narrower where the lateral DCM would lie past the landed sole's inner edge less the margin: the
    # recovery step lifts the foot on that side (the walk's sway heads the DCM for the midline)
    toward = math.copysign(1.0, lateral)
    inner = plan.pattern.params.sole.inner - min(params.zmp_margin, RECOVERY_ZMP_MARGIN) - CAPTURE_STEP_INNER_ROOM
    width = min(abs(lateral), max(toward * float(dcm_local[1]) + inner, params.min_step_width))
    landing = ankle + turn @ np.array([float(np.clip(dcm_local[0] - CAPTURE_STEP_DCM_AHEAD, low, high)),
                                       toward * width])
    footholds = {support: ankle, swing: landing}
    recovery_params = replace(params, max_early_landing=math.inf, max_landing_shift_per_height=math.inf)
    try:
        step = recovery_step_plan(plan, touchdown, com, vel, recovery_params, footholds, failure)
    except InfeasibleStop as error:
        raise InfeasibleStop(f"{failure}; capture step: {error}") from error
    x, y = (lipm.LipmTrajectory.from_zmp(t, [duration, *np.diff(traj.breaks)],
                                         [lipm.pad([float(zmp[axis])]), *traj.zmp],
                                         float(state.com[axis]), float(state.com_vel[axis]), w, rest_tail=True)
            for axis, traj in enumerate((step.x, step.y)))
    final_yaw = {support: float(state.feet_yaw[support]), swing: float(state.next_landing_yaw)}
    new = StopPlan(
        signal_time=plan.signal_time, start_time=t, case=plan.case, support=plan.support, start_support="single",
        landing_time=touchdown, transition_end=step.transition_end, slowdown_end=step.slowdown_end,
        halt_end=step.halt_end, step_length=float((turn.T @ (landing - ankle))[0]), zmp_max=None,
        landing_foot=swing, landing_position=landing, final_feet={support: ankle.copy(), swing: landing},
        x=x, y=y, pattern=plan.pattern, params=params, start_state=replace(state, next_landing=landing),
        final_yaw=final_yaw, heading=float(state.feet_yaw[support]), capture_landing=True, braked_swing=True,
        next_step=step)
    new.swing_start = {"pos": state.feet[swing], "vel": state.feet_vel[swing], "acc": state.feet_acc[swing]}
    new.upper_body_peak = state.upper_body + state.upper_body_rate * (new.slowdown_end - t) / 3.0  # eq. 33
    new.crouch_window = plan.crouch_window or (plan.start_time, plan.halt_end)
    # until the touchdown the ZMP stands still on the support sole; after it the recovery step's own margin
    new.min_zmp_margin = min(float(start_polygon(new).margin(zmp[None, :])[0]), step.min_zmp_margin)
    return with_compute_time(new, wall)


def capture_setup(start: ReplanStart, com_xy, com_vel_xy):
    """The capture landing's start, its solve's limits and the plan's own ``(state, limits, params)``,
    or None where it does not apply.

    * the support ZMP held at the support sole's edge towards the swing side, less the ZMP margin
      (at most :data:`RECOVERY_ZMP_MARGIN`): the ankle strategy slows the lateral DCM;
    * the touchdown: the latest at which the lateral DCM has not come nearer than
      :data:`CAPTURE_DCM_PAST_ANKLE` to the outer side of the widest landing ankle
      (:func:`~drake_estop.planning.capture.capture_time`, eq. 6-9), or the sagittal DCM (the ZMP on the
      toe) to the farthest landing ankle (``max_step_length``), whichever comes first (a forward push
      alone keeps the plan's lateral landing and ZMP), on the servo grid, no sooner than
      the swing's descent at :data:`CAPTURE_DESCENT_SPEED`, and later (up to the plan's landing) where
      the swing cannot brake onto any landing point by then at :data:`CAPTURE_SWING_ACCELERATION`
      (:func:`swing_reach`);
    * sagittally the support ZMP (on the sole, less the margin) sends the DCM
      :data:`CAPTURE_DCM_BEHIND_LANDING` behind the reachable landing nearest the DCM with the ZMP held,
      and the step length is bounded to the reachable landings; laterally the landing is the capture
      rule's (:func:`~drake_estop.planning.capture.capture_landing_y`).

    None where the plan has no landing ahead, neither the lateral DCM passes the widest landing ankle
    nor the sagittal DCM the farthest one before the plan's touchdown (a push towards the support foot
    needs a crossover step: :func:`drake_estop.planning.crossover.crossover_stop`), or no landing sooner
    than the plan's reaches :data:`CAPTURE_LANDING_SPAN` of landing points.
    """
    plan, changes = start.plan, start.changes
    params = capture_parameters(start.params)
    swing = plan.landing_foot
    if swing is None or start.double:
        return None
    support = next(side for side in SIDES if side != swing)
    ankle = np.asarray(changes["feet"][support][:2], float)
    turn = rotation(float(changes["feet_yaw"][support]))
    w, sole, margin, dt = plan.pattern.w, plan.pattern.params.sole, params.zmp_margin, params.servo_period
    swing_local = turn.T @ (changes["feet"][swing][:2] - ankle)
    toward = 1.0 if swing_local[1] > 0 else -1.0  # the swing foot's side
    dcm = turn.T @ (np.asarray(com_xy, float)[:2] + np.asarray(com_vel_xy, float)[:2] / w - ankle)
    held = turn.T @ (np.asarray(changes["zmp"], float)[:2] - ankle)
    remaining = plan.landing_time - float(changes["time"])
    # the support ZMP at the sole's edge towards the swing side slows a DCM heading there
    edge_zmp = toward * (sole.lateral_edges(support)[0 if toward > 0 else 1] - margin)
    widest = toward * params.max_step_width
    lateral_deadline, sagittal_deadline = _capture_deadlines(dcm, toward, edge_zmp, widest, sole, margin, params,
                                                             remaining, w)
    deadlines = [d for d in (lateral_deadline, sagittal_deadline) if d is not None]
    if not deadlines:
        return None  # the DCM does not head past the widest or the farthest landing before the plan's touchdown
    deadline = min(deadlines)
    # the landing's offset across the support sole: the widest step, or for a forward push alone the plan's
    if lateral_deadline is None:
        across = float((turn.T @ (np.asarray(plan.landing_position, float)[:2] - ankle))[1])
        zmp_local = np.array([held[0], held[1]])
    else:
        across = widest
        zmp_local = np.array([held[0], edge_zmp])
    acceleration = capture_swing_acceleration(params)
    landing, reach = _capture_touchdown(plan, changes, params, swing, turn, swing_local, across, deadline,
                                        acceleration)
    if reach is None:
        return None
    grow = math.exp(w * landing)
    held_dcm = zmp_local[0] + (float(dcm[0]) - zmp_local[0]) * grow  # at the touchdown, the ZMP held (eq. 6-9)
    aim = float(np.clip(held_dcm + CAPTURE_DCM_BEHIND_LANDING, *reach)) - CAPTURE_DCM_BEHIND_LANDING
    zmp_local[0] = float(np.clip(zmp_to_reach(float(dcm[0]), aim, grow), -sole.heel + margin, sole.toe - margin))
    low = max(reach[0] - zmp_local[0], params.min_step_length)  # step lengths from the support ZMP
    high = min(reach[1] - zmp_local[0], params.max_step_length)
    if low >= high - 1e-3:
        return None
    # the mean swing speed the reachable landings need (the braking limit checked them already)
    speed = max(math.hypot(x - swing_local[0], across - swing_local[1]) for x in reach) / landing + 1e-6
    limits = replace(params, min_landing_time=max(landing - dt, dt), max_landing_time=landing + 1e-9,
                     min_step_length=low, max_step_length=high, max_swing_speed=max(params.max_swing_speed, speed),
                     max_swing_acceleration=acceleration)
    landing_xy = ankle + turn @ np.array([float(np.clip(swing_local[0], reach[0], reach[1])), across])
    state = replace(plan.start_state, **dict(changes, zmp=ankle + turn @ zmp_local, zmp_rate=np.zeros(2),
                                             zmp_accel=np.zeros(2), next_landing=landing_xy))
    return state, limits, params


def _capture_deadlines(dcm, toward: float, edge_zmp: float, widest: float, sole, margin: float,
                       params: StopParameters, remaining: float, w: float):
    """:func:`capture_setup`'s ``(lateral, sagittal)`` deadlines [s] (:func:`_capture_deadline`) of the DCM ``dcm``
    (support sole's frame [m]) past the widest landing ankle ``widest`` [m], the ZMP at ``edge_zmp`` [m], and past the
    farthest, the ZMP on the toe; None for an axis where it does not pass within ``remaining`` [s]."""
    lateral = _capture_deadline(float(dcm[1]), edge_zmp, widest + toward * CAPTURE_DCM_PAST_ANKLE, widest, remaining, w)
    # sagittally the ZMP on the toe slows a DCM running past the farthest landing ankle (N-step capture: a
    # landing that does not stop the robot is followed by the recovery step)
    farthest = params.max_step_length
    sagittal = _capture_deadline(float(dcm[0]), sole.toe - margin, farthest + CAPTURE_DCM_PAST_ANKLE,
                                 farthest, remaining, w)
    return lateral, sagittal


def _capture_touchdown(plan: StopPlan, changes: dict, params: StopParameters, swing: str, turn, swing_local,
                       across: float, deadline: float, acceleration: float):
    """:func:`capture_setup`'s touchdown [s from the re-plan's start] and the landing points the swing reaches by then
    (:func:`swing_reach`), ``(landing, reach)``: by ``deadline`` on the servo grid, no sooner than the swing's descent,
    later where it reaches less than :data:`CAPTURE_LANDING_SPAN`; ``reach`` None where it does not by the plan's."""
    dt = params.servo_period
    soonest = snap_to_tick(soonest_capture_landing(params, changes, swing), dt)
    landing = max(math.floor(deadline / dt + 1e-9) * dt, soonest)
    latest = plan.landing_time - float(changes["time"]) - dt
    swing_vel, swing_acc = (turn.T @ changes[key][swing][:2] for key in ("feet_vel", "feet_acc"))
    reach = None
    while landing <= latest + 1e-9:  # later where the swing cannot brake onto enough landings by then
        reach = swing_reach(swing_local, swing_vel, swing_acc, across, landing, acceleration)
        if reach is not None and reach[1] - reach[0] >= CAPTURE_LANDING_SPAN - 1e-9:
            break
        landing, reach = landing + dt, None
    return landing, reach


def capture_parameters(params: StopParameters) -> StopParameters:
    """``params`` for a hurried landing (the capture landing, the crossover step): a ZMP margin of at most
    :data:`RECOVERY_ZMP_MARGIN`, the swing coming down at :data:`CAPTURE_DESCENT_SPEED` at least."""
    return replace(params, zmp_margin=min(params.zmp_margin, RECOVERY_ZMP_MARGIN),
                   max_swing_descent_speed=max(params.max_swing_descent_speed, CAPTURE_DESCENT_SPEED))


def soonest_capture_landing(params: StopParameters, changes: dict, swing: str) -> float:
    """The soonest a hurried landing of the ``swing`` foot may touch down [s from ``changes["time"]``]: after
    its descent (:func:`~drake_estop.planning.problems.descent_time`, from its height, rate and acceleration in
    ``changes``, a re-plan start's) and the planner's shortest landing (the braked landing's own bound, to the
    plan's far landing point, is what a hurried landing replaces)."""
    feet, rates, accelerations = (changes[key] for key in ("feet", "feet_vel", "feet_acc"))
    return max(min(params.min_landing_time, SHORTEST_LANDING),
               descent_time(float(feet[swing][2]), params, float(rates[swing][2]), float(accelerations[swing][2])))


def capture_swing_acceleration(params: StopParameters) -> float:
    """The largest horizontal acceleration [m/s^2] of a hurried landing's swing: the stop's braking limit, at
    least :data:`CAPTURE_SWING_ACCELERATION`; that where the stop sets none (``inf``: :func:`swing_reach`
    needs a finite one)."""
    acceleration = max(params.max_swing_acceleration, CAPTURE_SWING_ACCELERATION)
    return acceleration if math.isfinite(acceleration) else CAPTURE_SWING_ACCELERATION


def _capture_deadline(dcm: float, zmp: float, edge: float, beyond: float, remaining: float, omega: float):
    """The latest time [s] at which a DCM ``dcm`` [m] diverging from ``zmp`` [m] (eq. 6-9) has not passed
    ``edge`` [m] (:func:`~drake_estop.planning.capture.capture_time`), where it passes ``beyond`` [m] (on the
    same side) before the plan's touchdown ``remaining`` [s] from now; else None (no hurry on this axis)."""
    side = math.copysign(1.0, edge - zmp)
    if side * (dcm - zmp) <= 0 or side * (zmp + (dcm - zmp) * math.exp(omega * remaining) - beyond) <= 0:
        return None
    return capture_time(dcm=dcm, zmp=zmp, edge=edge, omega=omega)


#: the spacing [m] and the landing points :func:`swing_reach` checks, from the swing ankle [m]
_REACH_STEP = 0.005
_REACH_GRID = np.arange(-1.0, 1.0 + 1e-9, _REACH_STEP)


def swing_reach(pos, vel, acc, lateral: float, duration: float, max_acceleration: float):
    """The sagittal interval ``(low, high)`` [m] of landing points ``(x, lateral)`` the landing swing
    (quintic Hermite from the ankle's ``pos``, ``vel``, ``acc`` to rest: as :func:`swing_braking_time`)
    reaches in ``duration`` [s] keeping its horizontal acceleration within ``max_acceleration`` [m/s^2];
    None where none does. Landing points on a 5 mm grid from 1 m behind to 1 m ahead of ``pos``.

    The acceleration at each grid time is affine in the landing point, so the points within the limit form
    an interval per grid time and their intersection is one interval (closed form); the grid points at its
    two ends are then checked as a grid search checks them."""
    pos, vel, acc = (np.asarray(v, float)[:2] for v in (pos, vel, acc))
    T = float(duration)
    bound = max_acceleration + 1e-9
    # acceleration at grid time j: (c_j dx + r_j[0], r_j[1]) for a landing dx ahead of the ankle
    c = _BRAKING_TERMS[0] / T**2
    r = (np.outer(_BRAKING_TERMS[0], [0.0, lateral - pos[1]]) / T**2 + np.outer(_BRAKING_TERMS[1], vel) / T
         + np.outer(_BRAKING_TERMS[2], acc))
    room = bound**2 - r[:, 1]**2
    if np.any(room < 0):
        return None
    half = np.sqrt(room)
    moving = np.abs(c) > 1e-12
    if np.any(~moving & (np.abs(r[:, 0]) > half)):
        return None
    ends = np.sort(np.stack([(-half - r[:, 0])[moving] / c[moving], (half - r[:, 0])[moving] / c[moving]]), axis=0)
    low, high = float(np.max(ends[0])), float(np.min(ends[1]))
    first = min(max(int(math.floor((low + 1.0) / _REACH_STEP)) - 1, 0), len(_REACH_GRID) - 1)
    last = min(max(int(math.ceil((high + 1.0) / _REACH_STEP)) + 1, 0), len(_REACH_GRID) - 1)
    if first > last:
        return None
    window = np.arange(first, last + 1)
    inside = window[_reach_accelerations(pos, vel, acc, lateral, T, _REACH_GRID[window]) <= bound]
    if len(inside) == 0:
        return None
    return float(pos[0] + _REACH_GRID[inside[0]]), float(pos[0] + _REACH_GRID[inside[-1]])


def _reach_accelerations(pos, vel, acc, lateral: float, duration: float, offsets):
    """The landing swing's horizontal acceleration norms [m/s^2] on its check grid, per landing point
    ``pos[0] + offsets`` (rows)."""
    xs = pos[0] + offsets
    distance = np.stack([xs - pos[0], np.full_like(xs, lateral - pos[1])], axis=1)  # (n, 2)
    T = duration
    terms = _BRAKING_TERMS
    swing = (terms[0][None, :, None] * distance[:, None, :] + terms[1][None, :, None] * vel * T
             + terms[2][None, :, None] * acc * T**2) / T**2
    return np.max(np.linalg.norm(swing, axis=2), axis=1)


def swing_braking_time(pos, vel, acc, target_xy, params: StopParameters) -> float:
    """Shortest time to touchdown [s], on the servo grid from ``params.min_landing_time``, in which the
    landing swing (:func:`~drake_estop.planning.plan.landing_swing`: quintic Hermite from the ankle's
    ``pos``, ``vel``, ``acc`` to ``target_xy`` at rest) keeps its horizontal acceleration within
    ``params.max_swing_acceleration``. ``params.min_landing_time`` without a limit, or where no duration up
    to ``params.max_landing_time`` keeps it (the ankle already accelerates harder than the limit: the swing
    starts there)."""
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
