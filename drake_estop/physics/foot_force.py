"""Foot force difference control: in double support the soles' heights share the load as the plan's ZMP does.

On stiff position servos the load of two feet on the floor is set by the feet's heights, not by the
plan: a foot commanded onto the floor while the body is tilted a few mrad hovers a millimetre or two
above it and takes no load. Measured on the G1 (0.056 m wide soles, 0.25 m step width): its body
rolled 8 mrad onto the rear foot's outer edge in the first landing's double support, the landed foot
rose 2.2 mm off the floor and took no load until the rear foot lifted; the robot then dropped onto
it with its COG moving outwards faster than the plan, the centre of pressure on the new stance foot's
outer edge, and fell two steps later.

HRP-2's stabiliser (Kajita et al., "Biped walking stabilization based on linear inverted pendulum
tracking", IROS 2010: foot force difference control) moves the feet's heights apart by the error
of the measured force difference against the one the reference ZMP asks for::

    d(dz)/dt = ((f_L - f_R) - (f_L^d - f_R^d)) / damping - dz / return_time
    z_L = z_L^ref + dz / 2,   z_R = z_R^ref - dz / 2

with ``f^d`` the measured total force split by where the plan's ZMP lies between the ankles (all on
the stance foot while the other swings), so an underloaded foot is pressed down and the other raised.
In single support the stance foot carries everything, as asked, and ``dz`` decays. With an engage time the
control acts only once both sole targets have stood that long (a robot whose walk needs no such control
gets it in a stop's double support alone); before that ``dz`` decays as in single support.

Which soles stand, and where the ZMP's split is taken, come from the targets the control adjusts, or, with
``planned_support`` (:func:`add_foot_force_control`), from the plan's own sole targets
(``planned_left_foot`` / ``planned_right_foot``). Read from the adjusted targets, after the swing-tilt
compensation, a landed foot whose correction decays (``return_time``) stays a few millimetres up and looks
airborne: measured on the default humanoid's campaign run 195, the control never engaged in the pushed stop's
double support and halt, and the split it would have asked for put the whole load on the other foot.
"""

from __future__ import annotations

import numpy as np
from pydrake.systems.framework import EventStatus, LeafSystem

from drake_estop.physics.swing_tilt import FEET, declare_feet_outputs
from drake_estop.systems.reference import SWING_HEIGHT
from drake_estop.timing import timed


def desired_force_difference(feet, zmp, total: float, swing_height: float = SWING_HEIGHT) -> float:
    """``f_L^d - f_R^d`` [N]: the measured ``total`` normal force [N] split by where ``zmp`` (x, y) lies
    between the ankles of ``feet`` (left then right sole targets, xyz first); all of it on the foot on
    the floor while the other's target is above ``swing_height`` [m]."""
    left, right = (np.asarray(foot, float) for foot in feet)
    if left[2] > swing_height and right[2] <= swing_height:
        return -total
    if right[2] > swing_height and left[2] <= swing_height:
        return total
    axis = left[:2] - right[:2]
    share = float(np.clip((np.asarray(zmp, float)[:2] - right[:2]) @ axis / (axis @ axis), 0.0, 1.0))
    return (2.0 * share - 1.0) * total


