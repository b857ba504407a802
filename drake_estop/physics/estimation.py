"""The state estimator: base pose, COG and the soles' footholds from the robot's sensors.

Blocks (sampled at the servo period through periodic discrete events)::

    RobotSensors --encoders, gyro, accelerometer, foot_forces, cop, wrench--> StateEstimator
        --> q, com, com_vel, stance, feet

* The sensors (:mod:`drake_estop.physics.sensors`): the pelvis IMU, joint
  encoders and foot force sensing, with noise and latency.
* :class:`StateEstimator` estimates the floating-base pose, the full ``q``,
  the COG and the COG velocity (see its docstring for the filters and the
  measured accuracy).
* :func:`add_state_estimation` adds and connects the sensors and the
  estimator.

Wiring (in the physics diagram; ``q0`` is the posture the simulation starts
from, ``perturbations`` a :class:`drake_estop.physics.perturbations.Perturbations`)::

    soles = sole_bodies(plant, robot)  # the bodies of the left and right sole frames, this order
    cop = builder.AddNamedSystem("cop_estimator", CopEstimator(
        plant=plant, scene_graph=scene_graph, bodies=soles))
    builder.Connect(plant.get_contact_results_output_port(), cop.contact_results_port)
    estimator = add_state_estimation(builder, plant, cop, servo_period=0.005,
                                     perturbations=perturbations, initial_q=q0,
                                     true_state=False, robot=robot)
    builder.Connect(estimator.com_port, controller_measured_com_input)
    builder.Connect(estimator.com_vel_port, controller_measured_com_vel_input)
    builder.Connect(estimator.sensors.cop_port, controller_measured_cop_input)  # same latency/noise path
    # estimator.q_port: full q estimate; estimator.stance_port: 0 left / 1 right

A note on Drake's event order, measured on this plant: the discrete
``MultibodyPlant`` (sampled output ports) has already stepped when the other
systems' periodic discrete updates at t_k read its outputs (they see the
state of t_k + 1 ms), while a publish event at t_k (a ``VectorLogSink``)
sees the state of t_k. Everything the controller's discrete updates read
at a tick is therefore mutually consistent. A logger on the estimator's
outputs makes it compute twice per tick (once for the log, once for its
update), which doubles its cost in wall-clock benchmarks but not in the
per-update work.
"""

from __future__ import annotations

import functools
import math

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.systems.framework import EventStatus, LeafSystem, ValueProducer
from pydrake.systems.sensors import Accelerometer, Gyroscope

from drake_estop.physics.estimator_math import cross, kf_step_axes, quat_exp, quat_multiply, quat_to_matrix
from drake_estop.physics.plant import sole_bodies, sole_frames
from drake_estop.physics.sensors import (
    SIGNALS,
    FootForceTorqueSensors,
    RobotSensors,
    actuated_position_indices,
)
from drake_estop.robots.parameters import as_robot
from drake_estop.timing import timed

# discrete state layout of StateEstimator
_QUAT = slice(0, 4)  # pelvis orientation (w, x, y, z) in world
_STANCE = 4  # 0: left, 1: right
_ANCHOR = slice(5, 8)  # world position of the stance sole frame origin [m]
_MEAN = slice(8, 14)  # KF means (c, cdot) for x, y, z
_COV = slice(14, 23)  # KF covariances (p00, p01, p11) for x, y, z
_T_LAST = 23  # time of the last update [s]
_UPDATED = 24  # 1 after the first update
_FOOT = (slice(25, 28), slice(28, 31))  # averaged world position of the left, right sole while loaded [m]
_LOADED = (31, 32)  # ticks each sole has been loaded (0: unloaded)
_D_LP = slice(33, 35)  # hybrid model: low-passed IMU-minus-force horizontal acceleration [m/s^2]
_HEADER = 35  # then the last outputs: q (nq), com (3), com_vel (3)


