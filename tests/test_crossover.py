"""The crossover step (planning/crossover.py): the legs' geometry, and the stop that lands across the support foot."""

import math

import numpy as np
import pytest

from drake_estop.planning import crossover, lipm, replan
from drake_estop.planning.crossover import (
    LATE_LATERAL,
    CrossoverPath,
    LegGeometry,
    crossover_delay,
    crossover_stop,
    knee,
    late_lateral,
    legs_clearance,
    segment_distance,
    soles_apart,
)
from drake_estop.planning.gait import NominalPattern, Sole
from drake_estop.planning.planner import InfeasibleStop, StopParameters, plan_stop, replan_stop
from drake_estop.planning.recovery import RECOVERY_ZMP_MARGIN

SLIM = LegGeometry(radius=0.03)  # a robot whose legs are thinner than the default humanoid's 5.5 cm
SIGNAL, PUSHED = 2.95, 3.1  # the left foot stands alone, the right swings
PUSH = 0.36  # [m/s] to the left, onto the standing foot: the lateral DCM reaches its sole's outer bound


def _brute_distance(a0, a1, b0, b1, n=401):
    s = np.linspace(0.0, 1.0, n)[:, None]
    a = np.asarray(a0) + s * (np.asarray(a1) - np.asarray(a0))
    b = np.asarray(b0) + s * (np.asarray(b1) - np.asarray(b0))
    return float(np.min(np.linalg.norm(a[:, None, :] - b[None, :, :], axis=2)))


@pytest.mark.parametrize("seed", range(6))
def test_segment_distance_is_the_least_distance_between_the_segments(seed):
    rng = np.random.default_rng(seed)
    a0, a1, b0, b1 = rng.normal(size=(4, 3))
    assert segment_distance(a0, a1, b0, b1) == pytest.approx(_brute_distance(a0, a1, b0, b1), abs=5e-3)


def test_segment_distance_of_crossing_parallel_and_touching_segments():
    assert segment_distance([0, -1, 0], [0, 1, 0], [-1, 0, 0], [1, 0, 0]) == pytest.approx(0.0, abs=1e-12)
    assert segment_distance([0, 0, 0], [1, 0, 0], [0, 0.2, 0], [1, 0.2, 0]) == pytest.approx(0.2)
    assert segment_distance([0, 0, 0], [1, 0, 0], [2, 0.1, 0], [3, 0.1, 0]) == pytest.approx(math.hypot(1.0, 0.1))


def test_the_knee_keeps_the_thigh_and_shank_lengths_and_bends_forward():
    geometry = LegGeometry()
    hip, ankle = np.array([0.0, 0.06, 0.65]), np.array([0.1, 0.1, 0.105])
    joint = knee(hip, ankle, (1.0, 0.0), geometry)
    assert np.linalg.norm(joint - hip) == pytest.approx(geometry.thigh)
    assert np.linalg.norm(joint - ankle) == pytest.approx(geometry.shank)
    midpoint = 0.5 * (hip + ankle)
    assert joint[0] > midpoint[0] + 0.05  # ahead of the hip-ankle line
    assert knee(hip, hip + [0.0, 0.0, -0.61], (1.0, 0.0), geometry) is None  # longer than the leg


def test_legs_standing_apart_clear_and_legs_crossed_side_by_side_collide():
    geometry = LegGeometry()
    hips = [np.array([0.0, -0.06, 0.647]), np.array([0.0, 0.06, 0.647])]
    apart = [np.array([0.0, -0.095, 0.105]), np.array([0.0, 0.095, 0.105])]
    # the default stance: the legs' axes 12-19 cm apart, their capsules 11 cm thick
    assert legs_clearance(hips, apart, (1.0, 0.0), geometry) == pytest.approx(0.12 - 2 * geometry.radius, abs=0.01)
    crossed = [np.array([0.0, 0.095, 0.105]), np.array([0.0, -0.095, 0.105])]
    assert legs_clearance(hips, crossed, (1.0, 0.0), geometry) < -0.05
    assert legs_clearance(hips, [apart[0], apart[1] + [0, 0, -0.3]], (1.0, 0.0), geometry) == -math.inf


@pytest.mark.parametrize("delay", range(4))
def test_the_late_lateral_shapes_rest_at_both_ends_and_move_later_with_the_delay(delay):
    shape = LATE_LATERAL[delay]
    for s, value in ((0.0, 0.0), (1.0, 1.0)):
        assert lipm.poly_eval(shape, s) == pytest.approx(value, abs=1e-12)
        for derivative in (1, 2):
            assert lipm.poly_eval(shape, s, derivative) == pytest.approx(0.0, abs=1e-9)
    if delay:
        assert lipm.poly_eval(shape, 0.5) < lipm.poly_eval(LATE_LATERAL[delay - 1], 0.5) - 0.05
    else:
        np.testing.assert_allclose(lipm.pad(lipm.SMOOTHSTEP, len(shape)), shape, atol=1e-12)
    np.testing.assert_array_equal(late_lateral(delay), shape)


