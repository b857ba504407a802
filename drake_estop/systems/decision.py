"""What the stop controller does at a servo tick: its mode, and the one function that chooses.

:class:`~drake_estop.systems.stop_controller.StopPlannerSystem` keeps a :class:`StopMode` in its Context
and, each tick, gathers an :class:`Observation` (the filtered measured COG, the estimated soles, the soles
that landed again) and calls :func:`decide`. That function is the only code that chooses what the
controller does: walk on, latch the stop, take a planned step, re-plan, or hold the plan. The system then
executes the :class:`Action` (plans with :mod:`drake_estop.planning.planner` and
:mod:`drake_estop.planning.replan`). Everything here is pure Python and numpy, so it is tested and read
without a diagram. :class:`StopPlannerConfig` holds the planner system's settings, which are the
decision's limits.
"""

from __future__ import annotations

import dataclasses
import enum
import math
from dataclasses import dataclass

import numpy as np

from drake_estop.planning.gait import SIDES
from drake_estop.planning.late_landing import LATE_LANDING_GRACE
from drake_estop.planning.planner import MAX_LATCH_SOLVES
from drake_estop.planning.replan import (
    MAX_REPLAN_SOLVES,
    MAX_STOP_STEPS,
    check_solve_bound,
    check_step_bound,
    replan_support,
    shortest_replanned_landing,
)
from drake_estop.systems.plan_sequence import landings_made, last_landing
from drake_estop.systems.stop_numerics import dcm_deviation, foothold_loaded, off_foothold
from drake_estop.validation import check_positive

#: With ``foothold_replan``, a loaded sole this far [m] from the plan's foot re-plans the stop on the measured
#: feet (``foothold_tolerance``). The estimate is good to 3 mm (a 17 N s push: both soles within 3 mm); the
#: robustness benchmark's planned-polygon CoP failures stood on feet 5-20 mm off, the CoP in the measured soles.
FOOTHOLD_TOLERANCE = 0.005
#: With ``late_landing``, how long after the touchdown it missed a landing may still be re-timed [s]: the
#: touchdown reflex's deepest descent (15 mm) at its 0.1 m/s, with room.
MAX_LATE_LANDING = 0.2
#: With ``halt_footholds``, how many times a stop's halt may be re-planned on the measured feet.
MAX_HALT_REPLANS = 1


class StopMode(enum.IntEnum):
    """The stop controller's mode: the first element of the planner system's ``mode`` output.

    The second element counts the landings still to come (``steps_left``, dimensionless).

    Attributes
    ----------
    WALKING, LATCHED, SINGLE_SUPPORT_STOP, STEPPING, DOUBLE_SUPPORT_STOP, HALT, STANDING : int
        The modes in the order a stop passes them (dimensionless codes 0-6; :func:`stop_mode`).
    """

    WALKING = 0  #: no stop signal: the nominal walk plays
    LATCHED = 1  #: the stop is planned; the walk's own step ends first (a late signal, III.C)
    SINGLE_SUPPORT_STOP = 2  #: the stop's one landing is on its way (III.A)
    STEPPING = 3  #: a step beyond the paper's one landing is on its way (recovery step, two-step capture)
    DOUBLE_SUPPORT_STOP = 4  #: ZMP transition and slowdown on both feet (III.B)
    HALT = 5  #: the COG comes to rest between the feet
    STANDING = 6  #: at rest


def stop_mode(plan, t: float, latched: bool) -> tuple[StopMode, int]:
    """``(mode, steps_left)`` of a controller playing ``plan`` (None before the latch) at ``t`` [s].

    ``steps_left`` counts the landings after ``t``: the walk's own before a late signal's stop, the stop's
    landing, and the step planned after it (:attr:`~drake_estop.planning.plan.StopPlan.next_step`).
    """
    if plan is None:
        return (StopMode.LATCHED if latched else StopMode.WALKING), 0
    steps_left = sum(step["time"] > t + 1e-9 for step in plan.landings) + (plan.next_step is not None)
    phase = plan.phase(t)
    if phase == "stopped":
        return StopMode.STANDING, 0
    if phase == "walking" or t < plan.start_time:
        return StopMode.LATCHED, steps_left
    if phase == "landing":
        stepping = plan.recovery_step or plan.next_step is not None
        return (StopMode.STEPPING if stepping else StopMode.SINGLE_SUPPORT_STOP), steps_left
    if phase == "halt":
        return StopMode.HALT, steps_left
    return StopMode.DOUBLE_SUPPORT_STOP, steps_left