class StateEstimator(LeafSystem):
    """Floating-base pose, COG and COG velocity from encoders, IMU and foot force sensing.

    .. pydrake_system::

        name: StateEstimator
        input_ports:
        - encoders
        - gyro
        - accelerometer
        - foot_forces
        - cop
        - wrench
        - true_state
        output_ports:
        - q
        - com
        - com_vel
        - stance
        - feet
        - sole_heights

    Inputs are :class:`RobotSensors`' outputs of the same names (units
    there); ``true_state`` (nq + nv, the plant state) is read only with
    ``true_state=True`` and may stay unconnected otherwise.

    Outputs:
      - ``q`` (nq): full plant positions estimate (pelvis quaternion wxyz,
        pelvis position [m], joints [rad] = the encoders).
      - ``com`` (3) [m], ``com_vel`` (3) [m/s]: COG and its velocity, world.
      - ``stance`` (1): 0 = left, 1 = right (the anchored foot).
      - ``feet`` (6): the soles' estimated world positions ``[x_left, y_left,
        x_right, y_right]`` [m] (a loaded sole's averaged since it was loaded,
        step 2 below; an unloaded one's current) and the ticks each has been
        loaded, ``[n_left, n_right]`` (0: unloaded, capped at
        ``foot_window``). Footholds for the planner: where a foot actually
        landed.
      - ``sole_heights`` (2): the same soles' estimated heights above the
        floor the stance sole is anchored on, ``[z_left, z_right]`` [m]
        (negative: below it, where the floor is lower than the plan's).

    Timing. The filter state is updated by a periodic discrete event at
    every servo tick. The outputs are computed (one cached evaluation) from
    the state of the previous tick and the inputs at the context time, so a
    controller that samples ``com`` in its own discrete update at tick k
    gets the estimate that includes the measurements of tick k, with no
    added tick of delay (the only delay is RobotSensors' latency).

    Per tick (dt = time since the last update):

    1. **Attitude** (complementary / Mahony filter on SO(3)): integrate the
       gyro, ``R <- R Exp((w + k_att e) dt)`` with ``e = u_hat x R^T e_z``,
       ``u`` the accelerometer's specific force minus the COG's horizontal
       acceleration from the measured ground force (``g f_xy / f_z``,
       ``accel_compensation``), applied only while ``| |u| - g | < accel_gate``.
       Roll and pitch are pulled to gravity with the time constant
       ``1 / attitude_gain`` (20 s); yaw is the gyro's alone. Measured on a
       3.3 s closed-loop walk: gain 0.5 uncompensated tilted the estimate by
       up to 1.27 deg (the walk's accelerations; 18 mm of COG error), 0.5
       compensated 0.51 deg, 0.05-0.02 compensated 0.10-0.12 deg; the pure
       gyro (gain 0) 0.08 deg but it drifts with gyro noise (random walk
       0.01 rad/s * sqrt(5 ms * t): 0.13 deg after 10 s).
    2. **Leg kinematics anchored on the stance foot**: the encoders and R
       give the soles' and the COG's positions relative to the pelvis
       (nominal model, one forward kinematics per tick in a scratch plant
       context held in a cache entry). The stance foot is the one with the
       larger normal force (switching needs a margin of
       ``stance_hysteresis`` of the total force). The other sole's world
       position is averaged over the last ``foot_window`` ticks while it is
       loaded (above ``min_contact_force``); when it becomes stance that
       average, with z = 0 (assumed flat on the floor), is anchored (with
       encoder noise the averaging halves the COG error of the walk: 4.4 ->
       1.9 mm RMS). The pelvis position is ``anchor - p_sole_rel``; the
       soles' orientation is not used.
    3. **COG and COG velocity**: a 2-state Kalman filter per axis on
       ``[c, cdot]`` (white-acceleration process noise ``accel_noise``
       [m/s^2]) corrected by the kinematic COG (std ``com_noise`` [m]),
       predicted with an acceleration input ``u``:

       * ``model="force"``: Newton on the measured ground force,
         ``u = g f_xy / f_z`` (mass-free; exact whatever the limbs' angular
         momentum). Blind to forces that do not go through the feet: under
         a pelvis push the feet push back and ``u`` has the wrong sign.
       * ``model="imu"``: the pelvis accelerometer rotated to the world,
         ``u = (R a_S)_xy``: sees pushes, but the pelvis does not
         accelerate like the COG while the legs swing.
       * ``model="hybrid"`` (default): ``u = g f_xy / f_z + s(d)``, ``d`` the
         IMU-minus-force acceleration low-passed with
         ``push_filter_time`` (10 ms), ``s`` a dead zone of
         ``push_threshold`` (0.5 m/s^2): the force model while the two
         agree, the IMU's extra acceleration when something else pushes.
       * ``model="lipm"``: ``c'' = omega^2 (c - p_cop)``,
         ``omega = sqrt(g / z_c)`` with ``z_c`` the robot's walking COG height (0.814 m for the
         default humanoid; the paper's eq. 1-2 LIPM, exact discretisation), kept for comparison; it
         ignores the limbs' angular momentum.

       Vertical: a constant-velocity model (``vertical_accel_noise``).

       Measured COG-velocity error (horizontal norm, RMS / max, mm/s; seed 1
       for the noise) with the defaults ``accel_noise = 1``,
       ``com_noise = 2e-3``::

                          walk 3.3 s         walk + noise      17 N s push, standing (during / 0.1 s after)
            force          8.7 / 21           9.7 / 27          126 / 182, 100 / 185
            imu           16.8 / 47          18.2 / 55           11 / 22,   19 / 39
            hybrid         4.8 / 12           6.7 / 19           42 / 54,   33 / 56
            lipm          29.9 / 77          29.8 / 75          102 / 150,  91 / 153

       (hybrid with a 0.25 m/s^2 dead zone: walk 6.8 / 27, push 31 / 38.)
       COG position error on the walk: 1.0 / 2.3 mm, with noise 1.9 / 4.2 mm.

        ``true_state=True`` bypasses all of this: ``q`` is the true plant q and
    ``com``/``com_vel`` are computed from the true q, v with the nominal
    model (for debugging the controller without estimation errors; no
    latency and no noise either; ``stance`` still from the foot forces).

    The initial pose (``initial_q``, nq) is the robot's known start pose
    (it sets the attitude, the stance anchor and the COG filter); the
    default is the plant's default positions.

    ``robot`` (a :class:`~drake_estop.robots.RobotDescription`, a name or None: the default humanoid)
    names the floating base (where the IMU sits) and the sole frames; ``com_height`` [m] (the LIPM
    model's) defaults to its walking COG height.
    """

    def __init__(self, *, plant, servo_period: float, initial_q=None, true_state: bool = False, timer=None,
                 model: str = "hybrid", attitude_gain: float = 0.05, accel_compensation: bool = True,
                 accel_gate: float = 2.0,
                 stance_hysteresis: float = 0.1, min_contact_force: float = 20.0, foot_window: int = 40,
                 push_threshold: float = 0.5, push_filter_time: float = 0.01,
                 com_noise: float = 2e-3, accel_noise: float = 1.0, vertical_accel_noise: float = 2.0,
                 com_height: float | None = None, robot=None):
        super().__init__()
        robot = as_robot(robot)
        com_height = robot.walking_com_height if com_height is None else com_height
        if model not in ("force", "lipm", "imu", "hybrid"):
            raise ValueError(f"model must be 'force', 'lipm', 'imu' or 'hybrid', got {model!r}")
        self._plant = plant
        self._period = float(servo_period)
        self._true = bool(true_state)
        self._model = model
        self._k_att = float(attitude_gain)
        self._compensate = bool(accel_compensation)
        self._gate = float(accel_gate)
        self._hyst = float(stance_hysteresis)
        self._foot_window = float(max(int(foot_window), 1))
        self._push_threshold = float(push_threshold)
        self._push_tau = float(push_filter_time)
        self._min_force = float(min_contact_force)
        self._r = float(com_noise) ** 2
        self._sa = float(accel_noise)
        self._sz = float(vertical_accel_noise)
        self._g = float(-plant.gravity_field().gravity_vector()[2])  # the robot's local g (Drake: 9.81)
        self._omega = math.sqrt(self._g / com_height)
        self._nq = plant.num_positions()
        self._q_idx = actuated_position_indices(plant)
        na = len(self._q_idx)
        base = plant.GetBodyByName(robot.floating_base)
        if not base.is_floating_base_body():
            raise ValueError(f"{robot.floating_base} must be a floating body")
        self._base_q = base.floating_positions_start()
        # each sole as (its body, the sole frame's pose in the body or None where the frames are one)
        self._soles = [(frame.body(), None if frame.index() == frame.body().body_frame().index()
                        else frame.GetFixedPoseInBodyFrame()) for frame in sole_frames(plant, robot)]

        self.encoders_port = self.DeclareVectorInputPort("encoders", na)
        self.gyro_port = self.DeclareVectorInputPort("gyro", 3)
        self.accelerometer_port = self.DeclareVectorInputPort("accelerometer", 3)
        self.foot_forces_port = self.DeclareVectorInputPort("foot_forces", 2)
        self.cop_port = self.DeclareVectorInputPort("cop", 2)
        self.wrench_port = self.DeclareVectorInputPort("wrench", 6)
        self.true_state_port = self.DeclareVectorInputPort("true_state", plant.num_multibody_states())

        self._scratch = self.DeclareCacheEntry(
            "scratch plant context",
            ValueProducer(allocate=lambda: AbstractValue.Make(plant.CreateDefaultContext()),
                          calc=lambda context, value: None),
            {self.nothing_ticket()})
        self._xd = self.DeclareDiscreteState(self.initial_state(initial_q))
        self._estimate = self.DeclareCacheEntry(
            "estimate", ValueProducer(allocate=lambda: AbstractValue.Make(np.zeros(_HEADER + self._nq + 6)),
                                      calc=timed(self._calc_estimate, timer)),
            {self.time_ticket(), self.all_input_ports_ticket(), self.xd_ticket()})
        self.DeclarePeriodicDiscreteUpdateEvent(self._period, 0.0, timed(self._update, timer))
        ticket = {self._estimate.ticket()}
        out = _HEADER + self._nq
        self.q_port = self.DeclareVectorOutputPort(
            "q", self._nq, lambda c, o: o.SetFromVector(self._estimate.Eval(c)[_HEADER:out]),
            prerequisites_of_calc=ticket)
        self.com_port = self.DeclareVectorOutputPort(
            "com", 3, lambda c, o: o.SetFromVector(self._estimate.Eval(c)[out:out + 3]),
            prerequisites_of_calc=ticket)
        self.com_vel_port = self.DeclareVectorOutputPort(
            "com_vel", 3, lambda c, o: o.SetFromVector(self._estimate.Eval(c)[out + 3:out + 6]),
            prerequisites_of_calc=ticket)
        self.stance_port = self.DeclareVectorOutputPort(
            "stance", 1, lambda c, o: o.SetAtIndex(0, self._estimate.Eval(c)[_STANCE]),
            prerequisites_of_calc=ticket)
        self.feet_port = self.DeclareVectorOutputPort("feet", 6, self._calc_feet, prerequisites_of_calc=ticket)
        self.sole_heights_port = self.DeclareVectorOutputPort(
            "sole_heights", 2, lambda c, o: o.SetFromVector([self._estimate.Eval(c)[foot][2] for foot in _FOOT]),
            prerequisites_of_calc=ticket)

    # ---------------------------------------------------------------- state

    def initial_state(self, initial_q=None) -> np.ndarray:
        """Discrete state for a robot at rest in ``initial_q`` (default: the plant's default positions)."""
        plant = self._plant
        context = plant.CreateDefaultContext()
        q = plant.GetPositions(context) if initial_q is None else np.asarray(initial_q, float)
        if q.shape != (self._nq,):
            raise ValueError(f"initial_q must have {self._nq} entries, got shape {q.shape}")
        plant.SetPositions(context, q)
        feet = self._sole_positions(plant, context)
        stance = 0 if feet[0][2] <= feet[1][2] + 1e-9 else 1
        anchor = feet[stance].copy()
        anchor[2] = 0.0
        # the anchored sole is put at z = 0: shift the known pose to match
        shift = anchor - feet[stance]
        com = plant.CalcCenterOfMassPositionInWorld(context) + shift
        x = np.zeros(_HEADER + self._nq + 6)
        quat = q[self._base_q:self._base_q + 4]
        x[_QUAT] = quat / np.linalg.norm(quat)
        x[_STANCE] = stance
        x[_ANCHOR] = anchor
        x[_MEAN] = [com[0], 0.0, com[1], 0.0, com[2], 0.0]
        x[_COV] = np.tile([self._r, 0.0, 1e-4], 3)
        x[_T_LAST] = 0.0
        x[_UPDATED] = 0.0
        for side in (0, 1):
            x[_FOOT[side]] = feet[side] + shift
        q_out = q.copy()
        q_out[self._base_q + 4:self._base_q + 7] += shift
        x[_HEADER:_HEADER + self._nq] = q_out
        x[_HEADER + self._nq:_HEADER + self._nq + 3] = com
        return x

    def _sole_positions(self, plant, context) -> list:
        """The sole frames' origins in the world of ``context`` (a context of ``plant``), left then right."""
        out = []
        for body, X_BS in self._soles:
            X_WB = plant.EvalBodyPoseInWorld(context, body)
            out.append(X_WB.translation() if X_BS is None else (X_WB @ X_BS).translation())
        return out

    def _calc_feet(self, context, output):
        x = self._estimate.Eval(context)
        output.SetFromVector([*x[_FOOT[0]][:2], *x[_FOOT[1]][:2], x[_LOADED[0]], x[_LOADED[1]]])

    def _averaged_feet(self, x, feet_world, forces):
        """Step 2's foot average: each loaded sole's world position averaged over its last
        ``foot_window`` loaded ticks, an unloaded one's current; returns ``(averages, loaded ticks)``."""
        foot_avg = [x[_FOOT[0]].copy(), x[_FOOT[1]].copy()]
        loaded = [x[_LOADED[0]], x[_LOADED[1]]]
        for side in (0, 1):
            if forces[side] > self._min_force:
                loaded[side] = min(loaded[side] + 1.0, self._foot_window)
                foot_avg[side] += (feet_world[side] - foot_avg[side]) / loaded[side]
            else:
                loaded[side] = 0.0
                foot_avg[side] = feet_world[side].copy()
        return foot_avg, loaded

    def set_initial_pose(self, context, q):
        """Reset ``context``'s (this system's) filter state to the robot at rest in ``q``."""
        context.get_mutable_discrete_state(self._xd).SetFromVector(self.initial_state(q))

    # ---------------------------------------------------------------- update

    def _update(self, context, discrete_state):
        x = self._estimate.Eval(context)
        discrete_state.get_mutable_vector(self._xd).SetFromVector(x)
        return EventStatus.Succeeded()

    def _calc_estimate(self, context, value):
        x = context.get_discrete_state(self._xd).get_value()
        t = context.get_time()
        if x[_UPDATED] and t <= x[_T_LAST]:  # already updated at this time: the stored result
            value.set_value(x.copy())
            return
        value.set_value(self._true_estimate(context, x) if self._true else self._step(context, x, t))

    def _true_estimate(self, context, x):
        plant = self._plant
        scratch = self._scratch.get_mutable_cache_entry_value(context).GetMutableValueOrThrow()
        state = self.true_state_port.Eval(context)
        plant.SetPositionsAndVelocities(scratch, state)
        y = x.copy()
        y[_T_LAST], y[_UPDATED] = context.get_time(), 1.0
        forces = self.foot_forces_port.Eval(context)
        y[_STANCE] = 0.0 if forces[0] >= forces[1] else 1.0
        # the footholds, from the true soles
        soles = self._sole_positions(plant, scratch)
        foot_avg, loaded = self._averaged_feet(x, soles, forces)
        y[_FOOT[0]], y[_FOOT[1]] = foot_avg
        y[_LOADED[0]], y[_LOADED[1]] = loaded
        out = _HEADER + self._nq
        y[_HEADER:out] = state[:self._nq]
        y[out:out + 3] = plant.CalcCenterOfMassPositionInWorld(scratch)
        y[out + 3:out + 6] = plant.CalcCenterOfMassTranslationalVelocityInWorld(scratch)
        return y

    def _cog_filters(self, context, x, dt, quat, acc, wrench, fz, total, com_meas):
        """The COG filters' step over ``dt`` [s] (one Kalman filter per axis, ``self._model``'s input), from
        ``x``'s estimate to the measured COG ``com_meas`` [m]: the new ``(mean, cov, d_lp)``."""
        a_world = quat_to_matrix(quat) @ acc - np.array([0.0, 0.0, self._g])
        a_force = self._g * wrench[3:5] / fz if fz > self._min_force else np.zeros(2)
        d_lp = x[_D_LP] + (dt / (self._push_tau + dt)) * (a_world[:2] - a_force - x[_D_LP])
        if self._model == "lipm":
            axes = [self._lipm_axis(context, axis, dt, total) for axis in (0, 1)] + [(*_kinematic_model(dt), 0.0)]
            A, B = np.stack([a for a, _, _ in axes]), np.stack([b for _, b, _ in axes])
            u = np.array([u for _, _, u in axes])
        else:
            A, B = _kinematic_models(dt)
            if self._model == "imu":
                inputs = a_world[:2]
            elif self._model == "hybrid":
                inputs = [force + math.copysign(max(abs(d) - self._push_threshold, 0.0), d)
                          for force, d in zip(a_force, d_lp)]
            else:
                inputs = a_force
            u = np.array([inputs[0], inputs[1], 0.0])
        # one Kalman filter per axis, all three in one call (each axis the bits of its own)
        mean, cov = kf_step_axes(x[_MEAN].reshape(3, 2), x[_COV].reshape(3, 3), A, B, u,
                                 _process_noises(dt, self._sa, self._sz), com_meas, self._r)
        return mean.ravel(), cov.ravel(), d_lp

    def _lipm_axis(self, context, axis, dt, total):
        """The ``lipm`` model's ``(A, B, u)`` of horizontal ``axis`` over ``dt`` [s]: the LIPM about the measured
        CoP where the feet bear weight, else a constant velocity."""
        p = self.cop_port.Eval(context)[axis]
        if total > self._min_force and math.isfinite(p):
            ch, sh = math.cosh(self._omega * dt), math.sinh(self._omega * dt)
            A = np.array([[ch, sh / self._omega], [self._omega * sh, ch]])
            return A, np.array([1.0 - ch, -self._omega * sh]), p
        return _kinematic_model(dt)[0], np.zeros(2), 0.0  # constant velocity: the kinematic model, no input

    def _step(self, context, x, t):
        plant = self._plant
        dt = max(t - x[_T_LAST], 0.0) if x[_UPDATED] else 0.0
        encoders = self.encoders_port.Eval(context)
        gyro = self.gyro_port.Eval(context)
        acc = self.accelerometer_port.Eval(context)
        forces = self.foot_forces_port.Eval(context)
        wrench = self.wrench_port.Eval(context)

        # 1. attitude
        quat = x[_QUAT]
        R = quat_to_matrix(quat)
        w = np.array(gyro, float)
        fz = wrench[5]
        if self._compensate and fz > self._min_force:
            # remove the COG's horizontal acceleration (Newton on the measured ground force)
            up = acc - R[:2, :].T @ (self._g * wrench[3:5] / fz)
        else:
            up = acc
        a_norm = math.sqrt(up[0] ** 2 + up[1] ** 2 + up[2] ** 2)
        if self._k_att > 0 and a_norm > 0 and abs(a_norm - self._g) < self._gate:
            w = w + self._k_att * cross(up / a_norm, R[2, :])  # R^T e_z = third row of R
        if dt > 0:
            quat = quat_multiply(quat, quat_exp(w * dt))
            quat = quat / math.sqrt(quat @ quat)

        # 2. leg kinematics (pelvis at the origin, estimated orientation)
        scratch = self._scratch.get_mutable_cache_entry_value(context).GetMutableValueOrThrow()
        q = np.zeros(self._nq)
        q[self._q_idx] = encoders
        q[self._base_q:self._base_q + 4] = quat
        plant.SetPositions(scratch, q)
        feet = self._sole_positions(plant, scratch)
        com_rel = plant.CalcCenterOfMassPositionInWorld(scratch)
        stance = int(x[_STANCE])
        anchor = x[_ANCHOR].copy()
        base = anchor - feet[stance]
        # the loaded non-stance sole: average its position since it was loaded (noise)
        foot_avg, loaded = self._averaged_feet(x, [base + feet[0], base + feet[1]], forces)
        total = forces[0] + forces[1]
        if total > self._min_force:
            other = 1 - stance
            if forces[other] > forces[stance] + self._hyst * total:
                anchor = foot_avg[other].copy()
                anchor[2] = 0.0
                stance = other
        base = anchor - feet[stance]
        q[self._base_q + 4:self._base_q + 7] = base
        com_meas = base + com_rel

        # 3. COG filters
        mean, cov, d_lp = self._cog_filters(context, x, dt, quat, acc, wrench, fz, total, com_meas)

        y = x.copy()
        y[_QUAT], y[_STANCE], y[_ANCHOR] = quat, stance, anchor
        y[_MEAN], y[_COV] = mean, cov
        y[_T_LAST], y[_UPDATED] = t, 1.0
        y[_FOOT[0]], y[_FOOT[1]] = foot_avg
        y[_D_LP] = d_lp
        y[_LOADED[0]], y[_LOADED[1]] = loaded
        out = _HEADER + self._nq
        y[_HEADER:out] = q
        y[out:out + 3] = mean[0::2]
        y[out + 3:out + 6] = mean[1::2]
        return y


