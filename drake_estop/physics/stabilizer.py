"""Measured-state feedback for the physics mode: COG measurement, DCM stabiliser, joint targets.

* :class:`CogMeasurement` reads the plant state and outputs the measured
  centre of mass and its velocity (``CalcCenterOfMassPositionInWorld``,
  ``CalcCenterOfMassTranslationalVelocityInWorld``).
* :class:`DcmStabilizer` is a divergent-component-of-motion (DCM, "capture
  point") tracking controller in the style of Englsberger et al. (2015) /
  Takenaka et al. (2009), realised on a position-controlled robot as a
  correction of the COG target handed to the whole-body IK (the "COG
  correction" of Kajita et al. 2010).
* :class:`DesiredStateInterpolator` turns the IK's positions (one solve per
  servo tick) into the plant's PD ``desired_state`` ``[q_a, v_a]``.

Control law (per horizontal axis, ``omega = sqrt(g / z_ref)``)::

    xi      = x + xdot / omega                          (measured DCM)
    xi_ref  = x_ref + xdot_ref / omega                  (planned DCM)
    e      <- low-pass(xi - xi_ref)                     (time constant dcm_filter_time_constant)
    p_des   = p_ref + (1 + k_dcm / omega) e             (DCM law: the DCM error decays as exp(-k_dcm t))
    p_cmd   = p_ref + s (p_des - p_ref),  s in [0, 1]   (saturation in the support polygon)
    d_hat  <- low-pass(p_cop - p_lipm)                  (ZMP model error: angular momentum, servo lag)
    u       = p_cmd - p_ref - k_model d_hat             (ZMP of the COG offset)
    offset'' = omega^2 (offset - u)                     (LIPM of the COG offset, exact zero-order hold)
    com_cmd = com_ref + [offset, 0]

``s`` is the largest scale keeping ``p_cmd`` at least ``zmp_margin`` inside
the planned support polygon (the sole rectangles of the feet whose planned
lift is zero), but never requiring more margin than ``p_ref`` itself has,
so zero DCM error always gives ``p_cmd = p_ref`` and zero correction.
``p_lipm = p_ref + u`` is the LIPM ZMP of the commanded COG motion; with
stiff joint servos the robot's centre of pressure is ``p_lipm`` plus the
multibody model error, which ``d_hat`` estimates and (with ``k_model`` = 1)
cancels, so the measured CoP follows ``p_cmd``.

With perfect servo tracking (measured = commanded COG) the offset obeys
``offset'' + (omega + k_dcm) offset' + omega k_dcm offset = omega^2 k_model d_hat``:
poles at ``-omega`` and ``-k_dcm``, stable for every ``k_dcm > 0``.

Gain choice (defaults, measured on the closed-loop physics diagram of
:func:`drake_estop.physics.plant.run_closed_loop`, see the report there):
``k_dcm = 0.5 1/s`` with the DCM error low-passed at
``dcm_filter_time_constant = 0.1 s``, ``k_model = 0``. With perfect servo
tracking any ``k_dcm > 0`` is stable, but on the simulated robot:

* unfiltered, the DCM term ``p_cmd - p_ref = (1 + k_dcm / omega) e``
  reaches the real ZMP algebraically (through the commanded COG
  acceleration) and excited the 20-30 rad/s mode of the body rocking on
  the stiff ankle servos (3 Hz limit cycle of +-1 cm commanded ZMP while
  standing, k_dcm = 7); the 0.1 s filter removes it;
* ``k_dcm >= 2`` (filtered or not) turned the lateral rocking of the first
  single-support step (the multibody ZMP error of the LIPM plan puts the
  CoP on the sole edges, up to ~5 cm from the LIPM ZMP) into a growing
  oscillation and the robot fell in both paper scenarios, with or without
  the preview feedforward;
* a constant bias ``b`` of the measured COG (servo sag) ends in a COG
  offset ``-(omega / k_dcm) b``: small ``k_dcm`` trades stability for a
  larger static error (k_dcm = 0.5: ~7 b, about 1.5 cm at rest).

``zmp_margin = 10 mm``: the point-contact corner spheres sit 5 mm inside the
sole rectangle, plus 5 mm for CoP noise. ``k_model = 0``: cancelling the
estimated model error (20 ms filter) made the falls no better.
``max_offset`` bounds the COG correction (safety clamp; 8 cm by default).
"""

