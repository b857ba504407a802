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
