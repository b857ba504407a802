"""Sensors (noise, latency) and the state estimator: systems in isolation, then the standing humanoid."""

import math
import time

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder, LeafSystem
from pydrake.systems.primitives import ConstantVectorSource, LogVectorOutput

from drake_estop.model import LEFT_SOLE, RIGHT_SOLE, nominal_standing_configuration
from drake_estop.physics.estimation import StateEstimator, add_state_estimation
from drake_estop.physics.perturbations import Perturbations, Push, add_pelvis_push
from drake_estop.physics.plant import CopEstimator, PhysicsParameters, actuated_indices, add_physics_plant
from drake_estop.physics.sensors import (
    ACCELEROMETER_NOISE,
    ENCODER_NOISE,
    GYRO_NOISE,
    SENSOR_SIGNALS,
    SIGNALS,
    FootForceTorqueSensors,
    RobotSensors,
    actuated_position_indices,
    noise_sample,
)

DT = 0.005
G = 9.81


@pytest.fixture(scope="module")
def plant():
    builder = DiagramBuilder()
    plant, _, _, _ = add_physics_plant(builder, PhysicsParameters())
    return plant


@pytest.fixture(scope="module")
def q0(plant):
    return nominal_standing_configuration(plant)


def _fix_sensor_inputs(sensors, context, plant, q, *, forces=(290.0, 290.0)):
    x = np.concatenate([q, np.zeros(plant.num_velocities())])
    sensors.state_port.FixValue(context, x)
    sensors.gyro_in_port.FixValue(context, [0.01, -0.02, 0.03])
    sensors.accelerometer_in_port.FixValue(context, [0.0, 0.0, G])
    sensors.foot_forces_in_port.FixValue(context, list(forces))
    sensors.cop_in_port.FixValue(context, [0.01, 0.0])
    sensors.wrench_in_port.FixValue(context, [1.0, 2.0, 3.0, 0.0, 0.0, sum(forces)])
    sensors.foot_ft_in_port.FixValue(context, np.arange(12.0))


# --------------------------------------------------------------------------
# RobotSensors.


def test_sensors_without_noise_pass_the_true_signals(plant, q0):
    sensors = RobotSensors(plant=plant, servo_period=DT)
    context = sensors.CreateDefaultContext()
    _fix_sensor_inputs(sensors, context, plant, q0)
    assert np.array_equal(sensors.encoders_port.Eval(context), q0[actuated_position_indices(plant)])
    assert np.array_equal(sensors.gyro_port.Eval(context), [0.01, -0.02, 0.03])
    assert np.array_equal(sensors.accelerometer_port.Eval(context), [0.0, 0.0, G])
    assert np.array_equal(sensors.wrench_port.Eval(context), [1, 2, 3, 0, 0, 580])
    assert np.array_equal(sensors.foot_ft_port.Eval(context), np.arange(12.0))
    assert np.array_equal(actuated_position_indices(plant), actuated_indices(plant)[0])


def _noise(plant, q0, seed, ticks):
    sensors = RobotSensors(plant=plant, servo_period=DT, noise=True, seed=seed)
    context = sensors.CreateDefaultContext()
    _fix_sensor_inputs(sensors, context, plant, q0)
    clean = q0[actuated_position_indices(plant)]
    rows = []
    for k in ticks:
        context.SetTime(k * DT)
        rows.append(np.concatenate([sensors.encoders_port.Eval(context) - clean,
                                    sensors.gyro_port.Eval(context) - [0.01, -0.02, 0.03],
                                    sensors.accelerometer_port.Eval(context) - [0, 0, G],
                                    sensors.foot_forces_port.Eval(context) - 290.0,
                                    sensors.wrench_port.Eval(context) - [1, 2, 3, 0, 0, 580],
                                    sensors.foot_ft_port.Eval(context) - np.arange(12.0)]))
    return np.array(rows)


