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


@pytest.mark.parametrize("dvy, width", [(-0.2, 0.26), (0.1, 0.17)])
def test_the_landing_widths_are_the_stop_parameters(dvy, width):
    """A robot's own step widths (StopParameters.min_step_width / max_step_width) bound the landing."""
    t = 3.15 if dvy < 0 else 3.37
    support_y, _ = _support_y(t)
    params = replace(PARAMS, min_step_width=0.17) if dvy > 0 else replace(PARAMS, max_step_width=0.26)
    plan = plan_stop(PATTERN, t, params, measured=_measured(t, dvy))
    assert plan.landing_position[1] == pytest.approx(support_y - width)


@pytest.mark.parametrize("changes, message", [
    ({"min_step_width": 0.0}, "min_step_width must be a positive"),
    ({"max_step_width": math.inf}, "max_step_width must be a positive finite"),
    ({"min_step_width": 0.3, "max_step_width": 0.3}, "min_step_width must be below max_step_width"),
])
def test_bad_landing_widths_are_refused_naming_the_field(changes, message):
    with pytest.raises(ValueError, match=message):
        StopParameters(**changes)


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


# -- the lateral reach of one landing, and why a second lateral step adds none --------------------------


def _dcm_after(dcm, zmp, duration):
    """The DCM [m] after ``duration`` [s] with the ZMP held at ``zmp`` (eq. 6-9, one axis)."""
    return zmp + (dcm - zmp) * math.exp(PATTERN.w * duration)


@pytest.mark.parametrize("side", [1.0, -1.0])
def test_capture_time_is_when_the_dcm_reaches_the_edge(side):
    """A DCM 4.7 cm out over the swing foot's side, the stance ZMP on the inner edge less 3 cm (0.07 m from
    the stance ankle's 0.095) and the outer edge of a landing 0.30 m out less 3 cm: the DCM gets there
    0.295 s later (the measured DCM just after a 29 N s push to the right at 2.95 s; the controller's
    landing came 0.44 s later, 7 cm too late)."""
    zmp, dcm = side * 0.07, side * -0.047
    edge = side * (0.095 - (capture.MAX_STEP_WIDTH + PATTERN.params.sole.outer - PARAMS.zmp_margin))
    latest = capture.capture_time(dcm=dcm, zmp=zmp, edge=edge, omega=PATTERN.w)
    assert latest == pytest.approx(0.295, abs=1e-3)
    assert _dcm_after(dcm, zmp, latest) == pytest.approx(edge, abs=1e-12)
    assert side * (_dcm_after(dcm, zmp, 0.44) - edge) < -0.07
    # heading away from the edge or resting on the ZMP: it never gets there; past it already: no time left
    assert capture.capture_time(dcm=side * 0.08, zmp=zmp, edge=edge, omega=PATTERN.w) == math.inf
    assert capture.capture_time(dcm=zmp, zmp=zmp, edge=edge, omega=PATTERN.w) == math.inf
    assert capture.capture_time(dcm=edge - side * 0.01, zmp=zmp, edge=edge, omega=PATTERN.w) == 0.0


@pytest.mark.parametrize("kwargs, name", [({"dcm": math.nan}, "dcm"), ({"zmp": math.inf}, "zmp"),
                                          ({"edge": "0.1"}, "edge"), ({"omega": 0.0}, "omega")])
def test_capture_time_rejects_bad_input_naming_it(kwargs, name):
    with pytest.raises(ValueError, match=name):
        capture.capture_time(**{"dcm": 0.1, "zmp": 0.0, "edge": 0.2, "omega": PATTERN.w, **kwargs})


