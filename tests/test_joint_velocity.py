"""Joint-velocity limits of the stop through the whole-body IK.

The planner keeps every joint under its URDF ``<limit velocity=...>`` at every servo tick:
the landing knee stays bent (fore reach), the swing foot descends no faster than the walk's
own swing and a foot already coming down is not lifted again. Measured with
``benchmarks/bench_joint_velocity.py`` (IK per tick, finite differences at the servo period).
"""

import numpy as np
import pytest
from scripts import load_script

from drake_estop.planning.gait import NominalPattern
from drake_estop.planning.plan import landing_swing
from drake_estop.planning.planner import StopParameters
from drake_estop.planning.problems import descent_time


@pytest.fixture(scope="module")
def bench():
    return load_script("benchmarks/bench_joint_velocity.py")


@pytest.fixture(scope="module")
def checker(bench):
    return bench.JointVelocityChecker()


@pytest.mark.parametrize("signal", [3.4, 3.5])
def test_paper_stops_within_joint_velocity_limits(checker, signal):
    result = checker.check(signal)
    assert result["case"] == "one-step"
    assert result["violation_ticks"] == 0, result["events"][:3]
    assert result["worst_ratio"] <= 1.0
    assert result["ik_error_max"] < 1e-4


def test_stride_within_joint_velocity_limits(checker):
    """Every 20 ms of the stride (single and double support): no tick over a joint's limit."""
    start, end = checker.pattern.stride()
    over = {}
    for t in np.arange(start, end - 1e-9, 0.02):
        result = checker.check(round(float(t), 6))
        if result["violation_ticks"]:
            over[round(float(t), 3)] = (result["worst_joint"], round(result["worst_speed"], 2))
    assert not over


def test_measurement_catches_the_old_straight_knee_landing(bench):
    """The old limits (fore reach 0.22 m with the knee straight, mean swing 1.2 m/s, no bound on
    the descent) drive the landing knee far over its 6 rad/s: the check is not vacuous."""
    old = bench.JointVelocityChecker(params=StopParameters(
        max_fore_reach=0.22, max_swing_speed=1.2, max_swing_descent_speed=100.0))
    result = old.check(3.25)
    assert result["violation_ticks"] > 0
    assert result["worst_joint"] == "r_knee" and result["worst_speed"] > 12.0


def test_descending_foot_is_not_lifted_again():
    """A foot caught just before touchdown (3.4 s: 6 mm up, coming down) lands without the
    clearance bump that re-lifted it by 2 cm within 0.1 s."""
    pos, vel, acc = np.array([0.887, -0.095, 0.0056]), np.array([0.34, 0.0, -0.157]), np.array([0.0, 0.0, 2.24])
    heights = [landing_swing(pos, vel, acc, (0.93, -0.095), t, 0.1, 0.05)[2] for t in np.linspace(0, 0.1, 41)]
    assert max(heights) <= pos[2] + 1e-12
    assert min(heights) >= -1e-12
    # a foot leaving the floor still gets its clearance
    lift = [landing_swing(np.zeros(3), np.zeros(3), np.zeros(3), (0.3, 0.0), t, 0.4, 0.05)[2]
            for t in np.linspace(0, 0.4, 41)]
    assert max(lift) >= 0.025 - 1e-9


def test_landing_waits_for_the_descent(params, stride_plans):
    """Landing from swing height h takes at least 15/8 h / max_swing_descent_speed from a foot at rest or
    rising (its descent starts from rest), and at least the descent that keeps a foot already coming down
    under that speed; a foot caught on its way down then descends no faster than that bound and never
    rises again."""
    descending = 0
    for plan in stride_plans:
        if plan.landing_foot is None:
            continue
        lift = float(plan.swing_start["pos"][2])
        rate, accel = float(plan.swing_start["vel"][2]), float(plan.swing_start["acc"][2])
        duration = plan.landing_time - plan.start_time
        assert duration >= descent_time(lift, params, rate, accel) - 1e-9, plan.signal_time
        if plan.swing_start["vel"][2] > 0:  # still rising: goes up first, bound from h only
            continue
        descending += 1
        times = np.linspace(0.0, duration, 201)
        rate = np.diff([plan.feet(plan.start_time + t)[plan.landing_foot][2] for t in times]) / np.diff(times)
        # never rises again (the clearance bump re-lifted such a foot by 2 cm within 0.1 s); a foot caught
        # a millimetre above the floor and braking its descent may ripple by micrometres
        assert rate.max() <= 1e-3, plan.signal_time
        assert -rate.min() <= params.max_swing_descent_speed, plan.signal_time
    assert descending >= 20


def test_earliest_touchdown_never_recedes_along_the_walk(params):
    """The earliest touchdown the descent limit allows, t + descent_time(foot state at t), does not move
    later while the walk's swing foot comes down: a foot caught later in its descent lands no later than
    the same foot caught earlier could, until the landing-time floor itself (``min_landing_time``) is what
    bounds it. Timed as a descent from rest (15/8 h / v) it moved 35 ms later over the first half of the
    descent, and mid-stance signals could not land before the COG outran the fore leg's reach."""
    pattern = NominalPattern()
    start, end = pattern.stride()
    times, earliest = [], []
    for t in np.arange(start, end, params.servo_period):
        state = pattern.state(t)
        if state.support != "single":
            continue
        swing = "right" if state.support_foot == "left" else "left"
        rate, accel = float(state.feet_vel[swing][2]), float(state.feet_acc[swing][2])
        if rate < 0:
            times.append(t)
            earliest.append(t + descent_time(float(state.feet[swing][2]), params, rate, accel))
    times, earliest = np.array(times), np.array(earliest)
    assert len(earliest) > 20
    later = np.flatnonzero(np.diff(earliest) > 1e-9) + 1
    assert np.all(earliest[later] - times[later] <= params.min_landing_time + 1e-9), times[later]


def test_descent_time_on_the_servo_grid():
    params = StopParameters()
    assert descent_time(0.0, params) == 0.0
    assert descent_time(0.048, params) == pytest.approx(0.3)
    # the Hermite's own check agrees with the closed form from rest (a vanishing rate takes the grid path)
    assert descent_time(0.048, params, -1e-12) == pytest.approx(0.3)
    # a foot already coming down at the walk's pace (0.27 m/s) keeps it: sooner than from rest
    assert descent_time(0.04, params) == pytest.approx(0.25)
    assert descent_time(0.04, params, -0.27) == pytest.approx(0.2)
    assert descent_time(1.0, params) == pytest.approx(params.max_landing_time - params.servo_period)
    with pytest.raises(ValueError):
        StopParameters(max_swing_descent_speed=0.0)