def test_noise_levels_and_seeds(plant, q0):
    ticks = range(400)
    a = _noise(plant, q0, 3, ticks)
    na = len(actuated_position_indices(plant))
    assert np.std(a[:, :na]) == pytest.approx(ENCODER_NOISE, rel=0.05)
    assert np.std(a[:, na:na + 3]) == pytest.approx(GYRO_NOISE, rel=0.1)
    assert np.std(a[:, na + 3:na + 6]) == pytest.approx(ACCELEROMETER_NOISE, rel=0.1)
    assert np.all(a[:, na + 6:] == 0.0)  # force sensing is noise-free
    assert abs(np.corrcoef(a[1:, 0], a[:-1, 0])[0, 1]) < 0.15  # white from tick to tick
    # same seed: identical, in a fresh system and context, in any evaluation order
    assert np.array_equal(_noise(plant, q0, 3, ticks[::-1])[::-1], a)
    # the noise is held between ticks
    assert np.array_equal(_noise(plant, q0, 3, [10.4])[0], a[10])
    assert not np.allclose(_noise(plant, q0, 4, ticks), a)
    assert not np.allclose(noise_sample(0, 0, 5, 3), noise_sample(1, 0, 5, 3))


class _TickClock(LeafSystem):
    """Vector output (size n) whose every entry is the servo tick index of the context time."""

    def __init__(self, n):
        super().__init__()
        self.DeclareVectorOutputPort("tick", n, lambda c, o: o.SetFromVector(
            np.full(n, math.floor(c.get_time() / DT + 1e-6))))


class _Sampler(LeafSystem):
    """Records its input in a periodic discrete update, as a controller would."""

    def __init__(self, n):
        super().__init__()
        self.u = self.DeclareVectorInputPort("u", n)
        self.seen = []  # test instrument only
        self.DeclareDiscreteState(1)
        self.DeclarePeriodicDiscreteUpdateEvent(DT, 0.0, self._update)

    def _update(self, context, xd):
        self.seen.append((round(context.get_time() / DT), self.u.Eval(context)[0]))


@pytest.mark.parametrize("latency", [0, 1, 3])
def test_latency_shifts_every_signal_by_exactly_n_ticks(plant, latency):
    builder = DiagramBuilder()
    sensors = builder.AddSystem(RobotSensors(plant=plant, servo_period=DT, latency_ticks=latency))
    assert sensors.latency_ticks == latency
    for port in (sensors.state_port, sensors.gyro_in_port, sensors.accelerometer_in_port,
                 sensors.foot_forces_in_port, sensors.cop_in_port, sensors.wrench_in_port, sensors.foot_ft_in_port):
        clock = builder.AddSystem(_TickClock(port.size()))
        builder.Connect(clock.get_output_port(), port)
    samplers = {}
    for name in SENSOR_SIGNALS:
        port = sensors.GetOutputPort(name)
        samplers[name] = builder.AddSystem(_Sampler(port.size()))
        builder.Connect(port, samplers[name].u)
    logger = LogVectorOutput(sensors.gyro_port, builder, DT)
    diagram = builder.Build()
    simulator = Simulator(diagram)
    simulator.AdvanceTo(20 * DT)
    for name, sampler in samplers.items():
        seen = sampler.seen[:21]
        assert [v for _, v in seen] == [max(k - latency, 0) for k, _ in seen], name
    logged = logger.FindLog(simulator.get_context()).data()[0]
    assert list(logged) == [max(k - latency, 0) for k in range(len(logged))]


def test_foot_force_torque_sensors_read_in_the_sole_frame(plant, q0):
    """A 400 N push up at a point 3 cm ahead of and 2 cm outboard of the left sole's origin, in a turned,
    tilted sole: the sensor reads f_z = 400 in its own frame and the moment of that point about its origin
    (CoP = (0.03, 0.02) in the sole frame); the right sole, unloaded, reads zero."""
    from pydrake.common.value import AbstractValue
    from pydrake.math import RollPitchYaw

    context = plant.CreateDefaultContext()
    q = q0.copy()
    q[:4] = RollPitchYaw(0.05, -0.03, 0.4).ToQuaternion().wxyz()  # the floating base turned and tilted
    plant.SetPositions(context, q)
    sole = plant.GetFrameByName(LEFT_SOLE).CalcPoseInWorld(context)
    rot = sole.rotation().matrix()
    point = sole.multiply(np.array([0.03, 0.02, 0.0]))
    force = rot @ np.array([0.0, 0.0, 400.0])
    sensors = FootForceTorqueSensors(plant=plant)
    sensor_context = sensors.CreateDefaultContext()
    sensors.body_wrenches_port.FixValue(sensor_context, np.concatenate([np.cross(point, force), force, np.zeros(6)]))
    sensors.body_poses_port.FixValue(sensor_context, AbstractValue.Make(
        list(plant.get_body_poses_output_port().Eval(context))))
    reading = sensors.foot_ft_port.Eval(sensor_context)
    np.testing.assert_allclose(reading[3:6], [0.0, 0.0, 400.0], atol=1e-9)
    np.testing.assert_allclose([-reading[1] / reading[5], reading[0] / reading[5]], [0.03, 0.02], atol=1e-12)
    np.testing.assert_array_equal(reading[6:], 0.0)