@dataclass(frozen=True)
class StopPlannerConfig:
    """The settings of :class:`~drake_estop.systems.stop_controller.StopPlannerSystem`: the decision's limits.

    Attributes
    ----------
    replan_threshold : float
        DCM deviation that makes the latch plan from the measured state, and a re-plan before the
        landing [m] (default 0.05).
    landed_replan_threshold : float
        DCM deviation that triggers a re-plan after the landing [m] (default 0.08).
    replan_interval : float
        Shortest time between re-plans [s] (default 0.05).
    blend_time : float
        Duration of the COG blend into a plan from the measured state [s] (default 0.2).
    measured_footholds : bool
        Re-plans after the landing stand on ``measured_feet`` (default True; False keeps the plan's feet).
    foothold_ticks : int
        Loaded ticks after which a landed sole's measured position is its foothold (default 2).
    foothold_replan : bool
        A loaded sole off the plan's foot by ``foothold_tolerance`` re-plans after the landing (default
        False: on the seed-0 campaign 382/500 against 376, but 49 falls against 43).
    foothold_tolerance : float
        That distance [m] (default :data:`FOOTHOLD_TOLERANCE`); also what makes a re-landed sole re-plan.
    relanded_footholds : bool
        A sole that lost contact after the landing and landed again off the plan's foothold re-plans the
        stop where it stands (default True).
    halt_footholds : bool
        The halt is re-planned once on the measured feet: a loaded sole off the plan's foot by
        ``foothold_tolerance`` in the halt, with the DCM within ``landed_replan_threshold`` of the plan's,
        re-plans the double-support stop where the soles stand, from the plan's own COG; without it the halt
        plays out on the plan's feet (default False). A stop with no landing takes both soles once both are
        loaded. In the halt neither a sole that lands again nor the DCM re-plans then.
    recovery_step : bool
        A re-plan after the landing that finds no double-support stop steps the rear foot forward, and a
        capture landing that stops nothing steps again (default True).
    capture_landing : bool
        A single-support re-plan whose other tries find no stop lands sooner, at the widest step (default
        True).
    crossover_step : bool
        A single-support re-plan first tries a crossover step (default False).
    max_steps : int
        The most landings after the signal, the walk's own included (default :data:`MAX_STOP_STEPS`).
    max_replan_solves : int or None
        Stop solves a re-plan may do in one tick (default 2; None: all of its tries on one tick).
    max_latch_solves : int or None
        Stop solves the latch's search from the measured state may do (default
        :data:`drake_estop.planning.planner.MAX_LATCH_SOLVES`; None: unbounded).
    reference_fallback : bool
        Where no stop exists from the measured state at the signal, plan the paper's stop from the
        reference and re-plan from the measured state (default True; False raises InfeasibleStop).
    plan_ahead : bool
        Every tick before the latch has the stop of a signal at that tick from the reference, so the
        latch on the reference is a look-up (default True). A stop in the signal's own phase was planned
        before the run (:func:`~drake_estop.systems.stop_numerics.nominal_stop_table`); the others
        (III.C) are planned on the tick.
    late_landing : bool
        A landing sole that has carried no weight by the touchdown re-times the stop: the ZMP stays on the
        stance sole and the foot lands a moment later, again while it stays unloaded
        (:func:`~drake_estop.planning.late_landing.late_landing_stop`; default False). Meant with the
        touchdown reflex (``ControllerOptions.touchdown``), which lowers the foot until it carries weight.
    max_late_landing : float
        How long after the touchdown it missed a landing may still be re-timed [s] (default
        :data:`MAX_LATE_LANDING`).

    Raises
    ------
    ValueError
        Naming the field: a time constant or threshold that is not positive and finite, or a
        ``foothold_ticks``, ``max_steps``, ``max_replan_solves`` or ``max_latch_solves`` that is not a
        positive integer.
    """

    replan_threshold: float = 0.05
    landed_replan_threshold: float = 0.08
    replan_interval: float = 0.05
    blend_time: float = 0.2
    measured_footholds: bool = True
    foothold_ticks: int = 2
    foothold_replan: bool = False
    foothold_tolerance: float = FOOTHOLD_TOLERANCE
    relanded_footholds: bool = True
    halt_footholds: bool = False
    recovery_step: bool = True
    capture_landing: bool = True
    crossover_step: bool = False
    max_steps: int = MAX_STOP_STEPS
    max_replan_solves: int | None = MAX_REPLAN_SOLVES
    max_latch_solves: int | None = MAX_LATCH_SOLVES
    reference_fallback: bool = True
    plan_ahead: bool = True
    late_landing: bool = False
    max_late_landing: float = MAX_LATE_LANDING

    def __post_init__(self):
        for name in ("replan_threshold", "blend_time", "replan_interval", "landed_replan_threshold",
                     "foothold_tolerance", "max_late_landing"):
            check_positive(name, getattr(self, name))
        ticks = self.foothold_ticks
        if (isinstance(ticks, bool) or not isinstance(ticks, (int, float)) or not math.isfinite(ticks)
                or ticks != int(ticks) or ticks < 1):
            raise ValueError(f"foothold_ticks must be a positive integer, got {ticks!r}")
        check_step_bound(self.max_steps)
        check_solve_bound(self.max_replan_solves, "max_replan_solves")
        check_solve_bound(self.max_latch_solves, "max_latch_solves")

    @classmethod
    def field_names(cls) -> tuple:
        """The settings' names, in declaration order."""
        return tuple(f.name for f in dataclasses.fields(cls))

    def replaced(self, **changes) -> StopPlannerConfig:
        """A copy with ``changes`` (field: value), checked again."""
        return dataclasses.replace(self, **changes)


