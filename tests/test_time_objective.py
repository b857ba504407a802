"""StopParameters(objective="time"): the soonest rest between the feet (planning/brake.py), every tick of
the stride; its parameter, option and scenario field; re-plans from a pushed state."""

import json
import math

import numpy as np
import pytest
from checks import plan_lipm_error

from drake_estop.cli import main
from drake_estop.planning.gait import GaitParameters, NominalPattern
from drake_estop.planning.planner import InfeasibleStop, StopParameters, plan_stop, replan_stop
from drake_estop.planning.replan import ankle_zmp
from drake_estop.planning.rollout import stride_ticks
from drake_estop.scenario import load_scenario

TIME = StopParameters(objective="time")


@pytest.fixture(scope="module")
def time_plans(pattern, stride_times):
    return [plan_stop(pattern, t, TIME) for t in stride_times]


def _rest_on_the_feet_segment(plan, rest, tol=1e-9):
    """The rest point is where the time objective may rest the COG (brake.rest_points): on the segment
    from the final feet's midpoint to the ankle ahead, within the rear leg's reach. Returns the fraction."""
    feet = plan.final_feet
    heading = np.array([math.cos(plan.heading), math.sin(plan.heading)])
    rear, fore = sorted((feet["left"], feet["right"]), key=lambda xy: float(heading @ xy))
    midpoint = 0.5 * (rear + fore)
    half = fore - midpoint
    offset = rest - midpoint
    fraction = float(offset @ half / (half @ half)) if half @ half > 1e-18 else 0.0
    np.testing.assert_allclose(offset, fraction * half, atol=tol, err_msg=str(plan.signal_time))
    assert -tol <= fraction <= 1.0 + tol, (plan.signal_time, fraction)
    if fraction > tol:  # beyond the midpoint only within the rear leg's reach
        assert heading @ (rest - rear) <= plan.params.max_rear_reach + 1e-9, plan.signal_time
    return fraction


def _ticks(plan, start, end):
    dt = plan.params.servo_period
    return start + dt * np.arange(int(round((end - start) / dt)) + 1)


def test_time_to_rest_median_at_most_0_6_s_and_never_later_than_the_paper(time_plans, stride_plans):
    """The behaviour the objective is for: over every tick of the stride the COG rests at the feet's
    midpoint 0.6 s after the signal or sooner (median; the paper's objective: about 1.1 s), and at
    no tick later than with the paper's objective."""
    rest = np.array([plan.halt_end - plan.signal_time for plan in time_plans])
    paper = np.array([plan.halt_end - plan.signal_time for plan in stride_plans])
    assert np.median(rest) <= 0.6, np.median(rest)
    assert np.all(rest <= paper + 1e-9), [(p.signal_time, r, q) for p, r, q in zip(time_plans, rest, paper) if r > q]


def test_one_step_wherever_the_paper_objective_is(time_plans, stride_plans):
    for plan, paper in zip(time_plans, stride_plans):
        assert plan.steps_after_signal <= max(1, paper.steps_after_signal), plan.signal_time
        if paper.case == "one-step":
            assert plan.case == "one-step", plan.signal_time
    # most signals land once, replanned: the nominal step is finished only where that is sooner
    assert sum(plan.case == "one-step" for plan in time_plans) >= 0.85 * len(time_plans)


def test_cog_at_rest_between_the_feet_at_halt_end(time_plans):
    """The COG rests on the segment from the feet's midpoint to the fore ankle (within the rear leg's
    reach), the ZMP under it; at the midpoint itself wherever the stop reaches it without passing it."""
    fractions = []
    for plan in time_plans:
        pos, vel, _, zmp = plan.com([plan.halt_end, plan.halt_end + 2.0])
        np.testing.assert_allclose(pos[1], pos[0], atol=1e-9, err_msg=str(plan.signal_time))  # eq. 27
        np.testing.assert_allclose(vel, 0.0, atol=1e-9, err_msg=str(plan.signal_time))  # eq. 28
        np.testing.assert_allclose(zmp, pos, atol=1e-9, err_msg=str(plan.signal_time))
        fractions.append(_rest_on_the_feet_segment(plan, pos[0]))
        # still moving just before: halt_end is when the COG comes to rest, not an arbitrary later time
        assert np.linalg.norm(plan.com([plan.halt_end - 0.05])[1]) > 1e-3, plan.signal_time
    assert sum(f < 1e-9 for f in fractions) >= len(fractions) // 2, fractions  # most at the midpoint


