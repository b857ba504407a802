"""The controller's landing settings: a re-planned landing no sooner than its swing can brake
(``max_swing_acceleration``), and the landing foot coming down onto its landing point instead of skimming
the floor towards it (``landing_approach_slope``, ``landing_approach_height``)."""

import math
from dataclasses import replace

import numpy as np
import pytest

from drake_estop.planning import lipm
from drake_estop.planning.capture_landing import swing_braking_time
from drake_estop.planning.gait import NominalPattern
from drake_estop.planning.plan import landing_swing, landing_swing_polynomials
from drake_estop.planning.planner import StopParameters, plan_stop, replan_stop

DT = 0.005
NOMINAL = NominalPattern()
# a swing re-planned while the foot comes down fast and low (29 N s forward push at 2.95 s, re-planned at
# 3.315 s): 2.7 cm up, descending at 0.26 m/s, 1.2 m/s forward, 15 cm and 0.205 s from its landing point
DESCENDING = (np.array([0.836, -0.095, 0.027]), np.array([1.186, 0.0, -0.257]), np.array([-7.07, 0.0, 0.08]),
              (0.988, -0.095), 0.205)
LIFT = 0.05
HEIGHT = 0.01  # StopParameters.landing_approach_height


def _swing(slope, samples=83):
    pos, vel, acc, target, duration = DESCENDING
    times = np.linspace(0.0, duration, samples)
    path = np.array([landing_swing(pos, vel, acc, target, t, duration, LIFT, approach_slope=slope,
                                   approach_height=HEIGHT) for t in times])
    distance = np.hypot(path[:, 0] - target[0], path[:, 1] - target[1])
    return times / duration, path, distance


def test_without_an_approach_slope_a_descending_swing_skims_the_floor():
    """The quintic alone (the paper's planner) keeps the descent rate: the foot is 4 mm or lower while still
    2 cm or more from its landing point, where the servo's few millimetres of lag put it on the floor."""
    _, path, distance = _swing(0.0)
    assert np.any((path[:, 2] < 0.004) & (distance > 0.02))


@pytest.mark.parametrize("slope", [0.3, 0.6, 1.0])
def test_the_approach_slope_keeps_the_foot_above_its_glide_line(slope):
    s, path, distance = _swing(slope)
    second_half = s >= 0.5
    wanted = np.minimum(slope * distance, HEIGHT)
    # held on landing_swing's grid of 1/40 of the swing; between its points within a few tenths of a mm
    assert np.all(path[second_half, 2] >= wanted[second_half] - 3e-4)
    assert not np.any((path[:, 2] < 0.004) & (distance > 0.004 / slope + 1e-6))
    # the same start and landing: the swing continues from the foot's state and lands at rest on its point
    pos, vel, _, target, duration = DESCENDING
    np.testing.assert_allclose(path[0], pos, atol=1e-12)
    np.testing.assert_allclose(path[-1], [*target, 0.0], atol=1e-12)
    unit = landing_swing_polynomials(*DESCENDING[:4], duration, LIFT, approach_slope=slope, approach_height=HEIGHT)
    for axis in range(3):  # position, velocity and acceleration continuous at the start, zero at touchdown
        assert lipm.poly_eval(unit[axis], 1.0, 1) == pytest.approx(0.0, abs=1e-9)
        assert lipm.poly_eval(unit[axis], 1.0, 2) == pytest.approx(0.0, abs=1e-9)
        assert lipm.poly_eval(unit[axis], 0.0, 1) / duration == pytest.approx(vel[axis], abs=1e-9)
    assert np.all(path[:, 2] >= -1e-12)