@dataclass(frozen=True)
class Observation:
    """What the stop planner system knows at a tick, for :func:`decide`.

    Attributes
    ----------
    time : float
        The tick [s].
    latched : bool
        Whether the e-stop trigger has latched a signal.
    signal_time : float
        The latched signal's time [s] (meaningless unless ``latched``).
    measured : tuple or None
        The filtered measured COG ``(com_xy, com_vel_xy)`` [m, m/s] less the learnt tracking bias, or None
        without a measurement.
    reference_deviation : float or None
        Before the latch's plan: the measured DCM's distance from the walk's at :func:`planning_time` [m]
        (None without a measurement or once a plan is in force).
    feet : numpy.ndarray or None
        The estimated soles ``[x_l, y_l, x_r, y_r, loaded ticks l, loaded ticks r]``, or None when the
        ``measured_feet`` input is not connected.
    relanded : dict
        ``{side: xy}``: soles that landed again off the plan's foothold after the landing.
    relanded_now : bool
        Whether one of them did so on this tick.
    """

    time: float
    latched: bool = False
    signal_time: float = math.nan
    measured: tuple | None = None
    reference_deviation: float | None = None
    feet: np.ndarray | None = None
    relanded: dict = dataclasses.field(default_factory=dict)
    relanded_now: bool = False


class ActionKind(enum.Enum):
    """What the stop planner system does at a tick (:class:`Action`)."""

    WALK = "walk"  #: play the walk; judge the one-step feasibility of a signal now, plan its stop ahead
    LATCH = "latch"  #: plan the stop
    NEXT_STEP = "next step"  #: take the step planned after a capture landing, re-planned from the measurement
    REPLAN = "replan"  #: re-plan the stop from the measured state
    RETIME = "retime"  #: land later: the landing sole has carried no weight by the touchdown
    HOLD = "hold"  #: keep the plan and a re-plan's tries left for the next tick
    WAIT = "wait"  #: keep the plan; a re-plan's tries left are dropped


