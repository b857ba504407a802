"""Side-stepping walks: the leading foot widens the stance by ``side_step``, the trailing one closes it.

A lateral walk never narrows its stance below ``step_width`` (an 8 cm side step with a narrowing
trailing foot would put the soles 0.11 m apart at the ankles, edge to edge). The stop must end at
rest inside the support polygon from any tick of such a walk, and a footstep list whose soles
really overlap is still rejected, naming the step.
"""

import json
import math

import numpy as np
import pytest
from checks import independent_polygon

from drake_estop.planning.gait import Footstep, GaitParameters, NominalPattern, footstep_list, initial_stance
from drake_estop.planning.planner import StopParameters, plan_stop
from drake_estop.planning.rollout import stride_ticks

PARAMS = StopParameters()
SIDE_STEPS = [dict(side_step=0.08, step_length=0.1), dict(side_step=0.10, step_length=0.0),
              dict(side_step=-0.10, step_length=0.0), dict(side_step=0.10, step_length=0.1),
              dict(side_step=-0.10, step_length=0.1)]


def stance_after_each_step(gait: GaitParameters):
    """(left, right) ankle xy after each footstep of ``gait``, from the standing stance."""
    feet = {side: np.array(xy, float) for side, xy in initial_stance(gait).items()}
    stances = []
    for step in footstep_list(gait):
        feet[step.side] = np.array([step.x, step.y])
        stances.append((feet["left"].copy(), feet["right"].copy()))
    return stances


