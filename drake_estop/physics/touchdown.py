"""Touchdown by contact: a landing sole that reaches the plan's floor and finds none keeps coming down until it
carries weight, and stays where it found the floor.

On stiff position servos a landing ends on the clock: at the plan's touchdown the swing target reaches the
floor (``z = 0``) and stops. Where the floor lies lower (a hole, a step down the plan does not know of), the
foot stops above it and takes no load while the plan moves the ZMP onto it. Measured, the 3.4 s stop with the
floor 10 mm lower under its landing spot: the foot hovered over the hole and the robot fell; with this reflex
it found the floor 0.1 s late and the stop met every criterion.

:class:`TouchdownByContact` sits on the sole targets between the planner (and its other reflexes) and the
IK. A foot the reference has put down after a swing (its target's lift at most
:data:`~drake_estop.systems.reference.SWING_HEIGHT`) is landing until its force sensor first reads
``contact_force``. If it still carries no weight ``grace_time`` after the reference put it down (longer than
the sensor's delay at an ordinary landing, so the walk's own landings are left alone) and the estimator has
it below the plan's floor (by ``below_floor``: it has come down past ``z = 0`` and found nothing), its
target goes on down at ``descent_speed``, at most ``max_depth`` below the reference. A sole that hovers higher
is left alone: its hover is the body's tilt (the swing-tilt compensation's), not the floor's, and pressing
it down tips the stiff robot (measured earlier on the push suite: 6 stops against 8). From its touchdown
the depth is held (the floor is there) and a sole that later unloads (the robot rocking) is not pushed
further; while the reference lifts the foot the depth returns to zero over ``return_time``, so the next
swing starts from the plan's path without a jump. Both feet start landed (the robot stands).
"""

from __future__ import annotations

import numpy as np
from pydrake.systems.framework import EventStatus, LeafSystem

from drake_estop.physics.swing_tilt import FEET, declare_feet_outputs
from drake_estop.systems.reference import SWING_HEIGHT
from drake_estop.timing import timed
from drake_estop.validation import check_positive


def next_depth(depth: float, landed: bool, down_time: float, *, planned_down: bool, loaded: bool, floor_missing: bool,
               dt: float, descent_speed: float, max_depth: float, return_time: float, grace_time: float) -> tuple:
    """One servo tick of a sole's touchdown: ``(depth, landed, down_time)``, its target's depth below the
    reference [m], whether it has touched down since the reference put it on the floor, and how long the
    reference has had it there [s]. Put down, not ``loaded`` for longer than ``grace_time`` [s] (the sensor's
    delay at an ordinary landing) and with its ``floor_missing`` (the estimate has it below the plan's floor),
    it goes down at ``descent_speed`` [m/s] to ``max_depth`` [m]; from its touchdown on the depth is held;
    while the reference lifts it the depth goes back towards zero over ``return_time`` [s]."""
    if not planned_down:
        return depth * max(0.0, 1.0 - dt / return_time), False, 0.0
    down_time += dt
    if landed or loaded:
        return depth, True, down_time
    if down_time <= grace_time + 1e-9 or not floor_missing:
        return depth, False, down_time
    return min(depth + descent_speed * dt, max_depth), False, down_time