def test_soles_apart_needs_a_gap_along_one_axis():
    sole = Sole()
    assert soles_apart((0, 0), (0.0, -0.19), sole, "left", "right")  # the default stance
    assert not soles_apart((0, 0), (0.0, 0.1), sole, "left", "right")  # crossed, side by side: overlapping
    assert soles_apart((0, 0), (sole.toe + sole.heel + 0.02, 0.1), sole, "left", "right")  # crossed in front


def _path(landing, com_landing=(0.05, 0.03), start=(-0.1, -0.19)):
    return CrossoverPath(start=np.array(start), landing=np.array(landing), com_start=np.array([0.0, 0.0]),
                         com_landing=np.array(com_landing), height=0.814, lift=0.05, swing_side=-1.0)


def test_a_crossover_is_never_chosen_where_the_legs_would_collide():
    """Every landing the check passes keeps the capsules apart on a grid ten times finer than its own."""
    sole, chosen = Sole(), 0
    for geometry in (LegGeometry(), SLIM):
        for x in np.arange(0.0, 0.4, 0.02):
            for y in np.arange(0.0, 0.3, 0.02):
                path = _path((x, y))
                delay = crossover_delay(path, geometry, sole)
                if delay is None:
                    continue
                chosen += 1
                assert soles_apart((0.0, 0.0), path.landing, sole, "left", "right")
                fine = min(crossover._clearance_at(path, float(s), delay, geometry) for s in np.linspace(0, 1, 111))
                assert fine > 0.0, (geometry, x, y, delay, fine)
    assert chosen > 5  # the slim legs allow some


def test_the_support_knee_bars_the_default_humanoids_crossovers_where_slim_legs_pass():
    sole = Sole()
    path = _path((0.26, 0.06))
    assert crossover_delay(path, SLIM, sole) is not None
    assert crossover_delay(path, LegGeometry(), sole) is None
    assert crossover._clearance_at(path, 1.0, 0, LegGeometry()) < 0.0  # at the touchdown already
    assert crossover_delay(_path((0.26, 0.06), com_landing=(-0.3, 0.03)), SLIM, sole) is None  # out of reach


@pytest.fixture(scope="module")
def pushed_left():
    """A plan at 2.95 s and, at 3.1 s, its COG pushed 0.36 m/s to the left, onto the left foot standing alone."""
    pattern = NominalPattern()
    plan = plan_stop(pattern, SIGNAL, StopParameters(zmp_margin=0.03, max_swing_acceleration=15.0))
    pos, vel, _, _ = plan.com([PUSHED])
    vel = vel[0].copy()
    vel[1] += PUSH
    return plan, pos[0].copy(), vel


def _start(plan, com, vel):
    return replan.ReplanStart(plan, PUSHED, com, vel, False, plan.params)


def test_the_crossover_stop_lands_across_the_support_foot_in_front_of_its_leg(pushed_left):
    plan, com, vel = pushed_left
    new = crossover_stop(_start(plan, com, vel), com, vel, SLIM)
    support = plan.feet(PUSHED)["left"][:2]
    landing = new.landing_position - support
    assert new.crossover and new.step_kind == "crossover step" and new.landing_foot == "right"
    assert landing[1] > Sole().outer  # beyond the support ankle, past its sole's outer edge
    assert soles_apart((0.0, 0.0), landing, Sole(), "left", "right")
    assert new.min_zmp_margin >= min(plan.params.zmp_margin, RECOVERY_ZMP_MARGIN) - 1e-9
    # the COG is continuous at the re-plan and at rest at the end; the LIPM holds (eq. 4)
    before, after = plan.com([PUSHED]), new.com([PUSHED])
    np.testing.assert_allclose(after[0][0], com, atol=1e-9)
    np.testing.assert_allclose(after[1][0], vel, atol=1e-9)
    assert np.allclose(before[0], after[0], atol=1e-9)
    end = new.com([new.halt_end + 0.5])
    assert np.max(np.abs(end[1])) < 1e-6
    times = np.linspace(PUSHED, new.halt_end, 200)
    pos, _, acc, zmp = new.com(times)
    np.testing.assert_allclose(zmp, pos - acc / plan.pattern.w**2, atol=1e-6)
    # the swing moves across late: at mid-swing nearer its start than the quintic would have it
    delay = new.swing_start["cross_delay"]
    middle = 0.5 * (PUSHED + new.landing_time)
    start_y, target_y = new.swing_start["pos"][1], new.landing_position[1]
    quintic = start_y + (target_y - start_y) * 0.5
    assert abs(new.feet(middle)["right"][1] - start_y) <= abs(quintic - start_y) + 1e-9
    assert delay == 0 or abs(new.feet(middle)["right"][1] - start_y) < abs(quintic - start_y) - 0.01


