"""The hip strategy (drake_estop.physics.hip_strategy): its bow profile, the LeafSystem in isolation
(fixed inputs, one update at a time, then simulated), the robot's trunk joint, and bad settings."""

import math

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator

from drake_estop.physics.hip_strategy import (
    HIP_STRATEGY,
    RATE_TICKS,
    HipStrategy,
    bow_duration,
    bow_profile,
    heading_of,
    push_rate,
    trunk_pitch_setup,
)
from drake_estop.systems.decision import StopMode

PROFILE = {name: HIP_STRATEGY[name] for name in ("rise_time", "hold_time", "return_time")}
OMEGA = math.sqrt(9.80665 / 0.814)
UPPER = 4  # upper-body joints of the test system; the trunk is joint 1


def test_the_bow_rises_holds_and_returns_smoothly():
    start, amplitude = 1.0, 0.12
    times = np.arange(0.9, start + bow_duration(**PROFILE) + 0.2, 1e-4)
    values = np.array([bow_profile(t, start=start, amplitude=amplitude, **PROFILE) for t in times])
    bow, rate = values[:, 0], values[:, 1]
    assert np.all(bow[times <= start] == 0.0) and np.all(bow[times >= start + bow_duration(**PROFILE)] == 0.0)
    held = (times >= start + PROFILE["rise_time"]) & (times <= start + PROFILE["rise_time"] + PROFILE["hold_time"])
    np.testing.assert_allclose(bow[held], amplitude, atol=1e-12)
    assert np.max(bow) <= amplitude + 1e-12 and np.min(bow) >= -1e-12
    np.testing.assert_allclose(np.gradient(bow, times), rate, atol=2e-3)  # the rate is the bow's slope
    assert np.max(np.abs(np.diff(bow))) < 1.9 * amplitude / PROFILE["rise_time"] * 1e-4  # continuous
    assert np.max(rate) == pytest.approx(1.875 * amplitude / PROFILE["rise_time"], rel=1e-3)
    assert bow_profile(5.0, start=math.nan, amplitude=amplitude, **PROFILE) == (0.0, 0.0)


def test_heading_is_the_mean_of_the_soles_yaw():
    def sole(yaw):
        return [0, 0, 0, math.cos(yaw / 2), 0, 0, math.sin(yaw / 2)]

    np.testing.assert_allclose(heading_of(sole(0.0), sole(0.0)), [1, 0], atol=1e-12)
    np.testing.assert_allclose(heading_of(sole(0.2), sole(0.4)), [math.cos(0.3), math.sin(0.3)], atol=1e-12)


def _system(**settings):
    return HipStrategy(**{"upper_body_size": UPPER, "joint_index": 1, "omega": OMEGA, "lower": -0.0873,
                          "upper": 1.0472, "max_speed": 3.0, **settings})


def _fix(system, context, *, ahead=0.0, mode=StopMode.SINGLE_SUPPORT_STOP, yaw=0.0, trunk=0.0, zmp_behind=0.0):
    """Inputs with the estimated DCM ``ahead`` [m] of the reference's along the feet's heading ``yaw``,
    the reference ZMP ``zmp_behind`` [m] behind the estimated DCM."""
    heading = np.array([math.cos(yaw), math.sin(yaw)])
    sole = [0, 0, 0, math.cos(yaw / 2), 0, 0, math.sin(yaw / 2)]
    system.GetInputPort("upper_body").FixValue(context, [0.0, trunk, 0.0, 0.0])
    system.GetInputPort("com").FixValue(context, [0.5, 0.0, 0.8])
    system.GetInputPort("com_vel").FixValue(context, [0.3, 0.0, 0.0])
    system.GetInputPort("left_foot").FixValue(context, sole)
    system.GetInputPort("right_foot").FixValue(context, sole)
    system.GetInputPort("mode").FixValue(context, [float(mode), 1.0])
    system.GetInputPort("measured_com").FixValue(context, [0.5, 0.0, 0.8])
    measured_vel = np.array([0.3 + ahead * OMEGA * heading[0], ahead * OMEGA * heading[1]])
    system.GetInputPort("measured_com_vel").FixValue(context, [*measured_vel, 0.0])
    dcm = np.array([0.5, 0.0]) + measured_vel / OMEGA
    system.GetInputPort("zmp").FixValue(context, dcm - zmp_behind * heading)
    return float(heading @ dcm)


def _pushing(system, context, dcm, rate):
    """The history of an estimated DCM that reaches ``dcm`` [m] along the heading this tick, moving at
    ``rate`` [m/s]."""
    past = [dcm - (RATE_TICKS + 1 - k) * 0.005 * rate for k in range(RATE_TICKS + 1)]
    context.get_mutable_discrete_state(1).SetFromVector(past)


