"""The walk's COG corrected for the whole body's momentum: its whole-body ZMP (measured on the IK's joint
trajectory) within millimetres of the planned one, inside the G1's soles where the LIPM's walk leaves them."""

import warnings

import numpy as np
import pytest
from robot_helpers import needs_robots

from drake_estop.planning.gait import GaitParameters, NominalPattern
from drake_estop.robots import as_robot
from drake_estop.systems.diagram import build_diagram
from drake_estop.systems.whole_body_walk import corrected_walk, walk_zmp_shift, whole_body_pattern


@pytest.mark.slow
def test_the_default_walk_s_whole_body_zmp_comes_to_the_plan():
    """The default humanoid's walk: its limbs put the whole body's ZMP up to 75 mm from the plan's (the swing
    foot braking, the arms); corrected in two passes, within 10 mm (4.0 mm measured), still inside the soles,
    the IK within its bounds and the ZMP planned the same."""
    plain = walk_zmp_shift(NominalPattern())
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # the IK missing its bounds warns
        pattern = whole_body_pattern()
        corrected = walk_zmp_shift(pattern)
    assert plain.largest > 0.05
    assert corrected.largest < 0.01
    assert corrected.least_margin > 0.04
    np.testing.assert_array_equal(pattern.com(plain.times)[3], NominalPattern().com(plain.times)[3])
    # the first pass's measurement is the LIPM walk's (what bench_robots reports without rolling it again)
    first = corrected_walk().lipm_shift
    assert corrected_walk().pattern is pattern
    np.testing.assert_array_equal(first.shift, plain.shift)
    np.testing.assert_array_equal(first.margin, plain.margin)


@pytest.mark.slow
@needs_robots
def test_the_g1_walk_s_whole_body_zmp_stays_in_its_soles():
    """The G1's own walk (legs 43 % of its mass): its whole-body ZMP leaves the 0.056 m wide soles (14 mm
    behind the stance heel, 181 ticks) where its LIPM ZMP does not; corrected, it stays over 1 cm inside."""
    robot = as_robot("g1")
    walk = corrected_walk(robot)
    plain, corrected = walk.lipm_shift, walk_zmp_shift(walk.pattern, robot)
    assert plain.least_margin < -0.005
    assert corrected.least_margin > 0.01
    assert corrected.largest < 0.01 < plain.largest


@pytest.mark.parametrize("passes", [0, -1, 1.5, True])
def test_bad_passes_are_named(passes):
    with pytest.raises(ValueError, match="passes"):
        whole_body_pattern(passes=passes)


def test_a_diagram_takes_a_pattern_and_refuses_other_gait_parameters():
    pattern = NominalPattern()
    assert build_diagram(pattern=pattern).pattern is pattern
    with pytest.raises(ValueError, match="gait_params and pattern disagree"):
        build_diagram(pattern=pattern, gait_params=GaitParameters(step_length=0.2))


@pytest.mark.slow
def test_the_online_controller_walks_the_corrected_walk_when_asked():
    """``ControllerOptions(whole_body_walk=True)``: the run walks the corrected pattern (its planned COG
    before the signal is the corrected one, not the LIPM's) and the paper's 3.4 s stop meets every
    criterion; a pattern given with a correction is walked as it is, a plain one is corrected."""
    from drake_estop.physics.controller_options import ControllerOptions
    from drake_estop.physics.online import _checked_pattern, run_online

    corrected = whole_body_pattern()
    assert _checked_pattern(None, corrected, None, True) is corrected
    assert _checked_pattern(None, None, None, True) is corrected  # built once per robot and gait
    assert _checked_pattern(None, NominalPattern(), None, True).com_correction is not None
    assert _checked_pattern(None, None, None, False).com_correction is None
    result = run_online(estop_time=3.4, controller=ControllerOptions(whole_body_walk=True))
    assert result.success, result.criteria
    walking = (result.times > 1.0) & (result.times < 3.3)
    expected = corrected.com(result.times[walking])[0]
    lipm = NominalPattern().com(result.times[walking])[0]
    np.testing.assert_allclose(result.com_plan[walking, :2], expected, atol=1e-9)
    assert np.abs(result.com_plan[walking, :2] - lipm).max() > 1e-3
