"""The measured COG as the stop planner uses it: low-passed, less the servo's steady tracking bias.

:class:`MeasuredComFilter` sits between a state estimate (``measured_com``, ``measured_com_vel``) and
:class:`~drake_estop.systems.stop_controller.StopPlannerSystem`'s inputs of the same names. Landing impacts
put 0.1 m/s spikes of a few ms on the estimated COG velocity (3 cm of divergent component of motion) that
are no reason to re-plan, hence the low-pass; and the position servos track the walk with a steady error
that a plan from the measured state must not turn into a jump, hence the bias, learnt while walking.
"""

from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import EventStatus, LeafSystem, ValueProducer

from drake_estop.planning.gait import NominalPattern
from drake_estop.systems.stop_numerics import PatternCom
from drake_estop.systems.trigger import EStopTrigger
from drake_estop.timing import timed
from drake_estop.validation import check_positive


class MeasuredComFilter(LeafSystem):
    """The estimated COG low-passed, less the tracking bias learnt while walking.

    .. pydrake_system::

        name: MeasuredComFilter
        input_ports:
        - measured_com
        - measured_com_vel
        - stop
        output_ports:
        - com
        - com_vel

    Each tick the outputs are this tick's filtered COG (x, y), ``filtered + alpha (measured - filtered)``
    with ``alpha = dt / (filter_time_constant + dt)`` (the measurement itself on the first tick), less the
    bias learnt up to the previous tick: what a latch on this tick plans from. The periodic (unrestricted)
    update keeps the filtered COG and, until ``stop`` latches, low-passes ``filtered - pattern`` into the bias over
    ``bias_time_constant``. The heights (z) pass through. Without a finite measurement the outputs are NaN
    and the state stays.

    Parameters
    ----------
    pattern : NominalPattern
        The walk whose COG the bias is measured against.
    servo_period : float
        The controller's tick [s].
    filter_time_constant : float, optional
        Low-pass time constant of the measured COG [s] (default 0.03).
    bias_time_constant : float, optional
        Time constant of the learnt tracking bias [s] (default 0.5).
    timer : drake_estop.timing.TickTimer, optional
        Records the wall-clock time of every update [s].

    Notes
    -----
    Inputs ``measured_com`` (3) [m], ``measured_com_vel`` (3) [m/s], ``stop`` (2, the trigger's
    ``[latched, time]``); outputs ``com`` (3) [m] and ``com_vel`` (3) [m/s].

    Raises
    ------
    ValueError
        If a time constant or ``servo_period`` is not positive and finite (the message names it).
    """

    def __init__(self, *, pattern: NominalPattern, servo_period: float, filter_time_constant: float = 0.03,
                 bias_time_constant: float = 0.5, timer=None):
        super().__init__()
        for name, value in (("servo_period", servo_period), ("filter_time_constant", filter_time_constant),
                            ("bias_time_constant", bias_time_constant)):
            check_positive(name, value)
        self._pattern_com = PatternCom(pattern, servo_period)
        self._filter_alpha = servo_period / (filter_time_constant + servo_period)
        self._bias_alpha = servo_period / (bias_time_constant + servo_period)
        self.measured_com_port = self.DeclareVectorInputPort("measured_com", 3)
        self.measured_com_vel_port = self.DeclareVectorInputPort("measured_com_vel", 3)
        self.stop_port = self.DeclareVectorInputPort("stop", 2)
        self._filtered_state = self.DeclareDiscreteState(4)
        self._started_state = self.DeclareDiscreteState(1)
        self._bias_state = self.DeclareDiscreteState(4)
        # this tick's filtered COG (4), it less the bias (4) and the heights (2), NaN without a measurement:
        # computed once a tick for both outputs and the update
        self._tick = self.DeclareCacheEntry(
            "filtered", ValueProducer(allocate=lambda: AbstractValue.Make(np.full(10, np.nan)), calc=self._calc_tick),
            {self.all_input_ports_ticket(), self.xd_ticket()})
        self.com_port = self.DeclareVectorOutputPort(
            "com", 3, lambda context, out: out.SetFromVector(self._tick.Eval(context)[[4, 5, 8]]),
            prerequisites_of_calc={self._tick.ticket()})
        self.com_vel_port = self.DeclareVectorOutputPort(
            "com_vel", 3, lambda context, out: out.SetFromVector(self._tick.Eval(context)[[6, 7, 9]]),
            prerequisites_of_calc={self._tick.ticket()})
        # unrestricted, as the planner's: both read the estimate of the tick before any update of it (a discrete
        # update runs after the unrestricted ones, when the new reference has reached the simulated robot's
        # actuation and, through its accelerometer, the estimate)
        self.DeclarePeriodicUnrestrictedUpdateEvent(servo_period, 0.0, timed(self._update, timer))

    def _calc_tick(self, context, value):
        """``[filtered (4), filtered - bias (4), heights (2)]``: ``filtered + alpha (measured - filtered)`` (the
        measurement itself on the first tick), the bias learnt up to the previous tick; NaN without a finite
        measurement."""
        out = np.full(10, np.nan)
        if self.measured_com_port.HasValue(context):
            com, vel = self.measured_com_port.Eval(context), self.measured_com_vel_port.Eval(context)
            if np.all(np.isfinite(com)) and np.all(np.isfinite(vel)):
                raw = np.concatenate([com[:2], vel[:2]])
                filtered = context.get_discrete_state(self._filtered_state).value()
                started = context.get_discrete_state(self._started_state).value()[0] != 0.0
                filtered = filtered + self._filter_alpha * (raw - filtered) if started else raw
                out = np.concatenate([filtered, filtered - context.get_discrete_state(self._bias_state).value(),
                                      [com[2], vel[2]]])
        value.set_value(out)

    def _update(self, context, state):
        tick = self._tick.Eval(context)
        if not np.isfinite(tick[0]):
            return EventStatus.DidNothing()
        filtered = tick[:4]
        state.get_mutable_discrete_state(self._filtered_state).set_value(filtered)
        state.get_mutable_discrete_state(self._started_state).set_value([1.0])
        latched, _ = EStopTrigger.latched(self.stop_port.Eval(context))
        if not latched:
            bias = context.get_discrete_state(self._bias_state).value()
            pos, vel = self._pattern_com.at(context.get_time())
            state.get_mutable_discrete_state(self._bias_state).set_value(
                bias + self._bias_alpha * (filtered - np.concatenate([pos, vel]) - bias))
        return EventStatus.Succeeded()

    def bias(self, context) -> np.ndarray:
        """The learnt tracking bias ``[x, y, vx, vy]`` [m, m/s] in ``context``."""
        return context.get_discrete_state(self._bias_state).value().copy()
