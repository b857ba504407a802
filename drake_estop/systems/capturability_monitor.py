"""The capturability verdict at every servo tick: what the robot can still catch, from the measured state.

:class:`CapturabilityMonitor` observes; it does not act. Each tick it evaluates
:func:`drake_estop.planning.capturability.capturability` on the estimator's COG, COG velocity and feet (the
DCM, eq. 4; the loaded soles are the support) and on the commanded swing foot's height and descent rate
(the swing's least time to touch down), and holds ``[steps, margin, margin_speed]`` in its discrete state.
``steps`` is -1 where no N <= 3 captures the state. The whole verdict, its witness steps included, of the
first tick at or after ``report_time`` (the later of the signal and the end of the last push) is kept too
(:meth:`CapturabilityMonitor.reported`): the run's summary gives it.
"""

from __future__ import annotations

import math

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import BasicVector, EventStatus, LeafSystem

from drake_estop.planning.capturability import SteppingLimits, capturability, swing_touchdown_time
from drake_estop.planning.plan import StopParameters
from drake_estop.timing import per_tick, timed

SIDES = ("left", "right")
#: The output's entries.
FIELDS = ("steps", "margin", "margin_speed")


class CapturabilityMonitor(LeafSystem):
    """The N-step capturability of the measured state, once a servo tick (module docstring).

    .. pydrake_system::

        name: CapturabilityMonitor
        input_ports:
        - measured_com
        - measured_com_vel
        - measured_feet
        - left_foot
        - right_foot
        output_ports:
        - capturability

    ``capturability`` is ``[steps, margin [m], margin_speed [m/s]]``; the inputs are the estimator's COG [m],
    COG velocity [m/s] and feet (left xy, right xy [m], each sole's loaded ticks) and the commanded soles'
    poses ``[x, y, z, qw, qx, qy, qz]`` [m].

    Parameters
    ----------
    omega : float
        The LIPM's natural frequency sqrt(g / z) [1/s] (the walk's ``NominalPattern.w``).
    limits : SteppingLimits
        Where and when the feet can land.
    params : StopParameters
        The stop's limits: the swing's descent (the least time to touch down) and ``servo_period`` [s].
    report_time : float
        The time [s] from which the first tick's whole verdict is kept (:meth:`reported`; inf: none).
    timer : TickTimer, optional
        Times each tick's update (:func:`drake_estop.timing.timed`): the verdict's cost shows beside the
        controller's blocks.
    """

    def __init__(self, *, omega: float, limits: SteppingLimits, params: StopParameters,
                 report_time: float = float("inf"), timer=None):
        super().__init__()
        self._omega, self._limits, self._params = float(omega), limits, params
        self._report_time = float(report_time)
        self.measured_com_port = self.DeclareVectorInputPort("measured_com", 3)
        self.measured_com_vel_port = self.DeclareVectorInputPort("measured_com_vel", 3)
        # the estimator's feet: left xy, right xy, then each sole's loaded ticks (0: unloaded)
        self.measured_feet_port = self.DeclareVectorInputPort("measured_feet", 6)
        self.foot_ports = {side: self.DeclareVectorInputPort(f"{side}_foot", 7) for side in SIDES}
        # [steps, margin, margin_speed], then the commanded soles' last heights (their descent rate)
        self._state = self.DeclareDiscreteState(BasicVector([0.0, 0.0, 0.0, 0.0, 0.0]))
        self._reported = self.DeclareAbstractState(AbstractValue.Make(None))  # the report tick's verdict
        # unrestricted: the report tick sets the abstract state too (the state is a few numbers to copy)
        self.DeclarePeriodicUnrestrictedUpdateEvent(params.servo_period, 0.0, timed(self._update, timer))
        self.capturability_port = self.DeclareVectorOutputPort(
            "capturability", len(FIELDS),
            lambda context, output: output.SetFromVector(context.get_discrete_state(self._state).get_value()[:3]),
            prerequisites_of_calc={self.xd_ticket()})

    @property
    def servo_period(self) -> float:
        """The tick [s] of its updates."""
        return self._params.servo_period

    def reported(self, context):
        """The whole :class:`~drake_estop.planning.capturability.Capturability` of the first tick at or after
        ``report_time`` (None before it)."""
        return context.get_abstract_state(self._reported).get_value()

    def _update(self, context, state) -> EventStatus:
        previous = context.get_discrete_state(self._state).get_value()
        soles = [self.foot_ports[side].Eval(context) for side in SIDES]  # [x, y, z, qw, qx, qy, qz]
        heights = np.array([sole[2] for sole in soles])
        verdict = self.verdict(self.measured_com_port.Eval(context)[:2], self.measured_com_vel_port.Eval(context)[:2],
                               self.measured_feet_port.Eval(context), heights,
                               (heights - previous[3:]) / self._params.servo_period,
                               headings=[_yaw(sole[3:7]) for sole in soles])
        state.get_mutable_discrete_state(self._state).SetFromVector(
            [verdict.steps, verdict.margin, verdict.margin_speed, *heights])
        if context.get_time() >= self._report_time - 1e-9 and self.reported(context) is None:
            state.get_mutable_abstract_state(self._reported).set_value(verdict)
        return EventStatus.Succeeded()

    def verdict(self, com, com_vel, feet, heights, rates, headings=(0.0, 0.0)):
        """The :class:`~drake_estop.planning.capturability.Capturability` of a COG ``com`` [m] moving at
        ``com_vel`` [m/s] on the estimator's ``feet`` (left xy, right xy, loaded ticks), the commanded soles at
        ``heights`` [m] moving at ``rates`` [m/s] and turned to ``headings`` [rad] (left, right). One loaded
        sole: single support on it, its heading the soles'; both or neither: both feet down (either may step,
        after a weight shift), the left sole's heading."""
        dcm = np.asarray(com, dtype=float) + np.asarray(com_vel, dtype=float) / self._omega
        ankles = {"left": np.asarray(feet[0:2], dtype=float), "right": np.asarray(feet[2:4], dtype=float)}
        loaded = [side for side, ticks in zip(SIDES, feet[4:6]) if ticks > 0.0]
        common = dict(omega=self._omega, limits=self._limits)
        if len(loaded) == 1:
            stance = loaded[0]
            swing = "right" if stance == "left" else "left"
            index = SIDES.index(swing)
            first = swing_touchdown_time(self._params, float(heights[index]), float(rates[index]))
            return capturability(dcm, stance_ankle=ankles[stance], stance_side=stance, first_step_time=first,
                                 swing_foot=ankles[swing], heading=float(headings[1 - index]), **common)
        return capturability(dcm, stance_ankle=ankles["left"], stance_side="left", other_ankle=ankles["right"],
                             first_step_time=self._limits.min_step_time, heading=float(headings[0]), **common)