def _state_after_update(system, context):
    return system.EvalUniquePeriodicDiscreteUpdate(context).get_vector(0).CopyToVector()


def test_ports():
    system = _system()
    assert [system.get_input_port(i).get_name() for i in range(system.num_input_ports())] == [
        "upper_body", "com", "com_vel", "zmp", "left_foot", "right_foot", "mode", "measured_com",
        "measured_com_vel"]
    assert [system.get_output_port(i).get_name() for i in range(system.num_output_ports())] == ["upper_body", "bow"]


def test_a_dcm_pushed_ahead_past_the_trigger_in_the_stop_starts_a_forward_bow():
    system = _system()
    context = system.CreateDefaultContext()
    context.SetTime(2.0)
    ahead, fast = HIP_STRATEGY["trigger"] + 0.005, HIP_STRATEGY["min_rate"] + 0.1
    dcm = _fix(system, context, ahead=ahead)
    assert system.deviation(context) == pytest.approx(ahead)
    _pushing(system, context, dcm, fast)
    np.testing.assert_allclose(_state_after_update(system, context), [2.0, HIP_STRATEGY["amplitude"]])
    updated = system.EvalUniquePeriodicDiscreteUpdate(context).get_vector(1).CopyToVector()
    np.testing.assert_allclose(np.diff(updated), 0.005 * fast)  # the history moved on by a tick
    dcm = _fix(system, context, ahead=HIP_STRATEGY["trigger"] - 0.005)  # within the trigger: no bow
    _pushing(system, context, dcm, fast)
    assert math.isnan(_state_after_update(system, context)[0])


def test_a_dcm_drifting_ahead_slower_than_a_push_or_not_yet_measured_starts_no_bow():
    system = _system()
    context = system.CreateDefaultContext()
    dcm = _fix(system, context, ahead=0.1)
    assert math.isnan(_state_after_update(system, context)[0])  # no history yet: no rate
    _pushing(system, context, dcm, HIP_STRATEGY["min_rate"] - 0.1)  # a rebound, the walk's own error
    assert math.isnan(_state_after_update(system, context)[0])


def test_a_dcm_diverging_from_the_reference_zmp_as_the_lipm_does_is_no_push():
    """The DCM moves at omega (xi - p) on its own (eq. 6-9): only what a force adds counts."""
    system = _system()
    context = system.CreateDefaultContext()
    rate = HIP_STRATEGY["min_rate"] + 0.5
    dcm = _fix(system, context, ahead=0.1, zmp_behind=rate / OMEGA)  # the LIPM's divergence is ``rate``
    _pushing(system, context, dcm, rate)
    assert math.isnan(_state_after_update(system, context)[0])
    dcm = _fix(system, context, ahead=0.1, zmp_behind=0.1 / OMEGA)  # 0.1 m/s of it the LIPM's, the rest a push
    _pushing(system, context, dcm, rate)
    assert _state_after_update(system, context)[1] == pytest.approx(HIP_STRATEGY["amplitude"])


def test_push_rate_is_the_dcm_rate_less_the_lipm_divergence():
    assert push_rate([0.10, 0.11, 0.12, 0.13, 0.14], 0.02, 0.5) == pytest.approx(1.5)
    assert math.isnan(push_rate([math.nan, 0.11, 0.12, 0.13, 0.14], 0.02, 0.5))


def test_no_bow_while_walking_or_stopped():
    system = _system()
    context = system.CreateDefaultContext()
    for mode in (StopMode.WALKING, StopMode.STANDING):
        _pushing(system, context, _fix(system, context, ahead=0.1, mode=mode), 2.0)
        assert math.isnan(_state_after_update(system, context)[0]), mode


def test_a_dcm_pushed_behind_bows_back_only_where_asked():
    system = _system()
    context = system.CreateDefaultContext()
    _pushing(system, context, _fix(system, context, ahead=-0.1), -2.0)
    assert math.isnan(_state_after_update(system, context)[0])  # by default the trunk bows forward only
    forward = HipStrategy(upper_body_size=UPPER, joint_index=1, omega=OMEGA, direction=-1.0)
    context = forward.CreateDefaultContext()
    _pushing(forward, context, _fix(forward, context, ahead=-0.1), -2.0)  # (the joint's sign is not the bow's)
    assert math.isnan(_state_after_update(forward, context)[0])