class FootForceDifferenceControl(LeafSystem):
    """Raises one sole target and lowers the other by the error of the feet's measured force difference.

    .. pydrake_system::

        name: FootForceDifferenceControl
        input_ports:
        - left_foot
        - right_foot
        - zmp
        - foot_ft
        - planned_left_foot
        - planned_right_foot
        output_ports:
        - left_foot
        - right_foot
        - height_difference

    Ports:
      - ``left_foot``, ``right_foot`` in (7): sole targets ``[x, y, z, qw, qx, qy, qz]`` (z: above the floor).
      - ``zmp`` (2): the plan's ZMP [m].
      - ``foot_ft`` (12): the soles' force/torque sensors, left then right, each ``[n, f]`` in the sole frame.
      - ``planned_left_foot``, ``planned_right_foot`` (7): the plan's sole targets, which say which soles
        stand (z at most :data:`~drake_estop.systems.reference.SWING_HEIGHT`); left unconnected, the
        ``left_foot`` / ``right_foot`` inputs say it.
      - ``left_foot``, ``right_foot`` out (7): the targets with ``+dz / 2`` and ``-dz / 2`` on z.
      - ``height_difference`` (1): ``dz`` [m].

    Parameters (keyword-only): ``servo_period`` [s], ``damping`` [N s/m], ``return_time`` [s],
    ``max_offset`` [m] (the bound on ``|dz|``), ``engage_time`` [s] (the control acts once both sole
    targets have been on the floor this long; before that ``dz`` decays; default 0: always, single
    support included), ``timer`` (a :class:`drake_estop.timing.TickTimer`).
    """

    def __init__(self, *, servo_period=0.005, damping=5000.0, return_time=0.5, max_offset=0.02, engage_time=0.0,
                 timer=None):
        super().__init__()
        for name, value in (("servo_period", servo_period), ("damping", damping), ("return_time", return_time),
                            ("max_offset", max_offset)):
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be positive, got {value!r}")
        if not (np.isfinite(engage_time) and engage_time >= 0):
            raise ValueError(f"engage_time must be non-negative, got {engage_time!r}")
        self._dt, self._damping, self._return, self._max = servo_period, damping, return_time, max_offset
        self._engage = engage_time
        # how long both sole targets have been on the floor [s]
        self._both_down = self.DeclareDiscreteState(1)
        self.feet_in_ports = [self.DeclareVectorInputPort(f"{side}_foot", 7) for side in FEET]
        self.zmp_port = self.DeclareVectorInputPort("zmp", 2)
        self.foot_ft_port = self.DeclareVectorInputPort("foot_ft", 12)
        self.planned_feet_ports = [self.DeclareVectorInputPort(f"planned_{side}_foot", 7) for side in FEET]
        self._dz = self.DeclareDiscreteState(1)
        self.feet_out_ports = declare_feet_outputs(self, self.feet_in_ports, self._foot_calc)
        self.height_difference_port = self.DeclareStateOutputPort("height_difference", self._dz)
        self.DeclarePeriodicDiscreteUpdateEvent(servo_period, 0.0, timed(self._update, timer))

    def force_error(self, context) -> float:
        """``(f_L - f_R) - (f_L^d - f_R^d)`` [N] from the sensors' normal forces (negative ones as 0)."""
        forces = np.maximum(self.foot_ft_port.Eval(context).reshape(2, 6)[:, 5], 0.0)
        feet = self.planned_feet(context)
        desired = desired_force_difference(feet, self.zmp_port.Eval(context), float(forces.sum()))
        return float(forces[0] - forces[1]) - desired

    def planned_feet(self, context) -> list:
        """The plan's sole targets, left then right: the ``planned_*_foot`` inputs, else (unconnected) the
        ``*_foot`` inputs."""
        ports = self.planned_feet_ports if self.planned_feet_ports[0].HasValue(context) else self.feet_in_ports
        return [port.Eval(context) for port in ports]

    def _update(self, context, discrete_state):
        dz = float(context.get_discrete_state(self._dz).value()[0])
        down = all(foot[2] <= SWING_HEIGHT for foot in self.planned_feet(context))
        both_down = float(context.get_discrete_state(self._both_down).value()[0]) + self._dt if down else 0.0
        discrete_state.set_value(self._both_down, [both_down])
        engaged = both_down >= self._engage - 1e-9
        rate = (self.force_error(context) / self._damping if engaged else 0.0) - dz / self._return
        discrete_state.set_value(self._dz, [float(np.clip(dz + self._dt * rate, -self._max, self._max))])
        return EventStatus.Succeeded()

    def _foot_calc(self, k):
        sign = 0.5 if k == 0 else -0.5

        def calc(context, output):
            foot = np.array(self.feet_in_ports[k].Eval(context), dtype=float)
            foot[2] += sign * context.get_discrete_state(self._dz).value()[0]
            output.SetFromVector(foot)
        return calc


def add_foot_force_control(builder, *, feet, zmp_source, sensors, servo_period, timer=None, planned_support=False,
                           **settings):
    """A :class:`FootForceDifferenceControl` fed ``feet``' ``left_foot`` / ``right_foot`` outputs (the
    planner or a swing-foot compensation), ``zmp_source``'s ``zmp`` (the planner) and ``sensors``' feet
    force/torque sensors; with ``planned_support`` also ``zmp_source``'s feet, which then say which soles
    stand. Returns the system: its feet outputs go to the IK."""
    system = builder.AddNamedSystem("foot_force_difference_control", FootForceDifferenceControl(
        servo_period=servo_period, timer=timer, **settings))
    for k, side in enumerate(FEET):
        builder.Connect(feet.GetOutputPort(f"{side}_foot"), system.feet_in_ports[k])
        if planned_support:
            builder.Connect(zmp_source.GetOutputPort(f"{side}_foot"), system.planned_feet_ports[k])
    builder.Connect(zmp_source.GetOutputPort("zmp"), system.zmp_port)
    builder.Connect(sensors.foot_ft_port, system.foot_ft_port)
    return system