def _yaw(quaternion) -> float:
    """The heading [rad] of a sole turned by the unit ``quaternion`` ``[w, x, y, z]``."""
    w, x, y, z = (float(v) for v in quaternion)
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def add_capturability_monitor(builder, *, estimator, reference, omega: float, limits: SteppingLimits,
                              params: StopParameters, report_time: float = float("inf"), timer=None,
                              name: str = "capturability_monitor") -> CapturabilityMonitor:
    """Add a :class:`CapturabilityMonitor` fed by ``estimator`` (its ``com``, ``com_vel`` and ``feet``
    outputs) and ``reference`` (its ``left_foot`` / ``right_foot``: the commanded soles)."""
    monitor = builder.AddNamedSystem(name, CapturabilityMonitor(omega=omega, limits=limits, params=params,
                                                                report_time=report_time, timer=timer))
    builder.Connect(estimator.com_port, monitor.measured_com_port)
    builder.Connect(estimator.com_vel_port, monitor.measured_com_vel_port)
    builder.Connect(estimator.feet_port, monitor.measured_feet_port)
    for side in SIDES:
        builder.Connect(reference.GetOutputPort(f"{side}_foot"), monitor.foot_ports[side])
    return monitor


def report_time(estop_time: float | None, pushes=()) -> float:
    """The later of the stop signal and the end of the last push [s] (inf with neither)."""
    times = [float(estop_time)] if estop_time is not None else []
    times += [p.time + p.duration for p in pushes]
    return max(times) if times else float("inf")


def capturability_summary(reported, per_tick: np.ndarray, servo_period: float, since: float,
                          until: float = float("inf")) -> dict:
    """The run summary's ``capturability``: the ``reported`` verdict (:meth:`CapturabilityMonitor.reported`,
    or None) as ``{steps, margin, margin_speed, witness}``, and ``worst``, the tick from ``since`` [s] on and
    before ``until`` [s] (a fall: the verdict on a robot falling says nothing) of least margin in ``per_tick``
    (rows: ticks k * servo_period; columns :data:`FIELDS`), with its ``time``; None without such a tick."""
    summary = reported.as_dict() if reported is not None else {"steps": None, "margin": None,
                                                               "margin_speed": None, "witness": []}
    first = max(int(round(since / servo_period)), 0) if np.isfinite(since) else len(per_tick)
    last = int(math.ceil(until / servo_period - 1e-9)) if np.isfinite(until) else len(per_tick)
    margins = per_tick[first:max(last, first), 1]
    if np.any(np.isfinite(margins)):
        k = first + int(np.nanargmin(margins))
        summary["worst"] = {"time": k * servo_period, "steps": int(per_tick[k, 0]),
                            "margin": float(per_tick[k, 1]), "margin_speed": float(per_tick[k, 2])}
    else:
        summary["worst"] = None
    return summary


def monitor_results(monitor: CapturabilityMonitor, logger, root_context, since: float,
                    until: float = float("inf")) -> dict:
    """A run's capturability from its ``monitor`` and the ``logger`` of its output (``root_context``: the
    diagram's): ``capture`` (ticks x :data:`FIELDS`, per servo tick from 0) and ``capturability``
    (:func:`capturability_summary`, the worst tick from ``since`` [s], the signal, until ``until``, a fall)."""
    servo_period = monitor.servo_period
    rows = per_tick(logger.FindLog(root_context), servo_period).reshape(-1, len(FIELDS))
    reported = monitor.reported(monitor.GetMyContextFromRoot(root_context))
    return {"capture": rows, "capturability": capturability_summary(reported, rows, servo_period, since, until)}
