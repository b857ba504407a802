"""``StopParameters.max_early_landing``: the landing no earlier than a bound before the nominal touchdown.

The online controller lands at most 50 ms before the walk's own touchdown (its first plan): a
signal at lift-off (2.85 s) otherwise lands 0.16 s early, with the lateral COG still over the
support foot, and the 0.1 s lateral ZMP swing to the landing foot set the physics robot rocking
from foot to foot for 2 s (tests/test_online_pushes.py has the physics run).
"""

import math
from dataclasses import replace

import numpy as np
import pytest
from checks import plan_lipm_error

from drake_estop.physics.online import controller_stop_parameters
from drake_estop.planning.planner import StopParameters, plan_stop, replan_stop

LIFT_OFF_SIGNALS = (2.85, 2.87, 2.89, 2.91)  # the third step lifts off at 2.85 s, touches down at 3.49 s


def _touchdown(plan):
    return plan.pattern.steps[plan.start_state.step_index]["touchdown"]


@pytest.mark.parametrize("value", [-0.01, float("nan"), "0.1"])
def test_max_early_landing_must_be_non_negative(value):
    with pytest.raises(ValueError, match="max_early_landing"):
        StopParameters(max_early_landing=value)


def test_the_paper_and_the_controller_defaults():
    assert StopParameters().max_early_landing == math.inf
    assert controller_stop_parameters().max_early_landing == pytest.approx(0.05)
    # a tighter bound asked for is kept
    assert controller_stop_parameters(StopParameters(max_early_landing=0.0)).max_early_landing == 0.0


@pytest.mark.parametrize("signal", LIFT_OFF_SIGNALS)
def test_lift_off_signals_land_at_most_50_ms_early_and_still_stop_in_one_step(pattern, signal):
    params = controller_stop_parameters()
    free = plan_stop(pattern, signal, replace(params, max_early_landing=math.inf))
    bounded = plan_stop(pattern, signal, params)
    touchdown = _touchdown(bounded)
    assert free.landing_time < touchdown - 0.05 - 1e-9  # the unbounded optimum lands earlier
    assert bounded.case == "one-step"
    assert touchdown - 0.05 - 1e-9 <= bounded.landing_time <= touchdown + 1e-9
    # still a stop: LIPM-consistent, the sagittal COG at rest at the slowdown end (eq. 17), all of it
    # at the halt's end between the feet
    assert plan_lipm_error(bounded, after_halt=0.5) < 1e-3
    free_end, bounded_end = (plan.com([plan.slowdown_end])[1][0] for plan in (free, bounded))
    assert abs(bounded_end[0]) < 1e-6
    _, vel, _, _ = bounded.com([bounded.halt_end])
    assert np.linalg.norm(vel[0]) < 1e-6
    # the later landing leaves the halt less lateral COG speed to absorb (0.05 m/s against 0.12 at 2.85 s)
    assert abs(bounded_end[1]) < abs(free_end[1]) - 0.02


def test_the_bound_changes_only_the_early_single_support_plans(pattern):
    """Over the stride only the signals that would land more than 50 ms early change: those just after
    lift-off, and a foot caught mid-descent (3.33 s) that keeps coming down at the walk's pace and could
    land 55 ms early; the one-step share stays (40 of 40 with the controller's parameters)."""
    params = controller_stop_parameters()
    free = replace(params, max_early_landing=math.inf)
    changed, one_step = [], 0
    for t in np.round(np.arange(2.85, 3.65 - 1e-9, 0.02), 3):
        a, b = plan_stop(pattern, t, free), plan_stop(pattern, t, params)
        one_step += b.case == "one-step"
        assert a.case == b.case
        if abs(a.landing_time - b.landing_time) > 1e-9:
            changed.append(float(t))
            assert a.landing_time < _touchdown(a) - 0.05
    assert changed == [*LIFT_OFF_SIGNALS, 3.33]
    assert one_step == 40


def test_replans_may_land_early(pattern):
    """A re-plan after a push ignores the bound: a COG slowed by a backward push lands sooner (3.40 s,
    before the 3.44 s the bound allows the first plan)."""
    params = controller_stop_parameters()
    plan = plan_stop(pattern, 2.85, params)
    t = 3.0
    pos, vel, _, _ = plan.com([t])
    pushed = replan_stop(plan, t, pos[0], vel[0] + np.array([-0.1, 0.0]))
    assert pushed.params.max_early_landing == math.inf
    assert pushed.case == "one-step"
    assert pushed.landing_time < _touchdown(plan) - 0.05 - 1e-9
