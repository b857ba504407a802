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

import dataclasses
import time

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import EventStatus, ValueProducer

from drake_estop.planning.gait import SIDES, NominalPattern
from drake_estop.planning.late_landing import late_landing_stop
from drake_estop.planning.planner import (
    InfeasibleStop,
    StopParameters,
    one_step_feasible,
    plan_stop,
    warm_up,
)
from drake_estop.planning.replan import REPLAN_TRIES, ReplanPending, replan_stop
from drake_estop.systems.decision import (
    FOOTHOLD_TOLERANCE,  # noqa: F401  importable from here too
    ActionKind,
    Observation,
    StopMode,
    StopPlannerConfig,
    decide,
    planning_time,
    stop_mode,
)
from drake_estop.systems.foothold_monitor import Relanded
from drake_estop.systems.plan_sequence import AheadPlan, PlanHandle, PlanSequence
from drake_estop.systems.reference import (
    REFERENCE_SLICES,
    ReferenceLayout,
    ReferenceSystem,
    WalkingPatternSource,  # noqa: F401  a public building block, importable from here too
    blended_reference,
    pattern_layout,
    reference_vector,
)
from drake_estop.systems.stop_numerics import PatternCom, nominal_stop, nominal_stop_table, one_step_column, tick_entry
from drake_estop.systems.trigger import EStopTrigger
from drake_estop.timing import timed