def test_lipm_residual_at_every_tick(time_plans, pattern):
    """The planned COG and ZMP satisfy x'' = w^2 (x - p) (eq. 4) at every servo tick of every stop."""
    w2 = pattern.w**2
    for plan in time_plans:
        pos, _, acc, zmp = plan.com(_ticks(plan, plan.signal_time, plan.halt_end + 0.5))
        assert np.abs(acc - w2 * (pos - zmp)).max() < 1e-9, plan.signal_time


def test_cog_obeys_lipm_by_independent_integration(time_plans, pattern):
    for plan in time_plans[::4]:
        assert plan_lipm_error(plan, after_halt=0.5) < 1e-3, plan.signal_time


def test_continuous_with_the_pattern_at_the_start(time_plans, pattern):
    """Position, velocity, ZMP (eq. 10-12) and the ZMP's rate and acceleration (eq. 13) carry over
    from the walk where the stop leaves it, and through every phase boundary."""
    for plan in time_plans:
        t0 = plan.start_time
        walk = [traj.evaluate_at(t0) for traj in pattern.trajectories]
        stop = [traj.evaluate_at(t0) for traj in (plan.x, plan.y)]
        for axis in (0, 1):
            for k, name, tol in ((0, "position", 1e-9), (1, "velocity", 1e-9), (3, "zmp", 1e-9),
                                 (4, "zmp rate", 1e-6), (5, "zmp acceleration", 1e-4)):
                assert stop[axis][k] == pytest.approx(walk[axis][k], abs=tol), (plan.signal_time, axis, name)
        for b in (plan.landing_time, plan.transition_end, plan.slowdown_end, plan.halt_end):
            for traj in (plan.x, plan.y):
                before, after = traj.evaluate_at(b - 1e-9), traj.evaluate_at(b + 1e-9)
                assert np.allclose(before[:4], after[:4], atol=1e-6), (plan.signal_time, b)
                assert np.allclose(before[4:], after[4:], atol=1e-4), (plan.signal_time, b)


def test_zmp_inside_the_support_polygon_with_the_margin_at_every_tick(time_plans, params):
    assert TIME.zmp_margin == params.zmp_margin == 0.01
    for plan in time_plans:
        assert plan.min_zmp_margin >= TIME.zmp_margin - 1e-9, plan.signal_time
        times = _ticks(plan, plan.start_time, plan.halt_end + 0.2)
        zmp = plan.com(times)[3]
        worst = min(float(plan.polygon(t).margin(z)[0]) for t, z in zip(times, zmp))  # independent of the planner
        assert worst >= TIME.zmp_margin - 1e-9, (plan.signal_time, worst)


def test_phase_times_ordered_on_ticks_and_the_limits_kept(time_plans):
    for plan in time_plans:
        times = (plan.start_time, plan.landing_time, plan.transition_end, plan.slowdown_end, plan.halt_end)
        assert all(a <= b + 1e-12 for a, b in zip(times, times[1:])), (plan.signal_time, times)
        for b in times:
            assert abs(b / TIME.servo_period - round(b / TIME.servo_period)) < 1e-6
        assert plan.transition_end - plan.landing_time >= TIME.min_transition_time - 1e-9
        assert plan.halt_end - plan.slowdown_end >= TIME.min_transition_time - 1e-9
        if plan.landing_foot is not None:
            duration = plan.landing_time - plan.start_time
            # no sooner than min_landing_time, or than the nominal touchdown where that comes first
            nominal = plan.pattern.steps[plan.start_state.step_index]["touchdown"]
            assert duration >= min(TIME.min_landing_time, nominal - plan.start_time) - 1e-9
            assert TIME.min_step_length - 1e-12 <= plan.step_length <= TIME.max_step_length + 1e-12
            swing = plan.swing_start["pos"][:2]
            assert np.linalg.norm(plan.landing_position - swing) / duration <= TIME.max_swing_speed + 1e-9
            # the fore leg's reach at the touchdown (landing ankle ahead of the COG)
            assert plan.landing_position[0] - plan.com([plan.landing_time])[0][0, 0] <= TIME.max_fore_reach + 1e-9


