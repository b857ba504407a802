"""The robot's sensors: what the controller gets of the simulated robot.

Blocks (all sampled at the servo period through periodic discrete events)::

    MultibodyPlant --body_poses, body_spatial_velocities--> Gyroscope (pelvis) --+
    MultibodyPlant --body_poses, velocities, accelerations--> Accelerometer -----+
    MultibodyPlant --state--> (encoders) ----------------------------------------+--> RobotSensors --> encoders, gyro,
    CopEstimator --body_normal_forces, cop, wrench--> ---------------------------+    (noise,          accelerometer,
    CopEstimator --body_wrenches--> FootForceTorqueSensors --foot_ft--> ---------+     latency)        foot_forces, cop,
                                                                                                       wrench, foot_ft

* ``Gyroscope`` / ``Accelerometer`` are Drake's (``pydrake.systems.sensors``)
  on the pelvis (sensor frame = pelvis frame): the angular velocity of the
  pelvis in the pelvis frame [rad/s] and its proper acceleration
  ``R_PW (a_WP - g_W)`` in the pelvis frame [m/s^2] (+9.81 along the pelvis
  z axis at rest, upright).
* :class:`FootForceTorqueSensors`: the soles' six-axis force/torque sensors.
* :class:`RobotSensors` turns the true signals into what the controller
  gets: joint encoders (the actuated joints' positions), IMU, foot normal
  forces, CoP and the ground wrench (:class:`drake_estop.physics.plant.CopEstimator`,
  reused), with optional white Gaussian noise and a latency of N servo
  ticks. The noise is a pure function of (seed, stream, servo tick) through
  a counter-based generator (numpy ``Philox(key=(seed, stream),
  counter=tick)``): no random-generator state outside the Context, the same
  seed gives the same noise in every run and every process. The latency is a
  ring buffer of the last N samples in the Context's discrete state.

:func:`drake_estop.physics.estimation.add_state_estimation` adds and connects
these and the state estimator.
"""

from __future__ import annotations

import math

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import EventStatus, LeafSystem, ValueProducer

from drake_estop.physics.estimator_math import cross
from drake_estop.physics.plant import sole_frames
from drake_estop.timing import timed, untimed

#: Noise standard deviations of ``--sensor-noise``.
ENCODER_NOISE = 1e-3  # [rad]
GYRO_NOISE = 0.01  # [rad/s]
ACCELEROMETER_NOISE = 0.05  # [m/s^2]

#: Order and sizes of RobotSensors' / StateEstimator's measurement signals (na = actuated joints).
SIGNALS = ("encoders", "gyro", "accelerometer", "foot_forces", "cop", "wrench")
#: RobotSensors' signals: the estimator's, then the feet's force/torque sensors (read by the ankles'
#: foot-edge compliance, :mod:`drake_estop.physics.compliance`).
SENSOR_SIGNALS = SIGNALS + ("foot_ft",)


def _signal_sizes(num_actuated):
    return {"encoders": num_actuated, "gyro": 3, "accelerometer": 3, "foot_forces": 2, "cop": 2, "wrench": 6,
            "foot_ft": 12}


def actuated_position_indices(plant):
    """q indices of the actuated joints in JointActuatorIndex order (the encoders' order)."""
    return np.array([plant.get_joint_actuator(i).joint().position_start()
                     for i in plant.GetJointActuatorIndices()])


def noise_sample(seed: int, stream: int, tick: int, size: int) -> np.ndarray:
    """Standard normal vector for (seed, stream, tick): a counter-based, stateless generator."""
    bits = np.random.Philox(key=np.array([seed, stream], dtype=np.uint64),
                            counter=np.array([tick, 0, 0, 0], dtype=np.uint64))
    return np.random.Generator(bits).standard_normal(size)