def test_latency_validation(plant):
    with pytest.raises(ValueError, match="--latency"):
        RobotSensors(plant=plant, servo_period=DT, latency_ticks=-1)


# --------------------------------------------------------------------------
# StateEstimator in isolation.


def _estimator_context(estimator, plant, q, *, gyro=(0.0, 0.0, 0.0), acc=(0.0, 0.0, G), forces=(290.0, 290.0)):
    context = estimator.CreateDefaultContext()
    estimator.encoders_port.FixValue(context, q[actuated_position_indices(plant)])
    estimator.gyro_port.FixValue(context, list(gyro))
    estimator.accelerometer_port.FixValue(context, list(acc))
    estimator.foot_forces_port.FixValue(context, list(forces))
    estimator.cop_port.FixValue(context, [0.0, 0.0])
    estimator.wrench_port.FixValue(context, [0, 0, 0, 0, 0, sum(forces)])
    return context


def test_static_robot_is_estimated_exactly(plant, q0):
    estimator = StateEstimator(plant=plant, servo_period=DT, initial_q=q0)
    context = _estimator_context(estimator, plant, q0)
    truth = plant.CreateDefaultContext()
    plant.SetPositions(truth, q0)
    com = plant.CalcCenterOfMassPositionInWorld(truth)
    for k in range(3):
        context.SetTime(k * DT)
        assert np.allclose(estimator.q_port.Eval(context), q0, atol=1e-9)
        assert np.allclose(estimator.com_port.Eval(context), com, atol=1e-9)
        assert np.allclose(estimator.com_vel_port.Eval(context), 0.0, atol=1e-9)
        state = estimator.EvalUniquePeriodicDiscreteUpdate(context)
        context.SetDiscreteState(state.get_vector().get_value())
        # after its own update at this tick the outputs do not change
        assert np.allclose(estimator.com_port.Eval(context), com, atol=1e-9)


def test_gyro_integration_gives_yaw(plant, q0):
    estimator = StateEstimator(plant=plant, servo_period=DT, initial_q=q0)
    context = _estimator_context(estimator, plant, q0, gyro=(0.0, 0.0, 0.5))
    simulator = Simulator(estimator, context)
    simulator.AdvanceTo(1.0)
    w, x, y, z = estimator.q_port.Eval(context)[:4]
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    assert yaw == pytest.approx(0.5, abs=1e-9)


def test_accelerometer_corrects_roll_and_pitch(plant, q0):
    """Start with a 0.1 rad roll error; the accelerometer says upright: the error decays as exp(-k t)."""
    gain = 0.5
    estimator = StateEstimator(plant=plant, servo_period=DT, initial_q=q0, attitude_gain=gain)
    context = _estimator_context(estimator, plant, q0)
    tilted = q0.copy()
    tilted[:4] = [math.cos(0.05), math.sin(0.05), 0.0, 0.0]
    estimator.set_initial_pose(context, tilted)
    Simulator(estimator, context).AdvanceTo(2.0)
    w, x = estimator.q_port.Eval(context)[:2]
    roll = 2 * math.atan2(x, w)
    assert roll == pytest.approx(0.1 * math.exp(-gain * 2.0), rel=0.02)


def test_stance_switch_keeps_the_pelvis_continuous(plant, q0):
    estimator = StateEstimator(plant=plant, servo_period=DT, initial_q=q0)
    context = _estimator_context(estimator, plant, q0, forces=(500.0, 80.0))
    Simulator(estimator, context).AdvanceTo(0.02)
    assert estimator.stance_port.Eval(context)[0] == 0.0
    before = estimator.q_port.Eval(context).copy()
    estimator.foot_forces_port.FixValue(context, [80.0, 500.0])
    Simulator(estimator, context).AdvanceTo(0.04)
    assert estimator.stance_port.Eval(context)[0] == 1.0
    assert np.allclose(estimator.q_port.Eval(context), before, atol=1e-9)
    # a small imbalance within the hysteresis does not switch back
    estimator.foot_forces_port.FixValue(context, [300.0, 280.0])
    Simulator(estimator, context).AdvanceTo(0.06)
    assert estimator.stance_port.Eval(context)[0] == 1.0