def test_turning_walk_keeps_the_margin_in_the_turned_soles():
    """The geometry goes through the support polygons of the turned soles: a turning walk's stops keep
    the margin tick by tick and rest between the feet."""
    pattern = NominalPattern(GaitParameters(turn=15.0))
    for t in stride_ticks(pattern, TIME)[::10]:
        plan = plan_stop(pattern, float(t), TIME)
        for tick, zmp in zip(times := _ticks(plan, plan.start_time, plan.halt_end), plan.com(times)[3]):
            assert plan.polygon(tick).margin(zmp)[0] >= TIME.zmp_margin - 1e-9, (t, tick)
        _rest_on_the_feet_segment(plan, plan.com([plan.halt_end])[0][0])


@pytest.mark.parametrize("value", ["fast", "Time", None])
def test_bad_objective_names_the_parameter(value):
    with pytest.raises(ValueError, match="objective"):
        StopParameters(objective=value)


def test_cli_objective_option(tmp_path, capsys):
    assert main(["simulate", "--kinematic", "--objective", "fast"]) == 2
    assert "--objective" in capsys.readouterr().err
    summary = tmp_path / "s.json"
    assert main(["simulate", "--kinematic", "--estop-time", "3.1", "--objective", "time", "--summary",
                 str(summary)]) == 0
    plan = plan_stop(NominalPattern(), 3.1, TIME)
    assert json.loads(summary.read_text())["phase_times"]["halt_end"] == pytest.approx(plan.halt_end, abs=1e-12)
    assert plan.halt_end < plan_stop(NominalPattern(), 3.1).halt_end


def test_scenario_objective_field(capsys):
    assert load_scenario(text="{stop: {objective: time}}").stop.objective == "time"
    with pytest.raises(ValueError, match="objective"):
        load_scenario(text="{stop: {objective: quick}}")
    assert main(["simulate", "--kinematic", "--scenario-text", "{stop: {objective: quick}}"]) == 2
    assert "objective" in capsys.readouterr().err


def _check_replan(plan, new, t, com, vel):
    assert new.start_time == pytest.approx(t)
    start = np.array([traj.evaluate_at(t)[3] for traj in (new.x, new.y)])
    before = np.array([traj.evaluate_at(t)[3] for traj in (plan.x, plan.y)])
    if np.max(np.abs(start - before)) > 1e-9:
        # the ankle strategy (replan_stop's fallback where the plan's ZMP gives no stop): the support ZMP
        # steps to ankle_zmp's point, or one of its two components (the time objective's brake then moves
        # it on the sole; the polygon check below covers it)
        ankle = ankle_zmp(plan, t, com, vel)
        assert ankle is not None and new.landing_foot is not None
        choices = [ankle, np.array([before[0], ankle[1]]), np.array([ankle[0], before[1]])]
        assert min(np.max(np.abs(start - c)) for c in choices) < 1e-9
    else:
        for old, traj in ((plan.x, new.x), (plan.y, new.y)):
            a, b = old.evaluate_at(t), traj.evaluate_at(t)
            assert b[3] == pytest.approx(a[3], abs=1e-9)  # eq. 12: the ZMP continues
            assert b[4] == pytest.approx(a[4], abs=1e-6) and b[5] == pytest.approx(a[5], abs=1e-4)  # eq. 13
    pos, v, _, _ = new.com([t])
    np.testing.assert_allclose(pos[0], com, atol=1e-12)  # eq. 10-11: from the measured COG
    np.testing.assert_allclose(v[0], vel, atol=1e-12)
    times = _ticks(new, t, new.halt_end)
    pos, _, _, zmp = new.com(times)
    assert np.all(np.isfinite(pos)) and np.all(np.isfinite(zmp))
    assert min(float(new.polygon(s).margin(z)[0]) for s, z in zip(times, zmp)) >= TIME.zmp_margin - 1e-9
    end, rest, _, _ = new.com([new.halt_end + 1.0])
    _rest_on_the_feet_segment(new, end[0])
    np.testing.assert_allclose(rest[0], 0.0, atol=1e-9)


