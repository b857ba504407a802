"""FootEdgeCompliance (stance ankles yield to a foot-rolling moment) in isolation."""

import numpy as np
import pytest

from drake_estop.model import SOLE, nominal_standing_configuration
from drake_estop.physics.compliance import FootEdgeCompliance
from drake_estop.systems.ik import shared_ik

DT = 0.005
DAMPING = 50.0
RETURN = 0.3
FZ = 500.0


@pytest.fixture(scope="module")
def setup():
    plant, _, _ = shared_ik()
    return plant, nominal_standing_configuration(plant)


def _system(plant, **settings):
    return FootEdgeCompliance(plant=plant, servo_period=DT, damping=DAMPING, return_time=RETURN,
                              edge_margin=0.01, **settings)


def _ft(cop_in_sole, fz=FZ):
    """A sole's force/torque reading [n, f] (sole frame, about its origin): fz at the point ``cop_in_sole``."""
    p = np.array([cop_in_sole[0], cop_in_sole[1], 0.0])
    f = np.array([0.0, 0.0, fz])
    return np.concatenate([np.cross(p, f), f])


def _context(system, q, left, right):
    context = system.CreateDefaultContext()
    system.q_in_port.FixValue(context, q)
    system.foot_ft_port.FixValue(context, np.concatenate([left, right]))
    return context


def _ankles(plant, q):
    return np.array([q[plant.GetJointByName(name).position_start()]
                     for name in ("l_ankle_roll", "l_ankle_pitch", "r_ankle_roll", "r_ankle_pitch")])


def test_ports(setup):
    plant, _ = setup
    system = _system(plant)
    assert [system.get_input_port(i).get_name() for i in range(system.num_input_ports())] == [
        "q", "foot_ft"]
    assert [system.get_output_port(i).get_name() for i in range(system.num_output_ports())] == ["q", "offsets"]


def test_cop_inside_the_safe_region_changes_nothing(setup):
    plant, q = setup
    system = _system(plant)
    context = _context(system, q, _ft([0.05, 0.02]), _ft([-0.05, 0.0]))
    np.testing.assert_array_equal(system.rolling_moments(context), 0.0)
    context.SetDiscreteState(system.EvalUniquePeriodicDiscreteUpdate(context).get_vector().value())
    np.testing.assert_array_equal(system.offsets_port.Eval(context), 0.0)
    np.testing.assert_array_equal(system.q_port.Eval(context), q)


def test_cop_on_the_outer_edge_rolls_the_ankle_with_the_moment(setup):
    """Left CoP 4 mm inside the outer (+y) edge, 10 mm safe inset: 6 mm excess, m_x = +3 N m; the left
    ankle roll moves by dt m / damping in one tick, the rest stays (the right foot is off the ground)."""
    plant, q = setup
    system = _system(plant)
    cop = [0.0, SOLE.outer - 0.004]
    context = _context(system, q, _ft(cop), np.zeros(6))
    moments = system.rolling_moments(context)
    np.testing.assert_allclose(moments, [0.006 * FZ, 0.0, 0.0, 0.0], atol=1e-9)
    context.SetDiscreteState(system.EvalUniquePeriodicDiscreteUpdate(context).get_vector().value())
    expected = np.array([DT * 0.006 * FZ / DAMPING, 0.0, 0.0, 0.0])
    np.testing.assert_allclose(system.offsets_port.Eval(context), expected, atol=1e-12)
    np.testing.assert_allclose(_ankles(plant, system.q_port.Eval(context)) - _ankles(plant, q), expected, atol=1e-12)


def test_cop_at_the_right_toe_pitches_the_right_ankle_down(setup):
    """The right foot's CoP 6 mm past the safe region towards the toe: m_y = -0.006 f_z (the toe
    pushed up), so the right ankle pitch offset is negative."""
    plant, q = setup
    system = _system(plant)
    context = _context(system, q, np.zeros(6), _ft([SOLE.toe - 0.004, 0.0]))
    np.testing.assert_allclose(system.rolling_moments(context), [0.0, 0.0, 0.0, -0.006 * FZ], atol=1e-9)


def test_offsets_return_when_the_foot_is_off_the_ground(setup):
    plant, q = setup
    system = _system(plant, max_offset=0.2)
    context = _context(system, q, _ft([0.0, 0.0], fz=10.0), np.zeros(6))
    context.SetDiscreteState(np.array([0.1, -0.1, 0.05, 0.0]))
    context.SetDiscreteState(system.EvalUniquePeriodicDiscreteUpdate(context).get_vector().value())
    np.testing.assert_allclose(system.offsets_port.Eval(context), np.array([0.1, -0.1, 0.05, 0.0]) * (1 - DT / RETURN))


def test_offsets_are_bounded(setup):
    plant, q = setup
    system = _system(plant, max_offset=0.01)
    context = _context(system, q, _ft([0.0, SOLE.outer], fz=5000.0), np.zeros(6))
    for _ in range(50):
        context.SetDiscreteState(system.EvalUniquePeriodicDiscreteUpdate(context).get_vector().value())
    assert system.offsets_port.Eval(context)[0] == pytest.approx(0.01)


@pytest.mark.parametrize("name, value", [("damping", 0.0), ("return_time", -1.0), ("max_offset", float("nan")),
                                         ("servo_period", 0.0), ("edge_margin", 0.06), ("edge_margin", -0.01)])
def test_bad_settings_raise_naming_the_parameter(setup, name, value):
    plant, _ = setup
    with pytest.raises(ValueError, match=name):
        FootEdgeCompliance(plant=plant, **{name: value})
