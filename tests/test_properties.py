"""Property tests: random gaits and signal times never give NaN or a plan that breaks limits silently."""

import math

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drake_estop.gait import GaitParameters, NominalPattern
from drake_estop.planner import InfeasibleStop, StopParameters, plan_stop

gaits = st.builds(
    GaitParameters,
    com_height=st.floats(0.6, 0.95),
    step_length=st.floats(0.0, 0.35),
    step_time=st.floats(0.6, 1.4),
    double_support_ratio=st.floats(0.1, 0.4),
    num_steps=st.integers(3, 6),
)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(gait=gaits, fraction=st.floats(0.0, 1.0), crouch=st.booleans())
def test_random_signal_never_nan_never_silently_infeasible(gait, fraction, crouch):
    pattern = NominalPattern(gait)
    params = StopParameters(crouch=crouch)
    signal = fraction * (pattern.end_time + 0.5)
    try:
        plan = plan_stop(pattern, signal, params)
    except InfeasibleStop as error:
        assert str(error)  # a named reason, never a silent bad plan
        return
    times = np.arange(plan.signal_time, plan.halt_end + 1.0, params.servo_period)
    pos, vel, acc, zmp = plan.com(times)
    z, _, _ = plan.com_height(times)
    for array in (pos, vel, acc, zmp, z):
        assert np.all(np.isfinite(array))
    assert np.linalg.norm(plan.com([plan.halt_end + 1.0])[1]) < 1e-6
    if plan.x is not None and plan.case != "standing":
        assert plan.min_zmp_margin >= 0.0
    if plan.step_length is not None:
        assert plan.step_length <= params.max_step_length + 1e-12
        duration = plan.landing_time - plan.start_time
        assert duration >= params.min_landing_time - 1e-9
        distance = np.linalg.norm(plan.landing_position - plan.swing_start["pos"][:2])
        assert distance / duration <= params.max_swing_speed + 1e-9
    for t in (plan.start_time, plan.landing_time, plan.slowdown_end, plan.halt_end):
        assert math.isfinite(t)
