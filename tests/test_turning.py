"""Stops of turning and side-stepping walks and of random footstep lists.

The stride-wide checks of the straight walk (tests/test_planner.py), repeated on turning gaits
of +-15 deg per step and on side-stepping: LIPM residual, continuity, the ZMP inside the
support polygon of the *turned* soles at every tick, rest at the turned feet's midpoint, and
one step wherever a generic solver finds a one-step stop. The support polygon is rebuilt here
from the sole rectangle, the feet and their headings, independently of the planner's own.
"""

import math

import numpy as np
import pytest
from checks import independent_polygon, lipm_tracking_error, plan_lipm_error
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from reference import reference_solve

from drake_estop.planning import assembly
from drake_estop.planning.assembly import stop_problem
from drake_estop.planning.gait import (
    MAX_TURN_DEG,
    Footstep,
    GaitParameters,
    NominalPattern,
    check_footsteps,
    footstep_list,
    load_footsteps,
)
from drake_estop.planning.heading import FramedPattern, HeadingFrame, stop_heading
from drake_estop.planning.lipm import LipmTrajectory
from drake_estop.planning.planner import InfeasibleStop, StopParameters, one_step_feasible, plan_stop
from drake_estop.planning.rollout import rollout, stride_ticks

GAITS = {
    "turn-left-15": GaitParameters(turn=15.0),
    "turn-right-15": GaitParameters(turn=-15.0),
    "side-step-left": GaitParameters(step_length=0.0, side_step=0.04),
    "side-step-right-forward": GaitParameters(step_length=0.15, side_step=-0.04),
}
PARAMS = StopParameters()


@pytest.fixture(scope="module", params=list(GAITS))
def gait_plans(request):
    pattern = NominalPattern(GAITS[request.param])
    return request.param, pattern, [plan_stop(pattern, t, PARAMS) for t in stride_ticks(pattern, PARAMS)]


def _ticks(plan, start, end):
    dt = plan.params.servo_period
    return start + dt * np.arange(int(round((end - start) / dt)) + 1)