from __future__ import annotations

import math

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import BasicVector, EventStatus, LeafSystem, ValueProducer

from drake_estop.planning.gait import Sole
from drake_estop.planning.lipm import GRAVITY  # the one gravity value

SIDES = ("left", "right")
_LIFT_ON_GROUND = 1e-9

# discrete state layout of DcmStabilizer
_OFFSET = slice(0, 2)  # COG offset [m]
_OFFSET_RATE = slice(2, 4)  # [m/s]
_MODEL_ERROR = slice(4, 6)  # d_hat [m]
_ZMP_CMD = slice(6, 8)  # commanded ZMP p_cmd (after saturation) [m]
_ZMP_LIPM = slice(8, 10)  # LIPM ZMP of the commanded COG motion [m]
_DCM_ERROR = slice(10, 12)  # measured - planned DCM at the last update [m]
_SATURATION = 12  # scale s < 1: saturated
_DCM_FILTERED = slice(13, 15)  # low-passed DCM error [m]
_STATE_SIZE = 15


# --------------------------------------------------------------------------
# Measurement.


class CogMeasurement(LeafSystem):
    """Measured centre of mass and its velocity from the plant state.

    .. pydrake_system::

        name: CogMeasurement
        input_ports:
        - state
        output_ports:
        - com
        - com_vel

    Ports:
      - ``state`` (plant.num_multibody_states()): ``[q, v]`` of ``plant``
        (connect ``plant.get_state_output_port()``).
      - ``com`` (3): COG in world [m].
      - ``com_vel`` (3): COG translational velocity in world [m/s].

    Both outputs come from one cached evaluation per input value; the plant
    context they are computed in is a per-Context scratch cache entry.
    """

    def __init__(self, *, plant):
        super().__init__()
        self._plant = plant
        self.state_port = self.DeclareVectorInputPort("state", plant.num_multibody_states())
        self._scratch = self.DeclareCacheEntry(
            "scratch plant context",
            ValueProducer(allocate=lambda: AbstractValue.Make(plant.CreateDefaultContext()),
                          calc=lambda context, value: None),
            {self.nothing_ticket()})
        self._values = self.DeclareCacheEntry(
            "com and com_vel",
            ValueProducer(allocate=lambda: AbstractValue.Make(np.zeros(6)), calc=self._calc_values),
            {self.state_port.ticket()})
        ticket = {self._values.ticket()}
        self.com_port = self.DeclareVectorOutputPort(
            "com", 3, lambda c, o: o.SetFromVector(self._values.Eval(c)[:3]), prerequisites_of_calc=ticket)
        self.com_vel_port = self.DeclareVectorOutputPort(
            "com_vel", 3, lambda c, o: o.SetFromVector(self._values.Eval(c)[3:]),
            prerequisites_of_calc=ticket)

    def _calc_values(self, context, value):
        scratch = self._scratch.get_mutable_cache_entry_value(context).GetMutableValueOrThrow()
        self._plant.SetPositionsAndVelocities(scratch, self.state_port.Eval(context))
        value.set_value(np.concatenate([
            self._plant.CalcCenterOfMassPositionInWorld(scratch),
            self._plant.CalcCenterOfMassTranslationalVelocityInWorld(scratch)]))


# --------------------------------------------------------------------------
# Support polygon helpers (half-planes of the planned soles).


def _yaw(quaternion_wxyz):
    w, x, y, z = np.asarray(quaternion_wxyz, float) / np.linalg.norm(quaternion_wxyz)
    return math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


def support_corners(left_foot, right_foot, sole: Sole):
    """Corners (k, 2) of the sole rectangles of the feet whose planned lift is zero.

    ``left_foot`` / ``right_foot`` are sole poses ``[x, y, lift, qw, qx, qy, qz]``.
    Returns None when neither foot is on the ground (a flight phase; the
    walking plans never have one).
    """
    corners = []
    for side, pose in zip(SIDES, (left_foot, right_foot)):
        pose = np.asarray(pose, float)
        if pose[2] > _LIFT_ON_GROUND:
            continue
        local = sole.corners((0.0, 0.0), side)
        yaw = _yaw(pose[3:7])
        c, s = math.cos(yaw), math.sin(yaw)
        corners.append(local @ np.array([[c, s], [-s, c]]) + pose[:2])
    return np.vstack(corners) if corners else None