@pytest.mark.parametrize("signal", [2.9, 3.1, 3.3, 3.55])
def test_replan_from_a_pushed_state_is_valid_or_infeasible(pattern, signal):
    """Re-plans (online controller, after a push) of time-objective plans, in the swing (the ZMP
    moving on the support sole, then held) and after the landing: a plan continuous with the old
    one's ZMP (or, the ankle strategy, stepped to a point of the support sole and held there), from the
    measured COG, inside the polygon, at rest between the feet; or InfeasibleStop. Never a NaN."""
    plan = plan_stop(pattern, signal, TIME)
    outcomes = {"plan": 0, "infeasible": 0}
    for fraction in (0.05, 0.3, 0.6, 0.9):
        t = plan.start_time + round(fraction * (plan.slowdown_end - plan.start_time) / TIME.servo_period) * 0.005
        pos, vel, _, _ = plan.com([t])
        for push in ([0.08, 0.0], [-0.05, 0.0], [0.0, 0.08], [0.03, -0.06]):
            com, v = pos[0] + 0.1 * np.array(push), vel[0] + np.array(push)
            try:
                new = replan_stop(plan, t, com, v)
            except InfeasibleStop:
                outcomes["infeasible"] += 1
                continue
            if new is None:  # nothing left to re-plan at this tick (the last ZMP transition)
                assert not plan.landing_time <= t < plan.slowdown_end
                continue
            outcomes["plan"] += 1
            assert new.params.objective == "time"
            _check_replan(plan, new, t, com, v)
    assert outcomes["plan"] >= 6, outcomes


def test_paper_objective_is_the_default(stride_plans):
    assert StopParameters().objective == "paper"
    assert all(plan.params.objective == "paper" for plan in stride_plans)
    assert math.isfinite(stride_plans[0].cost) and stride_plans[0].newton_iterations > 0


@pytest.mark.parametrize("margin", [-0.02, math.nan])
def test_a_plan_failing_the_zmp_verification_is_never_handed_out(pattern, monkeypatch, margin):
    """The planner's own tick-by-tick ZMP check (verify_zmp) stands behind the brake's: a plan it
    rejects (outside the margin, or NaN) raises InfeasibleStop instead of being returned."""
    from drake_estop.planning import assembly

    monkeypatch.setattr(assembly, "verify_zmp", lambda plan, final_polygon=None: margin)
    for signal in (3.1, 3.55):
        with pytest.raises(InfeasibleStop):
            plan_stop(pattern, signal, TIME)


def _backward_speed(plan):
    """The largest COG speed backwards along the walk (negative x velocity) [m/s] at the servo ticks from
    the plan start to the rest."""
    _, vel, _, _ = plan.com(_ticks(plan, plan.start_time, plan.halt_end))
    return max(0.0, float(-vel[:, 0].min()))


def test_the_cog_never_backs_up(time_plans):
    """A time-optimal LIPM stop holds the ZMP ahead of the COG until it rests (orbital energy): coming
    back is lost time. At every tick of the stride, single and double support, no backward speed above
    5 mm/s: where the COG cannot stop on the midpoint without passing it (late in the swing, in double
    support at 0.4-0.55 m/s) it rests further on, between the feet."""
    backward = {round(plan.signal_time, 3): _backward_speed(plan) for plan in time_plans}
    assert len(backward) == 160
    assert max(backward.values()) <= 5e-3, {t: b for t, b in backward.items() if b > 5e-3}