class FootForceTorqueSensors(LeafSystem):
    """The soles' six-axis force/torque sensors: each sole's ground wrench in its own frame.

    .. pydrake_system::

        name: FootForceTorqueSensors
        input_ports:
        - body_wrenches
        - body_poses
        output_ports:
        - foot_ft

    Ports:
      - ``body_wrenches`` (12): ``[n, f]`` of the ground on the left then the right sole body about the
        world origin, world frame (:attr:`drake_estop.physics.plant.CopEstimator.body_wrenches_port`,
        the estimator built with the two soles).
      - ``body_poses`` (abstract): the plant's body poses.
      - ``foot_ft`` (12): per sole (left, right) ``[n (3), f (3)]``: the moment about the sole frame's
        origin and the force, both in the sole frame [N m, N] (what a sensor in the foot measures).

    ``robot`` (a :class:`~drake_estop.robots.RobotDescription`, a name or None: the default humanoid)
    names the sole frames.
    """

    def __init__(self, *, plant, robot=None):
        super().__init__()
        frames = sole_frames(plant, robot)  # the robot's (default: the default humanoid's), left then right
        self._bodies = [int(frame.body().index()) for frame in frames]
        self._sole_in_body = [frame.GetFixedPoseInBodyFrame() for frame in frames]
        self.body_wrenches_port = self.DeclareVectorInputPort("body_wrenches", 12)
        self.body_poses_port = self.DeclareAbstractInputPort(
            "body_poses", plant.get_body_poses_output_port().Allocate())
        self.foot_ft_port = self.DeclareVectorOutputPort("foot_ft", 12, self._calc)

    def _calc(self, context, output):
        wrenches = self.body_wrenches_port.Eval(context).reshape(2, 6)
        poses = self.body_poses_port.Eval(context)
        out = np.empty(12)
        for k in range(2):
            sole = poses[self._bodies[k]] @ self._sole_in_body[k]
            rot, origin = sole.rotation().matrix(), sole.translation()
            moment, force = wrenches[k, :3], wrenches[k, 3:]
            out[6 * k:6 * k + 3] = rot.T @ (moment - cross(origin, force))
            out[6 * k + 3:6 * k + 6] = rot.T @ force
        output.SetFromVector(out)