def _half_planes(corners):
    """Outward unit normals (m, 2) and offsets (m,) of the convex hull of ``corners``."""
    from drake_estop.planning.geometry import convex_hull
    v = convex_hull(corners)
    edges = np.roll(v, -1, axis=0) - v
    normals = np.stack([edges[:, 1], -edges[:, 0]], axis=1)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return normals, np.sum(normals * v, axis=1)


def saturation_scale(p_ref, delta, corners, margin):
    """Largest ``s`` in [0, 1] keeping ``p_ref + s delta`` ``margin`` inside the hull of ``corners``.

    The margin is reduced to ``p_ref``'s own margin when that is smaller (a
    plan may put its ZMP closer than ``margin`` to an edge), and to zero when
    ``p_ref`` is outside: the correction may then only move inwards.
    """
    if corners is None or not np.any(delta):
        return 1.0
    normals, offsets = _half_planes(corners)
    room = offsets - normals @ np.asarray(p_ref, float)  # >= 0 inside
    own = float(np.min(room))
    slack = room - min(margin, max(own, 0.0))
    rate = normals @ np.asarray(delta, float)
    scale = 1.0
    for r, d in zip(slack, rate):
        if d > 1e-15:
            scale = min(scale, max(r, 0.0) / d)
    return float(min(max(scale, 0.0), 1.0))


# --------------------------------------------------------------------------
# The stabiliser.