@dataclass(frozen=True)
class Action:
    """The decision of a tick (:func:`decide`).

    Attributes
    ----------
    kind : ActionKind
        What to do.
    reason : str
        Why, in words (one line of the table in :func:`decide`'s docstring).
    plan_time : float or None
        ``WALK`` and ``LATCH``: the time [s] the stop is planned for (the signal's tick from the reference,
        else the tick of the measurement).
    from_measured : bool
        ``WALK`` and ``LATCH``: plan from the measured state (else from the reference).
    feet : dict or None
        ``REPLAN``: ``{side: xy}`` footholds to stand the stop on (None: the plan's).
    recovery_step : bool
        ``REPLAN``: the re-plan may step the rear foot out (or take two steps).
    first_try : int
        ``REPLAN``: the first of the support's tries (:data:`drake_estop.planning.replan.REPLAN_TRIES`).
    resumed : bool
        ``REPLAN``: the tries go on from an earlier tick (the re-plan keeps that tick as its last try).
    from_plan : bool
        ``REPLAN``: from the plan's own COG at the tick (the command goes on: only the feet change), not the
        measured one.
    """

    kind: ActionKind
    reason: str = ""
    plan_time: float | None = None
    from_measured: bool = False
    feet: dict | None = None
    recovery_step: bool = False
    first_try: int = 0
    resumed: bool = False
    from_plan: bool = False


def planning_time(observation: Observation) -> float:
    """The tick [s] a plan from the measured state at ``observation`` starts at: the later of the tick and
    the latched signal."""
    if observation.latched:
        return max(observation.signal_time, observation.time)
    return observation.time


def decide(observation: Observation, handle, config: StopPlannerConfig) -> Action:
    """The stop controller's choice at a tick: the only code that decides what it does.

    ``handle`` is the planner system's :class:`~drake_estop.systems.plan_sequence.PlanHandle` (the plan in
    force, its history, the last re-plan's tick and tries left), ``config`` the limits. The mode column is
    :func:`stop_mode` of that plan at the tick, which the plan and the time say. Situations are taken top
    down; the first that holds decides.

    ==========================  ===============================================  =============
    mode                        situation                                        action
    ==========================  ===============================================  =============
    WALKING                     no signal latched                                WALK
    WALKING                     a signal latched                                 LATCH
    (any stop)                  a capture landing's touchdown, a step planned     NEXT_STEP
                                after it
    (any stop)                  no measured state                                HOLD
    (any stop)                  the landing sole unloaded ``LATE_LANDING_GRACE``  RETIME
                                past the touchdown (at once past a re-timed
                                one), within ``max_late_landing`` of the first
                                (``late_landing``)
    (any stop)                  within ``replan_interval`` of the last try, no   WAIT
                                tries left, no sole re-landed on this tick
    HALT (``halt_footholds``)   a loaded sole off the plan's, the DCM within      REPLAN on the
                                ``landed_replan_threshold``, no halt re-plan yet  measured feet, from
                                (else WAIT: a re-landed sole, the DCM off)        the plan's COG
    (any stop)                  a sole re-landed off its foothold                REPLAN on it
    (any stop)                  the DCM within its threshold, the soles on the   WAIT
                                plan's (or no ``foothold_replan``)
    SINGLE_SUPPORT_STOP,        the DCM past ``replan_threshold``                REPLAN (single
    STEPPING, LATCHED                                                            support tries)
    DOUBLE_SUPPORT_STOP, HALT   the DCM past ``landed_replan_threshold``, or a    REPLAN on the
                                loaded sole off the plan's (``foothold_replan``)  measured feet
    ==========================  ===============================================  =============

    WALK and LATCH plan from the measured state where its DCM has left the walk's by more than
    ``replan_threshold``, else from the reference at the signal's tick. A REPLAN may step out
    (``recovery_step``) only when the DCM deviates and the stop has room for it within ``max_steps``
    (two landings in single support, one in double). Tries left from an earlier tick (``handle.pending``)
    go on in the same support; a re-landed sole starts the tries again.
    """
    if handle.plan is None:
        return _before_the_plan(observation, config)
    plan, t = handle.plan, observation.time
    if plan.next_step is not None and t >= plan.landing_time - 1e-9:
        return Action(ActionKind.NEXT_STEP, "the capture landing touched down: its next step")
    if observation.measured is None:
        return Action(ActionKind.HOLD, "no measured state")
    if config.late_landing and landing_late(observation, plan, config.max_late_landing):
        return Action(ActionKind.RETIME, "the landing sole carries no weight past the touchdown")
    landed = plan.landing_foot is None or t >= plan.landing_time - shortest_replanned_landing(plan)
    # a sole re-landed off its foothold after the landing re-plans at once (no interval on its
    # first tick: the sole's new place is a fact, not a deviation that a blend may still remove)
    relanded = observation.relanded if landed else None
    # a re-plan with tries left (ReplanPending) goes on at this tick, in the same support
    support = replan_support(plan, t, config.halt_footholds)
    pending = handle.pending if handle.pending and handle.pending[0] == support else None
    if not (relanded and observation.relanded_now) and pending is None and (
            t - handle.last_try < config.replan_interval - 1e-9):
        return Action(ActionKind.WAIT, "within the re-plan interval")  # let the last blend act first
    if config.halt_footholds and plan.slowdown_end <= t < plan.halt_end:
        return _in_the_halt(observation, handle, t, config)
    threshold = config.landed_replan_threshold if landed else config.replan_threshold
    deviated = dcm_deviation(plan, t, observation.measured) > threshold
    # the measured feet: for a re-plan after the landing, and (option) to see whether they left the plan's
    landing = last_landing(handle.history) if landed else None
    watch_feet = config.foothold_replan and t < plan.slowdown_end and landing is not None
    feet = _footholds(observation.feet, landing, config) if deviated or watch_feet else None
    if relanded:  # the re-landed soles where they are; the other from the footholds, or the plan's
        feet, pending, reason = {**(feet or {}), **relanded}, None, "a sole landed again off its foothold"
    elif deviated:
        reason = f"the DCM left the plan by more than {threshold:g} m"
    elif watch_feet and _feet_moved(observation.feet, plan, t, feet, config):
        reason = "a loaded sole left the plan's foothold"
    else:
        return Action(ActionKind.WAIT, "on the plan")
    # the recovery step (in single support: the second of a two-step capture) within max_steps
    room = config.max_steps - landings_made(handle.history, t) >= (2 if support == "single" else 1)
    # a re-plan for the feet alone (the DCM within its threshold) takes no recovery step
    return Action(ActionKind.REPLAN, reason, feet=feet, recovery_step=config.recovery_step and deviated and room,
                  first_try=pending[1] if pending else 0, resumed=pending is not None)


