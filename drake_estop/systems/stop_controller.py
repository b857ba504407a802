"""The stop planner system and the stop controller's wiring.

* :class:`StopPlannerSystem` plays the nominal pattern until it sees the latch,
  then calls :func:`drake_estop.planning.planner.plan_stop` once (Fig. 7 of the paper:
  the four-phase stop is planned in real time at the servo tick of the
  signal) and keeps the :class:`~drake_estop.planning.planner.StopPlan` in an abstract
  state of its Context; from then on it plays the plan, re-planning from the
  measured state.
* :func:`add_stop_controller` adds an :class:`~drake_estop.systems.trigger.EStopTrigger`
  and a :class:`StopPlannerSystem` wired together; :func:`connect_reference`
  connects a reference source to :class:`drake_estop.systems.ik.WholeBodyIK`.

The reference layout and the walk's source :class:`~drake_estop.systems.reference.WalkingPatternSource` live in
:mod:`drake_estop.systems.reference`, the plan bookkeeping in :mod:`drake_estop.systems.plan_sequence`, the
planner system's numeric rules in :mod:`drake_estop.systems.stop_numerics`.
"""

from __future__ import annotations

import math
import time

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import EventStatus

from drake_estop.planning.gait import SIDES, NominalPattern
from drake_estop.planning.planner import (
    MAX_LATCH_SOLVES,
    InfeasibleStop,
    StopParameters,
    one_step_feasible,
    plan_stop,
    snap_to_tick,
    warm_up,
)
from drake_estop.planning.replan import (
    MAX_REPLAN_SOLVES,
    MAX_STOP_STEPS,
    REPLAN_TRIES,
    ReplanPending,
    check_solve_bound,
    check_step_bound,
    replan_stop,
    replan_support,
    shortest_replanned_landing,
)
from drake_estop.systems.plan_sequence import AheadPlan, PlanHandle, PlanSequence, landings_made, last_landing
from drake_estop.systems.reference import (
    REFERENCE_SLICES,
    ReferenceLayout,
    ReferenceSystem,
    WalkingPatternSource,  # noqa: F401  a public building block, importable from here too
    blended_reference,
    pattern_layout,
    reference_vector,
)
from drake_estop.systems.stop_numerics import (
    dcm_deviation,
    dcm_distance,
    foothold_loaded,
    nominal_one_step_table,
    off_foothold,
    relanded_soles,
)
from drake_estop.systems.trigger import EStopTrigger
from drake_estop.timing import timed

#: With ``foothold_replan``, a loaded sole this far [m] from the plan's foot re-plans the stop on the measured
#: feet (``foothold_tolerance``). The estimate is good to 3 mm (a 17 N s push: both soles within 3 mm); the
#: robustness benchmark's planned-polygon CoP failures stood on feet 5-20 mm off, the CoP in the measured soles.
FOOTHOLD_TOLERANCE = 0.005


