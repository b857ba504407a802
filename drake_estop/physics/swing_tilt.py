"""Swing-foot tilt compensation: the landing foot is commanded where it lands in the world.

On stiff position servos a sideways push turns the whole robot about its stance foot (the stance
ankle yields, :mod:`drake_estop.physics.compliance`, and the servos deflect). The joint servos hold
the swing leg's angles, so the swing foot turns with the body. Measured, 17 N s to the right at
3.15 s (left foot supporting, the push towards the swing side): the body rolled 0.04 rad, the swing
foot came down about 8 mm low (0.19 m from the stance foot) and rolled with it, struck the floor on
its outer edge 70 ms before the planned landing and 1.7 cm short, the plan went on swinging it, the
stance foot unloaded and slid 2.4 cm, and the centre of pressure left the planned support by 16 mm.

This is what hrpsys-base's Stabilizer corrects with its swing end-effector modification
(``calcSwingEEModification``): while a foot swings, its target is corrected by the measured error of
its pose relative to the support foot; once the foot is in contact (planned or measured) the
correction returns to zero exponentially. Here the error is taken as the body's measured tilt: with
``dR`` the roll and pitch of the estimated floating base against the IK's commanded base (yaw left
out, less a dead band that keeps the walk's own sway of a few mrad out of it), the robot is close to
the IK's posture turned by ``dR`` about the stance foot ``a``, so the swing target ``(p, R)`` is
commanded as::

    p_ik = a + dR^T (p - a),    R_ik = dR^T R

and the foot reaches ``(p, R)`` in the world: level and at its planned place. While the plan swings
the foot and its force/torque sensor reads no load, the correction follows the measured tilt; after
the touchdown it decays with ``return_time``, so the landed leg lowers against the body and rights
it instead of jumping back.
"""

from __future__ import annotations

import numpy as np
from pydrake.systems.framework import EventStatus, LeafSystem

from drake_estop.robots.parameters import as_robot
from drake_estop.systems.ik import matrix_to_quaternion, quaternion_to_matrix, rotation_exp, rotation_log
from drake_estop.systems.reference import SWING_HEIGHT
from drake_estop.timing import timed

FEET = ("left", "right")


def declare_feet_outputs(system, feet_in_ports, calc_for) -> list:
    """The ``left_foot`` / ``right_foot`` outputs (7: position, quaternion; ``FEET`` order) of a system that
    adjusts the feet targets on their way to the IK: output ``k`` is ``calc_for(k)``, computed from
    ``feet_in_ports`` and the system's discrete state."""
    tickets = {port.ticket() for port in feet_in_ports} | {system.xd_ticket()}
    return [system.DeclareVectorOutputPort(f"{side}_foot", 7, calc_for(k), prerequisites_of_calc=tickets)
            for k, side in enumerate(FEET)]


def base_tilt(measured_quat, commanded_quat, deadband: float = 0.0, max_tilt: float = np.inf) -> np.ndarray:
    """Rotation vector [rad] of the measured base orientation against the commanded one, world frame:
    its roll and pitch (the vertical component dropped), shrunk by ``deadband`` and capped at
    ``max_tilt`` in norm. Zero for a non-finite input."""
    if not (np.all(np.isfinite(measured_quat)) and np.all(np.isfinite(commanded_quat))):
        return np.zeros(3)
    tilt = rotation_log(quaternion_to_matrix(measured_quat) @ quaternion_to_matrix(commanded_quat).T)
    tilt[2] = 0.0
    norm = float(np.linalg.norm(tilt))
    if norm <= deadband:
        return np.zeros(3)
    return tilt * (min(norm - deadband, max_tilt) / norm)


def compensated_foot(foot, pivot, tilt) -> np.ndarray:
    """Sole pose 7-vector ``[x, y, z, qw, qx, qy, qz]`` turned by ``-tilt`` (rotation vector) about
    ``pivot`` (xyz): where to command a foot so that a robot turned by ``tilt`` about ``pivot`` puts it
    at ``foot``."""
    out = np.array(foot, dtype=float)
    if not np.any(tilt):
        return out
    back = rotation_exp(-np.asarray(tilt, float))
    out[:3] = pivot + back @ (out[:3] - pivot)
    out[3:] = matrix_to_quaternion(back @ quaternion_to_matrix(out[3:]))
    return out