@functools.lru_cache(maxsize=8)
def _kinematic_model(dt: float) -> tuple:
    """The COG filter's constant-acceleration model ``(A, B)`` over ``dt`` [s], read-only: made once per step
    length (the servo period, every tick but the first) instead of every tick."""
    return _read_only(np.array([[1.0, dt], [0.0, 1.0]])), _read_only(np.array([0.5 * dt * dt, dt]))


@functools.lru_cache(maxsize=8)
def _kinematic_models(dt: float) -> tuple:
    """:func:`_kinematic_model` of the three axes, stacked ``((3, 2, 2), (3, 2))``, read-only."""
    A, B = _kinematic_model(dt)
    return _read_only(np.stack([A] * 3)), _read_only(np.stack([B] * 3))


@functools.lru_cache(maxsize=16)
def _process_noises(dt: float, horizontal: float, vertical: float) -> np.ndarray:
    """The COG filters' process noise over ``dt`` [s] for an acceleration noise [m/s^2] of ``horizontal`` on x
    and y and ``vertical`` on z, stacked (3, 2, 2), read-only."""
    return _read_only(np.stack([sigma ** 2 * np.array([[dt ** 4 / 4, dt ** 3 / 2], [dt ** 3 / 2, dt ** 2]])
                                for sigma in (horizontal, horizontal, vertical)]))