class StopPlannerSystem(ReferenceSystem):
    """Nominal pattern until the stop latches, then the four-phase stop.

    Every ``params.servo_period`` an unrestricted update reads ``stop``; on
    the first tick that sees ``[1, t_signal]`` it calls
    ``plan_stop(pattern, t_signal, params)`` (the plan starts at the servo
    tick of the signal, from the nominal state there) and stores the plan in
    the abstract state.  Outputs are functions of time and that state.

    .. pydrake_system::

        name: StopPlannerSystem
        input_ports:
        - stop
        - measured_com
        - measured_com_vel
        - measured_feet
        output_ports:
        - com
        - com_vel
        - zmp
        - left_foot
        - right_foot
        - upper_body
        - arm_joints
        - phase
        - plan
        - one_step_feasible

    ``measured_com`` / ``measured_com_vel`` (3 each, optional: a state
    estimate). When connected, the planner low-passes them
    (``filter_time_constant``), learns the servo's steady tracking bias while
    walking (``bias_time_constant``) and, from the signal on, plans from the
    measured state where its DCM ``x + v / omega`` has left the reference by
    more than ``replan_threshold`` (else from the reference). After the
    signal it re-plans (:func:`drake_estop.planning.planner.replan_stop`, at most once
    a tick, ``replan_interval`` apart) while the measured DCM leaves the plan
    by more than ``replan_threshold`` before the landing or
    ``landed_replan_threshold`` after it; the COG command is blended into a
    plan made from the measured state over ``blend_time``. :meth:`plans`
    returns the plan and its re-plans, :meth:`replans` their count.

    ``measured_feet`` (6, optional: :class:`StateEstimator`'s ``feet``,
    ``[x_l, y_l, x_r, y_r, loaded ticks l, loaded ticks r]``). When
    connected, a re-plan after the landing (once the landed sole has been
    loaded for ``foothold_ticks`` ticks) solves the double-support stop on the
    soles' estimated positions instead of the plan's feet, and the sole
    targets are blended onto them with the COG. Measured on a 17 N s push to
    the right at 2.95 s: the swing foot landed 1.9 cm inside and 7 mm ahead
    of its target, and the support foot, unloaded by the landing impact, slid
    9 mm; the estimate put both within 3 mm. Both sides are used: the landing
    foot alone, relative to the planned support foot, missed the slide and
    left the CoP 0.6 mm outside the support. Every re-plan after a landing
    of the stop takes them (once the last landed sole has been loaded
    ``foothold_ticks`` ticks: a re-plan on the touchdown tick itself keeps
    the plan's feet, and the next one picks them up); a stop signalled in
    double support keeps the walk's feet until a recovery step lands.
    With ``foothold_replan`` (off by default), a sole loaded ``foothold_ticks``
    ticks and measured more than ``foothold_tolerance`` from the plan's makes
    such a re-plan on its own, with the DCM on the plan (before the halt,
    without a recovery step), and again each time it has moved that far
    from the last plan's (no sooner than ``replan_interval``). 17 N s right
    at 2.95 s: after the first, the rear sole, rocked off the floor, slid
    11 mm; the CoP reached its heel, 7.7 mm outside the plan's.
    With ``relanded_footholds`` (on by default), a sole that re-lands after
    the landing re-plans the stop where it stands, at once (the re-plan
    interval does not hold it back): one that stood on the floor after the
    latch, lost contact while the plan has it down and has been loaded
    ``foothold_ticks`` ticks again, more than ``foothold_tolerance`` from the
    plan's foothold (:meth:`_relanded`). Measured, 17 N s forward at 2.95 s
    with the braked landing: in the halt the robot rocked onto the fore
    foot, the rear sole left the floor for 35 ms and came down 6 mm behind
    its foothold, and the CoP ran to the rear heel, inside the measured sole
    and 0.4 mm outside the plan's. The landing itself is no re-landing (the
    swing sole never stood).

    ``max_replan_solves`` (default 2) bounds a tick's re-plan work: a
    re-plan solves at most that many stops a tick (``replan_stop``'s
    ``max_solves``); tries left (the ankle strategy's third and fourth
    stance ZMPs, the capture landing) go on at the next tick, from its measurement, while the
    measured DCM still leaves the plan. A failing single-support re-plan
    (four solves, each failing at the halt) took 7 ms of the tick at this
    machine's slow hours; two solves are the held ZMP and the ankle ZMP, or
    a double-support re-plan and its recovery step.

    ``recovery_step`` (default True): a re-plan after the landing that finds
    no double-support stop (the DCM 5 cm or more past the fore foot's ankle
    and not heading for the rear foot's side, the rear leg within reach)
    steps the rear foot past the fore foot
    (:func:`drake_estop.planning.planner.replan_stop`). The step is not
    re-planned before its touchdown (a re-plan that hurried it struck the
    floor at 2.3 kN and the robot bounced for 75 ms); after it the re-plans
    are double-support stops on the measured feet again. With it, a capture
    landing that stops nothing takes two steps (:meth:`_take_next_step`).

    ``phase`` is the index into ``PHASES``; ``plan`` (abstract) is the
    stored StopPlan, or None before the latch.  If no feasible stop exists the
    update fails and the Simulator raises with the planner's message.

    ``one_step_feasible`` (1): before the latch, 1.0 if a stop signal at this
    tick would stop within one step (the plan's ``case`` would be
    "one-step"), 0.0 if not ("next-step", the marginal case III.C, or
    "standing" / "already-stopping"). Each update computes it for a signal
    at its own tick, from the inputs the latch would plan from at that tick
    (:meth:`_plan_request`): the nominal walk's answer, looked up in
    :func:`nominal_one_step_table` (computed at construction), or, when the
    measured DCM has left the reference by more than ``replan_threshold``,
    :func:`drake_estop.planning.planner.one_step_feasible` from the measured
    state, solved on the tick. From the latch on it holds whether the
    latched stop (the first plan) is one-step; re-plans leave it.  It is
    discrete state set by the update, so the value published at tick ``t``
    (e.g. by a logger) is the previous tick's.

    Parameters
    ----------
    pattern : NominalPattern
        The walk the stop interrupts.
    params : StopParameters
        Weights, limits and servo period [s] of the planner.
    replan_threshold : float, optional
        DCM deviation that triggers a plan from the measured state, and a
        re-plan before the landing [m] (default 0.05).
    bias_time_constant : float, optional
        Time constant of the learned tracking bias [s] (default 0.5).
    filter_time_constant : float, optional
        Low-pass time constant of the measured COG [s] (default 0.03).
    blend_time : float, optional
        Duration of the COG blend into a plan from the measured state [s]
        (default 0.2).
    replan_interval : float, optional
        Shortest time between re-plans [s] (default 0.05).
    landed_replan_threshold : float, optional
        DCM deviation that triggers a re-plan after the landing [m] (default
        0.08).
    measured_footholds : bool, optional
        Whether re-plans after the landing use ``measured_feet`` (default
        True; False keeps the plan's feet, for comparison).
    foothold_ticks : int, optional
        Loaded ticks after which a landed sole's measured position is its
        foothold (default 2).
    foothold_replan : bool, optional
        Whether a loaded sole off the plan's foot re-plans after the landing
        (above; default False). On the seed-0 campaign: 382/500 against 376
        but 49 falls against 43 (a re-plan from a measured state within the
        thresholds can put the ZMP on the fore toe), so it is not the default.
    foothold_tolerance : float, optional
        That distance [m] (default :data:`FOOTHOLD_TOLERANCE`).
    recovery_step : bool, optional
        Whether a re-plan after the landing that finds no double-support
        stop steps the rear foot forward instead (``replan_stop``'s
        ``recovery_step``; default True, False keeps the plan, for
        comparison), and a capture landing that stops nothing steps again.
    max_steps : int, optional
        The most landings after the signal, the walk's own included (default
        :data:`MAX_STOP_STEPS`): a recovery step, or two steps, only within it.
    capture_landing : bool, optional
        Whether a single-support re-plan whose other tries find no stop lands sooner at the widest step
        where a sideways push sends the lateral DCM past it before the touchdown (``replan_stop``'s
        ``capture_landing``; default True, False for comparison).
    crossover_step : bool, optional
        A single-support re-plan first tries a crossover step (``replan_stop``'s ``crossover``; default False).
    relanded_footholds : bool, optional
        Whether a sole that lost contact after the landing and landed again
        more than ``foothold_tolerance`` from the plan's foothold re-plans the
        stop where it stands (default True; False for comparison).
    max_replan_solves : int or None, optional
        Stop solves a re-plan may do in one tick (default 2; None: all of
        its tries on one tick, for comparison).
    max_latch_solves : int or None, optional
        Stop solves the latch's search from the measured state may do
        (default :data:`drake_estop.planning.planner.MAX_LATCH_SOLVES`; None: every tick of the next two
        steps, up to a few hundred solves in one tick where no stop exists).
        A search that finds none within them is infeasible (see
        ``reference_fallback``). The search from the reference is not bounded.
    reference_fallback : bool, optional
        What the latch does when no stop exists from the measured state (a
        push under way at the signal; ``plan_stop`` raises InfeasibleStop):
        True (default) plans the paper's stop from the reference at the
        signal's tick, as without a measurement, so the robot is still
        controlled; re-plans from the measured state then go on every tick
        as after any deviation (:meth:`latch_fallback` gives the reason).
        False raises InfeasibleStop out of the update (ending the
        simulation), for comparison.
    plan_ahead : bool, optional
        Whether every tick before the latch plans the stop of a signal at
        that tick from the reference (default True). The latch sees a
        signal one tick later (the trigger's latch is its state); where it
        plans from the reference (the robot tracks it within
        ``replan_threshold``) it takes that plan, made from the same inputs
        (the same plan to the bit), instead of planning on its own tick:
        the stop's latency there is a look-up, and the planner's load is
        one warm plan every tick (0.5 ms median) rather than one cold plan
        (1.1-1.3 ms in the kinematic diagram) on the tick that counts.
        False plans on the latch's tick.
    timer : drake_estop.timing.TickTimer, optional
        Records the wall-clock time of every update [s].
    layout : drake_estop.systems.reference.ReferenceLayout, optional
        The robot's reference layout (its upper-body joints and their standing angles; default: the
        default robot's with the pattern's swinging joints).

    Notes
    -----
    Output ports: the same reference layout as :class:`WalkingPatternSource`
    (``com`` [m], ``com_vel`` [m/s], ``zmp`` [m], sole poses [m], joint
    targets [rad], ``phase``) plus the abstract ``plan`` and
    ``one_step_feasible`` (1, 0.0 or 1.0). Input ``stop``
    (2) is :class:`EStopTrigger`'s output; ``measured_com`` (3) [m] and
    ``measured_com_vel`` (3) [m/s] are optional.

    Raises
    ------
    ValueError
        If one of the time constants or thresholds is not positive and finite,
        or ``foothold_ticks``, ``max_steps`` or ``max_replan_solves`` is not a
        positive integer (the message names it).
    """

    def __init__(self, *, pattern: NominalPattern, params: StopParameters, replan_threshold: float = 0.05,
                 bias_time_constant: float = 0.5, filter_time_constant: float = 0.03, blend_time: float = 0.2,
                 replan_interval: float = 0.05, landed_replan_threshold: float = 0.08, measured_footholds: bool = True,
                 foothold_ticks: int = 2, foothold_replan: bool = False, foothold_tolerance: float = FOOTHOLD_TOLERANCE,
                 recovery_step: bool = True, capture_landing: bool = True, max_steps: int = MAX_STOP_STEPS,
                 crossover_step: bool = False, relanded_footholds: bool = True, reference_fallback: bool = True,
                 max_replan_solves: int | None = MAX_REPLAN_SOLVES, max_latch_solves: int | None = MAX_LATCH_SOLVES,
                 plan_ahead: bool = True, timer=None, layout: ReferenceLayout | None = None):
        super().__init__()
        for name, value in (("replan_threshold", replan_threshold), ("bias_time_constant", bias_time_constant),
                            ("filter_time_constant", filter_time_constant), ("blend_time", blend_time),
                            ("replan_interval", replan_interval),
                            ("landed_replan_threshold", landed_replan_threshold),
                            ("foothold_tolerance", foothold_tolerance)):
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be positive and finite, got {value!r}")
        if (isinstance(foothold_ticks, bool) or not isinstance(foothold_ticks, (int, float))
                or not math.isfinite(foothold_ticks) or foothold_ticks != int(foothold_ticks) or foothold_ticks < 1):
            raise ValueError(f"foothold_ticks must be a positive integer, got {foothold_ticks!r}")
        self._foothold_ticks, self._max_steps = int(foothold_ticks), check_step_bound(max_steps)
        self._max_replan_solves = check_solve_bound(max_replan_solves, "max_replan_solves")
        self._max_latch_solves = check_solve_bound(max_latch_solves, "max_latch_solves")
        self._foothold_tolerance = float(foothold_tolerance) if foothold_replan else None
        self._relanded_tolerance = float(foothold_tolerance) if relanded_footholds else None
        self._measured_footholds = bool(measured_footholds)
        self._recovery_step = bool(recovery_step)
        self._capture_landing, self._crossover = bool(capture_landing), bool(crossover_step)
        self._reference_fallback = bool(reference_fallback)
        self._pattern = pattern
        self._params = params
        self._replan_threshold = float(replan_threshold)
        self._blend_time = float(blend_time)
        self._replan_interval = float(replan_interval)
        self._landed_threshold = float(landed_replan_threshold)
        self._plan_state = self.DeclareAbstractState(AbstractValue.Make(PlanHandle()))
        # before the latch: the stop of a signal at the last tick, planned from the reference (plan_ahead)
        self._plan_ahead = bool(plan_ahead)
        self._ahead_state = self.DeclareAbstractState(AbstractValue.Make(AheadPlan()))
        self.stop_port = self.DeclareVectorInputPort("stop", 2)
        # optional: the estimated COG; when connected the stop is planned (and re-planned) from it
        self.measured_com_port = self.DeclareVectorInputPort("measured_com", 3)
        self.measured_com_vel_port = self.DeclareVectorInputPort("measured_com_vel", 3)
        # optional: the estimated soles; a re-plan after the landing stands on the measured foothold
        self.measured_feet_port = self.DeclareVectorInputPort("measured_feet", 6)
        # low-passed (measured - reference) COG position and velocity while walking: the servo's
        # steady tracking error, which a plan from the measured state must not turn into a jump
        self._bias_alpha = params.servo_period / (bias_time_constant + params.servo_period)
        # and the measured COG low-passed over filter_time_constant: landing impacts put 0.1 m/s
        # spikes of a few ms on the COG velocity (3 cm of DCM) that are no reason to re-plan
        self._filter_alpha = params.servo_period / (filter_time_constant + params.servo_period)
        self._bias_state = self.DeclareDiscreteState(4)
        self._filtered_state = self.DeclareDiscreteState(4)
        self._filter_started = self.DeclareDiscreteState(1)
        # per sole (SIDES order): its SOLE_* stage since the latch (_relanded, stop_numerics.next_sole_stage)
        self._sole_stages = self.DeclareDiscreteState(2)
        # whether a signal at the last tick would stop in one step (after the latch: the latched plan's case)
        self._one_step_table = nominal_one_step_table(pattern, params)
        self._feasible_state = self.DeclareDiscreteState([float(self._one_step_table[0])])
        # the pattern's COG (x, y) position and velocity at every servo tick of the walk, for the tracking
        # bias and the deviation that every tick before the latch measures against it (the pattern is the
        # walk, computed before the run; the array path gives the bits of the one-instant one)
        ticks = np.arange(int(math.ceil(pattern.end_time / params.servo_period)) + 1) * params.servo_period
        self._pattern_com = pattern.com(ticks)[:2]
        self._declare_reference_outputs({self.time_ticket(), self.all_state_ticket()}, timer,
                                        pattern_layout(pattern, layout))
        self.plan_port = self.DeclareAbstractOutputPort(
            "plan", lambda: AbstractValue.Make(PlanHandle()), self._calc_plan_output,
            prerequisites_of_calc={self.abstract_state_ticket(self._plan_state)})
        self.one_step_feasible_port = self.DeclareStateOutputPort("one_step_feasible", self._feasible_state)
        self.DeclarePeriodicUnrestrictedUpdateEvent(params.servo_period, 0.0, timed(self._update, timer))

    @property
    def pattern(self):
        return self._pattern

    @property
    def params(self):
        return self._params

    def _handle(self, context):
        return context.get_abstract_state(self._plan_state).get_value()

    def _calc_plan_output(self, context, value):
        value.set_value(self._handle(context))

    def plan(self, context):
        """The StopPlan stored in ``context`` (None before the latch)."""
        return self._handle(context).plan

    def ahead_plan(self, context) -> AheadPlan:
        """The stop planned ahead of the latch in ``context`` (``plan_ahead``): ``signal_time`` and ``plan``."""
        return context.get_abstract_state(self._ahead_state).get_value()

    def plan_wall_time(self, context):
        """Wall-clock seconds the update spent in ``plan_stop`` (nan before)."""
        return self._handle(context).wall_time

    def plans(self, context) -> PlanSequence | None:
        """Every plan made since the signal, each in force from its start (None before the latch)."""
        history = self._handle(context).history
        return PlanSequence(history) if history else None

    def latch_fallback(self, context) -> str | None:
        """Why the latch in ``context`` planned from the reference although a measured state was given
        (no stop existed from it: the planner's message; ``reference_fallback``), or None."""
        return self._handle(context).latch_fallback

    def replans(self, context):
        """``(re-plans made, re-plans that found no feasible stop)`` since the signal."""
        handle = self._handle(context)
        return handle.replans, handle.replan_failures

    def _raw_measured(self, context):
        if not self.measured_com_port.HasValue(context):
            return None
        com, vel = self.measured_com_port.Eval(context), self.measured_com_vel_port.Eval(context)
        if not (np.all(np.isfinite(com)) and np.all(np.isfinite(vel))):
            return None
        return np.concatenate([com[:2], vel[:2]])

    def _filter(self, context, state, track_bias):
        """Low-pass the measured COG (into ``state``); while walking, also the tracking bias against the
        pattern. Returns this tick's filtered COG less the bias learnt up to the previous tick (what a
        latch on this tick plans from) as ``(com_xy, com_vel_xy)``, or None without a measurement."""
        raw = self._raw_measured(context)
        bias = context.get_discrete_state(self._bias_state).value()
        if raw is None:
            return None
        filtered = context.get_discrete_state(self._filtered_state).value()
        started = context.get_discrete_state(self._filter_started).value()[0] != 0.0
        filtered = filtered + self._filter_alpha * (raw - filtered) if started else raw
        state.get_mutable_discrete_state(self._filtered_state).set_value(filtered)
        state.get_mutable_discrete_state(self._filter_started).set_value([1.0])
        corrected = filtered - bias
        if track_bias:
            pos, vel = self._pattern_com_at(context.get_time())
            bias = bias + self._bias_alpha * (filtered - np.concatenate([pos, vel]) - bias)
            state.get_mutable_discrete_state(self._bias_state).set_value(bias)
        return corrected[:2], corrected[2:]

    def _update(self, context, state):
        """Plan on the first tick that sees the latched stop; then re-plan (at most once a tick)
        while the measured DCM leaves the plan's by more than ``replan_threshold``. Before the
        latch, decide whether a signal at this tick would stop in one step."""
        handle = self._handle(context)
        latched, signal_time = EStopTrigger.latched(self.stop_port.Eval(context))
        measured = self._filter(context, state, track_bias=not latched)
        if handle.plan is not None:
            relanded, fresh = self._relanded(context, state, handle.plan)
            self._maybe_replan(context, state, handle, measured, relanded, fresh)
            return EventStatus.Succeeded()
        if not latched:
            t = context.get_time()
            feasible = self._one_step_feasible(*self._plan_request(t, t, measured))
            state.get_mutable_discrete_state(self._feasible_state).set_value([float(feasible)])
            if self._plan_ahead:
                state.get_mutable_abstract_state(self._ahead_state).set_value(self._plan_ahead_of_latch(t))
            return EventStatus.Succeeded()
        planned_time, measured = self._plan_request(signal_time, max(signal_time, context.get_time()), measured)
        start = time.perf_counter()
        plan = fallback = None
        ahead = self.ahead_plan(context).plan_for(signal_time)
        try:
            if measured is not None:  # from the state measured now (this tick, at or after the signal's)
                try:
                    plan = plan_stop(self._pattern, planned_time, self._params, measured=measured,
                                     max_solves=self._max_latch_solves)
                    plan.signal_time = min(plan.signal_time, signal_time)
                except InfeasibleStop as error:
                    if not self._reference_fallback:
                        raise
                    # no stop from the measured state: the paper's stop from the reference keeps the robot
                    # controlled, and the re-plans below keep trying from the measured state every tick
                    fallback, measured = str(error), None
            if plan is None:  # from the reference, at the signal's tick (planned_time without a measurement)
                plan = ahead if ahead is not None else plan_stop(self._pattern, signal_time, self._params)
        except (InfeasibleStop, ValueError) as error:
            # raised, not returned as EventStatus.Failed: Drake formats a failed status's message by
            # asking pydrake for this Python system's type name while AdvanceTo has released the GIL,
            # which crashed the process (SIGSEGV, drake 1.51.1). The exception reaches AdvanceTo's caller.
            raise InfeasibleStop(f"stop planning failed at t = {context.get_time():.3f} s: {error}") from error
        # a plan from the reference continues the command; one from the measured state is blended into
        handle = PlanHandle(plan, time.perf_counter() - start,
                             blend=None if measured is None else self._blend_into(context, plan),
                             latch_fallback=fallback)
        state.get_mutable_abstract_state(self._plan_state).set_value(handle)
        state.get_mutable_discrete_state(self._feasible_state).set_value([float(plan.case == "one-step")])
        return EventStatus.Succeeded()

    def _plan_ahead_of_latch(self, t) -> AheadPlan:
        """The stop of a signal at this tick ``t``, planned from the reference (``plan_ahead``): the latch
        sees a signal one tick after it (the trigger's latch is its state, published a tick later)."""
        try:
            return AheadPlan(t, plan_stop(self._pattern, t, self._params))
        except (InfeasibleStop, ValueError):
            return AheadPlan(t, None)  # the latch plans again and reports why

    def _plan_request(self, signal_time, now, measured):
        """What a latch at tick ``now`` of a signal at ``signal_time`` plans from: ``(time, measured)``.

        The signal's tick and the reference (``measured`` None) while the
        measured DCM ``x + v / omega`` stays within ``replan_threshold`` of
        the reference's (the robot follows it: the plan is continuous with the
        command); else tick ``now`` and the measured ``(com_xy, com_vel_xy)``.
        Used by the latch and by the one-step feasibility of every tick.
        """
        if measured is not None and self._pattern_deviation(now, measured) <= self._replan_threshold:
            measured = None
        return (signal_time, None) if measured is None else (now, measured)

    def _one_step_feasible(self, t, measured):
        """``one_step_feasible(pattern, t, params, measured=measured)``: looked up for the nominal walk."""
        if measured is None:
            k = int(round(snap_to_tick(t, self._params.servo_period) / self._params.servo_period))
            if 0 <= k < len(self._one_step_table):
                return bool(self._one_step_table[k])
        return one_step_feasible(self._pattern, t, self._params, measured=measured)

    def one_step_feasible(self, context) -> bool:
        """The ``one_step_feasible`` output in ``context`` as a bool."""
        return bool(context.get_discrete_state(self._feasible_state).value()[0] > 0.5)

    def _pattern_com_at(self, t: float):
        """The pattern's COG (x, y) position and velocity at ``t`` [m, m/s]: looked up on a servo tick
        of the walk, else evaluated (the same bits either way)."""
        dt = self._params.servo_period
        k = int(round(t / dt))
        positions, velocities = self._pattern_com
        if 0 <= k < len(positions) and k * dt == t:
            return positions[k], velocities[k]
        pos, vel, _, _ = self._pattern.com([t])
        return pos[0], vel[0]

    def _pattern_deviation(self, t: float, measured) -> float:
        """:func:`dcm_deviation` from the pattern at ``t``, its COG looked up (:meth:`_pattern_com_at`)."""
        return dcm_distance(measured, *self._pattern_com_at(t), self._pattern.w)

    def _relanded(self, context, state, plan):
        """``({side: xy}, fresh)``: the soles that landed again off the plan's foothold, and whether one
        of them did so on this tick.

        A sole re-lands when it stood on the floor after the latch (loaded
        ``foothold_ticks`` ticks where the plan has it down), lost contact
        (unloaded) and has been loaded ``foothold_ticks`` ticks again, the
        plan still having it down: the robot bounced off a hard touchdown, or
        rocked off that sole, and came back elsewhere. A sole more than
        ``foothold_tolerance`` from the plan's foothold (the estimate is good
        to 3 mm) is returned with its estimated position on every tick until
        a plan stands on it (a re-plan may have to wait for the landing's
        tick). The stages live in the discrete state (updated into
        ``state``); empty without ``measured_feet`` or with
        ``relanded_footholds=False``.
        """
        if self._relanded_tolerance is None or not self.measured_feet_port.HasValue(context):
            return {}, False
        feet = self.measured_feet_port.Eval(context)
        if not np.all(np.isfinite(feet)):
            return {}, False
        stages, relanded, fresh = relanded_soles(
            context.get_discrete_state(self._sole_stages).value(), feet, plan.feet(context.get_time()),
            self._foothold_ticks, self._relanded_tolerance)
        state.get_mutable_discrete_state(self._sole_stages).set_value(stages)
        return relanded, fresh

    def _maybe_replan(self, context, state, handle, measured, relanded=None, fresh=False):
        t = context.get_time()
        plan = handle.plan
        if plan.next_step is not None and t >= plan.landing_time - 1e-9:
            return self._take_next_step(context, state, handle, measured)
        if measured is None:
            return EventStatus.DidNothing()
        landed = plan.landing_foot is None or t >= plan.landing_time - shortest_replanned_landing(plan)
        # a sole re-landed off its foothold after the landing re-plans at once (no interval on its
        # first tick: the sole's new place is a fact, not a deviation that a blend may still remove)
        relanded = relanded if landed else None
        # a re-plan with tries left (ReplanPending) goes on at this tick, in the same support
        pending = handle.pending if handle.pending and handle.pending[0] == replan_support(plan, t) else None
        if not (relanded and fresh) and pending is None and t - handle.last_try < self._replan_interval - 1e-9:
            return self._drop_pending(state, handle)  # let the last re-plan's blend act before judging it
        threshold = self._landed_threshold if landed else self._replan_threshold
        deviated = dcm_deviation(plan, t, measured) > threshold
        # the measured feet: for a re-plan after the landing, and (option) to see whether they left the plan's
        landing = last_landing(handle.history) if landed else None
        wanted = deviated or (self._foothold_tolerance is not None and t < plan.slowdown_end and landing is not None)
        feet = self._footholds(context, landing) if wanted else None
        if feet is None:
            landing = None
        if relanded:  # the re-landed soles where they are; the other from the footholds, or the plan's
            feet = {**(feet or {}), **relanded}
            pending = None  # the soles moved: a new re-plan, all of its tries
        elif not deviated and not self._feet_moved(context, plan, t, feet):
            return self._drop_pending(state, handle)
        start = time.perf_counter()
        # the recovery step (in single support: the second of a two-step capture) within max_steps
        room = self._max_steps - landings_made(handle.history, t) >= (2 if replan_support(plan, t) == "single" else 1)
        try:  # a re-plan for the feet alone (the DCM within its threshold) takes no recovery step
            new = replan_stop(plan, t, *measured, feet=feet, recovery_step=self._recovery_step and deviated and room,
                              capture_landing=self._capture_landing, crossover=self._crossover,
                              first_try=pending[1] if pending else 0, max_solves=self._max_replan_solves)
        except ReplanPending as error:
            new, failures, left = None, handle.replan_failures, (error.support, error.next_try)
        except InfeasibleStop:
            new, failures, left = None, handle.replan_failures + 1, None
        else:
            failures, left = handle.replan_failures, None
        wall = time.perf_counter() - start
        if new is None and failures == handle.replan_failures and left is None:
            return self._drop_pending(state, handle)  # nothing left to re-plan (the foot has landed)
        updated = handle.replaced(
            plan=new or plan, wall_time=wall, replans=handle.replans + (new is not None), replan_failures=failures,
            max_wall_time=max(handle.max_wall_time, wall),
            blend=self._blend_into(context, new) if new is not None else handle.blend,
            history=handle.history + ((new,) if new is not None else ()),
            last_try=handle.last_try if pending else t,  # a resumed sequence keeps its first tick
            pending=left)
        state.get_mutable_abstract_state(self._plan_state).set_value(updated)
        return EventStatus.Succeeded()

    def _take_next_step(self, context, state, handle, measured):
        """At a two-step capture's touchdown (:func:`~drake_estop.planning.replan.capture_step`): its
        recovery step re-planned from the measured state, else as planned. No double-support stop: on a
        35 N s forward push one, feasible on the LIPM, fell (the body pitched about the support toe)."""
        t, plan = context.get_time(), handle.plan
        start = time.perf_counter()
        try:
            new = None if measured is None else replan_stop(
                plan, t, *measured, recovery_step=True, capture_landing=self._capture_landing,
                first_try=REPLAN_TRIES["double"].index("recovery step"))
        except InfeasibleStop:
            new = None
        if new is None:  # the recovery step as planned at the capture landing's re-plan
            new = plan.next_step
        wall = time.perf_counter() - start
        updated = handle.replaced(
            plan=new, wall_time=wall, replans=handle.replans + 1, max_wall_time=max(handle.max_wall_time, wall),
            blend=self._blend_into(context, new), history=handle.history + (new,), last_try=t, pending=None)
        state.get_mutable_abstract_state(self._plan_state).set_value(updated)
        return EventStatus.Succeeded()

    def _drop_pending(self, state, handle):
        """A re-plan's tries left (``handle.pending``) dropped, in ``state``: the tick does not re-plan."""
        if handle.pending is None:
            return EventStatus.DidNothing()
        state.get_mutable_abstract_state(self._plan_state).set_value(handle.replaced(pending=None))
        return EventStatus.Succeeded()

    def _feet_moved(self, context, plan, t, feet) -> bool:
        """Whether a sole of ``feet`` (:meth:`_footholds`) that is a foothold (:func:`foothold_loaded`) lies more than
        ``foothold_tolerance`` from where ``plan`` has it at ``t``; False without a measurement or a tolerance."""
        if feet is None or self._foothold_tolerance is None:
            return False
        planned, measured = plan.feet(t), self.measured_feet_port.Eval(context)
        return any(foothold_loaded(measured, side, self._foothold_ticks)
                   and off_foothold(xy, planned[side], self._foothold_tolerance) for side, xy in feet.items())

    def _footholds(self, context, landing):
        """``{side: xy}``: both soles' estimated positions, once the foot of ``landing`` (the stop's last
        plan with a landing, :func:`~drake_estop.systems.plan_sequence.last_landing`) has been loaded
        ``foothold_ticks`` ticks; None without a measurement or before any landing of the stop (``landing``
        None: a stop signalled in double support keeps the walk's feet until a recovery step lands)."""
        if not self._measured_footholds or landing is None or not self.measured_feet_port.HasValue(context):
            return None
        feet = self.measured_feet_port.Eval(context)
        if not np.all(np.isfinite(feet)) or not foothold_loaded(feet, landing.landing_foot, self._foothold_ticks):
            return None
        return {side: feet[2 * k:2 * k + 2].copy() for k, side in enumerate(SIDES)}

    def _calc_reference(self, context):
        handle = self._handle(context)
        t = context.get_time()
        return blended_reference(reference_vector(t, pattern=self._pattern, plan=handle.plan, layout=self._layout),
                                 handle.blend, t)

    def _blend_into(self, context, plan):
        """The blend from the command now in force into ``plan`` (None if it starts continuous)."""
        t = context.get_time()
        if plan.start_time > t + 1e-9:
            return None
        current = self._reference.Eval(context)
        pos, vel, _, _ = plan.com([t])
        dp = current[REFERENCE_SLICES["com"]][:2] - pos[0]
        dv = current[REFERENCE_SLICES["com_vel"]][:2] - vel[0]
        feet = plan.feet(t)
        dfeet = np.array([current[REFERENCE_SLICES[f"{side}_foot"]][:3] - feet[side] for side in SIDES])
        if max(np.max(np.abs(dp)), np.max(np.abs(dv)), np.max(np.abs(dfeet))) < 1e-9:
            return None
        return (t, dp, dv, self._blend_time, dfeet)


def add_stop_controller(builder, *, pattern, params, estop_time=None, meshcat=None,
                        button_name="Emergency stop", timer=None, **planner_options):
    """Add an EStopTrigger and a StopPlannerSystem wired together.

    Returns ``(trigger, planner)``; the trigger's ``stop_request`` input is
    left unconnected (export or connect it for an external stop source).
    ``planner_options`` go to :class:`StopPlannerSystem` (e.g. ``layout``, the
    robot's reference layout).
    The compiled solver is loaded here, at build time (one throw-away plan),
    so the stop's servo tick does not pay for it.
    """
    warm_up(pattern, params)
    trigger = builder.AddNamedSystem("estop_trigger", EStopTrigger(
        servo_period=params.servo_period, scheduled_time=estop_time,
        meshcat=meshcat, button_name=button_name))
    planner = builder.AddNamedSystem("stop_planner", StopPlannerSystem(
        pattern=pattern, params=params, timer=timer, **planner_options))
    builder.Connect(trigger.stop_port, planner.stop_port)
    return trigger, planner