def test_no_crossover_for_the_default_humanoids_legs_or_a_dcm_inside_the_sole(pushed_left):
    plan, com, vel = pushed_left
    assert crossover_stop(_start(plan, com, vel), com, vel) is None  # LegGeometry(): the support knee
    calm = vel.copy()
    calm[1] -= PUSH
    assert crossover_stop(_start(plan, com, calm), com, calm, SLIM) is None  # the ankle strategy holds it


def test_replan_stop_tries_the_crossover_only_when_asked(pushed_left, monkeypatch):
    plan, com, vel = pushed_left
    monkeypatch.setattr(crossover, "LegGeometry", lambda: SLIM)  # the re-plan's legs
    asked = replan_stop(plan, PUSHED, com, vel, crossover=True)
    assert asked.crossover and asked.step_kind == "crossover step"
    with pytest.raises(InfeasibleStop):  # without it no stop exists from this state
        replan_stop(plan, PUSHED, com, vel)


@pytest.mark.parametrize("delay", [1, 2, 3])
def test_a_crossover_swing_moves_across_late_and_lands_at_rest(delay):
    from drake_estop.planning.plan import landing_swing_polynomials
    pos, vel, acc, target = np.array([0.5, -0.09, 0.03]), np.array([1.2, 0.05, 0.1]), np.zeros(3), (0.87, 0.19)
    plain = landing_swing_polynomials(pos, vel, acc, target, 0.3, 0.05)
    late = landing_swing_polynomials(pos, vel, acc, target, 0.3, 0.05, cross_delay=delay)
    for axis in (0, 2):  # along and up: as the paper's quintic
        np.testing.assert_allclose(late[axis], plain[axis])
    middle = [lipm.poly_eval(polys[1], 0.5) for polys in (plain, late)]
    assert middle[1] < middle[0] - 0.03  # still nearer its own side at mid-swing
    assert lipm.poly_eval(late[1], 0.0) == pytest.approx(pos[1])
    assert lipm.poly_eval(late[1], 0.0, 1) == pytest.approx(vel[1] * 0.3)  # its lateral speed carried on
    assert lipm.poly_eval(late[1], 1.0) == pytest.approx(target[1])
    for derivative in (1, 2):
        assert lipm.poly_eval(late[1], 1.0, derivative) == pytest.approx(0.0, abs=1e-9)
    assert np.array_equal(landing_swing_polynomials(pos, vel, acc, target, 0.3, 0.05, cross_delay=0)[0], plain[0])


def _planner_pushed_left(**kwargs):
    """StopPlannerSystem (FixValue inputs, Simulator.AdvanceTo) latched at 2.95 s with the online controller's
    parameters, measuring at 3.1 s the COG pushed to the left (:func:`pushed_left`'s push). Returns the planner
    and its context."""
    from planner_helpers import latched_stop_planner

    from drake_estop.physics.online import controller_stop_parameters

    planner, context, simulator, first = latched_stop_planner(NominalPattern(), controller_stop_parameters(),
                                                              t0=SIGNAL, max_replan_solves=None, **kwargs)
    simulator.AdvanceTo(PUSHED - 0.0025)
    pos, vel, _, _ = first.com([PUSHED])
    planner.measured_com_port.FixValue(context, [*pos[0], 0.8])
    planner.measured_com_vel_port.FixValue(context, [vel[0][0], vel[0][1] + PUSH, 0.0])
    simulator.AdvanceTo(PUSHED + 0.0025)
    return planner, context


def test_the_planner_system_takes_a_crossover_step_only_with_crossover_step(monkeypatch):
    monkeypatch.setattr(crossover, "LegGeometry", lambda: SLIM)
    planner, context = _planner_pushed_left(crossover_step=True)
    assert planner.plan(context).crossover
    assert [s["kind"] for s in planner.plans(context).summary()["steps"]][-1] == "crossover step"
    planner, context = _planner_pushed_left()
    assert not planner.plan(context).crossover


def test_the_capturability_verdicts_crossover_reach_is_where_the_legs_clear():
    """The default humanoid's legs keep no crossover landing clear (its verdict counts none); slim legs do."""
    from drake_estop.planning.crossover import clear_crossover_reach
    from drake_estop.robots import stepping_limits
    from drake_estop.robots.parameters import as_robot

    assert clear_crossover_reach() == 0.0
    assert clear_crossover_reach(LegGeometry(radius=0.03)) == pytest.approx(0.10)
    assert stepping_limits(as_robot()).crossover_reach == 0.0
    assert stepping_limits(as_robot()).regions("left").keys() == {"nominal"}