class DcmStabilizer(LeafSystem):
    """DCM tracking by COG correction, saturated in the planned support polygon.

    .. pydrake_system::

        name: DcmStabilizer
        input_ports:
        - planned_com
        - planned_com_vel
        - planned_zmp
        - measured_com
        - measured_com_vel
        - measured_cop
        - left_foot
        - right_foot
        output_ports:
        - com
        - commanded_zmp
        - com_offset
        - dcm_error

    Ports (world frame, SI):
      - ``planned_com`` (3), ``planned_com_vel`` (3), ``planned_zmp`` (2):
        the reference (e.g. :class:`drake_estop.systems.stop_controller.StopPlannerSystem`).
      - ``measured_com`` (3), ``measured_com_vel`` (3): e.g.
        :class:`CogMeasurement` of the plant state.
      - ``measured_cop`` (2): centre of pressure (NaN while airborne: the
        model-error estimate then holds), e.g.
        :class:`drake_estop.physics.plant.CopEstimator`.
      - ``left_foot`` / ``right_foot`` (7): planned sole poses
        ``[x, y, lift, qw, qx, qy, qz]``; the feet with zero lift span the
        support polygon used for the saturation.
      - ``com`` (3): corrected COG target for the IK, ``planned_com +
        [offset, 0]`` (direct feedthrough of ``planned_com``).
      - ``commanded_zmp`` (2): ``p_cmd`` of the last update.
      - ``com_offset`` (2): the COG offset of the state.
      - ``dcm_error`` (2): measured - planned DCM at the last update.

    State: one discrete group (COG offset and rate, model-error estimate,
    commanded and LIPM ZMP, DCM error, saturation scale), updated every
    ``servo_period`` by a periodic discrete update; the update integrates the
    offset over one period, so the offset held in the state is the
    correction for the time it is read at. See the module docstring for the
    law and the gain choice.
    """

    def __init__(self, *, servo_period=0.005, sole: Sole | None = None, k_dcm=0.5, zmp_margin=0.01,
                 k_model=0.0, model_error_time_constant=0.02, dcm_filter_time_constant=0.1,
                 max_offset=0.08, gravity=GRAVITY):
        super().__init__()
        if not servo_period > 0:
            raise ValueError(f"servo_period must be positive, got {servo_period!r}")
        if not k_dcm > 0:
            raise ValueError(f"k_dcm must be positive, got {k_dcm!r}")
        if zmp_margin < 0 or max_offset <= 0 or model_error_time_constant < 0:
            raise ValueError("zmp_margin, model_error_time_constant must be >= 0 and max_offset > 0")
        self._dt = float(servo_period)
        self._sole = sole or Sole()
        self._k_dcm = float(k_dcm)
        self._margin = float(zmp_margin)
        self._k_model = float(k_model)
        self._alpha = self._dt / (float(model_error_time_constant) + self._dt)
        if dcm_filter_time_constant < 0:
            raise ValueError("dcm_filter_time_constant must be >= 0")
        self._beta = self._dt / (float(dcm_filter_time_constant) + self._dt)
        self._max_offset = float(max_offset)
        self._g = float(gravity)
        self.planned_com_port = self.DeclareVectorInputPort("planned_com", 3)
        self.planned_com_vel_port = self.DeclareVectorInputPort("planned_com_vel", 3)
        self.planned_zmp_port = self.DeclareVectorInputPort("planned_zmp", 2)
        self.measured_com_port = self.DeclareVectorInputPort("measured_com", 3)
        self.measured_com_vel_port = self.DeclareVectorInputPort("measured_com_vel", 3)
        self.measured_cop_port = self.DeclareVectorInputPort("measured_cop", 2)
        self.left_foot_port = self.DeclareVectorInputPort("left_foot", 7)
        self.right_foot_port = self.DeclareVectorInputPort("right_foot", 7)
        self._state = self.DeclareDiscreteState(_STATE_SIZE)
        self._init_state = np.zeros(_STATE_SIZE)
        self._init_state[_SATURATION] = 1.0
        self.com_port = self.DeclareVectorOutputPort(
            "com", 3, self._calc_com,
            prerequisites_of_calc={self.planned_com_port.ticket(), self.xd_ticket()})
        self.commanded_zmp_port = self._state_slice_output("commanded_zmp", _ZMP_CMD)
        self.com_offset_port = self._state_slice_output("com_offset", _OFFSET)
        self.dcm_error_port = self._state_slice_output("dcm_error", _DCM_ERROR)
        self.DeclareInitializationDiscreteUpdateEvent(self._initialize)
        self.DeclarePeriodicDiscreteUpdateEvent(self._dt, 0.0, self._update)

    # -- properties ----------------------------------------------------------

    @property
    def servo_period(self):
        return self._dt

    @property
    def k_dcm(self):
        return self._k_dcm

    @property
    def zmp_margin(self):
        return self._margin

    @property
    def k_model(self):
        return self._k_model

    def saturation(self, context):
        """Saturation scale ``s`` of the last update (1: not saturated)."""
        return float(context.get_discrete_state(self._state).value()[_SATURATION])

    def model_error(self, context):
        """The ZMP model-error estimate ``d_hat`` (2) held in the state."""
        return context.get_discrete_state(self._state).value()[_MODEL_ERROR].copy()

    # -- ports ---------------------------------------------------------------

    def _state_slice_output(self, name, entries):
        def calc(context, output):
            output.SetFromVector(context.get_discrete_state(self._state).value()[entries])
        return self.DeclareVectorOutputPort(name, 2, calc, prerequisites_of_calc={self.xd_ticket()})

    def _calc_com(self, context, output):
        com = np.array(self.planned_com_port.Eval(context), float)
        com[:2] += context.get_discrete_state(self._state).value()[_OFFSET]
        output.SetFromVector(com)

    # -- events --------------------------------------------------------------

    def _initialize(self, context, discrete_state):
        """Zero offset; the ZMP entries start at the planned ZMP when it is connected."""
        x = self._init_state.copy()
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
        cop = self.measured_cop_port.Eval(context)
        inputs = (com_ref, vel_ref, p_ref, com, vel)
        if not all(np.all(np.isfinite(v)) for v in inputs) or com_ref[2] <= 0:
            return EventStatus.DidNothing()
        omega = math.sqrt(self._g / com_ref[2])
        # model error: the CoP minus the LIPM ZMP the commanded COG motion had
        if np.all(np.isfinite(cop)):
            x[_MODEL_ERROR] += self._alpha * (cop - x[_ZMP_LIPM] - x[_MODEL_ERROR])
        error = (com[:2] + vel[:2] / omega) - (com_ref[:2] + vel_ref[:2] / omega)
        x[_DCM_FILTERED] += self._beta * (error - x[_DCM_FILTERED])
        delta = (1.0 + self._k_dcm / omega) * x[_DCM_FILTERED]
        corners = support_corners(self.left_foot_port.Eval(context), self.right_foot_port.Eval(context),
                                  self._sole)
        scale = saturation_scale(p_ref, delta, corners, self._margin)
        p_cmd = p_ref + scale * delta
        u = p_cmd - p_ref - self._k_model * x[_MODEL_ERROR]
        # exact zero-order-hold step of offset'' = omega^2 (offset - u)
        ch, sh = math.cosh(omega * self._dt), math.sinh(omega * self._dt)
        offset, rate = x[_OFFSET] - u, x[_OFFSET_RATE]
        new_offset = u + offset * ch + rate / omega * sh
        new_rate = offset * omega * sh + rate * ch
        norm = float(np.linalg.norm(new_offset))
        if norm > self._max_offset:
            new_offset *= self._max_offset / norm
            new_rate[:] = 0.0
        x[_OFFSET], x[_OFFSET_RATE] = new_offset, new_rate
        x[_ZMP_CMD], x[_ZMP_LIPM] = p_cmd, p_ref + u
        x[_DCM_ERROR] = error
        x[_SATURATION] = scale
        discrete_state.set_value(self._state, x)
        return EventStatus.Succeeded()