def test_late_in_the_swing_the_step_reaches_rest_without_coming_back(pattern):
    """3.39 s: the swing foot lands 0.1 s later; the brake starts on the support sole and the COG comes
    to rest at the midpoint from behind."""
    plan = plan_stop(pattern, 3.39, TIME)
    midpoint = 0.5 * (plan.final_feet["left"] + plan.final_feet["right"])
    pos, _, _, _ = plan.com(_ticks(plan, plan.start_time, plan.halt_end))
    assert _backward_speed(plan) <= 5e-3
    assert pos[:, 0].max() <= midpoint[0] + 1e-6
    assert plan.halt_end - plan.signal_time <= 0.35


def test_forward_stop_possible_is_the_orbital_energy_condition():
    """With the ZMP held at the polygon's front P the COG stops at P - sqrt((P - x)^2 - v^2 / w^2)."""
    from drake_estop.planning.brake import forward_stop_possible
    from drake_estop.planning.geometry import SupportPolygon

    w, front, midpoint = 3.5, 0.3, np.array([0.1, 0.0])
    polygon = SupportPolygon([[-0.2, -0.1], [front, -0.1], [front, 0.1], [-0.2, 0.1]])
    x = 0.0
    reach = w * math.sqrt((front - x) ** 2 - (front - midpoint[0]) ** 2)  # the speed that stops exactly there
    assert forward_stop_possible([x, 0.0], [0.99 * reach, 0.0], midpoint, polygon, w)
    assert not forward_stop_possible([x, 0.0], [1.01 * reach, 0.0], midpoint, polygon, w)
    assert not forward_stop_possible([0.15, 0.0], [0.0, 0.0], midpoint, polygon, w)  # already past it
    assert not forward_stop_possible([x, 0.0], [-0.1, 0.0], midpoint, polygon, w)  # moving backwards


def _wide_polygon(front):
    from drake_estop.planning.geometry import SupportPolygon

    return SupportPolygon([[-2.0, -1.0], [front, -1.0], [front, 1.0], [-2.0, 1.0]])


def test_lipm_rest_bound_is_zero_at_rest_on_the_midpoint():
    from scripts import load_script

    bench = load_script("benchmarks/bench_planner.py")
    midpoint = np.array([0.3, 0.05])
    assert bench.lipm_rest_bound(midpoint, [0.0, 0.0], midpoint, midpoint, lambda k: _wide_polygon(1.0), 3.5, 0.005,
                                 0.01) == 0.0


@pytest.mark.parametrize("monotone", [False, True])
def test_lipm_rest_bound_matches_the_bang_bang_stop(monotone):
    """The ZMP held at the front limit P brakes hardest (the COG's response to the ZMP is monotone, eq.
    6-9), so from x0 = P - (P - m) cosh(w T), v0 = w (P - m) sinh(w T) the LIPM rests at m at T at the
    soonest (with no ZMP rate limit; T a whole number of ticks, so the held ZMP is a zero-order hold):
    the LP's least time is T, without backing up too."""
    from scripts import load_script

    bench = load_script("benchmarks/bench_planner.py")
    w, dt, margin, front_limit, rest_time = 3.47, 0.005, 0.01, 0.1, 0.2
    x0 = front_limit - front_limit * math.cosh(w * rest_time)
    v0 = w * front_limit * math.sinh(w * rest_time)
    bound = bench.lipm_rest_bound([x0, 0.0], [v0, 0.0], [front_limit, 0.0], [0.0, 0.0],
                                  lambda k: _wide_polygon(front_limit + margin), w, dt, margin, max_zmp_rate=1e6,
                                  monotone=monotone)
    assert bound == pytest.approx(rest_time)


