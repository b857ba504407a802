"""Re-planning a stop from a measured state (after a push), and the recovery step.

:func:`replan_stop` solves the stop again at a servo tick from the measured COG (eq. 10-11) and
the current plan's ZMP (eq. 12-13): before the landing a new landing (III.A), with the ankle
strategy (:func:`ankle_zmp`) where the held ZMP finds none, and where no landing stops the robot
two steps (:func:`capture_step`: N-step capture); after it a double-support stop (III.B) on the
landed or measured feet, and where none exists the recovery step.
:func:`replan_support` says which applies, :data:`REPLAN_TRIES` lists the tries in order and
:class:`ReplanPending` resumes a call bounded by ``max_solves`` on a later tick.
:func:`swing_braking_time` bounds how soon a moving swing foot can land.
"""

from __future__ import annotations

import math
import time
from dataclasses import replace

import numpy as np

from drake_estop.planning import lipm
from drake_estop.planning.assembly import plan_from, with_compute_time
from drake_estop.planning.capture import capture_time
from drake_estop.planning.gait import SIDES, rotation
from drake_estop.planning.plan import SWING_GRID, InfeasibleStop, StopParameters, StopPlan, snap_to_tick
from drake_estop.planning.problems import descent_time
from drake_estop.planning.recovery import RECOVERY_ZMP_MARGIN, on_sole, zmp_to_reach
from drake_estop.planning.recovery import recovery_step as recovery_step_plan
from drake_estop.planning.zmp_check import start_polygon

#: A re-plan's tries, in order, by the support it starts in: single support (III.A) holds the plan's ZMP,
#: then the ankle strategy's stance ZMP, its lateral part alone, its sagittal part alone, then the capture
#: landing (:func:`_capture_landing`: sooner and nearer, by the DCM's deadline; with the recovery step, two
#: steps where one does not stop: :func:`capture_step`); double support
#: (III.B) holds the plan's ZMP, then takes the recovery step. ``replan_stop(first_try=k)`` starts at the k-th.
REPLAN_TRIES = {"single": ("held", "ankle", "ankle lateral", "ankle sagittal", "capture"),
                "double": ("held", "recovery step")}


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

#: The most landings a stop takes after its signal (the online controller's ``max_steps``): the paper's one,
#: a two-step capture's second (:func:`capture_step`) and one recovery step more (Koolen et al. 2012: past
#: three steps the capture region grows little).
MAX_STOP_STEPS = 3

def check_step_bound(value, name: str = "max_steps"):
    """``value`` if it bounds a stop's landings (a positive integer); else ``ValueError`` naming ``name``."""
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ValueError(f"{name} must be a positive integer, got {value!r}")
    return value


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
    if (plan.landing_foot is not None and t < plan.landing_time - shortest_replanned_landing(plan)
            and not plan.recovery_step):  # a recovery step lands as planned (a re-plan hurried it: 2.3 kN)
        return "single"
    return "double" if plan.landing_time <= t < plan.slowdown_end else None


def shortest_replanned_landing(plan: StopPlan) -> float:
    """The shortest landing [s] a single-support re-plan of ``plan`` may still make: the plan's
    ``min_landing_time`` (which a braked landing raised to its own braking time) or, for the capture
    landing (:func:`_capture_landing`), the planner's shortest landing, whichever is shorter."""
    return min(plan.params.min_landing_time, _SHORTEST_LANDING)


def _capture_only(plan: StopPlan, t: float) -> bool:
    """A single-support re-plan past the plan's own ``min_landing_time``: only the capture landing,
    which lands sooner, is left to try."""
    return t >= plan.landing_time - plan.params.min_landing_time


