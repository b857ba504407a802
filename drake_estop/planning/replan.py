"""Re-planning a stop from a measured state (after a push), and the recovery step.

:func:`replan_stop` solves the stop again at a servo tick from the measured COG (eq. 10-11) and
the current plan's ZMP (eq. 12-13): before the landing a new landing (III.A), with the ankle
strategy (:func:`ankle_zmp`) where the held ZMP finds none, and where no landing stops the robot
the capture landing (:mod:`drake_estop.planning.capture_landing`: sooner and nearer, and where that stops
nothing two steps, N-step capture); after it a double-support stop (III.B) on the landed or measured feet,
and where none exists the recovery step. Each try is a small :class:`ReplanTry` (whether it applies, and its
solve) run in the order of :data:`REPLAN_TRY_ORDER`. :func:`replan_support` says which support applies and
:class:`ReplanPending` resumes a call bounded by ``max_solves`` on a later tick.
"""

from __future__ import annotations

import math
import time
from dataclasses import replace

import numpy as np

from drake_estop.planning.assembly import plan_from, with_compute_time
from drake_estop.planning.capture_landing import SHORTEST_LANDING, capture_setup, swing_braking_time
from drake_estop.planning.capture_landing import capture_landing as capture_landing_plan
from drake_estop.planning.crossover import crossover_stop
from drake_estop.planning.gait import SIDES, rotation
from drake_estop.planning.plan import InfeasibleStop, StopParameters, StopPlan
from drake_estop.planning.recovery import on_sole, zmp_to_reach
from drake_estop.planning.recovery import recovery_step as recovery_step_plan


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
#: a two-step capture's second (:func:`~drake_estop.planning.capture_landing.capture_step`) and one recovery
#: step more (Koolen et al. 2012: past three steps the capture region grows little).
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


def replan_support(plan: StopPlan, t: float, halt: bool = False) -> str | None:
    """What :func:`replan_stop` re-plans at ``t``: "single" (the landing can still move), "double" (after
    the landing, before the halt; with ``halt``, before the halt's end), or None (nothing left to re-plan)."""
    if plan.x is None or t < plan.start_time:
        return None
    if (plan.landing_foot is not None and t < plan.landing_time - shortest_replanned_landing(plan)
            and not plan.recovery_step):  # a recovery step lands as planned (a re-plan hurried it: 2.3 kN)
        return "single"
    return "double" if plan.landing_time <= t < (plan.halt_end if halt else plan.slowdown_end) else None


def shortest_replanned_landing(plan: StopPlan) -> float:
    """The shortest landing [s] a single-support re-plan of ``plan`` may still make: the plan's
    ``min_landing_time`` (which a braked landing raised to its own braking time) or, for the capture
    landing (:func:`~drake_estop.planning.capture_landing.capture_landing`), the planner's shortest landing,
    whichever is shorter."""
    return min(plan.params.min_landing_time, SHORTEST_LANDING)


def _capture_only(plan: StopPlan, t: float) -> bool:
    """A single-support re-plan past the plan's own ``min_landing_time``: only the capture landing,
    which lands sooner, is left to try."""
    return t >= plan.landing_time - plan.params.min_landing_time