def landing_late(observation: Observation, plan, max_late: float) -> bool:
    """Whether ``plan``'s landing sole is late at the observation's tick: the plan has started and has a
    landing, the estimated soles say that sole carries no weight, and the tick lies
    :data:`~drake_estop.planning.late_landing.LATE_LANDING_GRACE` or more past the touchdown (the force
    sensing's delay at an ordinary landing; from a re-timed touchdown on, at once), and at most ``max_late``
    [s] past the first touchdown the landing missed."""
    feet, t = observation.feet, observation.time
    if plan.landing_foot is None or feet is None or t < plan.start_time - 1e-9:
        return False
    if feet[4 + SIDES.index(plan.landing_foot)] > 0:  # loaded ticks
        return False
    first = plan.landing_time if plan.late_since is None else plan.late_since
    grace = LATE_LANDING_GRACE if plan.late_since is None else 0.0
    return plan.landing_time + grace - 1e-9 <= t <= first + max_late + 1e-9


def _before_the_plan(observation: Observation, config: StopPlannerConfig) -> Action:
    """WALK or LATCH: from the reference while the measured DCM stays within ``replan_threshold`` of the
    walk's (the robot follows it: the plan is continuous with the command), else from the measured state."""
    deviation = observation.reference_deviation
    from_measured = observation.measured is not None and deviation is not None and not (
        deviation <= config.replan_threshold)
    kind = ActionKind.LATCH if observation.latched else ActionKind.WALK
    if from_measured:
        return Action(kind, "the measured DCM left the walk's", plan_time=planning_time(observation),
                      from_measured=True)
    reference_time = observation.signal_time if observation.latched else observation.time
    return Action(kind, "on the walk", plan_time=reference_time)