@pytest.mark.parametrize("kwargs", SIDE_STEPS, ids=lambda kw: f"{kw['side_step']:+.2f}/{kw['step_length']}")
def test_the_leading_foot_widens_the_stance_and_the_trailing_one_closes_it(kwargs):
    gait = GaitParameters(**kwargs)
    side_step, width = gait.side_step, gait.step_width
    steps = footstep_list(gait)
    leading = "left" if side_step > 0 else "right"
    assert steps[0].side == leading  # the first step is out, towards the travel
    widths = [left[1] - right[1] for left, right in stance_after_each_step(gait)]
    assert min(widths) >= width - 1e-12  # never narrower than standing
    expected = [width + abs(side_step) if k % 2 == 0 else width for k in range(len(steps) - 1)] + [width]
    np.testing.assert_allclose(widths, expected, atol=1e-12)
    previous = {side: np.array(xy) for side, xy in initial_stance(gait).items()}
    for k, step in enumerate(steps[:-1]):  # each foot moves side_step sideways, step_length forward
        assert step.y - previous[step.side][1] == pytest.approx(side_step, abs=1e-12)
        assert step.x == pytest.approx((k + 1) * gait.step_length, abs=1e-12)
        previous[step.side] = np.array([step.x, step.y])
    # the body moves side_step per stride: num_steps 8 is 4 strides
    final = 0.5 * (np.array([steps[-1].x, steps[-1].y]) + np.array([steps[-2].x, steps[-2].y]))
    assert final[1] == pytest.approx(side_step * (len(steps) // 2), abs=1e-12)


def test_a_side_step_to_the_right_is_the_mirror_of_one_to_the_left():
    for length, turn in ((0.0, 0.0), (0.1, 0.0), (0.1, 15.0)):
        left = footstep_list(GaitParameters(side_step=0.10, step_length=length, turn=turn))
        right = footstep_list(GaitParameters(side_step=-0.10, step_length=length, turn=-turn))
        for a, b in zip(left, right):
            assert {a.side, b.side} == {"left", "right"}
            assert (a.x, a.y, a.yaw) == pytest.approx((b.x, -b.y, -b.yaw), abs=1e-12)


def test_an_odd_walk_ends_with_the_leading_foot_beside_the_trailing_one():
    stances = stance_after_each_step(GaitParameters(side_step=0.1, step_length=0.0, num_steps=5))
    widths = [left[1] - right[1] for left, right in stances]
    np.testing.assert_allclose(widths, [0.29, 0.19, 0.29, 0.19, 0.19], atol=1e-12)


def stance_widths_in_the_landing_frame(gait: GaitParameters):
    """Left ankle less right ankle, across the heading of the foot that just landed, after each step [m]."""
    widths = []
    for step, (left, right) in zip(footstep_list(gait), stance_after_each_step(gait)):
        widths.append(float((left - right) @ np.array([-math.sin(step.yaw), math.cos(step.yaw)])))
    return np.array(widths)


@pytest.mark.parametrize("turn", [15.0, -15.0])
@pytest.mark.parametrize("side_step", [0.10, -0.10])
def test_side_steps_combine_with_turning(turn, side_step):
    gait = GaitParameters(side_step=side_step, step_length=0.1, turn=turn)  # raises if the soles touch
    steps = footstep_list(gait)
    assert steps[0].side == ("left" if side_step > 0 else "right")
    assert steps[-1].yaw == pytest.approx(math.radians(turn) * (len(steps) - 1), abs=1e-12)
    widths = stance_widths_in_the_landing_frame(gait)
    turning = stance_widths_in_the_landing_frame(GaitParameters(step_length=0.1, turn=turn))
    # the leading foot's steps are wider than the turn's own by most of the side step ...
    assert np.all(widths[0:-1:2] - turning[0:-1:2] > 0.5 * abs(side_step))
    # ... and the trailing foot closes to the turn's own stance, within 2 mm (the side step's chord)
    assert widths[1::2].min() >= turning.min() - 0.002
    assert widths[-1] == pytest.approx(gait.step_width, abs=1e-12)


def test_turning_alone_keeps_its_footsteps_to_the_bit():
    """The generated turning walk without a side step (values pinned from the arc-chord rule)."""
    steps = footstep_list(GaitParameters(turn=15.0))
    assert [(s.side, s.x, s.y, s.yaw) for s in steps] == [
        ("right", 0.32202126769688255, -0.05260509583144603, 0.2617993877991494),
        ("left", 0.5270973181655291, 0.23623530073506407, 0.5235987755982988),
        ("right", 0.8797784644656216, 0.26941617186543654, 0.7853981633974483),
        ("left", 0.9129593355959942, 0.622097318165529, 1.0471975511965976),
        ("right", 1.2017997321625042, 0.8271733686341757, 1.308996938995747),
        ("left", 1.0541946363310581, 1.1491946363310581, 1.5707963267948963),
        ("right", 1.2017997321625042, 1.4712159040279407, 1.8325957145940457),
        ("left", 1.0182738251675811, 1.422040285458462, 1.8325957145940457)]
    steps = footstep_list(GaitParameters(turn=-10.0, step_length=0.2, num_steps=5))
    assert [(s.side, s.x, s.y, s.yaw) for s in steps] == [
        ("right", 0.18274236273999075, -0.11098788508569139, -0.17453292519943295),
        ("left", 0.4249160184921013, 0.020075841404625525, -0.3490658503988659),
        ("right", 0.5261856622834928, -0.23599102327769736, -0.5235987755982988),
        ("left", 0.7985808940615123, -0.19565967509208199, -0.6981317007977318),
        ("right", 0.67645124822107, -0.3412081192846878, -0.6981317007977318)]


# -- soles that really overlap ------------------------------------------------------------------

def test_overlapping_soles_are_still_rejected_naming_the_step():
    # turning on the spot at 30 deg per step with the ankles 12 cm apart: the toes meet
    with pytest.raises(ValueError, match=r"step_width / side_step / turn: the soles overlap at step 1"):
        GaitParameters(step_length=0.0, step_width=0.12, turn=30.0)
    overlapping = (Footstep("left", 0.1, 0.095), Footstep("right", 0.1, 0.0), Footstep("left", 0.2, 0.1))
    with pytest.raises(ValueError, match=r"footsteps: the soles overlap at footsteps\[1\]"):
        GaitParameters(footsteps=overlapping)


def test_the_command_line_exits_2_naming_the_overlapping_step(capsys, tmp_path):
    from drake_estop.cli import main

    assert main(["simulate", "--kinematic", "--step-length", "0", "--step-width", "0.12", "--turn", "30"]) == 2
    assert "the soles overlap at step 1" in capsys.readouterr().err
    path = tmp_path / "steps.csv"
    path.write_text("side,x,y,yaw\nleft,0.1,0.095,0\nright,0.1,0.0,0\nleft,0.2,0.1,0\n")
    assert main(["simulate", "--kinematic", "--footsteps", str(path)]) == 2
    assert "the soles overlap at footsteps[1]" in capsys.readouterr().err


# -- the stop --------------------------------------------------------------------------------------

@pytest.mark.parametrize("kwargs", [dict(side_step=0.08, step_length=0.1), dict(side_step=0.10),
                                    dict(side_step=-0.10), dict(side_step=0.10, step_length=0.0),
                                    dict(side_step=-0.10, step_length=0.1, turn=15.0)],
                         ids=lambda kw: "/".join(f"{k}={v}" for k, v in kw.items()))
def test_stops_of_a_side_stepping_walk_end_at_rest_inside_the_polygon(kwargs):
    """Every 8th tick of the widening step's stride and of the closing one's."""
    pattern = NominalPattern(GaitParameters(**kwargs))
    ticks = np.concatenate([stride_ticks(pattern, PARAMS, 2), stride_ticks(pattern, PARAMS, 3)])[::8]
    for t in ticks:
        plan = plan_stop(pattern, t, PARAMS)
        assert plan.min_zmp_margin >= PARAMS.zmp_margin - 1e-9, t
        for s in np.arange(plan.start_time, plan.halt_end + 0.2, 0.02):
            assert independent_polygon(plan, s).margin(plan.com([s])[3])[0] >= PARAMS.zmp_margin - 1e-9, (t, s)
        mid = 0.5 * (plan.final_feet["left"] + plan.final_feet["right"])
        pos, vel = plan.com([plan.halt_end])[:2]
        np.testing.assert_allclose(pos[0], mid, atol=1e-6, err_msg=str(t))
        assert np.abs(vel).max() < 1e-6, t


@pytest.mark.parametrize("kwargs", [dict(side_step=0.08, step_length=0.1), dict(side_step=0.10, step_length=0.1),
                                    dict(side_step=-0.10, step_length=0.0)],
                         ids=lambda kw: "/".join(f"{k}={v}" for k, v in kw.items()))
def test_an_ordinary_side_step_stops_in_one_step_over_the_stride(kwargs):
    """Measured: 160 of 160 ticks one-step on the widening step's stride and on the closing one's."""
    pattern = NominalPattern(GaitParameters(**kwargs))
    for step_index in (2, 3):
        plans = [plan_stop(pattern, t, PARAMS) for t in stride_ticks(pattern, PARAMS, step_index)[::4]]
        assert all(plan.case == "one-step" for plan in plans), step_index


@pytest.mark.parametrize("side_step", ["0.08", "-0.10"])
def test_simulate_side_steps_8_and_10_cm(tmp_path, side_step):
    from drake_estop.cli import main

    summary = tmp_path / "s.json"
    assert main(["simulate", "--kinematic", "--side-step", side_step, "--step-length", "0.1",
                 "--estop-time", "3.4", "--summary", str(summary)]) == 0
    feet = json.loads(summary.read_text())["final_feet"]
    assert abs(feet["left"][1] - feet["right"][1]) >= GaitParameters().step_width - 1e-9
    assert math.copysign(1.0, feet["left"][1] + feet["right"][1]) == math.copysign(1.0, float(side_step))