def replan_stop(plan: StopPlan, t: float, com_xy, com_vel_xy, *, feet=None, recovery_step: bool = False,
                capture_landing: bool = True, first_try: int = 0, max_solves: int | None = None,
                crossover: bool = False, halt: bool = False) -> StopPlan | None:
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
    (:mod:`~drake_estop.planning.capture_landing`); False leaves it out, for comparison. Where that landing does
    not stop the robot either and ``recovery_step`` is set, it is followed by a recovery step of the old support
    foot (N-step capture, :func:`~drake_estop.planning.capture_landing.capture_step`: the plan lands once, and
    its :attr:`~drake_estop.planning.plan.StopPlan.next_step` is the second step).

    **Crossover step** (``crossover=True``; before the landing only; default off). Where the lateral DCM lies at the
    support sole's outer bound (a push towards the foot standing alone), the single-support re-plan first tries a
    landing beyond the support foot, in front of its leg, where the legs' geometry allows
    (:func:`drake_estop.planning.crossover.crossover_stop`); else the tries below as usual.

    **Bounded work.** The tries (:data:`REPLAN_TRY_ORDER`: up to five solves in single support, two in double support)
    run in order until one gives a stop. ``max_solves`` (None: no bound) caps the solves of this call: when it runs
    out with tries left, :class:`ReplanPending` says where to go on (``first_try``) on a later tick, from that
    tick's measurement. A try the ankle strategy would repeat (its stance ZMP within 1 mm of the plan's) is skipped
    and costs no solve.

    **The halt** (``halt=True``; default off). The halt is re-planned as the rest of the double support: a
    double-support stop from the measured COG on ``feet``, so that the COG comes to rest between the soles
    where they stand rather than where the plan put them.

    Returns None where nothing is left to re-plan (the halt unless ``halt``, a plan that has not started yet, a
    standing plan).
    Raises :class:`InfeasibleStop` when no stop exists from that state (:class:`ReplanPending` when tries are left),
    ``ValueError`` for non-finite ``feet``, a ``first_try`` outside the support's tries or a ``max_solves`` below 1.
    """
    footholds = _footholds(feet)
    check_solve_bound(max_solves)
    support = replan_support(plan, t, halt)
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


class ReplanTry:
    """One try of a re-plan (:func:`replan_stop`): :meth:`applies` says whether it applies from the
    :class:`ReplanAttempt` (its setup, or None: skipped, no solve), :meth:`solve` plans the stop or raises
    :class:`InfeasibleStop`. The tries of a support run in the order of :data:`REPLAN_TRY_ORDER`."""

    name = ""

    def applies(self, attempt: ReplanAttempt) -> tuple | None:
        return ()

    def solve(self, attempt: ReplanAttempt, *setup) -> StopPlan:
        raise NotImplementedError


class HeldZmp(ReplanTry):
    """The plan's ZMP held on the support foot (eq. 19), or on both feet after the landing (III.B)."""

    name = "held"

    def solve(self, attempt, *setup):
        return attempt.start.solve(stance_zmp=None)


class AnkleZmp(ReplanTry):
    """The ankle strategy: the support foot's ZMP moved to :func:`ankle_zmp` (``name`` "ankle"), or to its
    lateral or sagittal part alone; skipped where it would repeat the plan's ZMP (within 1 mm)."""

    def __init__(self, name: str):
        self.name = name

    def applies(self, attempt):
        ankle = attempt.ankle()
        if not ankle:
            return None
        stance_zmp = ankle[self.name]
        if np.max(np.abs(stance_zmp - attempt.start.zmp)) < 1e-3:  # the plan's ZMP at t: nothing new to try
            return None
        return (stance_zmp,)

    def solve(self, attempt, stance_zmp):
        return attempt.start.solve(stance_zmp=stance_zmp)


class CaptureLanding(ReplanTry):
    """Land sooner and nearer, by the DCM's deadline
    (:func:`~drake_estop.planning.capture_landing.capture_landing`), two steps where one stops nothing and a
    recovery step is allowed; applies where ``capture_landing`` is on and
    :func:`~drake_estop.planning.capture_landing.capture_setup` finds a deadline before the touchdown."""

    name = "capture"

    def applies(self, attempt):
        if not attempt.capture_landing:
            return None
        setup = capture_setup(attempt.start, attempt.com_xy, attempt.com_vel_xy)
        return None if setup is None else (setup,)

    def solve(self, attempt, setup):
        return capture_landing_plan(attempt.start, setup, attempt.failure, two_steps=attempt.recovery_step)


class RecoveryStep(ReplanTry):
    """The rear foot steps past the fore foot (:func:`~drake_estop.planning.recovery.recovery_step`), where
    ``recovery_step`` is on."""

    name = "recovery step"

    def applies(self, attempt):
        return () if attempt.recovery_step else None

    def solve(self, attempt, *setup):
        return recovery_step_plan(attempt.plan, attempt.t, attempt.com_xy, attempt.com_vel_xy, attempt.params,
                                  attempt.footholds, attempt.failure)


