"""DesiredStateInterpolator (IK positions -> PD desired state) in isolation."""

import numpy as np
import pytest

from drake_estop.physics.plant import DesiredStateInterpolator


@pytest.mark.parametrize("mode", ["interpolate", "extrapolate"])
def test_desired_state_interpolator(mode):
    dt = 0.005
    q0 = np.array([9.0, 1.0, 2.0])
    system = DesiredStateInterpolator(q_indices=[1, 2], initial_q=q0, servo_period=dt, mode=mode)
    context = system.CreateDefaultContext()
    system.q_port.FixValue(context, q0)
    context.SetDiscreteState(system.EvalUniquePeriodicDiscreteUpdate(context).get_vector().value())
    np.testing.assert_allclose(system.desired_state_port.Eval(context), [1.0, 2.0, 0.0, 0.0])
    # next tick: the source moved to q1; the state remembers q0 and the tick time
    q1 = np.array([9.0, 1.01, 1.98])
    system.q_port.FixValue(context, q1)
    context.SetTime(dt / 2)
    v = (q1[1:] - q0[1:]) / dt
    base = q0[1:] if mode == "interpolate" else q1[1:]
    np.testing.assert_allclose(system.desired_state_port.Eval(context), [*(base + v * dt / 2), *v])
    with pytest.raises(ValueError):
        DesiredStateInterpolator(q_indices=[0], initial_q=q0, mode="spline")


def test_velocity_limits_rate_limit_the_command_until_it_catches_up():
    """With ``velocity_limits`` a target further than limit * period from the last command is reached
    over several ticks, at the limit (SoftErrorLimiter); a slow target passes unchanged."""
    dt = 0.005
    q0 = np.array([9.0, 0.0, 0.0])
    system = DesiredStateInterpolator(q_indices=[1, 2], initial_q=q0, servo_period=dt,
                                      velocity_limits=[2.0, np.inf])
    context = system.CreateDefaultContext()
    target = np.array([9.0, 0.025, -0.5])  # joint 1: 2.5 ticks at 2 rad/s; joint 2: no limit
    system.q_port.FixValue(context, target)
    commands, rates = [], []
    for k in range(4):
        context.SetTime(k * dt)
        desired = system.desired_state_port.Eval(context)
        rates.append(desired[2:].copy())
        context.SetDiscreteState(system.EvalUniquePeriodicDiscreteUpdate(context).get_vector().value())
        commands.append(context.get_discrete_state().get_vector().value()[:2].copy())
    np.testing.assert_allclose([c[0] for c in commands], [0.01, 0.02, 0.025, 0.025])
    np.testing.assert_allclose([r[0] for r in rates], [2.0, 2.0, 1.0, 0.0])
    np.testing.assert_allclose(commands[0][1], -0.5)  # the unlimited joint goes at once
    assert max(abs(r[0]) for r in rates) <= 2.0 + 1e-12


@pytest.mark.parametrize("limits", [[1.0], [1.0, 0.0], [1.0, float("nan")], [-1.0, 1.0]])
def test_velocity_limits_must_be_positive_one_per_joint(limits):
    with pytest.raises(ValueError, match="velocity_limits"):
        DesiredStateInterpolator(q_indices=[1, 2], initial_q=np.zeros(3), velocity_limits=limits)


@pytest.mark.parametrize("fraction", [0.0, 1.5, float("nan")])
def test_velocity_limit_fraction_must_be_in_0_1(fraction):
    from pydrake.multibody.plant import MultibodyPlant
    from pydrake.systems.framework import DiagramBuilder

    from drake_estop.model import load_humanoid
    from drake_estop.physics.plant import add_servo_targets

    plant = MultibodyPlant(0.001)
    instance = load_humanoid(plant)
    plant.Finalize()
    with pytest.raises(ValueError, match="velocity_limit_fraction"):
        add_servo_targets(DiagramBuilder(), plant, instance, None, np.zeros(plant.num_positions()), 0.005,
                          velocity_limit_fraction=fraction)
