"""``StopParameters.max_landing_shift_per_height``: a low swing foot keeps (nearly) its nominal landing.

Found by the robustness campaign: with a 0.2385 m step, a signal 20-60 ms before touchdown (swing foot
0.1-2 mm above the floor) was planned as a one-step stop landing 6-8 cm past the nominal footstep. The
foot was dragged over the floor and the physics robot fell with no push at all (tests/test_online_pushes.py
has the physics run). The online controller allows 10 mm of landing shift per mm of swing height.
"""

import math
from dataclasses import replace

import numpy as np
import pytest
from checks import plan_lipm_error

from drake_estop.physics.online import controller_stop_parameters
from drake_estop.planning.gait import GaitParameters, NominalPattern
from drake_estop.planning.landing import MIN_LANDING_SHIFT
from drake_estop.planning.planner import StopParameters, plan_stop, replan_stop

SHORT_STEP = GaitParameters(step_length=0.2385)


def _shift(plan):
    """(where the swing foot at the signal finally stands against its nominal footstep [m], its height
    at the signal [m]); a next-step plan keeps the nominal footstep."""
    state = plan.pattern.state(plan.signal_time)
    swing = "right" if state.support_foot == "left" else "left"
    return abs(plan.final_feet[swing][0] - state.next_landing[0]), float(state.feet[swing][2])


@pytest.mark.parametrize("value", [0.0, -1.0, float("nan"), "10"])
def test_the_limit_must_be_positive(value):
    with pytest.raises(ValueError, match="max_landing_shift_per_height"):
        StopParameters(max_landing_shift_per_height=value)


def test_the_paper_and_the_controller_defaults():
    assert StopParameters().max_landing_shift_per_height == math.inf
    assert controller_stop_parameters().max_landing_shift_per_height == 10.0
    assert controller_stop_parameters(StopParameters(max_landing_shift_per_height=2.0)) \
        .max_landing_shift_per_height == 2.0


@pytest.mark.parametrize("signal", [3.43, 3.45, 3.47])
def test_a_foot_just_above_the_floor_keeps_its_landing(signal):
    pattern = NominalPattern(SHORT_STEP)
    params = controller_stop_parameters()
    free = plan_stop(pattern, signal, replace(params, max_landing_shift_per_height=math.inf))
    limited = plan_stop(pattern, signal, params)
    free_shift, height = _shift(free)
    assert height < 0.0025 and free_shift > 0.05  # the paper's plan drags the foot 5-8 cm
    shift, _ = _shift(limited)
    assert shift <= max(10.0 * height, MIN_LANDING_SHIFT) + 1e-9
    assert plan_lipm_error(limited, after_halt=0.5) < 1e-3
    _, vel, _, _ = limited.com([limited.halt_end])
    assert np.linalg.norm(vel[0]) < 1e-6


@pytest.mark.parametrize("gait", [GaitParameters(), SHORT_STEP])
def test_the_limit_holds_over_the_stride_and_changes_only_the_plans_it_must(gait):
    """Every plan of the stride (a signal every 20 ms) lands within the allowed shift; a plan whose
    unlimited landing was already within it is unchanged (to a millimetre: the narrowed bounds move the
    solver's grid start). On the default gait only the last tick before the touchdown changes (3.47 s, the
    foot 0.1 mm above the floor: its landing moves 1 mm, not 7)."""
    pattern = NominalPattern(gait)
    params = controller_stop_parameters()
    free_params = replace(params, max_landing_shift_per_height=math.inf)
    start, end = pattern.stride()
    changed = []
    for t in np.round(np.arange(start, end - 1e-9, 0.02), 3):
        free, limited = plan_stop(pattern, t, free_params), plan_stop(pattern, t, params)
        state = pattern.state(t)
        swing = "right" if state.support_foot == "left" else "left"
        if state.support != "single" or state.feet_vel[swing][2] >= 0.0:
            continue  # only a foot coming down is limited (a rising one gets a clearance bump)
        shift, height = _shift(limited)
        assert shift <= max(10.0 * height, MIN_LANDING_SHIFT) + 1e-9, t
        free_shift, _ = _shift(free)
        if free_shift <= max(10.0 * height, MIN_LANDING_SHIFT):
            assert limited.case == free.case
            assert limited.landing_time == pytest.approx(free.landing_time, abs=1e-9)
            for side in ("left", "right"):
                assert limited.final_feet[side] == pytest.approx(free.final_feet[side], abs=1e-3)
        else:
            changed.append(float(t))
    if gait == GaitParameters():
        assert changed == [3.47]
    else:
        assert changed  # the short step's late signals


def test_replans_ignore_the_limit():
    pattern = NominalPattern(SHORT_STEP)
    plan = plan_stop(pattern, 3.2, controller_stop_parameters())
    pos, vel, _, _ = plan.com([3.3])
    pushed = replan_stop(plan, 3.3, pos[0], vel[0] + np.array([0.1, 0.0]))
    assert pushed is not None and pushed.params.max_landing_shift_per_height == math.inf