#: A re-plan's tries, in order, by the support it starts in: single support (III.A) holds the plan's ZMP,
#: then the ankle strategy's stance ZMP, its lateral part alone, its sagittal part alone, then the capture
#: landing; double support (III.B) holds the plan's ZMP, then takes the recovery step.
REPLAN_TRY_ORDER = {"single": (HeldZmp(), AnkleZmp("ankle"), AnkleZmp("ankle lateral"), AnkleZmp("ankle sagittal"),
                               CaptureLanding()),
                    "double": (HeldZmp(), RecoveryStep())}
#: The tries' names in that order: ``replan_stop(first_try=k)`` starts at the k-th.
REPLAN_TRIES = {support: tuple(each.name for each in tries) for support, tries in REPLAN_TRY_ORDER.items()}


class ReplanAttempt:
    """What the tries of one :func:`replan_stop` call share: the start (:class:`ReplanStart`, built once), the
    measured COG, the footholds, the options, the last failure and the ankle strategy's ZMPs (computed once,
    when a try first asks)."""

    def __init__(self, plan, t, com_xy, com_vel_xy, support, footholds, *, recovery_step, capture_landing, failure):
        # a push may need the early step, and a landing moved further than a low foot could on its own
        self.params = replace(plan.params, max_early_landing=math.inf, max_landing_shift_per_height=math.inf)
        double = support == "double"
        self.start = ReplanStart(plan, t, com_xy, com_vel_xy, double, self.params, footholds if double else None)
        self.plan, self.t, self.com_xy, self.com_vel_xy = plan, t, com_xy, com_vel_xy
        self.footholds, self.recovery_step, self.capture_landing = footholds, recovery_step, capture_landing
        self.failure = failure
        self._ankle = None

    def ankle(self) -> dict:
        """:func:`_ankle_tries` at the start (cached)."""
        if self._ankle is None:
            self._ankle = _ankle_tries(self.plan, self.t, self.com_xy, self.com_vel_xy, self.start.zmp)
        return self._ankle


def _run_tries(plan: StopPlan, t: float, com_xy, com_vel_xy, support: str, first_try: int, footholds, *,
               recovery_step: bool, capture_landing: bool, max_solves: int | None, crossover: bool) -> StopPlan:
    """:func:`replan_stop`'s tries (:data:`REPLAN_TRY_ORDER`) from ``first_try`` on, the crossover step first
    where asked: the first stop; else raises the last failure, or :class:`ReplanPending`."""
    tries = REPLAN_TRY_ORDER[support]
    # resumed (first_try > 0): what a try that does not apply re-raises (the held ZMP always runs at 0)
    failure = InfeasibleStop(f"re-plan at t={t:.3f} s: the {support}-support tries before "
                             f"{tries[first_try].name!r} found no stop on earlier ticks") if first_try else None
    attempt = ReplanAttempt(plan, t, com_xy, com_vel_xy, support, footholds, recovery_step=recovery_step,
                            capture_landing=capture_landing, failure=failure)
    solves = 0
    if crossover and support == "single":  # before the ankle strategy and the capture landing: the DCM is past them
        try:
            found = crossover_stop(attempt.start, com_xy, com_vel_xy)
        except InfeasibleStop as error:
            attempt.failure, solves = error, 1
        else:
            if found is not None:
                return found
    for index in range(first_try, len(tries)):
        setup = tries[index].applies(attempt)
        if setup is None:
            continue  # the try does not apply here: no solve
        if max_solves is not None and solves >= max_solves:
            raise ReplanPending(f"{attempt.failure}; {len(tries) - index} of the {support}-support tries left "
                                f"from {tries[index].name!r}", support, index)
        solves += 1
        try:
            return tries[index].solve(attempt, *setup)
        except InfeasibleStop as error:
            attempt.failure = error
    raise attempt.failure


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


class ReplanStart:
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
