"""Which soles landed again off the stop plan's footholds: the foothold monitor beside the stop planner.

After a stop's landing a sole can bounce: it loses its load and lands again a centimetre away. The plan
still stands on the old foothold, so its ZMP and the real support part by that much. :class:`FootholdMonitor`
follows each sole through stages (:func:`drake_estop.systems.stop_numerics.next_sole_stage`: standing,
lifted by the plan, unloaded, re-landed) against the plan in force and the estimated soles, and reports a
sole that re-landed more than a tolerance off its foothold; the stop planner's decision then re-plans the
stop where that sole stands (:func:`drake_estop.systems.decision.decide`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import EventStatus, LeafSystem, ValueProducer

from drake_estop.systems.decision import FOOTHOLD_TOLERANCE
from drake_estop.systems.plan_sequence import PlanHandle
from drake_estop.systems.stop_numerics import relanded_soles
from drake_estop.timing import timed
from drake_estop.validation import check_positive


@dataclass(frozen=True)
class Relanded:
    """The ``relanded`` output of :class:`FootholdMonitor`.

    Attributes
    ----------
    soles : dict
        ``{side: xy}`` [m]: the soles standing again more than the tolerance off the plan's foothold, where
        they stand.
    fresh : bool
        Whether one of them landed again on this tick.
    """

    soles: dict = field(default_factory=dict)
    fresh: bool = False


class FootholdMonitor(LeafSystem):
    """The soles that landed again off the stop plan's footholds.

    .. pydrake_system::

        name: FootholdMonitor
        input_ports:
        - measured_feet
        - plan
        output_ports:
        - relanded

    Each tick the output is this tick's :class:`Relanded`, from each sole's stage up to the previous tick,
    the estimated soles and the plan's feet now; the periodic (unrestricted, as the planner's) update keeps
    the new stages. Before a plan is in force, or without finite soles, the output is empty and the stages
    stay.

    Parameters
    ----------
    servo_period : float
        The controller's tick [s].
    foothold_ticks : int, optional
        Loaded ticks after which a sole stands on a foothold (dimensionless, default 2).
    tolerance : float, optional
        How far off the plan's foothold a re-landed sole counts [m] (default
        :data:`~drake_estop.systems.decision.FOOTHOLD_TOLERANCE`).
    timer : drake_estop.timing.TickTimer, optional
        Records the wall-clock time of every update [s].

    Notes
    -----
    Inputs ``measured_feet`` (6: ``[x_l, y_l, x_r, y_r, loaded ticks l, loaded ticks r]`` [m], as
    :class:`~drake_estop.physics.estimation.StateEstimator`'s ``feet``) and ``plan`` (the stop planner's
    :class:`~drake_estop.systems.plan_sequence.PlanHandle`); output ``relanded`` (:class:`Relanded`).

    Raises
    ------
    ValueError
        Naming ``servo_period``, ``foothold_ticks`` or ``tolerance`` where it is not positive (and a whole
        number of ticks).
    """

    def __init__(self, *, servo_period: float, foothold_ticks: int = 2, tolerance: float = FOOTHOLD_TOLERANCE,
                 timer=None):
        super().__init__()
        check_positive("servo_period", servo_period)
        check_positive("tolerance", tolerance)
        if isinstance(foothold_ticks, bool) or not isinstance(foothold_ticks, int) or foothold_ticks < 1:
            raise ValueError(f"foothold_ticks must be a positive integer, got {foothold_ticks!r}")
        self._foothold_ticks = foothold_ticks
        self._tolerance = float(tolerance)
        self.measured_feet_port = self.DeclareVectorInputPort("measured_feet", 6)
        self.plan_port = self.DeclareAbstractInputPort("plan", AbstractValue.Make(PlanHandle()))
        # per sole (SIDES order): its SOLE_* stage (stop_numerics.next_sole_stage)
        self._stages = self.DeclareDiscreteState(2)
        # this tick's (new stages or None, Relanded): computed once a tick for the output and the update
        self._tick = self.DeclareCacheEntry(
            "relanded", ValueProducer(allocate=lambda: AbstractValue.Make((None, Relanded())), calc=self._calc_tick),
            {self.all_input_ports_ticket(), self.xd_ticket(), self.time_ticket()})
        self.relanded_port = self.DeclareAbstractOutputPort(
            "relanded", lambda: AbstractValue.Make(Relanded()),
            lambda context, value: value.set_value(self._tick.Eval(context)[1]),
            prerequisites_of_calc={self._tick.ticket()})
        self.DeclarePeriodicUnrestrictedUpdateEvent(servo_period, 0.0, timed(self._update, timer))

    def _calc_tick(self, context, value):
        plan = self.plan_port.Eval(context).plan if self.plan_port.HasValue(context) else None
        feet = self.measured_feet_port.Eval(context) if self.measured_feet_port.HasValue(context) else None
        if plan is None or feet is None or not np.all(np.isfinite(feet)):
            value.set_value((None, Relanded()))
            return
        stages, soles, fresh = relanded_soles(context.get_discrete_state(self._stages).value(), feet,
                                              plan.feet(context.get_time()), self._foothold_ticks, self._tolerance)
        value.set_value((stages, Relanded(soles, fresh)))

    def _update(self, context, state):
        stages, _ = self._tick.Eval(context)
        if stages is None:
            return EventStatus.DidNothing()
        state.get_mutable_discrete_state(self._stages).set_value(stages)
        return EventStatus.Succeeded()

    def stages(self, context) -> np.ndarray:
        """Each sole's stage (``SIDES`` order, :data:`~drake_estop.systems.stop_numerics.SOLE_STANDING`, ...)
        in ``context``."""
        return context.get_discrete_state(self._stages).value().copy()


def add_foothold_monitor(builder, *, planner, feet_port, timer=None) -> FootholdMonitor:
    """Add a :class:`FootholdMonitor` at ``planner``'s tick and settings (``foothold_ticks``,
    ``foothold_tolerance``), reading ``feet_port`` (the estimated soles) and the planner's plan, and feed its
    ``relanded`` output to the planner."""
    config = planner.config
    monitor = builder.AddNamedSystem("foothold_monitor", FootholdMonitor(
        servo_period=planner.params.servo_period, foothold_ticks=int(config.foothold_ticks),
        tolerance=config.foothold_tolerance, timer=timer))
    builder.Connect(feet_port, monitor.measured_feet_port)
    builder.Connect(planner.plan_port, monitor.plan_port)
    builder.Connect(monitor.relanded_port, planner.relanded_port)
    return monitor