class TouchdownByContact(LeafSystem):
    """Lowers a landing sole's target until the sole's force sensor measures weight.

    .. pydrake_system::

        name: TouchdownByContact
        input_ports:
        - left_foot
        - right_foot
        - foot_ft
        - sole_heights
        output_ports:
        - left_foot
        - right_foot
        - touchdown_depth

    Ports:
      - ``left_foot``, ``right_foot`` in (7): sole targets ``[x, y, z, qw, qx, qy, qz]`` (z: above the floor).
      - ``foot_ft`` (12): the soles' force/torque sensors, left then right, each ``[n, f]`` in the sole frame.
      - ``sole_heights`` (2): the soles' estimated heights above the floor [m], left then right
        (:class:`~drake_estop.physics.estimation.StateEstimator`'s).
      - ``left_foot``, ``right_foot`` out (7): the targets with z lowered by each foot's depth.
      - ``touchdown_depth`` (2): the depths [m], left then right (:func:`next_depth`).

    Parameters
    ----------
    servo_period : float
        The controller's tick [s].
    descent_speed : float, optional
        How fast a landing sole that carries no weight yet keeps coming down [m/s] (default 0.1).
    max_depth : float, optional
        The most a target goes below the reference [m] (default 0.015).
    contact_force : float, optional
        The normal force that means the sole carries weight [N] (default 50).
    return_time : float, optional
        The depth's return while the reference lifts the foot [s] (default 0.3).
    grace_time : float, optional
        How long a sole put down may carry no weight before it is lowered [s] (default 0.02: the force
        sensor's delay at an ordinary landing).
    below_floor : float, optional
        How far below the plan's floor an estimated sole must be before it comes down further [m] (default
        0.001: a sole at rest on the plan's floor is estimated within a few tenths of a millimetre of it; one
        the body's tilt holds higher, or a walk's landing a few ticks late, is not lowered).
    timer : drake_estop.timing.TickTimer, optional
        Records the wall-clock time of every update [s].

    Raises
    ------
    ValueError
        Naming a setting that is not positive and finite.
    """

    def __init__(self, *, servo_period: float = 0.005, descent_speed: float = 0.1, max_depth: float = 0.015,
                 contact_force: float = 50.0, return_time: float = 0.3, grace_time: float = 0.02,
                 below_floor: float = 0.001, timer=None):
        super().__init__()
        settings = {"servo_period": servo_period, "descent_speed": descent_speed, "max_depth": max_depth,
                    "contact_force": contact_force, "return_time": return_time, "grace_time": grace_time,
                    "below_floor": below_floor}
        for name, value in settings.items():
            check_positive(name, value)
        self._settings = {name: float(settings[name])
                          for name in ("descent_speed", "max_depth", "return_time", "grace_time")}
        self._dt, self._contact_force = float(servo_period), float(contact_force)
        self.feet_in_ports = [self.DeclareVectorInputPort(f"{side}_foot", 7) for side in FEET]
        self.foot_ft_port = self.DeclareVectorInputPort("foot_ft", 12)
        self.sole_heights_port = self.DeclareVectorInputPort("sole_heights", 2)
        self._below_floor = float(below_floor)
        self._depth = self.DeclareDiscreteState(2)
        self._landed = self.DeclareDiscreteState([1.0, 1.0])  # whether each foot touched down since put down
        self._down_time = self.DeclareDiscreteState(2)  # how long the reference has had each foot down [s]
        self.feet_out_ports = declare_feet_outputs(self, self.feet_in_ports, self._foot_calc)
        self.touchdown_depth_port = self.DeclareStateOutputPort("touchdown_depth", self._depth)
        self.DeclarePeriodicDiscreteUpdateEvent(servo_period, 0.0, timed(self._update, timer))

    def _update(self, context, discrete_state):
        forces = self.foot_ft_port.Eval(context).reshape(2, 6)[:, 5]
        heights = self.sole_heights_port.Eval(context)
        depth = context.get_discrete_state(self._depth).value()
        landed = context.get_discrete_state(self._landed).value()
        down_time = context.get_discrete_state(self._down_time).value()
        new = np.array([next_depth(float(depth[k]), bool(landed[k]), float(down_time[k]),
                                   planned_down=self.feet_in_ports[k].Eval(context)[2] <= SWING_HEIGHT,
                                   loaded=forces[k] >= self._contact_force,
                                   floor_missing=heights[k] <= -self._below_floor, dt=self._dt, **self._settings)
                        for k in range(len(FEET))], dtype=float)
        discrete_state.set_value(self._depth, new[:, 0])
        discrete_state.set_value(self._landed, new[:, 1])
        discrete_state.set_value(self._down_time, new[:, 2])
        return EventStatus.Succeeded()

    def _foot_calc(self, k):
        def calc(context, output):
            foot = np.array(self.feet_in_ports[k].Eval(context), dtype=float)
            foot[2] -= context.get_discrete_state(self._depth).value()[k]
            output.SetFromVector(foot)
        return calc


def add_touchdown_by_contact(builder, *, feet, estimator, servo_period, timer=None, **settings) -> TouchdownByContact:
    """A :class:`TouchdownByContact` fed ``feet``' ``left_foot`` / ``right_foot`` outputs, ``estimator``'s
    sole heights and its sensors' feet force/torque sensors (a
    :class:`~drake_estop.physics.estimation.StateEstimator` from ``add_state_estimation``). Returns the
    system: its feet outputs go to the IK."""
    system = builder.AddNamedSystem("touchdown_by_contact", TouchdownByContact(
        servo_period=servo_period, timer=timer, **settings))
    for k, side in enumerate(FEET):
        builder.Connect(feet.GetOutputPort(f"{side}_foot"), system.feet_in_ports[k])
    builder.Connect(estimator.sensors.foot_ft_port, system.foot_ft_port)
    builder.Connect(estimator.sole_heights_port, system.sole_heights_port)
    return system