# --------------------------------------------------------------------------
# IK positions -> PD desired state.


class DesiredStateInterpolator(LeafSystem):
    """Plant ``desired_state`` ``[q_a, v_a]`` from full positions updated once per servo tick.

    .. pydrake_system::

        name: DesiredStateInterpolator
        input_ports:
        - q
        output_ports:
        - desired_state

    ``q`` (nq) is read with direct feedthrough (connect a discrete source
    such as :class:`drake_estop.systems.ik.WholeBodyIK`, whose value changes only at
    the servo ticks). The state holds the previous tick's actuated positions
    and the tick time ``t_k``; with ``v_k = (q_k - q_{k-1}) / period``:

    * ``mode="interpolate"`` (default): ``q_a(t) = q_{k-1} + (t - t_k) v_k``,
      a first-order hold one servo period late -- continuous, no overshoot;
    * ``mode="extrapolate"``: ``q_a(t) = q_k + (t - t_k) v_k``, no delay but
      it overshoots when the reference decelerates (measured: a swing foot
      struck the floor 6 mm early and the robot bounced off the ground).
    ``q_indices`` / ``v_indices`` select the actuated joints (desired_state
    layout, e.g. :func:`drake_estop.physics.plant.actuated_indices`).
    """

    def __init__(self, *, q_indices, initial_q, servo_period=0.005, mode="interpolate"):
        super().__init__()
        if mode not in ("interpolate", "extrapolate"):
            raise ValueError(f"mode must be 'interpolate' or 'extrapolate', got {mode!r}")
        self._extrapolate = mode == "extrapolate"
        self._idx = np.asarray(q_indices, int)
        self._dt = float(servo_period)
        n = len(self._idx)
        initial = np.asarray(initial_q, float)
        self.q_port = self.DeclareVectorInputPort("q", len(initial))
        # [q_a of the previous tick, time of the last tick]
        self._state = self.DeclareDiscreteState(np.concatenate([initial[self._idx], [0.0]]))
        self.desired_state_port = self.DeclareVectorOutputPort(
            "desired_state", BasicVector(2 * n), self._calc,
            prerequisites_of_calc={self.q_port.ticket(), self.xd_ticket(), self.time_ticket()})
        self.DeclarePeriodicDiscreteUpdateEvent(self._dt, 0.0, self._update)

    def _update(self, context, discrete_state):
        q = self.q_port.Eval(context)[self._idx]
        discrete_state.set_value(self._state, np.concatenate([q, [context.get_time()]]))
        return EventStatus.Succeeded()

    def _calc(self, context, output):
        state = context.get_discrete_state(self._state).value()
        previous, tick = state[:-1], state[-1]
        q = self.q_port.Eval(context)[self._idx]
        v = (q - previous) / self._dt
        base = q if self._extrapolate else previous
        output.SetFromVector(np.concatenate([base + (context.get_time() - tick) * v, v]))
