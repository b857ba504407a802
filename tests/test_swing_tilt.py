"""SwingFootTiltCompensation (the swing foot's target turned against the body's tilt) in isolation."""

import math

import numpy as np
import pytest

from drake_estop.model import FLOATING_BASE, nominal_standing_configuration
from drake_estop.physics.swing_tilt import SwingFootTiltCompensation, base_tilt, compensated_foot
from drake_estop.systems.ik import matrix_to_quaternion, quaternion_to_matrix, rotation_exp, shared_ik

DT = 0.005
DEADBAND = 0.01
RETURN = 0.3
LEVEL = [1.0, 0.0, 0.0, 0.0]
STANCE = np.array([0.6, 0.095, 0.0, *LEVEL])  # the left foot on the floor
SWING = np.array([0.85, -0.095, 0.02, *LEVEL])  # the right foot 2 cm up


@pytest.fixture(scope="module")
def setup():
    plant, _, _ = shared_ik()
    q = nominal_standing_configuration(plant)
    return plant, q, plant.GetBodyByName(FLOATING_BASE).floating_positions_start()


def _tilted(q, base, rotvec):
    """``q`` with its floating base turned by ``rotvec`` (world frame)."""
    out = q.copy()
    out[base:base + 4] = matrix_to_quaternion(rotation_exp(np.asarray(rotvec, float))
                                              @ quaternion_to_matrix(q[base:base + 4]))
    return out


def _system(plant, **settings):
    return SwingFootTiltCompensation(plant=plant, servo_period=DT, deadband=DEADBAND, return_time=RETURN,
                                     **settings)


def _context(system, q_measured, q_commanded, left=STANCE, right=SWING, forces=(500.0, 0.0)):
    context = system.CreateDefaultContext()
    system.feet_in_ports[0].FixValue(context, left)
    system.feet_in_ports[1].FixValue(context, right)
    system.measured_q_port.FixValue(context, q_measured)
    system.commanded_q_port.FixValue(context, q_commanded)
    ft = np.zeros(12)
    ft[5], ft[11] = forces
    system.foot_ft_port.FixValue(context, ft)
    return context


def _tick(system, context):
    context.SetDiscreteState(system.EvalUniquePeriodicDiscreteUpdate(context).get_vector().value())


def test_ports(setup):
    plant, _, _ = setup
    system = _system(plant)
    assert [system.get_input_port(i).get_name() for i in range(system.num_input_ports())] == [
        "left_foot", "right_foot", "measured_q", "commanded_q", "foot_ft"]
    assert [system.get_output_port(i).get_name() for i in range(system.num_output_ports())] == [
        "left_foot", "right_foot", "tilt"]


def test_a_rolled_body_turns_the_swing_target_back_about_the_stance_foot(setup):
    """The body rolled 0.04 rad to the right (positive about x: its top goes to -y): the right swing
    foot's correction is the roll less the dead band; its target is turned back about the left foot, so
    it is commanded higher (the tilted robot carries it down) and rolled the other way; the stance foot
    is unchanged."""
    plant, q, base = setup
    system = _system(plant)
    roll = np.array([0.04, 0.0, 0.0])
    context = _context(system, _tilted(q, base, roll), q)
    _tick(system, context)
    correction = roll * (0.04 - DEADBAND) / 0.04
    np.testing.assert_allclose(system.tilt_port.Eval(context), [0, 0, 0, *correction], atol=1e-9)
    right = system.feet_out_ports[1].Eval(context)
    back = rotation_exp(-correction)
    np.testing.assert_allclose(right[:3], STANCE[:3] + back @ (SWING[:3] - STANCE[:3]), atol=1e-12)
    assert right[2] > SWING[2] + 0.19 * 0.029  # 0.19 m from the stance foot: about 5.5 mm higher
    np.testing.assert_allclose(quaternion_to_matrix(right[3:]), back, atol=1e-12)
    np.testing.assert_array_equal(system.feet_out_ports[0].Eval(context), STANCE)
    # a robot turned by the correction about the stance foot puts the foot at its planned pose
    world = STANCE[:3] + rotation_exp(correction) @ (right[:3] - STANCE[:3])
    np.testing.assert_allclose(world, SWING[:3], atol=1e-12)