def test_true_state_mode_outputs_the_plant_state(plant, q0):
    estimator = StateEstimator(plant=plant, servo_period=DT, initial_q=q0, true_state=True)
    context = _estimator_context(estimator, plant, q0)
    q = q0.copy()
    q[4:7] += [0.1, -0.05, 0.02]
    v = np.zeros(plant.num_velocities())
    v[3:6] = [0.2, 0.1, 0.0]
    estimator.true_state_port.FixValue(context, np.concatenate([q, v]))
    truth = plant.CreateDefaultContext()
    plant.SetPositionsAndVelocities(truth, np.concatenate([q, v]))
    assert np.allclose(estimator.q_port.Eval(context), q)
    assert np.allclose(estimator.com_port.Eval(context), plant.CalcCenterOfMassPositionInWorld(truth))
    assert np.allclose(estimator.com_vel_port.Eval(context),
                       plant.CalcCenterOfMassTranslationalVelocityInWorld(truth))


def _sole_xy(plant, q):
    context = plant.CreateDefaultContext()
    plant.SetPositions(context, q)
    return [plant.EvalBodyPoseInWorld(context, plant.GetBodyByName(name)).translation()[:2]
            for name in (LEFT_SOLE, RIGHT_SOLE)]


def _advance_ticks(estimator, context, ticks):
    for _ in range(ticks):
        state = estimator.EvalUniquePeriodicDiscreteUpdate(context)
        context.SetDiscreteState(state.get_vector().get_value())
        context.SetTime(context.get_time() + DT)


def test_feet_output_gives_the_soles_positions_and_loaded_ticks(plant, q0):
    """``feet``: [x_l, y_l, x_r, y_r, loaded ticks l, loaded ticks r]; a loaded sole counts its ticks (up to
    foot_window), an unloaded one is at 0 and starts again when loaded."""
    estimator = StateEstimator(plant=plant, servo_period=DT, initial_q=q0, foot_window=5)
    context = _estimator_context(estimator, plant, q0, forces=(500.0, 5.0))
    left, right = _sole_xy(plant, q0)
    _advance_ticks(estimator, context, 3)
    feet = estimator.feet_port.Eval(context)
    np.testing.assert_allclose(feet[:4], [*left, *right], atol=1e-9)
    np.testing.assert_array_equal(feet[4:], [4.0, 0.0])  # this tick's estimate counts it too
    estimator.foot_forces_port.FixValue(context, [300.0, 300.0])
    _advance_ticks(estimator, context, 8)
    np.testing.assert_array_equal(estimator.feet_port.Eval(context)[4:], [5.0, 5.0])  # capped at foot_window
    np.testing.assert_allclose(estimator.feet_port.Eval(context)[:4], [*left, *right], atol=1e-9)


def test_feet_output_follows_the_true_soles_in_true_state_mode(plant, q0):
    estimator = StateEstimator(plant=plant, servo_period=DT, initial_q=q0, true_state=True)
    context = _estimator_context(estimator, plant, q0, forces=(500.0, 5.0))
    q = q0.copy()
    q[4:7] += [0.1, -0.05, 0.0]
    estimator.true_state_port.FixValue(context, np.concatenate([q, np.zeros(plant.num_velocities())]))
    left, right = _sole_xy(plant, q)
    feet = estimator.feet_port.Eval(context)
    np.testing.assert_allclose(feet[:4], [*left, *right], atol=1e-9)
    np.testing.assert_array_equal(feet[4:], [1.0, 0.0])


def test_bad_options(plant, q0):
    with pytest.raises(ValueError, match="model"):
        StateEstimator(plant=plant, servo_period=DT, model="magic")
    with pytest.raises(ValueError, match="initial_q"):
        StateEstimator(plant=plant, servo_period=DT, initial_q=q0[:5])
    builder = DiagramBuilder()
    plant2, scene_graph, _, _ = add_physics_plant(builder, PhysicsParameters())
    wrong = builder.AddSystem(CopEstimator(plant=plant2, scene_graph=scene_graph,
                                           bodies=[plant2.GetBodyByName(RIGHT_SOLE)]))
    with pytest.raises(ValueError, match="left sole, right sole"):
        add_state_estimation(builder, plant2, wrong, servo_period=DT)


# --------------------------------------------------------------------------
# The humanoid standing on the contact plant.