def test_the_approach_height_caps_the_bump():
    """The bump holds the glide line up to landing_approach_height only: a swing that must still go far (here
    15 cm) is not lifted to slope x distance, and a descending foot never rises above where it was; with the
    controller's 1 cm it rises again by 1 mm at most on this swing (a 2 cm re-lift of a descending foot
    once drove a knee at 15 rad/s: test_joint_velocity)."""
    _, path, _ = _swing(0.6)
    low = int(np.argmin(path[: len(path) // 2, 2]))
    assert path[low:, 2].max() - path[low, 2] < 0.001
    assert path[:, 2].max() <= path[0, 2] + 1e-12


def test_a_swing_that_already_comes_down_steeply_is_left_alone():
    """A swing that lands steeper than the slope keeps its quintic: the nominal stop's landing."""
    pos, vel, acc = np.array([0.59, -0.095, 0.04]), np.array([0.05, 0.0, -0.1]), np.zeros(3)
    for t in np.linspace(0.0, 0.4, 17):
        np.testing.assert_allclose(landing_swing(pos, vel, acc, (0.6, -0.095), t, 0.4, LIFT, approach_slope=0.6,
                                                 approach_height=HEIGHT),
                                   landing_swing(pos, vel, acc, (0.6, -0.095), t, 0.4, LIFT), atol=1e-12)


def test_a_plan_caches_its_swing_and_follows_the_slope(pattern):
    plan = plan_stop(pattern, 3.3, StopParameters(landing_approach_slope=0.6))
    times = np.arange(plan.start_time, plan.landing_time, DT)
    feet = [plan.feet(float(t))[plan.landing_foot] for t in times]
    assert plan._swing_cache is not None
    again = [plan.feet(float(t))[plan.landing_foot] for t in times]
    np.testing.assert_array_equal(feet, again)
    # a new swing start is a new swing (the cache follows the values)
    moved = dict(plan.swing_start, pos=plan.swing_start["pos"] + np.array([0.01, 0.0, 0.0]))
    before = plan.feet(float(times[1]))[plan.landing_foot]
    plan.swing_start = moved
    assert plan.feet(float(times[1]))[plan.landing_foot][0] > before[0]
    plan.swing_start = {key: value for key, value in moved.items()}
    plan.swing_start["pos"] = moved["pos"] - np.array([0.01, 0.0, 0.0])
    np.testing.assert_allclose(plan.feet(float(times[1]))[plan.landing_foot], before, atol=1e-12)
    s = (times - plan.start_time) / (plan.landing_time - plan.start_time)
    distance = np.array([np.hypot(*(f[:2] - plan.landing_position)) for f in feet])
    heights = np.array([f[2] for f in feet])
    wanted = np.minimum(0.6 * distance, 0.01)
    assert np.all(heights[s >= 0.5] >= wanted[s >= 0.5] - 3e-4)


# the landing foot of the paper's stop at 3.1 s, 0.15 s before its touchdown: 6 cm from its landing point,
# 1.07 m/s forward, braking at 9.1 m/s^2
def _late_replan(limit):
    base = plan_stop(NOMINAL, 3.1, StopParameters())
    t = round((base.landing_time - 0.15) / DT) * DT
    h = 1e-3
    foot = [base.feet(t + d)[base.landing_foot] for d in (-h, 0.0, h)]
    state = (foot[1], (foot[2] - foot[0]) / (2 * h), (foot[2] - 2 * foot[1] + foot[0]) / h**2)
    params = StopParameters(max_swing_acceleration=limit)
    plan = plan_stop(NOMINAL, 3.1, params)
    pos, vel, _, _ = plan.com([t])
    new = replan_stop(plan, t, pos[0], vel[0] + np.array([0.1, 0.0]))  # pushed forward 0.1 m/s
    return t, state, plan, new, params


def _peak_acceleration(state, target, duration):
    unit = landing_swing_polynomials(*state, target, duration, LIFT)
    s = np.linspace(0.0, 1.0, 401)
    return float(np.max(np.hypot(lipm.poly_eval(unit[0], s, 2), lipm.poly_eval(unit[1], s, 2)))) / duration**2


def test_swing_braking_time_is_the_soonest_landing_within_the_limit():
    t, state, plan, _, params = _late_replan(10.0)
    soonest = swing_braking_time(*state, plan.landing_position, params)
    assert soonest > params.min_landing_time
    assert _peak_acceleration(state, plan.landing_position, soonest) <= 10.0 + 1e-6
    assert _peak_acceleration(state, plan.landing_position, soonest - DT) > 10.0
    # no limit (the paper), or a limit under the ankle's present 9.1 m/s^2: min_landing_time
    assert swing_braking_time(*state, plan.landing_position, StopParameters()) == StopParameters().min_landing_time
    assert swing_braking_time(*state, plan.landing_position, StopParameters(max_swing_acceleration=8.0)) \
        == pytest.approx(StopParameters().min_landing_time)


def test_swing_braking_time_searches_in_chunks_with_the_whole_grids_answer():
    """The search stops at the first chunk of durations with one within the limit; its answer is the
    whole grid's first, to the bit, also where it lies past the first chunk or nowhere."""
    from drake_estop.planning import capture_landing

    params = StopParameters(max_swing_acceleration=12.0)
    grid = np.arange(params.min_landing_time, params.max_landing_time - DT + 1e-9, DT)
    terms = capture_landing._BRAKING_TERMS

    def whole_grid(pos, vel, acc, target):
        distance = np.asarray(target, float)[:2] - pos[:2]
        T = grid[:, None, None]
        swing = (terms[0][None, :, None] * distance + terms[1][None, :, None] * vel[:2] * T
                 + terms[2][None, :, None] * acc[:2] * T**2) / T**2
        within = np.flatnonzero(np.max(np.linalg.norm(swing, axis=2), axis=1) <= params.max_swing_acceleration + 1e-9)
        return float(grid[within[0]]) if len(within) else params.min_landing_time

    rng = np.random.default_rng(7)
    answers = []
    for _ in range(300):
        pos, target = rng.uniform(-0.3, 0.3, 3), rng.uniform(-0.3, 0.3, 2)
        vel, acc = rng.uniform(-1.5, 1.5, 3), rng.uniform(-12.0, 12.0, 3)
        answers.append(swing_braking_time(pos, vel, acc, target, params))
        assert answers[-1] == whole_grid(pos, vel, acc, target)
    index = np.round((np.array(answers) - params.min_landing_time) / DT)
    assert np.sum(index >= capture_landing._BRAKING_CHUNK) >= 10  # answers past the first chunk were searched too
    assert np.sum(index == 0) >= 10  # and the first duration (or none within the limit)


def test_a_replanned_landing_waits_for_the_swing_to_brake():
    """Pushed 0.15 s before the touchdown, the paper's re-plan lands 45 ms sooner; with a 10 m/s^2 limit the
    landing is no sooner than the swing can brake to the plan's landing point."""
    t, state, _, free, _ = _late_replan(math.inf)
    assert free.landing_time - t == pytest.approx(0.105, abs=1e-9)
    t, state, plan, limited, params = _late_replan(10.0)
    soonest = swing_braking_time(*state, plan.landing_position, params)
    assert limited.landing_time - t >= soonest - 1e-9
    assert limited.landing_time > free.landing_time
    assert abs(limited.com([limited.slowdown_end])[1][0][0]) < 1e-6  # it still stops (eq. 17)


@pytest.mark.parametrize(("name", "value"), [
    ("landing_approach_slope", -0.1), ("landing_approach_slope", math.nan), ("landing_approach_slope", math.inf),
    ("landing_approach_slope", "0.6"), ("landing_approach_height", 0.0), ("landing_approach_height", -0.01),
    ("landing_approach_height", math.nan), ("landing_approach_height", math.inf),
    ("max_swing_acceleration", 0.0), ("max_swing_acceleration", -1.0), ("max_swing_acceleration", math.nan),
    ("max_swing_acceleration", "15"), ("landing_approach_when_braking", 1), ("landing_approach_when_braking", "no")])
def test_bad_landing_settings_raise_naming_them(name, value):
    with pytest.raises(ValueError, match=name):
        StopParameters(**{name: value})


def test_the_braked_landing_is_the_controllers_default_and_turns_off():
    from drake_estop.physics.online import BRAKED_LANDING, controller_stop_parameters
    default = controller_stop_parameters()
    assert default.max_swing_acceleration == pytest.approx(BRAKED_LANDING["max_swing_acceleration"])
    assert default.landing_approach_slope == pytest.approx(BRAKED_LANDING["landing_approach_slope"])
    assert default.landing_approach_when_braking  # the slope only where the braking limit bounds the landing
    paper = controller_stop_parameters(braked_landing=False)
    assert paper.max_swing_acceleration == math.inf and paper.landing_approach_slope == 0.0
    assert not paper.landing_approach_when_braking
    assert paper.zmp_margin == default.zmp_margin  # the controller's own settings stay
    # an approach slope given explicitly shapes every swing; a tighter limit or a steeper slope is kept
    option = controller_stop_parameters(replace(StopParameters(), **BRAKED_LANDING))
    assert option.landing_approach_slope == pytest.approx(0.6) and not option.landing_approach_when_braking
    tighter = controller_stop_parameters(replace(StopParameters(), max_swing_acceleration=10.0,
                                                 landing_approach_slope=0.8))
    assert tighter.max_swing_acceleration == 10.0 and tighter.landing_approach_slope == 0.8
    looser = controller_stop_parameters(replace(StopParameters(), max_swing_acceleration=30.0))
    assert looser.max_swing_acceleration == 15.0 and looser.landing_approach_when_braking


def _swing_of(plan, step=DT):
    times = np.arange(plan.start_time, plan.landing_time, step)
    return np.array([plan.feet(float(t))[plan.landing_foot] for t in times])


def _replan_at(t_before_landing, params, push=0.1):
    plan = plan_stop(NOMINAL, 3.1, params)
    t = round((plan.landing_time - t_before_landing) / DT) * DT
    pos, vel, _, _ = plan.com([t])
    return plan, replan_stop(plan, t, pos[0], vel[0] + np.array([push, 0.0]))


def test_with_landing_approach_when_braking_only_a_braked_swing_approaches():
    """``landing_approach_when_braking``: the approach slope shapes only a re-planned swing whose landing the
    braking limit bounds (the plan's ``braked_swing``); the signal's plan and a re-plan the limit leaves
    alone swing as without a slope (the paper's quintic), to the bit."""
    gated = StopParameters(max_swing_acceleration=10.0, landing_approach_slope=0.6, landing_approach_when_braking=True)
    plain = StopParameters(max_swing_acceleration=10.0)
    always = StopParameters(max_swing_acceleration=10.0, landing_approach_slope=0.6)
    first, held = _replan_at(0.15, gated)  # 0.15 s before the touchdown at 10 m/s^2: the limit bounds it
    assert not first.braked_swing and held.braked_swing
    np.testing.assert_array_equal(_swing_of(first), _swing_of(plan_stop(NOMINAL, 3.1, plain)))
    _, held_plain = _replan_at(0.15, plain)
    assert held.landing_time == held_plain.landing_time  # the same landing, from the same swing
    np.testing.assert_array_equal(_swing_of(held), _swing_of(replace(held_plain, params=always)))
    assert np.max(np.abs(_swing_of(held)[:, 2] - _swing_of(held_plain)[:, 2])) > 1e-3  # it does approach
    # a limit the swing keeps anyway (1000 m/s^2) bounds nothing: the re-planned swing is the quintic
    _, free = _replan_at(0.15, replace(gated, max_swing_acceleration=1000.0))
    _, free_plain = _replan_at(0.15, replace(plain, max_swing_acceleration=1000.0))
    assert not free.braked_swing
    np.testing.assert_array_equal(_swing_of(free), _swing_of(free_plain))
    assert np.max(np.abs(_swing_of(replace(free, braked_swing=True))[:, 2] - _swing_of(free)[:, 2])) > 1e-3