class StopPlannerSystem(ReferenceSystem):
    """Nominal pattern until the stop latches, then the four-phase stop, re-planned from the measured state.

    Every ``params.servo_period`` an unrestricted update reads ``stop`` and the measurements, keeps the
    stop's :class:`~drake_estop.systems.decision.StopMode` in the Context and executes what
    :func:`~drake_estop.systems.decision.decide` chooses (its docstring holds the table): before the
    latch it plays the walk (and plans the stop of a signal at this tick ahead, ``plan_ahead``); on the
    first tick that sees ``[1, t_signal]`` it calls ``plan_stop`` (Fig. 7 of the paper: the stop is
    planned in real time at the servo tick of the signal, from the reference, or from the measured state
    where it has left the walk) and stores the plan in the abstract state; from then on it plays the plan
    and re-plans (:func:`drake_estop.planning.replan.replan_stop`) where the measured DCM, or a landed
    sole, leaves it. Outputs are functions of time and that state.

    .. pydrake_system::

        name: StopPlannerSystem
        input_ports:
        - stop
        - measured_com
        - measured_com_vel
        - measured_feet
        - relanded
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
        - mode

    ``measured_com`` / ``measured_com_vel`` (3 each, optional): the state estimate as
    :class:`~drake_estop.systems.measured_com_filter.MeasuredComFilter` gives it (low-passed, less the
    servo's steady tracking bias learnt while walking). ``measured_feet`` (6, optional:
    :class:`StateEstimator`'s ``feet``, ``[x_l, y_l, x_r, y_r, loaded ticks l, loaded ticks r]``) puts a
    re-plan after the landing on the soles' estimated positions; ``relanded`` (abstract, optional: a
    :class:`~drake_estop.systems.foothold_monitor.FootholdMonitor`'s output,
    :func:`~drake_estop.systems.foothold_monitor.add_foothold_monitor`) says which soles landed again off
    the plan's footholds, and such a sole re-plans the stop at once. The COG command is blended into a plan
    made from the measured state over ``blend_time``. :meth:`plans` returns the plan and its re-plans,
    :meth:`replans` their count. Why each setting is what it is, with the measurements:
    ``docs/online_controller.md``.

    ``phase`` is the index into ``PHASES``; ``plan`` (abstract) is the stored StopPlan, or None before the
    latch; ``mode`` (2) is ``[StopMode, landings left]`` after the tick's update. If no feasible stop exists
    the update raises :class:`~drake_estop.planning.plan.InfeasibleStop` with the planner's message.

    ``one_step_feasible`` (1): before the latch, 1.0 if a stop signal at this tick would stop within one
    step (the plan's ``case`` would be "one-step"), 0.0 if not ("next-step", the marginal case III.C, or
    "standing" / "already-stopping"), for the inputs the latch would plan from at that tick: the nominal
    walk's answer, looked up in
    :func:`~drake_estop.systems.stop_numerics.nominal_one_step_table` (computed at construction), or, when the
    measured DCM has left the reference by more than ``replan_threshold``,
    :func:`drake_estop.planning.planner.one_step_feasible` solved on the tick. From the latch on it holds
    whether the latched stop is one-step. It is discrete state set by the update, so the value published
    at tick ``t`` (e.g. by a logger) is the previous tick's.

    Parameters
    ----------
    pattern : NominalPattern
        The walk the stop interrupts.
    params : StopParameters
        Weights, limits and servo period [s] of the planner.
    config : StopPlannerConfig, optional
        The re-planning settings: thresholds [m], intervals [s], the tries, the footholds (default
        ``StopPlannerConfig()``).
    timer : drake_estop.timing.TickTimer, optional
        Records the wall-clock time of every update [s].
    layout : drake_estop.systems.reference.ReferenceLayout, optional
        The robot's reference layout (its upper-body joints and their standing angles; default: the
        default robot's with the pattern's swinging joints).

    Notes
    -----
    Output ports: the same reference layout as :class:`WalkingPatternSource`
    (``com`` [m], ``com_vel`` [m/s], ``zmp`` [m], sole poses [m], joint
    targets [rad], ``phase``) plus the abstract ``plan``, ``one_step_feasible`` (1, 0.0 or 1.0) and
    ``mode`` (2, dimensionless). Input ``stop`` (2) is :class:`EStopTrigger`'s output;
    ``measured_com`` (3) [m], ``measured_com_vel`` (3) [m/s], ``measured_feet`` (6) [m, ticks] and
    ``relanded`` are optional.

    Raises
    ------
    ValueError
        If ``config`` is not a :class:`StopPlannerConfig` (its own fields raise naming themselves).
    """

    def __init__(self, *, pattern: NominalPattern, params: StopParameters, config: StopPlannerConfig | None = None,
                 timer=None, layout: ReferenceLayout | None = None):
        super().__init__()
        config = StopPlannerConfig() if config is None else config
        if not isinstance(config, StopPlannerConfig):
            raise ValueError(f"config must be a StopPlannerConfig, got {config!r}")
        self._config = config
        self._pattern = pattern
        self._params = params
        self._plan_state = self.DeclareAbstractState(AbstractValue.Make(PlanHandle()))
        # before the latch: the stop of a signal at the last tick, planned from the reference (plan_ahead)
        self._ahead_state = self.DeclareAbstractState(AbstractValue.Make(AheadPlan()))
        self.stop_port = self.DeclareVectorInputPort("stop", 2)
        # optional: the estimated COG; when connected the stop is planned (and re-planned) from it
        self.measured_com_port = self.DeclareVectorInputPort("measured_com", 3)
        self.measured_com_vel_port = self.DeclareVectorInputPort("measured_com_vel", 3)
        # optional: the estimated soles; a re-plan after the landing stands on the measured foothold
        self.measured_feet_port = self.DeclareVectorInputPort("measured_feet", 6)
        # optional: the soles that landed again off the plan's footholds (foothold_monitor.FootholdMonitor)
        self.relanded_port = self.DeclareAbstractInputPort("relanded", AbstractValue.Make(Relanded()))
        # whether a signal at the last tick would stop in one step (after the latch: the latched plan's case)
        self._nominal_stops = nominal_stop_table(pattern, params)
        self._one_step_table = one_step_column(self._nominal_stops)
        self._feasible_state = self.DeclareDiscreteState([float(self._one_step_table[0])])
        # the stop's mode after the last update and the landings left (decision.stop_mode)
        self._mode_state = self.DeclareDiscreteState([float(StopMode.WALKING), 0.0])
        # the pattern's COG at every servo tick, for the deviation every tick before the latch measures
        self._pattern_com = PatternCom(pattern, params.servo_period)
        self._declare_reference_outputs({self.time_ticket(), self.all_state_ticket()}, timer,
                                        pattern_layout(pattern, layout))
        # the last reference made and what it was made from (a plan handle is immutable and replaced on any
        # change): the unrestricted update invalidates the reference cache every tick although the handle
        # seldom changes, and the tick reads the reference before and after that update
        self._last_reference = self.DeclareCacheEntry(
            "last reference", ValueProducer(allocate=lambda: AbstractValue.Make(_ReferenceMemo()),
                                            calc=lambda context, value: None),
            {self.nothing_ticket()})
        self.plan_port = self.DeclareAbstractOutputPort(
            "plan", lambda: AbstractValue.Make(PlanHandle()), self._calc_plan_output,
            prerequisites_of_calc={self.abstract_state_ticket(self._plan_state)})
        self.one_step_feasible_port = self.DeclareStateOutputPort("one_step_feasible", self._feasible_state)
        self.mode_port = self.DeclareStateOutputPort("mode", self._mode_state)
        self.DeclarePeriodicUnrestrictedUpdateEvent(params.servo_period, 0.0, timed(self._update, timer))

    @property
    def pattern(self):
        return self._pattern

    @property
    def params(self):
        return self._params

    @property
    def config(self) -> StopPlannerConfig:
        """The re-planning settings."""
        return self._config

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

    def mode(self, context) -> tuple[StopMode, int]:
        """The ``mode`` output in ``context``: ``(StopMode, landings left)`` after the last update."""
        mode, steps_left = context.get_discrete_state(self._mode_state).value()
        return StopMode(int(mode)), int(steps_left)

    def replans(self, context):
        """``(re-plans made, re-plans that found no feasible stop)`` since the signal."""
        handle = self._handle(context)
        return handle.replans, handle.replan_failures

    def _measured(self, context):
        """The measured COG ``(com_xy, com_vel_xy)`` [m, m/s] (:class:`MeasuredComFilter`'s outputs: filtered,
        less the tracking bias), or None without a finite one."""
        if not self.measured_com_port.HasValue(context):
            return None
        com, vel = self.measured_com_port.Eval(context), self.measured_com_vel_port.Eval(context)
        if not (np.all(np.isfinite(com)) and np.all(np.isfinite(vel))):
            return None
        return com[:2], vel[:2]

    def _measured_feet(self, context):
        """The ``measured_feet`` input, or None where it is not connected."""
        return self.measured_feet_port.Eval(context) if self.measured_feet_port.HasValue(context) else None

    def _update(self, context, state):
        """Observe, :func:`~drake_estop.systems.decision.decide`, execute the action, and keep the mode."""
        handle = self._handle(context)
        latched, signal_time = EStopTrigger.latched(self.stop_port.Eval(context))
        measured = self._measured(context)
        t = context.get_time()
        relanded, fresh = self._relanded(context) if handle.plan is not None else ({}, False)
        observation = Observation(time=t, latched=latched, signal_time=signal_time, measured=measured,
                                  feet=self._measured_feet(context), relanded=relanded, relanded_now=fresh)
        if handle.plan is None and measured is not None:
            observation = dataclasses.replace(observation, reference_deviation=self._pattern_com.deviation(
                planning_time(observation), measured))
        action = decide(observation, handle, self._config)
        self._execute(action, context, state, handle, observation)
        after = state.get_mutable_abstract_state(self._plan_state).get_value().plan
        state.get_mutable_discrete_state(self._mode_state).set_value([float(v) for v in stop_mode(after, t, latched)])
        return EventStatus.Succeeded()

    def _execute(self, action, context, state, handle, observation):
        """Carry out ``action`` (:class:`~drake_estop.systems.decision.Action`) into ``state``."""
        kind = action.kind
        if kind is ActionKind.WALK:
            self._walk(context, state, action, observation)
        elif kind is ActionKind.LATCH:
            self._latch(context, state, action, observation)
        elif kind is ActionKind.NEXT_STEP:
            self._take_next_step(context, state, handle, observation.measured)
        elif kind is ActionKind.REPLAN:
            self._replan(context, state, handle, action, observation.measured)
        elif kind is ActionKind.RETIME:
            self._retime(context, state, handle, observation.measured)
        elif kind is ActionKind.WAIT:
            self._drop_pending(state, handle)

    def _walk(self, context, state, action, observation):
        """Before the latch: whether a signal at this tick would stop in one step, and its stop planned
        ahead from the reference (``plan_ahead``)."""
        t = context.get_time()
        measured = observation.measured if action.from_measured else None
        feasible = self._one_step_feasible(action.plan_time, measured)
        state.get_mutable_discrete_state(self._feasible_state).set_value([float(feasible)])
        if self._config.plan_ahead:
            state.get_mutable_abstract_state(self._ahead_state).set_value(self._plan_ahead_of_latch(t))

    def _latch(self, context, state, action, observation):
        """Plan the stop at the latch, from the measured state where ``action`` says so (falling back on the
        reference where none exists from it: ``reference_fallback``), else from the reference at the
        signal's tick (the plan made ahead, where there is one)."""
        signal_time, measured = observation.signal_time, observation.measured if action.from_measured else None
        start = time.perf_counter()
        plan = fallback = None
        ahead = self.ahead_plan(context).plan_for(signal_time)
        try:
            if measured is not None:  # from the state measured now (this tick, at or after the signal's)
                try:
                    plan = plan_stop(self._pattern, action.plan_time, self._params, measured=measured,
                                     max_solves=self._config.max_latch_solves)
                    plan.signal_time = min(plan.signal_time, signal_time)
                except InfeasibleStop as error:
                    if not self._config.reference_fallback:
                        raise
                    # no stop from the measured state: the paper's stop from the reference keeps the robot
                    # controlled, and the re-plans keep trying from the measured state every tick
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

    def _replan(self, context, state, handle, action, measured):
        """Re-plan the stop from ``measured`` as ``action`` says (its feet, tries and recovery step); a
        re-plan whose tries ran out of the tick's solves (ReplanPending) goes on at the next tick."""
        t, plan = context.get_time(), handle.plan
        pending = handle.pending if action.resumed else None
        if action.from_plan:  # the plan's own COG (eq. 10-11 with the command): only the feet change
            position, velocity, _, _ = plan.com([t])
            measured = (position[0], velocity[0])
        start = time.perf_counter()
        try:
            new = replan_stop(plan, t, *measured, feet=action.feet, recovery_step=action.recovery_step,
                              capture_landing=self._config.capture_landing, crossover=self._config.crossover_step,
                              first_try=action.first_try, max_solves=self._config.max_replan_solves,
                              halt=self._config.halt_footholds)
        except ReplanPending as error:
            new, failures, left = None, handle.replan_failures, (error.support, error.next_try)
        except InfeasibleStop:
            new, failures, left = None, handle.replan_failures + 1, None
        else:
            failures, left = handle.replan_failures, None
        wall = time.perf_counter() - start
        if new is None and failures == handle.replan_failures and left is None:
            return self._drop_pending(state, handle)  # nothing left to re-plan (the foot has landed)
        # a resumed sequence keeps its first tick as its last try
        updated = self._after_solve(context, handle, new, wall, failures=failures,
                                    last_try=handle.last_try if pending else t, pending=left)
        state.get_mutable_abstract_state(self._plan_state).set_value(updated)
        return EventStatus.Succeeded()

    def _retime(self, context, state, handle, measured):
        """The stop re-timed for a landing sole that carries no weight past the touchdown
        (:func:`~drake_estop.planning.late_landing.late_landing_stop`), blended into from the command; where
        no re-timed stop exists the plan goes on and the failure is counted."""
        t = context.get_time()
        start = time.perf_counter()
        try:
            new = late_landing_stop(handle.plan, t, *measured)
        except InfeasibleStop:
            new = None
        wall = time.perf_counter() - start
        updated = self._after_solve(context, handle, new, wall,
                                    failures=handle.replan_failures + (new is None),
                                    last_try=handle.last_try if new is None else t, pending=None)
        state.get_mutable_abstract_state(self._plan_state).set_value(updated)
        return EventStatus.Succeeded()

    def _after_solve(self, context, handle, new, wall, *, failures, last_try, pending):
        """``handle`` after a re-plan or re-timing solve that took ``wall`` [s]: ``new`` (None: none found, the
        plan goes on) in force, blended into from the command and added to the history, the failures counted
        as ``failures``, and ``last_try`` and ``pending`` as given."""
        found = new is not None
        return handle.replaced(
            plan=new if found else handle.plan, wall_time=wall, replans=handle.replans + found,
            replan_failures=failures, max_wall_time=max(handle.max_wall_time, wall),
            blend=self._blend_into(context, new) if found else handle.blend,
            history=handle.history + ((new,) if found else ()), last_try=last_try, pending=pending)

    def _plan_ahead_of_latch(self, t) -> AheadPlan:
        """The stop of a signal at this tick ``t``, planned from the reference (``plan_ahead``): the latch
        sees a signal one tick after it (the trigger's latch is its state, published a tick later). Where
        the stop lies in the signal's own phase it was planned before the run (:func:`nominal_stop_table`)
        and is looked up; else (III.C) it is planned on the tick."""
        ahead = nominal_stop(self._nominal_stops, t, self._params.servo_period)
        if ahead is not None:
            return AheadPlan(t, ahead)
        try:
            return AheadPlan(t, plan_stop(self._pattern, t, self._params))
        except (InfeasibleStop, ValueError):
            return AheadPlan(t, None)  # the latch plans again and reports why

    def _one_step_feasible(self, t, measured):
        """``one_step_feasible(pattern, t, params, measured=measured)``: looked up for the nominal walk."""
        if measured is None:
            feasible = tick_entry(self._one_step_table, t, self._params.servo_period)
            if feasible is not None:
                return bool(feasible)
        return one_step_feasible(self._pattern, t, self._params, measured=measured)

    def one_step_feasible(self, context) -> bool:
        """The ``one_step_feasible`` output in ``context`` as a bool."""
        return bool(context.get_discrete_state(self._feasible_state).value()[0] > 0.5)

    def _relanded(self, context):
        """``({side: xy}, fresh)`` from the ``relanded`` input (a
        :class:`~drake_estop.systems.foothold_monitor.FootholdMonitor`'s): the soles that landed again off the
        plan's foothold, and whether one of them did so on this tick; empty where the input is not connected
        or with ``relanded_footholds=False``."""
        if not self._config.relanded_footholds or not self.relanded_port.HasValue(context):
            return {}, False
        relanded = self.relanded_port.Eval(context)
        return relanded.soles, relanded.fresh

    def _take_next_step(self, context, state, handle, measured):
        """At a two-step capture's touchdown (:func:`~drake_estop.planning.capture_landing.capture_step`): its
        recovery step re-planned from the measured state, else as planned. No double-support stop: on a
        35 N s forward push one, feasible on the LIPM, fell (the body pitched about the support toe)."""
        t, plan = context.get_time(), handle.plan
        start = time.perf_counter()
        try:
            new = None if measured is None else replan_stop(
                plan, t, *measured, recovery_step=True, capture_landing=self._config.capture_landing,
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

    def _calc_reference(self, context):
        handle = self._handle(context)
        t = context.get_time()
        memo = self._last_reference.get_mutable_cache_entry_value(context).GetMutableValueOrThrow()
        if memo.handle is handle and memo.time == t:  # a function of the handle and the time alone
            return memo.reference
        reference = blended_reference(reference_vector(t, pattern=self._pattern, plan=handle.plan,
                                                       layout=self._layout), handle.blend, t)
        reference.setflags(write=False)  # shared by the memo: read, never written
        memo.handle, memo.time, memo.reference = handle, t, reference
        return reference

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
        return (t, dp, dv, self._config.blend_time, dfeet)


class _ReferenceMemo:
    """The last reference vector of a :class:`StopPlannerSystem`'s context and the plan handle and time it
    was made from (held in a cache entry: scratch, not state)."""

    __slots__ = ("handle", "time", "reference")

    def __init__(self):
        self.handle, self.time, self.reference = None, None, None

    def __deepcopy__(self, memo):  # a fresh context starts with an empty memo
        return _ReferenceMemo()


def add_stop_controller(builder, *, pattern, params, estop_time=None, meshcat=None,
                        button_name="Emergency stop", timer=None, config=None, layout=None):
    """Add an EStopTrigger and a StopPlannerSystem wired together.

    Returns ``(trigger, planner)``; the trigger's ``stop_request`` input is
    left unconnected (export or connect it for an external stop source).
    ``config`` (a :class:`StopPlannerConfig`) and ``layout`` (the robot's
    reference layout) go to :class:`StopPlannerSystem`.
    The compiled solver is loaded here, at build time (one throw-away plan),
    so the stop's servo tick does not pay for it.
    """
    warm_up(pattern, params)
    trigger = builder.AddNamedSystem("estop_trigger", EStopTrigger(
        servo_period=params.servo_period, scheduled_time=estop_time,
        meshcat=meshcat, button_name=button_name))
    planner = builder.AddNamedSystem("stop_planner", StopPlannerSystem(
        pattern=pattern, params=params, config=config, timer=timer, layout=layout))
    builder.Connect(trigger.stop_port, planner.stop_port)
    return trigger, planner