def _read_only(array: np.ndarray) -> np.ndarray:
    array.setflags(write=False)
    return array


# --------------------------------------------------------------------------
# AddToBuilder.


def add_state_estimation(builder, plant, cop_estimator, *, servo_period: float, perturbations=None,
                         true_state: bool = False, initial_q=None, name_prefix: str = "", timer=None,
                         robot=None, **estimator_options) -> StateEstimator:
    """Add the pelvis IMU, :class:`RobotSensors` and :class:`StateEstimator` and connect them.

    ``plant`` is the simulated (finalized) plant, ``cop_estimator`` a
    :class:`drake_estop.physics.plant.CopEstimator` already connected to the
    plant's contact results and built with ``bodies=`` the left and right
    sole bodies (in that order: :func:`drake_estop.physics.plant.sole_bodies`).
    ``robot`` (a description, a name or None: the default humanoid) is the
    robot in ``plant``. ``perturbations``
    (:class:`drake_estop.physics.perturbations.Perturbations`, optional) sets the
    noise, the seed and the latency. ``initial_q``: the robot's start pose
    (the q the simulation starts from). Extra keyword arguments go to
    :class:`StateEstimator`. Returns the estimator; its ``q_port``,
    ``com_port``, ``com_vel_port`` and ``stance_port`` are the outputs to
    connect. The sensors system is ``estimator.sensors``.
    """
    robot = as_robot(robot)
    soles = [body.index() for body in sole_bodies(plant, robot)]
    bodies = getattr(cop_estimator, "_bodies", None)
    if bodies is not None and list(bodies) != [int(i) for i in soles]:
        raise ValueError("cop_estimator must be built with bodies=[left sole, right sole]")
    latency = perturbations.latency_ticks if perturbations is not None else 0
    noise = perturbations.sensor_noise if perturbations is not None else False
    seed = perturbations.seed if perturbations is not None else 0
    pelvis = plant.GetBodyByName(robot.floating_base)
    gyro = builder.AddNamedSystem(f"{name_prefix}pelvis_gyro", Gyroscope(pelvis, RigidTransform()))
    accel = builder.AddNamedSystem(f"{name_prefix}pelvis_accelerometer", Accelerometer(
        pelvis, RigidTransform(), plant.gravity_field().gravity_vector()))
    builder.Connect(plant.get_body_poses_output_port(), gyro.get_body_poses_input_port())
    builder.Connect(plant.get_body_spatial_velocities_output_port(), gyro.get_body_velocities_input_port())
    builder.Connect(plant.get_body_poses_output_port(), accel.get_body_poses_input_port())
    builder.Connect(plant.get_body_spatial_velocities_output_port(), accel.get_body_velocities_input_port())
    builder.Connect(plant.get_body_spatial_accelerations_output_port(), accel.get_body_accelerations_input_port())
    sensors = builder.AddNamedSystem(f"{name_prefix}robot_sensors", RobotSensors(
        plant=plant, servo_period=servo_period, latency_ticks=latency, noise=noise, seed=seed, timer=timer))
    builder.Connect(plant.get_state_output_port(), sensors.state_port)
    builder.Connect(gyro.get_measurement_output_port(), sensors.gyro_in_port)
    builder.Connect(accel.get_measurement_output_port(), sensors.accelerometer_in_port)
    builder.Connect(cop_estimator.body_normal_forces_port, sensors.foot_forces_in_port)
    builder.Connect(cop_estimator.cop_port, sensors.cop_in_port)
    builder.Connect(cop_estimator.wrench_port, sensors.wrench_in_port)
    foot_ft = builder.AddNamedSystem(f"{name_prefix}foot_force_torque", FootForceTorqueSensors(plant=plant,
                                                                                               robot=robot))
    builder.Connect(cop_estimator.body_wrenches_port, foot_ft.body_wrenches_port)
    builder.Connect(plant.get_body_poses_output_port(), foot_ft.body_poses_port)
    builder.Connect(foot_ft.foot_ft_port, sensors.foot_ft_in_port)
    estimator = builder.AddNamedSystem(f"{name_prefix}state_estimator", StateEstimator(
        plant=plant, servo_period=servo_period, initial_q=initial_q, true_state=true_state, timer=timer,
        robot=robot, **estimator_options))
    for signal in SIGNALS:
        builder.Connect(sensors.GetOutputPort(signal), estimator.GetInputPort(signal))
    if true_state:
        builder.Connect(plant.get_state_output_port(), estimator.true_state_port)
    estimator.sensors = sensors
    estimator.imu = (gyro, accel)
    return estimator