def _standing(perturbations, duration=1.0, pushes=(), **options):
    builder = DiagramBuilder()
    plant, scene_graph, instance, _ = add_physics_plant(builder, PhysicsParameters())
    soles = [plant.GetBodyByName(n) for n in (LEFT_SOLE, RIGHT_SOLE)]
    cop = builder.AddSystem(CopEstimator(plant=plant, scene_graph=scene_graph, bodies=soles))
    builder.Connect(plant.get_contact_results_output_port(), cop.contact_results_port)
    q0 = nominal_standing_configuration(plant)
    q_idx, _ = actuated_indices(plant)
    hold = builder.AddSystem(ConstantVectorSource(np.concatenate([q0[q_idx], np.zeros(len(q_idx))])))
    builder.Connect(hold.get_output_port(), plant.get_desired_state_input_port(instance))
    add_pelvis_push(builder, plant, pushes)
    estimator = add_state_estimation(builder, plant, cop, servo_period=DT, perturbations=perturbations,
                                     initial_q=q0, **options)
    logs = {name: LogVectorOutput(port, builder, DT) for name, port in (
        ("state", plant.get_state_output_port()), ("com", estimator.com_port),
        ("com_vel", estimator.com_vel_port), ("q", estimator.q_port))}
    diagram = builder.Build()
    simulator = Simulator(diagram)
    context = simulator.get_mutable_context()
    plant.SetPositions(plant.GetMyMutableContextFromRoot(context), q0)
    costs = []
    step = estimator._step

    def timed(*args):
        start = time.perf_counter()
        result = step(*args)
        costs.append(time.perf_counter() - start)
        return result
    estimator._step = timed  # test instrument: the per-tick cost
    simulator.AdvanceTo(duration)
    data = {name: log.FindLog(context).data().T for name, log in logs.items()}
    scratch = plant.CreateDefaultContext()
    com, vel = [], []
    for x in data["state"]:
        plant.SetPositionsAndVelocities(scratch, x)
        com.append(plant.CalcCenterOfMassPositionInWorld(scratch))
        vel.append(plant.CalcCenterOfMassTranslationalVelocityInWorld(scratch))
    com_err = np.linalg.norm(data["com"] - np.array(com), axis=1)
    vel_err = np.linalg.norm((data["com_vel"] - np.array(vel))[:, :2], axis=1)
    base_err = np.linalg.norm(data["q"][:, 4:7] - data["state"][:, 4:7], axis=1)
    data["true_com_vel"] = np.array(vel)
    return com_err, vel_err, base_err, np.array(costs), data


def test_standing_robot_estimate_without_noise():
    com_err, vel_err, base_err, costs, _ = _standing(Perturbations())
    assert com_err.max() < 0.005
    assert vel_err.max() < 0.02
    assert base_err.max() < 0.005
    assert np.median(costs) < 2e-3  # measured ~0.2 ms; loose for a shared machine


def test_standing_robot_estimate_with_noise_is_bounded_and_reproducible():
    com_err, vel_err, _, _, data = _standing(Perturbations(sensor_noise=True, seed=1), duration=0.5)
    assert com_err.max() < 0.005
    assert vel_err.max() < 0.05
    again = _standing(Perturbations(sensor_noise=True, seed=1), duration=0.5)[4]
    assert np.array_equal(again["com_vel"], data["com_vel"])
    other = _standing(Perturbations(sensor_noise=True, seed=2), duration=0.5)[4]
    assert not np.array_equal(other["com_vel"], data["com_vel"])


def test_true_state_option_is_wired_by_add_state_estimation():
    com_err, vel_err, base_err, _, _ = _standing(Perturbations(sensor_noise=True), duration=0.2, true_state=True)
    assert com_err.max() < 1e-9 and vel_err.max() < 1e-9 and base_err.max() < 1e-9


def test_a_pelvis_push_is_seen_by_the_default_hybrid_filter():
    """170 N forward for 0.1 s: the feet push back, so a force-only model would see the wrong sign."""
    _, vel_err, _, _, data = _standing(Perturbations(), duration=0.5, pushes=[Push(0.3, 170.0, 0.0, 0.1)])
    t = DT * np.arange(len(vel_err))
    during = (t > 0.32) & (t < 0.4)
    assert vel_err[during].max() < 0.08  # measured 54 mm/s (force-only model: 182 mm/s)
    assert np.all(data["com_vel"][:len(t)][during, 0] > 0.0) and np.all(data["true_com_vel"][during, 0] > 0.0)