def test_the_dead_band_keeps_the_walks_own_sway_out(setup):
    plant, q, base = setup
    system = _system(plant)
    context = _context(system, _tilted(q, base, [0.006, -0.006, 0.0]), q)  # 8.5 mrad
    _tick(system, context)
    np.testing.assert_array_equal(system.tilt_port.Eval(context), 0.0)
    np.testing.assert_array_equal(system.feet_out_ports[1].Eval(context), SWING)


def test_yaw_is_left_out_and_the_tilt_is_capped(setup):
    plant, q, base = setup
    system = _system(plant, max_tilt=0.05)
    context = _context(system, _tilted(q, base, [0.0, 0.3, 0.2]), q)
    _tick(system, context)
    tilt = system.tilt_port.Eval(context)[3:]
    assert tilt[2] == pytest.approx(0.0, abs=1e-3)  # only the yaw the pitch's composition brings
    assert np.linalg.norm(tilt) == pytest.approx(0.05)
    assert tilt[1] > 0.0


def test_a_loaded_or_planted_foot_is_not_corrected_and_its_correction_returns(setup):
    """A swing foot whose sensor reads contact (an early touchdown), or a plan with both feet down,
    stops following the tilt; the correction then decays by dt / return_time a tick."""
    plant, q, base = setup
    rolled = _tilted(q, base, [0.05, 0.0, 0.0])
    for case in ({"forces": (500.0, 80.0)}, {"right": np.array([0.85, -0.095, 0.0, *LEVEL])}):
        system = _system(plant)
        context = _context(system, rolled, q, **case)
        start = np.array([0.0, 0.0, 0.0, -0.02, 0.01, 0.0])
        context.SetDiscreteState(start)
        _tick(system, context)
        np.testing.assert_allclose(system.tilt_port.Eval(context), start * (1 - DT / RETURN), atol=1e-15)
        assert system.swinging(context) == [False, False]


def test_the_left_foot_swinging_is_corrected_about_the_right(setup):
    plant, q, base = setup
    system = _system(plant)
    right_stance = np.array([0.6, -0.095, 0.0, *LEVEL])
    left_swing = np.array([0.85, 0.095, 0.03, *LEVEL])
    context = _context(system, _tilted(q, base, [-0.03, 0.0, 0.0]), q, left=left_swing, right=right_stance,
                       forces=(0.0, 500.0))
    _tick(system, context)
    assert system.swinging(context) == [True, False]
    tilt = system.tilt_port.Eval(context)
    np.testing.assert_allclose(tilt, [-0.02, 0.0, 0.0, 0.0, 0.0, 0.0], atol=1e-9)
    left = system.feet_out_ports[0].Eval(context)
    np.testing.assert_allclose(left[:3], right_stance[:3] + rotation_exp(-tilt[:3]) @ (left_swing[:3]
                                                                                      - right_stance[:3]))


def test_non_finite_orientations_give_no_correction():
    q = np.array([1.0, 0.0, 0.0, 0.0])
    np.testing.assert_array_equal(base_tilt(np.full(4, np.nan), q), 0.0)
    np.testing.assert_array_equal(compensated_foot(SWING, STANCE[:3], np.zeros(3)), SWING)


def test_base_tilt_matches_a_known_roll():
    level = np.array([1.0, 0.0, 0.0, 0.0])
    rolled = np.array([math.cos(0.025), math.sin(0.025), 0.0, 0.0])  # 0.05 rad about x
    np.testing.assert_allclose(base_tilt(rolled, level), [0.05, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(base_tilt(rolled, level, deadband=0.02), [0.03, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(base_tilt(rolled, level, max_tilt=0.01), [0.01, 0.0, 0.0], atol=1e-12)


@pytest.mark.parametrize("name, value", [("servo_period", 0.0), ("max_tilt", -1.0), ("return_time", float("nan")),
                                         ("swing_height", 0.0), ("deadband", -0.01),
                                         ("contact_force", float("inf"))])
def test_bad_settings_name_the_parameter(setup, name, value):
    plant, _, _ = setup
    with pytest.raises(ValueError, match=name):
        SwingFootTiltCompensation(plant=plant, **{name: value})
