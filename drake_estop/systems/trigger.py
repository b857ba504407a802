"""The emergency-stop trigger: latches the stop signal once, at a servo tick.

:class:`EStopTrigger` latches from a scheduled time, an input port or a
Meshcat button (the "emergency stop" a person presses); its ``stop`` output
feeds :class:`drake_estop.systems.stop_controller.StopPlannerSystem`.
"""

from __future__ import annotations

import numpy as np
from pydrake.systems.framework import EventStatus, LeafSystem


class EStopTrigger(LeafSystem):
    """Latches the emergency-stop signal once, at a servo tick.

    Sources, checked every ``servo_period``: (a) ``scheduled_time`` (the
    first tick at or after it), (b) the optional ``stop_request`` input port
    (any element > 0.5 requests the stop; leave it unconnected to ignore it),
    (c) a Meshcat button ``button_name`` (a click since the context was
    initialized).  The first request latches ``[1, t_tick]``; later requests
    and presses change nothing.

    .. pydrake_system::

        name: EStopTrigger
        input_ports:
        - stop_request
        output_ports:
        - stop

    Parameters
    ----------
    servo_period : float
        Period of the latch check [s] (HRP-2: 0.005 s).
    scheduled_time : float, optional
        Time of a scheduled stop signal [s]; None for none.
    meshcat : pydrake.geometry.Meshcat, optional
        Adds the button ``button_name`` there; a click latches the stop.
    button_name : str, optional
        Label of the Meshcat button (default "Emergency stop").
    request_size : int, optional
        Size of the ``stop_request`` input (default 1).

    Notes
    -----
    ``stop`` (2) is ``[latched (0 or 1), latch_time [s]]`` (latch_time is NaN
    before the latch). State: discrete ``[latched, latch_time]`` plus the
    button's click count at initialization (so a reused Meshcat button does
    not fire at once).
    """

    def __init__(self, *, servo_period, scheduled_time=None, meshcat=None,
                 button_name="Emergency stop", request_size=1):
        super().__init__()
        self._period = float(servo_period)
        self._scheduled = None if scheduled_time is None else float(scheduled_time)
        self._meshcat = meshcat
        self._button = button_name
        if meshcat is not None:
            meshcat.AddButton(button_name)
        self._latch_state = self.DeclareDiscreteState(np.array([0.0, np.nan]))
        self._clicks_state = self.DeclareDiscreteState(1)
        self.stop_request_port = self.DeclareVectorInputPort("stop_request", request_size)
        self.stop_port = self.DeclareStateOutputPort("stop", self._latch_state)
        self.DeclareInitializationDiscreteUpdateEvent(self._initialize)
        self.DeclarePeriodicDiscreteUpdateEvent(self._period, 0.0, self._update)

    @property
    def button_name(self):
        return self._button

    def _clicks(self):
        return 0 if self._meshcat is None else self._meshcat.GetButtonClicks(self._button)

    def _initialize(self, context, discrete_state):
        """Remember the button's click count when the simulation starts."""
        discrete_state.set_value(self._clicks_state, [float(self._clicks())])
        return EventStatus.Succeeded()

    def _requested(self, context):
        """True when any source asks for the stop at this tick."""
        t = context.get_time()
        if self._scheduled is not None and t >= self._scheduled - 1e-6 * self._period:
            return True
        if self.stop_request_port.HasValue(context) and np.any(
                self.stop_request_port.Eval(context) > 0.5):
            return True
        baseline = context.get_discrete_state(self._clicks_state).value()[0]
        return self._clicks() > baseline

    def _update(self, context, discrete_state):
        """Latch once; afterwards every request is ignored."""
        if context.get_discrete_state(self._latch_state).value()[0] > 0.5:
            return EventStatus.DidNothing()
        if not self._requested(context):
            return EventStatus.DidNothing()
        discrete_state.set_value(self._latch_state, [1.0, context.get_time()])
        return EventStatus.Succeeded()

    @staticmethod
    def latched(stop):
        """(latched, latch_time) of a ``stop`` port value."""
        return bool(stop[0] > 0.5), float(stop[1])