def replan_stop(plan: StopPlan, t: float, com_xy, com_vel_xy, *, feet=None, recovery_step: bool = False,
                capture_landing: bool = True, first_try: int = 0, max_solves: int | None = None,
                crossover: bool = False) -> StopPlan | None:
    """Re-plan a stop at tick ``t`` from the measured COG (e.g. after a push).

    The new plan starts at ``t`` from the current plan's ZMP (value, rate and acceleration: eq. 12-13) and feet, and
    from the measured COG position and velocity (eq. 10-11):

    * landing phase, while the landing can still move (before ``landing_time - min_landing_time``): landing time,
      step length and the later phases are solved again (III.A, eq. 21-26);
    * after the landing, in the ZMP transition or the slowdown: the stop is solved again as a double-support stop on
      the landed feet (III.B, eq. 29-31).

    **Ankle strategy.** The paper holds the ZMP still on the support foot until the landing (eq. 19). When no
    landing stops the measured state that way (a push towards the support foot's side puts the DCM over its outer
    edge; a forward push needs a step longer than ``max_step_length``), the single-support re-plan moves that ZMP,
    at rest, to :func:`ankle_zmp` (the point of the support sole, less ``zmp_margin``, that brings the DCM back to
    the plan's at its landing), then to its lateral part alone, then to its sagittal part alone, and keeps the first
    that gives a stop. The ZMP steps there at ``t`` (the COG stays continuous: position and velocity; eq. 10-11
    hold, eq. 12-13 do not); a physical robot's centre of pressure does the same under a push. Measured on the
    pushed physics benchmark: see ``benchmarks/ROBUSTNESS.md``.

    ``feet`` (after the landing only: ``{side: (x, y)}`` [m], either or both sides) are measured footholds: the
    double-support stop is solved on them instead of the plan's feet (a pushed swing foot lands centimetres from its
    target; its support polygon is where it stands). Ignored before the landing.

    **Recovery step** (``recovery_step=True``; after the landing only). Where no double-support stop exists (a
    forward push puts the DCM past the fore foot's ankle: stopping the COG between the feet then needs a ZMP beyond
    the toe, or stretches the rear leg past ``max_rear_reach``), the re-plan steps: the rear foot lifts at ``t`` and
    lands ahead (:func:`~drake_estop.planning.recovery.recovery_step`), the stop solved as a single-support stop
    (III.A, eq. 21-26) on the fore foot from the measured COG. A step out of double support where a stop would end:
    the paper's plan has no such step (its stop lands once); the field's push recovery (Pratt et al. 2006, IHMC)
    steps towards the capture point. Only forward (the rear foot steps past the fore foot), from a DCM at least
    :func:`~drake_estop.planning.recovery.recovery_dcm_ahead` past the fore ankle, not heading for the rear foot's
    side past the fore sole's inner edge (unless ``recovery_step_inward``: landing wider,
    :func:`~drake_estop.planning.recovery.recovery_landing_width`), with the rear leg within ``max_rear_reach``; a
    DCM outside the feet sideways or behind is not caught (sideways no step without a crossover would:
    :func:`drake_estop.planning.capture.step_out_gain`).

    **Capture landing** (``capture_landing=True``, the default; before the landing only). Where a sideways push
    sends the lateral DCM past the widest landing, or a forward push the sagittal DCM past the farthest one, before
    the plan's touchdown, the last single-support try lands sooner, where the swing can still brake
    (:func:`_capture_landing`, :func:`capture_setup`); False leaves it out, for comparison. Where that landing does
    not stop the robot either and ``recovery_step`` is set, it is followed by a recovery step of the old support
    foot (N-step capture, :func:`capture_step`: the plan lands once, and its
    :attr:`~drake_estop.planning.plan.StopPlan.next_step` is the second step).

    **Crossover step** (``crossover=True``; before the landing only; default off). Where the lateral DCM lies at the
    support sole's outer bound (a push towards the foot standing alone), the single-support re-plan first tries a
    landing beyond the support foot, in front of its leg, where the legs' geometry allows
    (:func:`drake_estop.planning.crossover.crossover_stop`); else the tries below as usual.

    **Bounded work.** The tries (:data:`REPLAN_TRIES`: up to five solves in single support, two in double support)
    run in order until one gives a stop. ``max_solves`` (None: no bound) caps the solves of this call: when it runs
    out with tries left, :class:`ReplanPending` says where to go on (``first_try``) on a later tick, from that
    tick's measurement. A try the ankle strategy would repeat (its stance ZMP within 1 mm of the plan's) is skipped
    and costs no solve.

    Returns None where nothing is left to re-plan (the halt, a plan that has not started yet, a standing plan).
    Raises :class:`InfeasibleStop` when no stop exists from that state (:class:`ReplanPending` when tries are left),
    ``ValueError`` for non-finite ``feet``, a ``first_try`` outside the support's tries or a ``max_solves`` below 1.
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
    if support == "single" and _capture_only(plan, t):
        first_try = max(first_try, tries.index("capture"))
    return _run_tries(plan, t, com_xy, com_vel_xy, support, first_try, footholds, recovery_step=recovery_step,
                      capture_landing=capture_landing, max_solves=max_solves, crossover=crossover)


def _run_tries(plan: StopPlan, t: float, com_xy, com_vel_xy, support: str, first_try: int, footholds, *,
               recovery_step: bool, capture_landing: bool, max_solves: int | None, crossover: bool) -> StopPlan:
    """:func:`replan_stop`'s tries (:data:`REPLAN_TRIES`) from ``first_try`` on, from one :class:`_ReplanStart`, the
    crossover step first where asked: the first stop; else raises the last failure, or :class:`ReplanPending`."""
    tries = REPLAN_TRIES[support]
    # a push may need the early step, and a landing moved further than a low foot could on its own
    params = replace(plan.params, max_early_landing=math.inf, max_landing_shift_per_height=math.inf)
    double = support == "double"
    start = _ReplanStart(plan, t, com_xy, com_vel_xy, double, params, footholds if double else None)
    # resumed (first_try > 0): what a try that does not apply re-raises (the held ZMP always runs at 0)
    failure = InfeasibleStop(f"re-plan at t={t:.3f} s: the {support}-support tries before "
                             f"{tries[first_try]!r} found no stop on earlier ticks") if first_try else None
    ankle, solves = None, 0
    if crossover and support == "single":  # before the ankle strategy and the capture landing: the DCM is past them
        from drake_estop.planning.crossover import crossover_stop  # (it plans with this module's helpers)
        try:
            found = crossover_stop(start, com_xy, com_vel_xy)
        except InfeasibleStop as error:
            failure, solves = error, 1
        else:
            if found is not None:
                return found
    for index in range(first_try, len(tries)):
        name, stance_zmp = tries[index], None
        if name == "recovery step" and not recovery_step:
            break
        if name.startswith("ankle"):  # the support foot's ZMP moved to take back the DCM deviation
            if ankle is None:
                ankle = _ankle_tries(plan, t, com_xy, com_vel_xy, start.zmp)
            if not ankle:
                continue
            stance_zmp = ankle[name]
            if np.max(np.abs(stance_zmp - start.zmp)) < 1e-3:  # the plan's ZMP at t: nothing new to try
                continue
        if name == "capture":
            capture = capture_setup(start, com_xy, com_vel_xy) if capture_landing else None
            if capture is None:
                continue  # the capture landing does not apply here: no solve
        if max_solves is not None and solves >= max_solves:
            raise ReplanPending(f"{failure}; {len(tries) - index} of the {support}-support tries left "
                                f"from {name!r}", support, index)
        solves += 1
        try:
            if name == "recovery step":
                return recovery_step_plan(plan, t, com_xy, com_vel_xy, params, footholds, failure)
            if name == "capture":
                return _capture_landing(start, capture, failure, two_steps=recovery_step)
            return start.solve(stance_zmp=stance_zmp)
        except InfeasibleStop as error:
            failure = error
    raise failure


#: How far [m] past the widest landing ankle (outwards) the lateral DCM may lie at a capture landing's
#: touchdown (:func:`_capture_landing`): negative, inside it. Measured on the 29 N s push to the right at
#: 2.95 s: with 0 the plan lands 35 ms later and the robot, whose real lateral DCM runs 2-3 cm ahead of the
#: LIPM's (its body rolls), falls; with -0.03 it stops.
CAPTURE_DCM_PAST_ANKLE = -0.03
_SHORTEST_LANDING = StopParameters().min_landing_time
#: How far [m] behind the nearest landing point the support ZMP sends the sagittal DCM by a capture landing's
#: touchdown (:func:`_capture_landing`).
CAPTURE_DCM_BEHIND_LANDING = 0.05
#: The least sagittal span [m] of landing points the capture landing's swing must reach by its touchdown.
CAPTURE_LANDING_SPAN = 0.03
#: The fastest descent [m/s] of a capture landing's swing foot (the planner's ``max_swing_descent_speed``, 0.3 m/s,
#: takes 0.29 s down from the 5 cm apex: by then a 0.5 m/s sideways push has the DCM past the widest landing).
CAPTURE_DESCENT_SPEED = 0.6
#: The largest horizontal acceleration [m/s^2] of a capture landing's swing foot (the braked landing's is 15:
#: with 15 the 29 N s push's capture landing reached 1 cm of landing points by its deadline and found no stop).
CAPTURE_SWING_ACCELERATION = 20.0


def _capture_landing(start: _ReplanStart, setup: tuple, failure: InfeasibleStop, two_steps: bool = False) -> StopPlan:
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


def capture_step(start: _ReplanStart, setup: tuple, failure: InfeasibleStop) -> StopPlan:
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


def capture_setup(start: _ReplanStart, com_xy, com_vel_xy):
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
    return max(min(params.min_landing_time, _SHORTEST_LANDING),
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
    wanted = zmp_to_reach(xi_now, xi_landing, grow)
    support = next(side for side in SIDES if side != plan.landing_foot)
    ankle = np.asarray(plan.feet(t)[support][:2], float)
    turn = rotation(float(plan.feet_yaw(t)[0][support]))
    zmp = on_sole(plan.pattern.params.sole, support, ankle, turn, turn.T @ (wanted - ankle), plan.params.zmp_margin)
    current = np.array([traj.evaluate_at(float(t))[3] for traj in (plan.x, plan.y)])
    return None if np.max(np.abs(zmp - current)) < 1e-3 else zmp


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
        new = plan_from(plan.pattern, replace(plan.start_state, **changes), self.params, plan.signal_time,
                         plan.case, zmp_region="polygon" if self.double else "fore")
        new.braked_swing = self.braked
        new.crouch_window = plan.crouch_window or (plan.start_time, plan.halt_end)
        return with_compute_time(new, wall)
