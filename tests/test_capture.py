"""Lateral landing from the measured state (planning/capture.py): the landing foot goes where the
lateral capture point goes, within the step widths the legs take; unperturbed plans are the paper's."""

import math
from dataclasses import replace

import numpy as np
import pytest

from drake_estop.planning import capture
from drake_estop.planning.gait import NominalPattern
from drake_estop.planning.planner import InfeasibleStop, StopParameters, plan_stop

PARAMS = StopParameters(zmp_margin=0.03, halt_durations=(1.0, 1.2, 1.5))  # the online controller's
PATTERN = NominalPattern()


def _measured(t, dvy):
    pos, vel, _, _ = PATTERN.com([t])
    return pos[0], vel[0] + np.array([0.0, dvy])


def _support_y(t):
    state = PATTERN.state(t)
    return float(state.feet[state.support_foot][1]), float(state.next_landing[1])


@pytest.mark.parametrize("t", [2.95, 3.15, 3.37])
def test_no_deviation_keeps_the_nominal_footstep(t):
    plan = plan_stop(PATTERN, t, PARAMS, measured=_measured(t, 0.0))
    reference = plan_stop(PATTERN, t, PARAMS)
    np.testing.assert_array_equal(plan.landing_position, reference.landing_position)
    assert plan.halt_end == reference.halt_end


def test_outward_deviation_widens_the_step_by_the_grown_dcm_deviation():
    t, dvy = 3.37, -0.05  # left foot supports: the right (swing) foot's side is -y
    support_y, nominal_y = _support_y(t)
    plan = plan_stop(PATTERN, t, PARAMS, measured=_measured(t, dvy))
    landing = plan.landing_time - plan.start_time
    expected = nominal_y + dvy / PATTERN.w * math.exp(PATTERN.w * landing)
    assert plan.landing_position[1] == pytest.approx(expected, abs=2e-3)  # the landing time moves a little
    assert plan.landing_position[1] < nominal_y - capture.SHIFT_THRESHOLD


def test_inward_deviation_narrows_the_step_but_not_below_the_minimum_width():
    t = 3.37
    support_y, nominal_y = _support_y(t)
    narrower = plan_stop(PATTERN, t, PARAMS, measured=_measured(t, 0.05))
    assert nominal_y + capture.SHIFT_THRESHOLD < narrower.landing_position[1] < support_y - capture.MIN_STEP_WIDTH
    clamped = plan_stop(PATTERN, t, PARAMS, measured=_measured(t, 0.1))
    assert clamped.landing_position[1] == pytest.approx(support_y - capture.MIN_STEP_WIDTH)


def test_wide_steps_are_clamped_to_the_maximum_width():
    t = 3.15
    support_y, _ = _support_y(t)
    plan = plan_stop(PATTERN, t, PARAMS, measured=_measured(t, -0.2))
    assert plan.landing_position[1] == pytest.approx(support_y - capture.MAX_STEP_WIDTH)


def test_a_deviation_under_the_threshold_keeps_the_nominal_footstep():
    t = 3.37
    _, nominal_y = _support_y(t)
    tiny = 1e-3 * PATTERN.w * math.exp(-PATTERN.w * 0.5)  # a shift of about 1 mm at the landing
    plan = plan_stop(PATTERN, t, PARAMS, measured=_measured(t, -tiny))
    assert plan.landing_position[1] == nominal_y


def test_capture_stops_what_the_nominal_footstep_cannot(monkeypatch):
    """A sideways deviation the nominal footstep cannot stop in one step (no plan at all, or only
    the next-step fallback) is stopped in one step by stepping to the capture point."""
    t = 3.37
    monkeypatch.setattr(capture, "SHIFT_THRESHOLD", math.inf)  # the paper's nominal footstep
    for dvy in (-0.2, 0.12):
        try:
            assert plan_stop(PATTERN, t, PARAMS, measured=_measured(t, dvy)).case != "one-step"
        except InfeasibleStop:
            pass
    monkeypatch.undo()
    for dvy in (-0.2, 0.12):
        plan = plan_stop(PATTERN, t, PARAMS, measured=_measured(t, dvy))
        assert plan.case == "one-step" and plan.min_zmp_margin >= PARAMS.zmp_margin - 1e-9


def test_a_support_zmp_moved_off_the_walks_counts_in_the_capture_step():
    """A re-plan's ankle strategy moves the support ZMP: with no COG deviation, a ZMP moved out by dp
    pushes the DCM in by dp (exp(w T) - 1) by the landing (eq. 6-9), and the landing follows it."""
    t, landing, dp = 3.37, 0.15, 0.03
    state = PATTERN.state(t)
    support_y, nominal_y = _support_y(t)
    outward = math.copysign(1.0, support_y - nominal_y)
    moved = replace(state, zmp=state.zmp + np.array([0.0, outward * dp]))
    assert capture.capture_landing_y(PATTERN, state, landing) is None
    expected = nominal_y - outward * dp * (math.exp(PATTERN.w * landing) - 1.0)
    assert capture.capture_landing_y(PATTERN, moved, landing) == pytest.approx(expected, abs=1e-12)
