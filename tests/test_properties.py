"""Property tests: random gaits and signal times inside the walk always give a finite stop that
keeps every limit, the ZMP margin included.

No ``InfeasibleStop`` is tolerated: for these gaits no state of the walk is known to be
unreachable (an exception swallowed here would hide, for example, a walk stepping in place
that cannot stop). Signals fall between the first lift-off and the last touchdown, so
every example tests a stop from walking (none while standing or after the walk ended).
"""

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drake_estop.planning.gait import GaitParameters, NominalPattern
from drake_estop.planning.planner import StopParameters, plan_stop


def nominal_swing_speed(gait) -> float:
    """Mean speed [m/s] of the walk's own swing foot: two step lengths over the single support."""
    return 2.0 * gait.step_length / (gait.step_time * (1.0 - gait.double_support_ratio))


# walks whose own swing stays within the planner's max_swing_speed: a faster walk's stop cannot land in
# time at some signals (test_a_walk_faster_than_the_swing_speed_limit_may_have_no_stop below)
gaits = st.builds(
    GaitParameters,
    com_height=st.floats(0.6, 0.95),
    step_length=st.one_of(st.just(0.0), st.floats(0.0, 0.05), st.floats(0.0, 0.35)),
    step_time=st.floats(0.6, 1.4),
    double_support_ratio=st.floats(0.1, 0.4),
    num_steps=st.integers(3, 6),
).filter(lambda gait: nominal_swing_speed(gait) <= StopParameters().max_swing_speed)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(gait=gaits, fraction=st.floats(0.0, 1.0), crouch=st.booleans())
def test_random_signal_inside_the_walk_stops_within_limits(gait, fraction, crouch):
    pattern = NominalPattern(gait)
    params = StopParameters(crouch=crouch)
    first, last = pattern.steps[0]["liftoff"], pattern.steps[-1]["touchdown"]
    signal = first + fraction * (last - first)
    plan = plan_stop(pattern, signal, params)  # InfeasibleStop fails the test
    assert plan.support in ("single", "double")
    assert plan.case in ("one-step", "next-step", "already-stopping")
    if plan.case == "already-stopping":  # only when the fallback runs into the walk's own final stop
        assert signal > pattern.steps[-1]["liftoff"] - 1e-9
    times = np.arange(plan.signal_time, plan.halt_end + 1.0, params.servo_period)
    pos, vel, acc, zmp = plan.com(times)
    z, _, _ = plan.com_height(times)
    for array in (pos, vel, acc, zmp, z):
        assert np.all(np.isfinite(array))
    assert np.linalg.norm(plan.com([plan.halt_end + 1.0])[1]) < 1e-6
    if plan.case != "already-stopping":
        assert plan.min_zmp_margin >= params.zmp_margin - 1e-9  # the README's 1 cm, not 0
        mid = 0.5 * (plan.final_feet["left"] + plan.final_feet["right"])
        np.testing.assert_allclose(plan.com([plan.halt_end + 1.0])[0][0], mid, atol=1e-6)
    if plan.step_length is not None:
        assert params.min_step_length - 1e-12 <= plan.step_length <= params.max_step_length + 1e-12
        duration = plan.landing_time - plan.start_time
        # no sooner than min_landing_time, or than the nominal touchdown where that comes first
        nominal = plan.pattern.steps[plan.start_state.step_index]["touchdown"]
        assert duration >= min(params.min_landing_time, nominal - plan.start_time) - 1e-9
        distance = np.linalg.norm(plan.landing_position - plan.swing_start["pos"][:2])
        assert distance / duration <= params.max_swing_speed + 1e-9
    for t in (plan.start_time, plan.landing_time, plan.slowdown_end, plan.halt_end):
        assert math.isfinite(t)


def test_a_walk_faster_than_the_swing_speed_limit_may_have_no_stop():
    """Found by the property test above: 0.34 m steps in 0.625 s with 12.5 % double support
    swing the foot at 1.26 m/s on average, over the planner's 1.12 m/s max_swing_speed. Early in a
    single support no landing within the limits stops the COG, nor does the next support phase: the
    planner raises InfeasibleStop naming the limit that binds (never a silent infeasible plan). 0.32 m
    steps (1.17 m/s) stop at every signal."""
    from drake_estop.planning.plan import InfeasibleStop

    fast = GaitParameters(com_height=0.75, step_length=0.34375, step_time=0.625, double_support_ratio=0.125,
                          num_steps=4)
    assert nominal_swing_speed(fast) > StopParameters().max_swing_speed
    with pytest.raises(InfeasibleStop, match="no feasible stop within two steps.*limited by max_"):
        plan_stop(NominalPattern(fast), 1.552734375, StopParameters(crouch=False))