def test_forward_stop_possible_counts_the_zmp_transition_to_the_front():
    """The ZMP gets to the front P by a transition of at least ``ramp`` (eq. 12-14), braking less on the
    way: a speed that the held ZMP would stop in time is too fast once the transition comes first, and
    ``ramp = 0`` is the orbital-energy condition alone."""
    from drake_estop.planning.brake import forward_stop_possible
    from drake_estop.planning.geometry import SupportPolygon

    w, front, rest = 3.5, 0.3, np.array([0.1, 0.0])
    polygon = SupportPolygon([[-0.2, -0.1], [front, -0.1], [front, 0.1], [-0.2, 0.1]])
    speed = 0.95 * w * math.sqrt(front**2 - (front - rest[0]) ** 2)
    assert forward_stop_possible([0.0, 0.0], [speed, 0.0], rest, polygon, w, [0.0, 0.0], 0.0)
    assert not forward_stop_possible([0.0, 0.0], [speed, 0.0], rest, polygon, w, [0.0, 0.0], 0.1)
    slow = 0.5 * speed
    assert forward_stop_possible([0.0, 0.0], [slow, 0.0], rest, polygon, w, [0.0, 0.0], 0.1)
    # the required margin moves the front back
    assert not forward_stop_possible([0.0, 0.0], [speed, 0.0], rest, polygon, w, required=0.05)


def test_rest_points_run_from_the_midpoint_to_the_fore_ankle_within_the_rear_reach():
    from drake_estop.planning.brake import REST_FRACTIONS, rest_points

    rear, fore = np.array([0.0, 0.1]), np.array([0.3, -0.1])
    points = rest_points(rear, fore, 0.26)
    np.testing.assert_allclose(points[0], [0.15, 0.0])  # the midpoint first
    np.testing.assert_allclose(points[-1, 0], 0.26)  # the rear leg's reach ends the segment
    assert len(points) == sum(f * 0.15 + 0.15 < 0.26 for f in REST_FRACTIONS) + 1
    for point in points:  # on the segment between the ankles
        fraction = (point[0] - 0.15) / 0.15
        np.testing.assert_allclose(point, [0.15, 0.0] + fraction * np.array([0.15, -0.1]), atol=1e-12)
    assert np.all(np.diff(points[:, 0]) > 0)
    np.testing.assert_allclose(rest_points(rear, fore, 1.0)[-1], fore)  # reach to spare: up to the fore ankle
    np.testing.assert_allclose(rest_points(fore, rear, 1.0), [[0.15, 0.0]])  # "fore" behind: the midpoint alone
    np.testing.assert_allclose(rest_points(rear, fore, 0.1), [[0.15, 0.0]])  # the midpoint out of reach already


def test_lipm_rest_bound_with_a_free_rest_point_is_never_later():
    """Resting anywhere on a segment from the midpoint (one more LP variable) is at least as soon as
    resting on the midpoint, and sooner for a COG that would have to pass the midpoint and come back;
    at rest on the segment it is zero."""
    from scripts import load_script

    bench = load_script("benchmarks/bench_planner.py")
    w, dt, margin = 3.47, 0.005, 0.01
    midpoint, rest_to = np.array([0.0, 0.0]), np.array([0.1, 0.0])
    polygon = lambda k: _wide_polygon(0.3)  # noqa: E731
    state = ([0.0, 0.0], [0.4, 0.0], [0.0, 0.0])  # at the midpoint, moving on at 0.4 m/s
    fixed = bench.lipm_rest_bound(*state, midpoint, polygon, w, dt, margin)
    free = bench.lipm_rest_bound(*state, midpoint, polygon, w, dt, margin, rest_to=rest_to)
    assert free < fixed - 0.02, (free, fixed)
    assert math.isinf(bench.lipm_rest_bound(*state, midpoint, polygon, w, dt, margin, monotone=True))
    assert math.isfinite(bench.lipm_rest_bound(*state, midpoint, polygon, w, dt, margin, monotone=True,
                                               rest_to=rest_to))
    on = np.array([0.05, 0.0])
    assert bench.lipm_rest_bound(on, [0.0, 0.0], on, midpoint, polygon, w, dt, margin, rest_to=rest_to) == \
        pytest.approx(dt, abs=dt)