class SwingFootTiltCompensation(LeafSystem):
    """Turns each swing foot's target against the body's measured tilt, about the stance foot.

    .. pydrake_system::

        name: SwingFootTiltCompensation
        input_ports:
        - left_foot
        - right_foot
        - measured_q
        - commanded_q
        - foot_ft
        output_ports:
        - left_foot
        - right_foot
        - tilt

    Ports:
      - ``left_foot``, ``right_foot`` in (7): the planner's sole targets ``[x, y, z, qw, qx, qy, qz]``
        (z is the lift above the floor).
      - ``measured_q`` (nq): the estimated configuration (its floating base's orientation is read).
      - ``commanded_q`` (nq): the IK's configuration (the servo reference); a state output, so no
        algebraic loop.
      - ``foot_ft`` (12): the soles' force/torque sensors, left then right, each ``[n, f]`` in the sole
        frame; a foot reading at least ``contact_force`` is in contact.
      - ``left_foot``, ``right_foot`` out (7): the compensated targets (for WholeBodyIK).
      - ``tilt`` (6): the correction of each foot, left then right, as a rotation vector [rad].

    A foot is swinging while its target is above ``swing_height`` and the other's is not, and its
    sensor reads less than ``contact_force``; its correction is then the measured tilt
    (:func:`base_tilt` with ``deadband`` and ``max_tilt``). Otherwise the correction decays
    (``return_time``). Parameters are keyword-only; ``timer`` is a
    :class:`drake_estop.timing.TickTimer`; ``robot`` (a description, a name or None: the default
    humanoid) names the floating base.
    """

    def __init__(self, *, plant, servo_period=0.005, deadband=0.01, max_tilt=0.17, return_time=0.3,
                 contact_force=50.0, swing_height=SWING_HEIGHT, timer=None, robot=None):
        super().__init__()
        for name, value in (("servo_period", servo_period), ("max_tilt", max_tilt), ("return_time", return_time),
                            ("swing_height", swing_height)):
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be positive, got {value!r}")
        for name, value in (("deadband", deadband), ("contact_force", contact_force)):
            if not (np.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be finite and non-negative, got {value!r}")
        self._deadband, self._max_tilt = deadband, max_tilt
        self._decay = max(0.0, 1.0 - servo_period / return_time)
        self._contact_force, self._swing_height = contact_force, swing_height
        base = plant.GetBodyByName(as_robot(robot).floating_base).floating_positions_start()
        self._quat = slice(base, base + 4)
        nq = plant.num_positions()
        self.feet_in_ports = [self.DeclareVectorInputPort(f"{side}_foot", 7) for side in FEET]
        self.measured_q_port = self.DeclareVectorInputPort("measured_q", nq)
        self.commanded_q_port = self.DeclareVectorInputPort("commanded_q", nq)
        self.foot_ft_port = self.DeclareVectorInputPort("foot_ft", 12)
        self._tilt = self.DeclareDiscreteState(6)
        self.feet_out_ports = declare_feet_outputs(self, self.feet_in_ports, self._foot_calc)
        self.tilt_port = self.DeclareStateOutputPort("tilt", self._tilt)
        self.DeclarePeriodicDiscreteUpdateEvent(servo_period, 0.0, timed(self._update, timer))

    def swinging(self, context) -> list[bool]:
        """Per foot, left then right: is it swinging (planned off the floor and not loaded)?"""
        feet = [port.Eval(context) for port in self.feet_in_ports]
        forces = self.foot_ft_port.Eval(context).reshape(2, 6)[:, 5]
        return [bool(feet[k][2] > self._swing_height and feet[1 - k][2] <= self._swing_height
                     and forces[k] < self._contact_force) for k in range(2)]

    def measured_tilt(self, context) -> np.ndarray:
        """:func:`base_tilt` of the measured against the commanded base, with this system's settings."""
        return base_tilt(self.measured_q_port.Eval(context)[self._quat],
                         self.commanded_q_port.Eval(context)[self._quat], self._deadband, self._max_tilt)

    def _update(self, context, discrete_state):
        tilt = context.get_discrete_state(self._tilt).value().reshape(2, 3) * self._decay
        swinging = self.swinging(context)
        if any(swinging):
            tilt[swinging.index(True)] = self.measured_tilt(context)
        discrete_state.set_value(self._tilt, tilt.ravel())
        return EventStatus.Succeeded()

    def _foot_calc(self, k):
        def calc(context, output):
            pivot = self.feet_in_ports[1 - k].Eval(context)[:3]
            tilt = context.get_discrete_state(self._tilt).value()[3 * k:3 * k + 3]
            output.SetFromVector(compensated_foot(self.feet_in_ports[k].Eval(context), pivot, tilt))
        return calc


def add_swing_tilt_compensation(builder, *, plant, reference, ik, estimator, servo_period, timer=None,
                                **settings):
    """A :class:`SwingFootTiltCompensation` fed ``reference``'s feet outputs (the planner),
    ``estimator.q_port``, ``ik.q_port`` and ``estimator.sensors``' feet force/torque sensors. ``plant``
    is the IK's plant (same positions as the estimator's). Returns the system: its feet outputs go to
    the IK (``connect_reference(..., feet=system)``)."""
    system = builder.AddNamedSystem("swing_tilt_compensation", SwingFootTiltCompensation(
        plant=plant, servo_period=servo_period, timer=timer, **settings))
    for k, side in enumerate(FEET):
        builder.Connect(reference.GetOutputPort(f"{side}_foot"), system.feet_in_ports[k])
    builder.Connect(estimator.q_port, system.measured_q_port)
    builder.Connect(ik.q_port, system.commanded_q_port)
    builder.Connect(estimator.sensors.foot_ft_port, system.foot_ft_port)
    return system