def test_a_dcm_behind_bows_back_within_the_joints_range():
    system = _system(backward=True)
    context = system.CreateDefaultContext()
    _pushing(system, context, _fix(system, context, ahead=-0.1, trunk=0.02), -2.0)
    # 0.12 rad back asked, the joint's lower limit -0.0873 rad from its target 0.02 rad allows 0.1073
    np.testing.assert_allclose(_state_after_update(system, context)[1], -0.0873 - 0.02)
    # the trunk at its limit: no bow that way
    _pushing(system, context, _fix(system, context, ahead=-0.1, trunk=-0.0873), -2.0)
    assert math.isnan(_state_after_update(system, context)[0])


def test_direction_minus_one_bows_forward_with_a_negative_angle():
    system = HipStrategy(upper_body_size=UPPER, joint_index=1, omega=OMEGA, direction=-1.0)
    context = system.CreateDefaultContext()
    _pushing(system, context, _fix(system, context, ahead=0.1), 2.0)
    assert _state_after_update(system, context)[1] == pytest.approx(-HIP_STRATEGY["amplitude"])


def test_the_deviation_is_taken_along_the_feet_heading():
    system = _system()
    context = system.CreateDefaultContext()
    dcm = _fix(system, context, ahead=0.06, yaw=math.pi / 2)  # the robot faces +y: ahead is +y
    assert system.deviation(context) == pytest.approx(0.06)
    _pushing(system, context, dcm, 2.0)
    assert _state_after_update(system, context)[1] == pytest.approx(HIP_STRATEGY["amplitude"])


def test_simulated_the_bow_reaches_the_ik_target_and_a_held_deviation_starts_no_second():
    system = _system()
    context = system.CreateDefaultContext()
    _pushing(system, context, _fix(system, context, ahead=0.1), 2.0)
    simulator = Simulator(system, context)
    simulator.AdvanceTo(HIP_STRATEGY["rise_time"] + 0.05)  # the bow started at t = 0 and is held
    targets = system.GetOutputPort("upper_body").Eval(context)
    np.testing.assert_allclose(targets, [0.0, HIP_STRATEGY["amplitude"], 0.0, 0.0], atol=1e-12)
    assert context.get_discrete_state(0).get_value()[0] == 0.0  # no new bow while this one is under way
    simulator.AdvanceTo(bow_duration(**PROFILE) - 0.01)
    assert 0.0 < system.GetOutputPort("bow").Eval(context)[0] < 1e-3
    simulator.AdvanceTo(bow_duration(**PROFILE) + 0.1)  # returned; the DCM held ahead is no push
    assert context.get_discrete_state(0).get_value()[0] == 0.0
    assert system.GetOutputPort("bow").Eval(context)[0] == 0.0


def test_the_default_humanoid_bows_its_chest_pitch_forward():
    from drake_estop.robots import load_robot
    from drake_estop.systems.diagram import robot_layout
    from drake_estop.systems.ik import shared_ik

    robot = load_robot("default")
    plant, _, _ = shared_ik(robot)
    from drake_estop.planning.gait import NominalPattern
    layout = robot_layout(robot, NominalPattern())
    setup = trunk_pitch_setup(plant, robot, layout)
    assert layout.upper_body[setup["joint_index"]] == "chest_pitch"
    assert setup["direction"] == 1.0
    assert (setup["lower"], setup["upper"], setup["max_speed"]) == pytest.approx((-0.0873, 1.0472, 3.0))


@pytest.mark.parametrize("name, value", [("trigger", 0.0), ("min_rate", -1.0), ("amplitude", -0.1),
                                         ("rise_time", math.nan), ("return_time", 0.0), ("hold_time", -0.1),
                                         ("omega", 0.0), ("servo_period", math.inf)])
def test_bad_settings_name_the_parameter(name, value):
    with pytest.raises(ValueError, match=name):
        _system(**{name: value})


def test_a_bow_faster_than_the_joint_is_refused_and_a_bad_joint_named():
    with pytest.raises(ValueError, match="rise_time"):
        _system(amplitude=0.6, rise_time=0.2)  # 5.6 rad/s against 3
    with pytest.raises(ValueError, match="joint_index"):
        HipStrategy(upper_body_size=UPPER, joint_index=UPPER, omega=OMEGA)
    with pytest.raises(ValueError, match="direction"):
        HipStrategy(upper_body_size=UPPER, joint_index=1, omega=OMEGA, direction=0.5)


def test_a_trunk_joint_outside_the_torso_is_refused_naming_it():
    from dataclasses import replace

    from drake_estop.robots import load_robot

    with pytest.raises(ValueError, match="trunk_pitch_joint 'l_elbow' is not one of the torso joints"):
        replace(load_robot("default"), trunk_pitch_joint="l_elbow")