@pytest.mark.parametrize("separation", [capture.MIN_STEP_WIDTH, 0.19, capture.MAX_STEP_WIDTH])
def test_a_second_lateral_step_catches_less_than_the_loaded_foot_standing(separation):
    """The foot on the push side carries the robot, the DCM beyond its outer edge. Stepping it further out
    (no crossover) needs the ZMP on the other foot first; with the controller's shortest ZMP transition
    and landing (0.1 s each) the DCM then runs further than the foot can reach (0.30 m from the other
    ankle): from the walk's 0.19 m stance it catches 5.3 cm less than the foot standing, from 0.15 m
    1.3 cm less. Only a step under 0.12 s (0.18 s from 0.15 m), ZMP transfer included, would gain."""
    sole, w = PATTERN.params.sole, PATTERN.w
    shortest = PARAMS.min_transition_time + PARAMS.min_landing_time
    gain = capture.step_out_gain(separation=separation, step_time=shortest, omega=w, sole=sole)
    assert gain < 0.0
    # the gain is the LIPM's: the DCM the step just catches, minus the one the standing foot just catches
    other, margin = 0.0, PARAMS.zmp_margin  # the other ankle at 0, the loaded one at +separation
    zmp = other + sole.inner - margin
    landed_edge = other + capture.MAX_STEP_WIDTH + sole.outer - margin
    caught = zmp + (landed_edge - zmp) * math.exp(-w * shortest)
    assert _dcm_after(caught, zmp, shortest) == pytest.approx(landed_edge, abs=1e-12)
    assert gain == pytest.approx(caught - (other + separation + sole.outer - margin), abs=1e-12)
    # break-even step time, and the gain falls with the step time
    even = math.log((capture.MAX_STEP_WIDTH + sole.outer - sole.inner) / (separation + sole.outer - sole.inner)) / w
    assert capture.step_out_gain(separation=separation, step_time=even, omega=w, sole=sole) == pytest.approx(0.0,
                                                                                                              abs=1e-12)
    assert even < 0.18
    times = np.linspace(0.0, 0.4, 9)
    assert np.all(np.diff([capture.step_out_gain(separation=separation, step_time=s, omega=w) for s in times]) < 0)


def test_step_out_gain_numbers_and_bad_input():
    w = PATTERN.w
    assert capture.step_out_gain(separation=0.19, step_time=0.2, omega=w) == pytest.approx(-0.0532, abs=5e-4)
    assert capture.step_out_gain(separation=0.15, step_time=0.2, omega=w) == pytest.approx(-0.0132, abs=5e-4)
    for kwargs, name in (({"separation": 0.1}, "separation"), ({"separation": 0.31}, "separation"),
                         ({"step_time": -0.1}, "step_time"), ({"step_time": math.nan}, "step_time"),
                         ({"omega": -1.0}, "omega"), ({"max_width": 0.1}, "max_width")):
        with pytest.raises(ValueError, match=name):
            capture.step_out_gain(**{"separation": 0.19, "step_time": 0.2, "omega": w, **kwargs})


def test_a_capture_landing_without_a_braking_limit_swings_at_the_capture_acceleration():
    """A stop whose swing has no braking limit (``max_swing_acceleration`` inf, the planner's default) still takes
    the capture landing: its swing is bounded by ``CAPTURE_SWING_ACCELERATION`` (20 m/s^2), the same landing as
    with that limit given (it raised OverflowError in the reach search before)."""
    from drake_estop.planning.capture_landing import CAPTURE_SWING_ACCELERATION, capture_swing_acceleration
    from drake_estop.planning.planner import replan_stop

    landings = []
    for limit in (math.inf, CAPTURE_SWING_ACCELERATION):
        params = StopParameters(zmp_margin=0.03, max_swing_acceleration=limit)
        assert capture_swing_acceleration(params) == CAPTURE_SWING_ACCELERATION
        plan = plan_stop(NominalPattern(), 2.95, params)
        pos, vel, _, _ = plan.com([3.1])
        caught = replan_stop(plan, 3.1, pos[0], vel[0] - np.array([0.0, 0.4]))  # pushed right, the swing's side
        assert caught.capture_landing
        landings.append((caught.landing_time, *caught.landing_position))
    np.testing.assert_allclose(landings[0], landings[1], atol=1e-12)
    assert capture_swing_acceleration(StopParameters(max_swing_acceleration=30.0)) == 30.0