def _footholds(feet, landing, config: StopPlannerConfig):
    """``{side: xy}``: both soles' estimated positions, once the foot of ``landing`` (the stop's last plan
    with a landing) has been loaded ``foothold_ticks`` ticks; None without a measurement, with
    ``measured_footholds`` off, or before any landing of the stop (a stop signalled in double support keeps
    the walk's feet until a recovery step lands)."""
    if not config.measured_footholds or landing is None or feet is None:
        return None
    return _loaded_footholds(feet, (landing.landing_foot,), config)


def _loaded_footholds(feet, sides, config: StopPlannerConfig):
    """``{side: xy}`` of both soles of ``feet`` once each of ``sides`` has been loaded ``foothold_ticks``
    ticks; None with a non-finite estimate."""
    if not np.all(np.isfinite(feet)) or not all(foothold_loaded(feet, side, config.foothold_ticks) for side in sides):
        return None
    return {side: feet[2 * k:2 * k + 2].copy() for k, side in enumerate(SIDES)}


def _in_the_halt(observation: Observation, handle, t: float, config: StopPlannerConfig) -> Action:
    """The halt with ``halt_footholds``: REPLAN on the measured feet, from the plan's own COG, where a loaded
    sole has left the plan's foothold and the DCM is within ``landed_replan_threshold`` of the plan's, at most
    :data:`MAX_HALT_REPLANS` times a stop; else WAIT. A sole that lands again and a DCM that leaves the plan
    do not re-plan the halt: both are the body rocking, and re-plans that chased the soles walked them
    together until the robot fell (campaign runs 290 and 47); with the DCM off the plan, the plan's COG is
    not the robot's."""
    if dcm_deviation(handle.plan, t, observation.measured) > config.landed_replan_threshold:
        return Action(ActionKind.WAIT, "in the halt, the DCM off the plan: its COG is not the robot's")
    feet = _standing_footholds(observation.feet, last_landing(handle.history), config)
    if not _feet_moved(observation.feet, handle.plan, t, feet, config):
        return Action(ActionKind.WAIT, "in the halt, the soles on the plan's")
    if halt_replans(handle.history) >= MAX_HALT_REPLANS:
        return Action(ActionKind.WAIT, "the halt re-planned already")
    return Action(ActionKind.REPLAN, "a loaded sole left the plan's foothold in the halt", feet=feet, from_plan=True)


def _standing_footholds(feet, landing, config: StopPlannerConfig):
    """:func:`_footholds`; for a stop with no landing (signalled in double support), both soles' estimated
    positions once each has been loaded ``foothold_ticks`` ticks."""
    if landing is not None:
        return _footholds(feet, landing, config)
    if not config.measured_footholds or feet is None:
        return None
    return _loaded_footholds(feet, SIDES, config)


def halt_replans(history) -> int:
    """How many plans of ``history`` (a stop's plans, in order) were made in the halt of the plan before."""
    return sum(new.start_time >= old.slowdown_end - 1e-9 for old, new in zip(history, history[1:]))


def _feet_moved(measured_feet, plan, t, feet, config: StopPlannerConfig) -> bool:
    """Whether a sole of ``feet`` (:func:`_footholds`) that is a foothold lies more than ``foothold_tolerance``
    from where ``plan`` has it at ``t``; False without footholds."""
    if feet is None:
        return False
    planned = plan.feet(t)
    return any(foothold_loaded(measured_feet, side, config.foothold_ticks)
               and off_foothold(xy, planned[side], config.foothold_tolerance) for side, xy in feet.items())


def mode_changes(modes, servo_period: float) -> list:
    """Where a run's mode changed: ``[{"time", "mode", "steps_left"}]`` from ``modes`` (one row a tick,
    ``[StopMode, landings left]``, row k set by the update of tick ``k * servo_period``; NaN rows skipped)."""
    changes, last = [], None
    for tick, row in enumerate(np.asarray(modes, float).reshape(-1, 2)):
        if not np.all(np.isfinite(row)):
            continue
        value = (StopMode(int(row[0])).name.lower(), int(row[1]))
        if value != last:
            changes.append({"time": round(tick * servo_period, 9), "mode": value[0], "steps_left": value[1]})
            last = value
    return changes