class RobotSensors(LeafSystem):
    """Encoders, IMU and foot force sensing with noise and latency.

    .. pydrake_system::

        name: RobotSensors
        input_ports:
        - state
        - gyro_in
        - accelerometer_in
        - foot_forces_in
        - cop_in
        - wrench_in
        - foot_ft_in
        output_ports:
        - encoders
        - gyro
        - accelerometer
        - foot_forces
        - cop
        - wrench
        - foot_ft

    Inputs (true signals):
      - ``state`` (nq + nv): the plant state (``plant.get_state_output_port()``);
        only the actuated joints' positions are read (the encoders).
      - ``gyro_in`` (3) [rad/s], ``accelerometer_in`` (3) [m/s^2]: Drake's
        ``Gyroscope`` / ``Accelerometer`` measurement outputs.
      - ``foot_forces_in`` (2) [N]: normal force on the left, right sole
        (``CopEstimator.body_normal_forces_port`` built with the two soles).
      - ``cop_in`` (2) [m]: ``CopEstimator.cop_port`` (NaN without support).
      - ``wrench_in`` (6): ``CopEstimator.wrench_port``, ground wrench
        ``[moment about the world origin, force]`` [N m, N], world frame.
      - ``foot_ft_in`` (12): the soles' force/torque sensors,
        :class:`FootForceTorqueSensors` (left then right, sole frames).

    Outputs (what the controller gets): the same signals, ``encoders`` (na)
    in ``JointActuatorIndex`` order [rad]. With ``noise``: white Gaussian
    noise of ``encoder_noise``, ``gyro_noise``, ``accelerometer_noise`` (per
    component, one independent draw per servo tick, held between ticks); the
    force signals are noise-free. With ``latency_ticks = N > 0`` every output
    at servo tick k is the sample of tick k - N (before the first N ticks:
    the sample of the first tick); with N = 0 the outputs are direct
    feedthrough of the current sample.

    The sample of tick k is taken at t_k = k * servo_period by a periodic
    discrete update; the noise is ``noise_sample(seed, stream, k)``, so it
    depends only on the context time and the seed.
    """

    def __init__(self, *, plant, servo_period: float, latency_ticks: int = 0, noise: bool = False, seed: int = 0,
                 timer=None,
                 encoder_noise: float = ENCODER_NOISE, gyro_noise: float = GYRO_NOISE,
                 accelerometer_noise: float = ACCELEROMETER_NOISE):
        super().__init__()
        if latency_ticks < 0 or int(latency_ticks) != latency_ticks:
            raise ValueError(f"--latency must be an integer number of ticks >= 0, got {latency_ticks!r}")
        self._period = float(servo_period)
        self._latency = int(latency_ticks)
        self._noise = bool(noise)
        self._seed = int(seed)
        self._q_idx = actuated_position_indices(plant)
        self._sizes = _signal_sizes(len(self._q_idx))
        offsets = np.cumsum([0] + [self._sizes[s] for s in SENSOR_SIGNALS])
        self._slices = {s: slice(int(offsets[k]), int(offsets[k + 1])) for k, s in enumerate(SENSOR_SIGNALS)}
        self._size = int(offsets[-1])
        self._sigma = np.zeros(self._size)
        self._sigma[self._slices["encoders"]] = encoder_noise
        self._sigma[self._slices["gyro"]] = gyro_noise
        self._sigma[self._slices["accelerometer"]] = accelerometer_noise
        self._noisy = slice(0, self._slices["accelerometer"].stop)

        self.state_port = self.DeclareVectorInputPort("state", plant.num_multibody_states())
        self.gyro_in_port = self.DeclareVectorInputPort("gyro_in", 3)
        self.accelerometer_in_port = self.DeclareVectorInputPort("accelerometer_in", 3)
        self.foot_forces_in_port = self.DeclareVectorInputPort("foot_forces_in", 2)
        self.cop_in_port = self.DeclareVectorInputPort("cop_in", 2)
        self.wrench_in_port = self.DeclareVectorInputPort("wrench_in", 6)
        self.foot_ft_in_port = self.DeclareVectorInputPort("foot_ft_in", 12)
        # the estimator's signals (noise added), without the feet's force/torque sensors: the stop planner's
        # update reads the estimate before the plant's step of the tick and the compliance does not, so
        # that six-axis signal (read by the compliance and the swing tilt after the step) passes through
        self._estimator_size = self._slices["foot_ft"].start
        self._sample = self.DeclareCacheEntry(
            "current sample", ValueProducer(allocate=lambda: AbstractValue.Make(np.zeros(self._estimator_size)),
                                            calc=untimed(self._calc_sample, timer)),
            {self.time_ticket(), self.state_port.ticket(),
             *(self.GetInputPort(f"{name}_in").ticket() for name in SIGNALS if name != "encoders")})
        if self._latency:
            self._buffer = self.DeclareDiscreteState(self._latency * self._size)
            self.DeclarePeriodicDiscreteUpdateEvent(self._period, 0.0, timed(self._shift, timer))
            self.DeclareInitializationDiscreteUpdateEvent(self._fill)
        # the six-axis reading is the simulated robot's work (the F/T sensors' own), left out of the
        # controller's tick time like the sample's (the swing tilt's or the latency buffer's update pulls it)
        self._foot_ft_reading = untimed(lambda context: self.foot_ft_in_port.Eval(context), timer)
        ports = {}
        for name in SENSOR_SIGNALS:
            if self._latency:
                calc, prerequisites = (lambda c, o, name=name: o.SetFromVector(self._delayed(c)[self._slices[name]]),
                                       {self.xd_ticket()})
            elif name == "foot_ft":
                calc, prerequisites = (lambda c, o: o.SetFromVector(self._foot_ft_reading(c)),
                                       {self.foot_ft_in_port.ticket()})
            else:
                calc, prerequisites = (
                    lambda c, o, name=name: o.SetFromVector(self._sample.Eval(c)[self._slices[name]]),
                    {self._sample.ticket()})
            ports[name] = self.DeclareVectorOutputPort(name, self._sizes[name], calc,
                                                       prerequisites_of_calc=prerequisites)
        self.encoders_port = ports["encoders"]
        self.gyro_port = ports["gyro"]
        self.accelerometer_port = ports["accelerometer"]
        self.foot_forces_port = ports["foot_forces"]
        self.cop_port = ports["cop"]
        self.wrench_port = ports["wrench"]
        self.foot_ft_port = ports["foot_ft"]

    @property
    def latency_ticks(self) -> int:
        return self._latency

    def tick(self, t: float) -> int:
        """Servo tick index of time ``t`` (the tick at or before t)."""
        return int(math.floor(t / self._period + 1e-6))

    def _calc_sample(self, context, value):
        x = np.concatenate([
            self.state_port.Eval(context)[self._q_idx], self.gyro_in_port.Eval(context),
            self.accelerometer_in_port.Eval(context), self.foot_forces_in_port.Eval(context),
            self.cop_in_port.Eval(context), self.wrench_in_port.Eval(context)])
        if self._noise:
            k = self.tick(context.get_time())
            n = self._noisy.stop
            x[:n] += self._sigma[:n] * noise_sample(self._seed, 0, k, n)
        value.set_value(x)

    def _full_sample(self, context):
        """This tick's whole sample: the estimator's signals, then the feet's force/torque sensors."""
        return np.concatenate([self._sample.Eval(context), self._foot_ft_reading(context)])

    def _delayed(self, context):
        """The sample of ``latency_ticks`` ticks ago (with latency only: the buffer's oldest)."""
        return context.get_discrete_state(self._buffer).get_value()[:self._size]

    def _fill(self, context, discrete_state):
        discrete_state.get_mutable_vector(self._buffer).SetFromVector(
            np.tile(self._full_sample(context), self._latency))
        return EventStatus.Succeeded()

    def _shift(self, context, discrete_state):
        old = context.get_discrete_state(self._buffer).get_value()
        discrete_state.get_mutable_vector(self._buffer).SetFromVector(
            np.concatenate([old[self._size:], self._full_sample(context)]))
        return EventStatus.Succeeded()