def test_the_gaits_really_turn_and_side_step(gait_plans):
    name, pattern, plans = gait_plans
    ends = [step["end"] for step in pattern.steps]
    yaws = [step["end_yaw"] for step in pattern.steps]
    if name.startswith("turn"):
        assert abs(yaws[-1]) == pytest.approx(math.radians(15.0) * (len(yaws) - 1), abs=1e-9)
        assert {plan.support for plan in plans} == {"single", "double"}
        assert any(abs(plan.heading) > 0.5 for plan in plans)  # solved in a turned frame
    else:
        mid = 0.5 * (pattern.final_feet["left"] + pattern.final_feet["right"])
        # the body moved sideways: side_step per stride (the leading foot out, the trailing one in)
        assert abs(mid[1]) == pytest.approx(0.04 * (len(ends) // 2), abs=1e-9)


def test_zmp_inside_the_turned_support_polygon_every_tick(gait_plans):
    name, _, plans = gait_plans
    for plan in plans:
        assert plan.min_zmp_margin >= PARAMS.zmp_margin - 1e-9, (name, plan.signal_time)
        for t in _ticks(plan, plan.start_time, plan.halt_end + 0.3)[::2]:
            zmp = plan.com([t])[3]
            assert independent_polygon(plan, t).margin(zmp)[0] >= PARAMS.zmp_margin - 1e-9, (name, plan.signal_time, t)


def test_rest_at_the_turned_feet_midpoint(gait_plans):
    name, pattern, plans = gait_plans
    for plan in plans:
        mid = 0.5 * (plan.final_feet["left"] + plan.final_feet["right"])
        pos, vel, _, zmp = plan.com([plan.halt_end, plan.halt_end + 2.0])
        np.testing.assert_allclose(pos, [mid, mid], atol=1e-6, err_msg=f"{name} {plan.signal_time}")
        np.testing.assert_allclose(zmp, [mid, mid], atol=1e-6)
        assert np.abs(vel).max() < 1e-6
        if plan.landing_foot is not None:  # the landing foot keeps its nominal heading
            step = pattern.steps[plan.start_state.step_index]
            assert plan.final_yaw[plan.landing_foot] == pytest.approx(step["end_yaw"], abs=1e-12)


def test_continuity_at_the_signal_and_the_phase_boundaries(gait_plans):
    name, _, plans = gait_plans
    eps = 1e-7
    for plan in plans:
        for b in (plan.start_time, plan.landing_time, plan.transition_end, plan.slowdown_end, plan.halt_end):
            before, after = plan.com([b - eps]), plan.com([b + eps])
            for k in range(4):
                assert np.abs(before[k] - after[k]).max() < 1e-4, (name, plan.signal_time, b, k)
        # the feet and their headings too
        t = plan.start_time
        for side in ("left", "right"):
            np.testing.assert_allclose(plan.feet(t - eps)[side], plan.feet(t + eps)[side], atol=1e-5)
            assert plan.feet_yaw(t - eps)[0][side] == pytest.approx(plan.feet_yaw(t + eps)[0][side], abs=1e-5)


def test_lipm_residual_by_independent_integration(gait_plans):
    name, pattern, plans = gait_plans
    for plan in plans[::10]:
        assert plan_lipm_error(plan, after_halt=0.5) < 1e-3, (name, plan.signal_time)


def test_one_step_wherever_a_generic_solver_finds_one(gait_plans):
    """Every fallback (III.C) comes from a state where the SLSQP reference solver, on the same
    problem in the stop's heading frame, finds no one-step parameters either, or, at most twice a
    stride, where the phase parameters exist but no halt keeps the ZMP ``zmp_margin`` inside the
    turned soles (a limit the reference does not model: +15 deg at 2.925 s, short of it by 0.1 mm)."""
    name, pattern, plans = gait_plans
    fallbacks = [plan for plan in plans if plan.case != "one-step"]
    assert len(fallbacks) <= 0.15 * len(plans), name  # measured: 1 of 160 at +15 deg (outer foot), 6 at -15
    halts = 0
    for plan in fallbacks[::3]:
        state = pattern.state(plan.signal_time)
        frame = HeadingFrame(stop_heading(state))
        problem, kind, _ = stop_problem(FramedPattern(pattern, frame), frame.state(state), PARAMS)
        if reference_solve(problem, kind, margin=0.005) is not None:
            with pytest.raises(InfeasibleStop, match="zmp_margin"):
                assembly.plan_from(pattern, state, PARAMS, plan.signal_time, "one-step")
            halts += 1
    assert halts <= 2, name


def test_one_step_feasible_agrees_with_the_planner_on_turning_walks(gait_plans):
    name, pattern, plans = gait_plans
    for plan in plans:
        feasible = one_step_feasible(pattern, plan.signal_time, PARAMS)
        assert feasible == (plan.case == "one-step"), (name, plan.signal_time)


def test_turning_stops_keep_the_straight_walks_one_step_share():
    """Measured: 104 and 109 of 160 ticks one-step at +15 / -15 deg (straight: 128); the fallbacks are
    the outer foot's longer swing (max_swing_speed) and its shorter reach (_lateral_reach)."""
    for turn in (15.0, -15.0):
        pattern = NominalPattern(GaitParameters(turn=turn))
        plans = [plan_stop(pattern, t, PARAMS) for t in stride_ticks(pattern, PARAMS)[::4]]
        assert sum(plan.case == "one-step" for plan in plans) >= 0.6 * len(plans)


def test_a_rotated_lipm_chain_is_the_rotated_motion():
    x = LipmTrajectory.from_zmp(0.0, [0.3, 0.5, 1.0], [[0.1], [0.2, 0.1, -0.05], [0.2]], 0.0, 0.3, 3.5)
    y = LipmTrajectory.from_zmp(0.0, [0.3, 0.5, 1.0], [[0.05], [-0.1, 0.2], [0.0]], 0.02, -0.1, 3.5)
    xr, yr = LipmTrajectory.rotated(x, y, 0.4)
    times = np.linspace(-0.1, 2.0, 50)
    c, s = math.cos(0.4), math.sin(0.4)
    for a, b, ar, br in zip(x.evaluate(times), y.evaluate(times), xr.evaluate(times), yr.evaluate(times)):
        np.testing.assert_allclose(ar, c * a - s * b, atol=1e-12)
        np.testing.assert_allclose(br, s * a + c * b, atol=1e-12)
    other = LipmTrajectory.from_zmp(0.0, [0.3, 1.0], [[0.1], [0.1]], 0.1, 0.0, 3.5)
    with pytest.raises(ValueError, match="breakpoints"):
        LipmTrajectory.rotated(x, other, 0.1)


# -- random footstep lists ------------------------------------------------------------------

@st.composite
def footstep_lists(draw):
    """3 to 6 steps: each advances, side-steps and turns the body frame by random amounts and lands
    the swing foot beside it; lists whose soles cross or overlap are discarded."""
    width = draw(st.floats(0.17, 0.26))
    x = y = heading = 0.0
    steps, swing = [], draw(st.sampled_from(("left", "right")))
    count = draw(st.integers(3, 6))
    for k in range(count):
        if k < count - 1:
            turn = math.radians(draw(st.floats(-20.0, 20.0)))
            length, side = draw(st.floats(0.0, 0.28)), draw(st.floats(-0.03, 0.03))
            chord = heading + 0.5 * turn
            x += length * math.cos(chord) - side * math.sin(chord)
            y += length * math.sin(chord) + side * math.cos(chord)
            heading += turn
        offset = width / 2 if swing == "left" else -width / 2
        duration = draw(st.one_of(st.just(math.nan), st.floats(0.7, 1.1)))
        steps.append(Footstep(swing, x - offset * math.sin(heading), y + offset * math.cos(heading), heading,
                              duration))
        swing = "left" if swing == "right" else "right"
    try:
        return GaitParameters(step_width=width, footsteps=tuple(steps))
    except ValueError:
        from hypothesis import reject

        reject()


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
@given(gait=footstep_lists(), fraction=st.floats(0.0, 1.0))
def test_random_footstep_lists_stop_within_the_turned_polygon(gait, fraction):
    pattern = NominalPattern(gait)
    first, last = pattern.steps[0]["liftoff"], pattern.steps[-1]["touchdown"]
    signal = first + fraction * (last - first)
    try:
        plan = plan_stop(pattern, signal, PARAMS)
    except InfeasibleStop as error:  # must name a limit, never be a crash
        assert "no feasible stop" in str(error)
        return
    times = _ticks(plan, plan.signal_time, plan.halt_end + 0.5)
    pos, vel, acc, zmp = plan.com(times)
    assert all(np.all(np.isfinite(a)) for a in (pos, vel, acc, zmp))
    assert np.abs(plan.com([plan.halt_end + 0.5])[1]).max() < 1e-6
    if plan.case in ("one-step", "next-step"):
        for t in times[::3]:
            assert independent_polygon(plan, t).margin(plan.com([t])[3])[0] >= PARAMS.zmp_margin - 1e-9, t
        mid = 0.5 * (plan.final_feet["left"] + plan.final_feet["right"])
        np.testing.assert_allclose(plan.com([plan.halt_end + 0.5])[0][0], mid, atol=1e-6)
    data = rollout(plan, after_halt=0.3)
    sel = data.times >= plan.signal_time
    for axis in (0, 1):
        assert lipm_tracking_error(data.times[sel], data.com[sel, axis], data.com_vel[sel, axis],
                                   data.zmp[sel, axis], pattern.w) < 1e-3


# -- footsteps: generation and bad input ------------------------------------------------------

def test_the_straight_walk_is_the_generated_footsteps_without_turn():
    steps = footstep_list(GaitParameters())
    assert [s.x for s in steps] == [0.3, 0.6, 0.8999999999999999, 1.2, 1.5, 1.7999999999999998, 2.1, 2.1]
    assert all(s.yaw == 0.0 for s in steps) and [s.side for s in steps[:2]] == ["right", "left"]


@pytest.mark.parametrize("kwargs, field", [
    (dict(turn=MAX_TURN_DEG + 1), "turn"),
    (dict(turn=math.nan), "turn"),
    (dict(side_step=math.inf), "side_step"),
    (dict(step_length=0.0, step_width=0.12, turn=30.0), "overlap at step 1"),
    (dict(footsteps=(Footstep("right", 0.3, -0.1), Footstep("right", 0.6, -0.1))), "alternate"),
    (dict(footsteps=(Footstep("right", 0.3, math.nan), Footstep("left", 0.6, 0.1))), "footsteps[0].y"),
    (dict(footsteps=(Footstep("right", 0.3, 0.3), Footstep("left", 0.6, 0.1))), "cross"),
    (dict(footsteps=(Footstep("right", 0.05, 0.0), Footstep("left", 0.3, 0.1))), "overlap"),
    (dict(footsteps=(Footstep("right", 0.3, -0.1, 0.7), Footstep("left", 0.6, 0.1, 0.7))), "limit"),
    (dict(footsteps=(Footstep("up", 0.3, -0.1), Footstep("left", 0.6, 0.1))), "footsteps[0].side"),
    (dict(footsteps=(Footstep("right", 0.3, -0.1, 0.0, -1.0), Footstep("left", 0.6, 0.1))), "duration"),
])
def test_bad_footsteps_name_the_field(kwargs, field):
    with pytest.raises(ValueError, match=field.replace("[", r"\[").replace("]", r"\]")):
        GaitParameters(**kwargs)


def test_crossing_feet_are_rejected_even_when_the_soles_do_not_touch():
    gait = GaitParameters.__new__(GaitParameters)  # bypass __post_init__ to reach the check directly
    object.__setattr__(gait, "footsteps", (Footstep("right", 0.0, 0.4), Footstep("left", 0.3, 0.6)))
    for name in ("step_width", "sole", "num_steps"):
        object.__setattr__(gait, name, getattr(GaitParameters(), name))
    with pytest.raises(ValueError, match="cross"):
        check_footsteps(gait)


def test_a_footstep_file_round_trip_and_its_errors(tmp_path):
    good = tmp_path / "good.csv"
    good.write_text("side,x,y,yaw,duration\nright,0.25,-0.095,0.0,\nleft,0.5,0.11,0.2,0.9\nright,0.5,-0.08,0.2,\n")
    steps = load_footsteps(good)
    assert steps[1] == Footstep("left", 0.5, 0.11, 0.2, 0.9) and math.isnan(steps[0].duration)
    pattern = NominalPattern(GaitParameters(footsteps=steps))
    assert pattern.steps[1]["step_end"] - pattern.steps[1]["liftoff"] == pytest.approx(0.9)
    for text, message in (("side,x,y\nright,0.2,-0.1\n", "missing column"),
                          ("side,x,y,yaw\nright,0.2,nan,0\nleft,0.3,0.1,0\n", "row 1"),
                          ("side,x,y,yaw\nright,0.2,abc,0\nleft,0.3,0.1,0\n", "must be a number"),
                          ("side,x,y,yaw\n", "no rows")):
        bad = tmp_path / "bad.csv"
        bad.write_text(text)
        with pytest.raises(ValueError, match=message):
            load_footsteps(bad)


# -- the command line, the scenario file and the Drake diagram ------------------------------------

def test_simulate_turning_writes_yaw_columns_and_turned_final_feet(tmp_path):
    import csv
    import json

    from drake_estop.cli import main

    log, summary = tmp_path / "log.csv", tmp_path / "summary.json"
    assert main(["simulate", "--kinematic", "--turn", "15", "--estop-time", "3.3", "--log", str(log),
                 "--summary", str(summary)]) == 0
    data = json.loads(summary.read_text())
    pattern = NominalPattern(GaitParameters(turn=15.0))
    plan = plan_stop(pattern, 3.3)
    for side in ("left", "right"):
        assert data["final_feet"][side] == pytest.approx([*plan.final_feet[side], plan.final_yaw[side]], abs=1e-12)
    # the landing foot keeps the 3rd step's heading
    assert data["final_feet"]["right"][2] == pytest.approx(math.radians(45.0))
    rows = list(csv.DictReader(log.open()))
    yaw = {side: np.array([float(r[f"{side}_yaw"]) for r in rows]) for side in ("left", "right")}
    assert yaw["left"][0] == 0.0 and yaw["left"][-1] == pytest.approx(plan.final_yaw["left"], abs=1e-9)
    assert yaw["right"][-1] == pytest.approx(plan.final_yaw["right"], abs=1e-9)
    assert np.abs(np.diff(yaw["right"])).max() < 0.02  # turns smoothly, no jump at the signal


def test_side_step_option_and_footsteps_file_reach_the_pattern(tmp_path):
    import json

    from drake_estop.cli import main

    summary = tmp_path / "s.json"
    assert main(["simulate", "--kinematic", "--step-length", "0", "--side-step", "0.06", "--estop-time", "3.3",
                 "--summary", str(summary)]) == 0
    feet = json.loads(summary.read_text())["final_feet"]
    assert 0.5 * (feet["left"][1] + feet["right"][1]) > 0.05  # it walked to the left
    steps = tmp_path / "steps.csv"
    steps.write_text("side,x,y,yaw\nright,0.2,-0.1,-0.1\nleft,0.4,0.06,-0.2\nright,0.45,-0.13,-0.2\n")
    assert main(["simulate", "--kinematic", "--footsteps", str(steps), "--estop-time", "2.0",
                 "--summary", str(summary)]) == 0
    feet = json.loads(summary.read_text())["final_feet"]
    # the signal in the double support after the first step: the right foot has landed turned by -0.1 rad
    assert feet["left"][2] == 0.0 and feet["right"][2] == pytest.approx(-0.1)
    assert feet["right"][:2] == pytest.approx([0.2, -0.1])


@pytest.mark.parametrize("content, named", [
    ("side,x,y\nright,0.2,-0.1\n", "missing column"),
    ("side,x,y,yaw\nright,0.2,nan,0\nleft,0.4,0.1,0\n", "must be finite"),
    ("side,x,y,yaw\nright,0.05,0.0,0\nleft,0.3,0.1,0\n", "overlap"),
    ("side,x,y,yaw\nright,0.0,0.4,0\nleft,0.3,0.6,0\n", "cross"),
    ("side,x,y,yaw\nright,0.3,-0.1,0.7\nleft,0.6,0.1,0.7\n", "limit"),
])
def test_bad_footstep_files_exit_2_naming_the_problem(tmp_path, capsys, content, named):
    from drake_estop.cli import main

    path = tmp_path / "steps.csv"
    path.write_text(content)
    assert main(["simulate", "--kinematic", "--footsteps", str(path)]) == 2
    err = capsys.readouterr().err
    assert "footsteps" in err and named in err


@pytest.mark.parametrize("args, named", [(["--turn", "31"], "--turn"), (["--turn", "nan"], "--turn"),
                                         (["--side-step", "inf"], "--side-step"),
                                         (["--footsteps", "/nonexistent/steps.csv"], "footsteps")])
def test_bad_turn_and_side_step_exit_2(capsys, args, named):
    from drake_estop.cli import main

    with pytest.raises(SystemExit) as raised:  # argparse rejects bad option values with status 2
        code = main(["simulate", "--kinematic", *args])
        raise SystemExit(code)
    assert raised.value.code == 2 and named in capsys.readouterr().err


def test_a_scenario_file_carries_the_footsteps():
    from drake_estop.scenario import Scenario, dump_scenario, load_scenario

    steps = (Footstep("right", 0.25, -0.1, -0.1), Footstep("left", 0.5, 0.07, -0.2, 0.9))
    scenario = Scenario(gait=GaitParameters(turn=0.0, footsteps=steps))
    back = load_scenario(text=dump_scenario(scenario))
    assert back.gait.footsteps[1] == steps[1]
    assert back.gait.footsteps[0].side == "right" and math.isnan(back.gait.footsteps[0].duration)
    turned = load_scenario(text="{gait: {turn: -10.0, side_step: 0.02}}")
    assert turned.gait.turn == -10.0 and turned.gait.side_step == 0.02
    with pytest.raises(ValueError, match="turn"):
        load_scenario(text="{gait: {turn: 45.0}}")


def test_the_whole_body_ik_follows_the_turned_feet():
    """The Drake diagram (planner, IK, humanoid) on a +15 deg/step walk stopped in single support:
    the soles reach their turned poses (position and heading) at every tick."""
    from drake_estop.systems.diagram import simulate_diagram

    result = simulate_diagram(gait_params=GaitParameters(turn=15.0), stop_params=PARAMS, estop_time=3.6)
    assert result.ik_failures == {"com": 0, "foot_position": 0, "foot_rotation": 0}
    assert result.ik_foot_rot_err.max() < 1e-3  # [rad]
    assert result.velocity_limit_violations.sum() == 0
    # a double-support stop: both feet stay where they are, turned by 30 and 45 deg
    assert result.plan.support == "double"
    assert result.plan.final_yaw == pytest.approx({"left": math.radians(30.0), "right": math.radians(45.0)})


def test_the_outer_foot_lands_with_a_bent_knee():
    """A single-support stop of a +15 deg/step walk lands the outer (right) foot: with the straight
    walk's fore reach its knee reached 14 rad/s in the IK (limit 6, 28 ticks over); the planner
    shortens the reach by the extra lateral offset (landing.lateral_reach)."""
    from drake_estop.systems.diagram import simulate_diagram

    result = simulate_diagram(gait_params=GaitParameters(turn=15.0), stop_params=PARAMS, estop_time=3.175)
    assert result.plan.case == "one-step" and result.plan.landing_foot == "right"
    assert result.velocity_limit_violations.sum() == 0


@pytest.mark.slow
def test_the_online_controller_stops_a_turning_walk_in_physics():
    """Physics (SAP plant, contact) under the online controller on a +10 deg/step walk, stopped in
    single support: every success criterion, CoP inside the *turned* planned soles included, and no
    joint over its velocity limit."""
    from drake_estop.physics.online import run_online

    gait = GaitParameters(turn=10.0)
    result = run_online(gait_params=gait, estop_time=3.3, pattern=NominalPattern(gait), after_halt=2.5)
    assert result.plan.heading != 0.0 and result.plan.landing_foot is not None
    assert result.success, result.criteria
    assert result.online["joint_velocity_violations"] == 0


def test_touchdown_com_offset_is_the_step_less_the_cog_at_touchdown_and_turns_with_the_frame():
    """The lateral-reach rule's per-step lookup: computed once per step, and a vector (turned, not moved)
    in a heading frame."""
    from drake_estop.planning.heading import FramedPattern, HeadingFrame

    pattern = NominalPattern(GaitParameters(turn=15.0))
    for index, step in enumerate(pattern.steps):
        expected = np.asarray(step["end"], float)[:2] - pattern.com([step["touchdown"]])[0][0]
        assert np.allclose(pattern.touchdown_com_offset(index), expected, atol=1e-12)
    assert pattern.touchdown_com_offset(2) is pattern.touchdown_com_offset(2)  # cached
    framed = FramedPattern(pattern, HeadingFrame(math.radians(30.0)))
    step = framed.steps[2]
    assert np.allclose(framed.touchdown_com_offset(2),
                       np.asarray(step["end"], float)[:2] - framed.com([step["touchdown"]])[0][0], atol=1e-12)
