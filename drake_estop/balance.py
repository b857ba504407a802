"""Online balance control on stiff position servos: DCM feedback realised by ankle damping control.

Why the earlier DCM stabiliser (:class:`drake_estop.stabilizer.DcmStabilizer`)
failed, in one paragraph: it realised the DCM law only through the COG target
handed to the IK, i.e. through the COG *acceleration* of a position-controlled
body. The ground reaction then follows the whole-body motion, not the LIPM:
the limbs' angular momentum and the crouch put the multibody ZMP of the
reference up to 8 cm off the planned ZMP (and 60 cm for one tick at a
stretched-knee touchdown), so the commanded ZMP never reached the floor. Where
the plan runs its ZMP 1 cm from a sole edge, the real centre of pressure went
over the edge, the stance foot rolled, and a COG correction that acts only
through the slow, non-minimum-phase LIPM could not catch it. Raising the gain
made it oscillate on the stiff ankles.

What changes (Kajita et al., IROS 2010, "Biped walking stabilization based on
linear inverted pendulum tracking", on HRP-2's stiff position servos):

1. **The centre of pressure is actuated directly.** Each stance ankle's pitch
   and roll references get an offset ``d`` from *foot damping control*:
   ``d' = -(a . (n_des - n_meas)) / D - d / T`` with ``n`` the ground moment
   about the sole origin from the foot's force/torque measurement and ``a``
   the joint axis. The stiff ankle servo turns the offset into torque within
   a servo tick, so the measured CoP of each foot follows its desired CoP at
   ``kp / D`` (about 40 1/s) whatever the model error: the multibody terms
   (limb angular momentum, crouch, servo lag) are measured, not modelled.
   The desired CoP is clamped ``foot_margin`` inside each sole, so a foot
   yields (the ankle gives) instead of rolling over its edge.
2. **DCM feedback picks the desired CoP.** ``xi = c + c'/omega`` (measured),
   ``p_des = p_ref + (1 + k_dcm / omega)(xi - xi_ref)`` makes the DCM error
   decay as ``exp(-k_dcm t)`` (``xi' = omega (xi - p)``), saturated
   ``polygon_margin`` inside the planned support polygon.
3. **The COG target follows the commanded CoP** (Kajita's "COG-ZMP" model):
   the IK's COG target is ``c_ref + offset`` with
   ``offset'' = omega^2 (offset - (p_des - p_ref))`` (exact zero-order hold),
   the LIPM of the correction, so the posture the IK produces matches the
   motion the CoP causes and the ankle offsets stay small (their leak ``T``
   returns them to the IK posture).

The stop plan leaves the controller room: :func:`controller_stop_parameters`
plans with a larger ZMP margin than the pure planner, so ``p_des`` has
centimetres to move in every phase.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.multibody.plant import ContactResults
from pydrake.systems.framework import EventStatus, LeafSystem

from drake_estop.gait import Sole
from drake_estop.stabilizer import saturation_scale, support_corners

from drake_estop.lipm import GRAVITY  # noqa: E402
import os
SIGN = float(os.environ.get("SIGN", "-1"))
SIDES = ("left", "right")
_LIFT_ON_GROUND = 1e-9

# discrete state layout of BalanceController
_OFFSET = slice(0, 2)  # COG target offset [m]
_OFFSET_RATE = slice(2, 4)  # [m/s]
_ANKLE = slice(4, 8)  # ankle offsets [rad]: left pitch, left roll, right pitch, right roll
_ZMP_CMD = slice(8, 10)  # desired CoP (total) [m]
_DCM_ERROR = slice(10, 12)  # measured - planned DCM [m]
_DCM_FILTERED = slice(12, 14)
_MODEL_ERROR = slice(14, 16)  # low-passed measured CoP - LIPM ZMP of the commanded motion [m]
_ZMP_LIPM = slice(16, 18)  # LIPM ZMP of the commanded motion (p_ref + u) [m]
_STATE_SIZE = 18


@dataclass(frozen=True)
class BalanceParameters:
    """Gains of :class:`BalanceController` (see the module docstring for the law)."""

    k_dcm: float = 3.0  # [1/s] DCM error decay rate
    dcm_filter_time_constant: float = 0.01  # [s] low-pass of the measured DCM error
    model_error_time_constant: float = 0.05  # [s] low-pass of the CoP model error
    polygon_margin: float = 0.015  # [m] desired CoP kept inside the planned support polygon
    foot_margin: float = 0.012  # [m] each foot's desired CoP kept inside its sole
    ankle_damping: float = 900.0  # D [N m s / rad]: CoP tracking rate kp / D
    ankle_leak_time: float = 0.6  # T [s]: ankle offsets return to the IK posture
    max_ankle_offset: float = 0.12  # [rad]
    contact_fraction: float = 0.08  # a foot is a stance foot above this share of the weight
    max_offset: float = 0.10  # [m] bound on the COG target correction
    enabled: bool = True

    def __post_init__(self):
        for name in ("k_dcm", "ankle_damping", "ankle_leak_time", "max_ankle_offset", "max_offset"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be positive and finite, got {value!r}")
        for name in ("dcm_filter_time_constant", "polygon_margin", "foot_margin", "contact_fraction"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be >= 0 and finite, got {value!r}")


def _yaw(quaternion_wxyz):
    w, x, y, z = np.asarray(quaternion_wxyz, float) / np.linalg.norm(quaternion_wxyz)
    return math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


def clamp_to_sole(point, pose, sole: Sole, side: str, margin: float):
    """``point`` (2) moved into the sole rectangle of the foot at ``pose`` (7), ``margin`` inside."""
    yaw = _yaw(pose[3:7])
    c, s = math.cos(yaw), math.sin(yaw)
    local = np.array([[c, s], [-s, c]]) @ (np.asarray(point, float) - pose[:2])
    left = sole.outer if side == "left" else sole.inner
    right = sole.inner if side == "left" else sole.outer
    local[0] = min(max(local[0], -sole.heel + margin), sole.toe - margin)
    local[1] = min(max(local[1], -right + margin), left - margin)
    return pose[:2] + np.array([[c, -s], [s, c]]) @ local


class FootForceSensors(LeafSystem):
    """Per-foot force/torque "sensors" from the plant's contact results.

    .. pydrake_system::

        name: FootForceSensors
        input_ports:
        - contact_results
        output_ports:
        - left_wrench
        - right_wrench

    Each output (6) is ``[n (3), f (3)]``: the ground's force on that foot and
    its moment about the world origin, world frame (what a sole force/torque
    sensor measures, expressed with the foot's kinematic pose; no noise).
    """

    def __init__(self, *, plant, left_sole_body, right_sole_body):
        super().__init__()
        self._bodies = {int(left_sole_body.index()): "left", int(right_sole_body.index()): "right"}
        self._world = int(plant.world_body().index())
        self.contact_results_port = self.DeclareAbstractInputPort(
            "contact_results", AbstractValue.Make(ContactResults()))
        self.left_wrench_port = self.DeclareVectorOutputPort(
            "left_wrench", 6, lambda c, o: o.SetFromVector(self.wrenches(c)["left"]))
        self.right_wrench_port = self.DeclareVectorOutputPort(
            "right_wrench", 6, lambda c, o: o.SetFromVector(self.wrenches(c)["right"]))

    def wrenches(self, context):
        """``{side: [n, f]}``: the ground's wrench on each foot about the world origin."""
        results = self.contact_results_port.Eval(context)
        out = {side: np.zeros(6) for side in SIDES}
        for i in range(results.num_point_pair_contacts()):
            info = results.point_pair_contact_info(i)
            a, b = int(info.bodyA_index()), int(info.bodyB_index())
            if a == self._world and b in self._bodies:
                side, sign = self._bodies[b], 1.0
            elif b == self._world and a in self._bodies:
                side, sign = self._bodies[a], -1.0
            else:
                continue
            f = sign * info.contact_force()
            out[side][:3] += np.cross(info.contact_point(), f)
            out[side][3:] += f
        return out


def foot_cop(wrench):
    """CoP (2) on the floor z = 0 of a ground wrench ``[n, f]`` about the world origin."""
    n, f = wrench[:3], wrench[3:]
    return np.array([-n[1], n[0]]) / f[2]


class BalanceController(LeafSystem):
    """DCM feedback through per-foot CoP (ankle damping) control and a LIPM COG correction.

    .. pydrake_system::

        name: BalanceController
        input_ports:
        - planned_com
        - planned_com_vel
        - planned_zmp
        - left_foot
        - right_foot
        - measured_com
        - measured_com_vel
        - measured_cop
        - foot_forces
        output_ports:
        - com
        - joint_offset
        - commanded_zmp
        - com_offset
        - dcm_error

    Ports (world frame, SI):
      - ``planned_com`` (3), ``planned_com_vel`` (3), ``planned_zmp`` (2),
        ``left_foot`` / ``right_foot`` (7, sole poses ``[x, y, lift, qw..qz]``):
        the stop planner's reference.
      - ``measured_com`` (3), ``measured_com_vel`` (3): the state estimate.
      - ``measured_cop`` (2): the centre of pressure of the ground reaction
        (NaN without contact); ``foot_forces`` (2): the left and right
        soles' normal forces [N] (force/torque sensors:
        :class:`drake_estop.physics.CopEstimator`).
      - ``com`` (3): COG target for the IK, ``planned_com + [offset, 0]``.
      - ``joint_offset`` (num_actuated): ankle pitch/roll offsets at the
        actuated-joint indices, zero elsewhere (added to the IK's joint
        targets).
      - ``commanded_zmp`` (2), ``com_offset`` (2), ``dcm_error`` (2): diagnostics.

    All state is one discrete group updated every ``servo_period``.
    """

    def __init__(self, *, servo_period: float, sole: Sole, num_actuated: int, ankle_indices: dict,
                 total_mass: float, params: BalanceParameters | None = None, gravity: float = GRAVITY):
        super().__init__()
        self._p = params or BalanceParameters()
        self._dt = float(servo_period)
        self._sole = sole
        self._n = int(num_actuated)
        self._ankles = {side: tuple(int(i) for i in ankle_indices[side]) for side in SIDES}
        self._weight = float(total_mass) * gravity
        self._g = float(gravity)
        self._beta = self._dt / (self._p.dcm_filter_time_constant + self._dt)
        self._alpha = self._dt / (self._p.model_error_time_constant + self._dt)
        self.planned_com_port = self.DeclareVectorInputPort("planned_com", 3)
        self.planned_com_vel_port = self.DeclareVectorInputPort("planned_com_vel", 3)
        self.planned_zmp_port = self.DeclareVectorInputPort("planned_zmp", 2)
        self.left_foot_port = self.DeclareVectorInputPort("left_foot", 7)
        self.right_foot_port = self.DeclareVectorInputPort("right_foot", 7)
        self.measured_com_port = self.DeclareVectorInputPort("measured_com", 3)
        self.measured_com_vel_port = self.DeclareVectorInputPort("measured_com_vel", 3)
        self.measured_cop_port = self.DeclareVectorInputPort("measured_cop", 2)
        self.foot_forces_port = self.DeclareVectorInputPort("foot_forces", 2)
        self._state = self.DeclareDiscreteState(_STATE_SIZE)
        self.com_port = self.DeclareVectorOutputPort(
            "com", 3, self._calc_com, prerequisites_of_calc={self.planned_com_port.ticket(), self.xd_ticket()})
        self.joint_offset_port = self.DeclareVectorOutputPort(
            "joint_offset", self._n, self._calc_joint_offset, prerequisites_of_calc={self.xd_ticket()})
        self.commanded_zmp_port = self._slice_output("commanded_zmp", _ZMP_CMD)
        self.com_offset_port = self._slice_output("com_offset", _OFFSET)
        self.dcm_error_port = self._slice_output("dcm_error", _DCM_ERROR)
        self.DeclareInitializationDiscreteUpdateEvent(self._initialize)
        self.DeclarePeriodicDiscreteUpdateEvent(self._dt, 0.0, self._update)

    # -- outputs -------------------------------------------------------------

    def _slice_output(self, name, entries):
        def calc(context, output):
            output.SetFromVector(context.get_discrete_state(self._state).value()[entries])
        return self.DeclareVectorOutputPort(name, 2, calc, prerequisites_of_calc={self.xd_ticket()})

    def _calc_com(self, context, output):
        com = np.array(self.planned_com_port.Eval(context), float)
        com[:2] += context.get_discrete_state(self._state).value()[_OFFSET]
        output.SetFromVector(com)

    def _calc_joint_offset(self, context, output):
        ankle = context.get_discrete_state(self._state).value()[_ANKLE]
        out = np.zeros(self._n)
        for k, side in enumerate(SIDES):
            pitch, roll = self._ankles[side]
            out[pitch], out[roll] = ankle[2 * k], ankle[2 * k + 1]
        output.SetFromVector(out)

    # -- events --------------------------------------------------------------

    def _initialize(self, context, discrete_state):
        x = np.zeros(_STATE_SIZE)
        if self.planned_zmp_port.HasValue(context):
            x[_ZMP_CMD] = x[_ZMP_LIPM] = self.planned_zmp_port.Eval(context)
        discrete_state.set_value(self._state, x)
        return EventStatus.Succeeded()

    def _update(self, context, discrete_state):
        x = context.get_discrete_state(self._state).value().copy()
        com_ref = self.planned_com_port.Eval(context)
        vel_ref = self.planned_com_vel_port.Eval(context)
        p_ref = np.asarray(self.planned_zmp_port.Eval(context), float)
        com = self.measured_com_port.Eval(context)
        vel = self.measured_com_vel_port.Eval(context)
        if not all(np.all(np.isfinite(v)) for v in (com_ref, vel_ref, p_ref, com, vel)) or com_ref[2] <= 0:
            return EventStatus.DidNothing()
        p = self._p
        omega = math.sqrt(self._g / com_ref[2])
        feet = {"left": np.asarray(self.left_foot_port.Eval(context), float),
                "right": np.asarray(self.right_foot_port.Eval(context), float)}
        # (2) DCM feedback: desired CoP, saturated in the planned support polygon
        error = (com[:2] + vel[:2] / omega) - (com_ref[:2] + vel_ref[:2] / omega)
        x[_DCM_FILTERED] += self._beta * (error - x[_DCM_FILTERED])
        delta = (1.0 + p.k_dcm / omega) * x[_DCM_FILTERED] if p.enabled else np.zeros(2)
        cop = np.asarray(self.measured_cop_port.Eval(context), float)
        if np.all(np.isfinite(cop)):
            x[_MODEL_ERROR] += self._alpha * (cop - x[_ZMP_LIPM] - x[_MODEL_ERROR])
        corners = support_corners(feet["left"], feet["right"], self._sole)
        # saturate where the CoP really is (plan + model error), so that the correction never asks
        # for a CoP beyond a sole edge the real CoP already sits on
        actual = p_ref + x[_MODEL_ERROR]
        p_des = p_ref + saturation_scale(actual, delta, corners, p.polygon_margin) * delta
        # (3) LIPM of the COG correction, exact zero-order hold over one tick
        u = p_des - p_ref
        ch, sh = math.cosh(omega * self._dt), math.sinh(omega * self._dt)
        offset, rate = x[_OFFSET] - u, x[_OFFSET_RATE]
        new_offset = u + offset * ch + rate / omega * sh
        new_rate = offset * omega * sh + rate * ch
        norm = float(np.linalg.norm(new_offset))
        if norm > p.max_offset:
            new_offset *= p.max_offset / norm
            new_rate[:] = 0.0
        x[_OFFSET], x[_OFFSET_RATE] = new_offset, new_rate
        x[_ZMP_LIPM] = p_ref + u
        # (1) damping control of the total CoP through the stance ankles, split by their load
        forces = np.asarray(self.foot_forces_port.Eval(context), float)
        total = float(np.sum(forces))
        ankle = x[_ANKLE].reshape(2, 2)
        for k, side in enumerate(SIDES):
            stance = (feet[side][2] <= _LIFT_ON_GROUND and forces[k] > p.contact_fraction * self._weight
                      and np.all(np.isfinite(cop)))
            if not (stance and p.enabled):
                ankle[k] *= math.exp(-self._dt / 0.05)  # unloaded foot: back to the IK posture quickly
                continue
            # ground-moment error about the CoP, world frame (n = r x f with r on the floor)
            moment_error = np.array([(p_des[1] - cop[1]), -(p_des[0] - cop[0])]) * total
            yaw = _yaw(feet[side][3:7])
            c, s = math.cos(yaw), math.sin(yaw)
            pitch_axis, roll_axis = np.array([-s, c]), np.array([c, s])
            share = forces[k] / total
            rates = SIGN * share * np.array([pitch_axis @ moment_error, roll_axis @ moment_error]) / p.ankle_damping
            ankle[k] += self._dt * (rates - ankle[k] / p.ankle_leak_time)
            np.clip(ankle[k], -p.max_ankle_offset, p.max_ankle_offset, out=ankle[k])
        x[_ANKLE] = ankle.ravel()
        x[_ZMP_CMD] = p_des
        x[_DCM_ERROR] = error
        discrete_state.set_value(self._state, x)
        return EventStatus.Succeeded()