class _ForceTorqueSource(LeafSystem):
    """Six-axis readings of zero that count their computations and take ``cpu_seconds`` of CPU each (a test
    instrument standing for the simulated sensors' work)."""

    def __init__(self, cpu_seconds=0.0):
        super().__init__()
        self.calls = 0
        self._cpu = cpu_seconds
        self.DeclareVectorOutputPort("y", 12, self._calc, prerequisites_of_calc={self.time_ticket()})

    def _calc(self, context, output):
        self.calls += 1
        end = time.thread_time() + self._cpu
        while time.thread_time() < end:
            pass
        output.SetFromVector(np.zeros(12))


def _sensors_reading(plant, q0, source, **options):
    """``(diagram, context, sensors)``: RobotSensors (``options``) whose six-axis input is ``source``, the
    other inputs fixed (the robot standing in ``q0``, ones)."""
    builder = DiagramBuilder()
    sensors = builder.AddSystem(RobotSensors(plant=plant, servo_period=DT, **options))
    builder.AddSystem(source)
    builder.Connect(source.get_output_port(), sensors.foot_ft_in_port)
    for port in (sensors.state_port, sensors.gyro_in_port, sensors.accelerometer_in_port,
                 sensors.foot_forces_in_port, sensors.cop_in_port, sensors.wrench_in_port):
        builder.ExportInput(port, port.get_name())
    diagram = builder.Build()
    context = diagram.CreateDefaultContext()
    for k in range(diagram.num_input_ports()):
        port = diagram.get_input_port(k)
        port.FixValue(context, np.concatenate([q0, np.zeros(plant.num_velocities())]) if port.get_name() == "state"
                      else np.ones(port.size()))
    return diagram, context, sensors


def test_the_estimators_signals_do_not_compute_the_feet_force_torque_sensors(plant, q0):
    """The stop planner's update reads the estimate before the plant's step of each tick, the compliance
    after it: the six-axis sensors (a Python system, twice a tick before) are computed for the latter only."""
    foot_ft = _ForceTorqueSource()
    _, context, sensors = _sensors_reading(plant, q0, foot_ft)
    sensor_context = sensors.GetMyContextFromRoot(context)
    for name in SIGNALS:
        sensors.GetOutputPort(name).Eval(sensor_context)
    assert foot_ft.calls == 0
    assert np.array_equal(sensors.foot_ft_port.Eval(sensor_context), np.zeros(12))
    assert foot_ft.calls == 1


@pytest.mark.parametrize("latency", [0, 1])
def test_the_feet_force_torque_readings_stay_out_of_the_controllers_tick_time(plant, q0, latency):
    """The six-axis sensors are the simulated robot's work: a controller block that reads them (the swing
    tilt, the compliance; with latency the sensors' own buffer update) is timed without it."""
    from drake_estop.timing import TickTimer

    timer = TickTimer(DT)
    diagram, context, sensors = _sensors_reading(plant, q0, _ForceTorqueSource(cpu_seconds=0.02),
                                                 latency_ticks=latency, timer=timer)
    if latency:
        # the buffer's periodic updates (timed) at 0 and DT; the second reads the sensors anew
        Simulator(diagram, context).AdvanceTo(DT + 1e-4)
    else:
        timer.wrap(lambda c: sensors.foot_ft_port.Eval(c), "reader")(sensors.GetMyContextFromRoot(context))
    ticks = timer.per_tick(clock="cpu")
    assert len(ticks) == 1 + latency
    assert np.all(ticks < 0.01)  # not the 20 ms of the sensors


def test_the_three_cog_filters_in_one_call_keep_each_axis_s_bits():
    """``kf_step_axes`` (the estimator's three COG filters in one call) gives each axis the bits of its own
    ``kf_step``, with and without a measurement."""
    from drake_estop.physics.estimator_math import kf_step, kf_step_axes

    rng = np.random.default_rng(5)
    for i in range(500):
        mean, cov, B, u = rng.normal(size=(3, 2)), rng.normal(size=(3, 3)), rng.normal(size=(3, 2)), rng.normal(size=3)
        A, Q, z, r = rng.normal(size=(3, 2, 2)), rng.normal(size=(3, 2, 2)), rng.normal(size=3), rng.uniform()
        if i % 3 == 0:
            z[i % 2] = np.nan
        m, c = kf_step_axes(mean, cov, A, B, u, Q, z, r)
        for axis in range(3):
            one = kf_step(mean[axis], cov[axis], A[axis], B[axis], u[axis], Q[axis], z[axis], r)
            assert np.array_equal(one[0], m[axis]) and np.array_equal(one[1], c[axis])
