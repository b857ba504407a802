"""Nominal walking pattern: eq. 4 within 1 mm, bounded, ends at rest, ZMP inside the soles."""

import numpy as np
import pytest
from checks import lipm_tracking_error
from robot_helpers import needs_robots

from drake_estop.planning.gait import GaitParameters, NominalPattern
from drake_estop.planning.geometry import SupportPolygon


def test_pattern_satisfies_lipm_by_independent_integration(pattern):
    t = np.arange(0.0, pattern.end_time + 0.5, 0.005)
    pos, vel, _, zmp = pattern.com(t)
    for axis in (0, 1):
        assert lipm_tracking_error(t, pos[:, axis], vel[:, axis], zmp[:, axis], pattern.w) < 1e-3


def test_pattern_starts_and_ends_at_rest(pattern):
    pos, vel, _, zmp = pattern.com([0.0, pattern.end_time, pattern.end_time + 2.0])
    assert np.abs(vel).max() < 1e-8
    mid = 0.5 * (pattern.final_feet["left"] + pattern.final_feet["right"])
    np.testing.assert_allclose(pos[1:], [mid, mid], atol=1e-8)
    np.testing.assert_allclose(zmp[1:], [mid, mid], atol=1e-8)


def _least_zmp_margin(pattern):
    """The least distance [m] of the pattern's ZMP inside the soles on the floor, every 5 ms to its end."""
    sole = pattern.params.sole
    margins = []
    for t in np.arange(0.0, pattern.end_time, 0.005):
        feet = pattern.feet_at(t)[0]
        support, _, side = pattern.support_at(t)
        sides = [side] if support == "single" else ["left", "right"]
        poly = SupportPolygon(np.vstack([sole.corners(feet[s][:2], s) for s in sides]))
        margins.append(poly.margin(pattern.com(t)[3])[0])
    return min(margins)


def test_pattern_zmp_inside_support_polygon(pattern):
    assert _least_zmp_margin(pattern) >= -1e-9


@needs_robots
@pytest.mark.parametrize("name", ["g1", "talos"])
def test_the_walk_ends_with_its_zmp_inside_narrow_soles(name):
    """The walk's final shift brings the COG to the feet's midpoint without a ZMP outside the soles: the G1's
    0.056 m wide soles and TALOS's keep 1.5 cm and more (its ZMP went 35 mm past the last stance foot's outer
    edge when the walk's DCM ended on that ankle, the COG still running towards it at the last touchdown)."""
    from drake_estop.robots import as_robot, gait_parameters

    assert _least_zmp_margin(NominalPattern(gait_parameters(as_robot(name)))) > 0.015


def test_swing_foot_lands_at_rest(pattern):
    step = pattern.steps[3]
    _, vel, _ = pattern.feet_at(step["touchdown"] - 1e-6)
    assert np.abs(vel[step["swing"]]).max() < 1e-3
    pos = pattern.feet_at(step["touchdown"])[0]
    np.testing.assert_allclose(pos[step["swing"]][:2], step["end"])


@pytest.mark.parametrize("name, value", [("com_height", 0.0), ("step_time", -1.0), ("com_height", float("nan")),
                                         ("double_support_ratio", 1.0), ("num_steps", 1)])
def test_bad_gait_parameters_name_the_parameter(name, value):
    with pytest.raises(ValueError, match=name):
        GaitParameters(**{name: value})


def test_other_gaits_build(pattern):
    for params in (GaitParameters(step_length=0.15), GaitParameters(step_time=1.2, double_support_ratio=0.3)):
        p = NominalPattern(params)
        t = np.arange(0, p.end_time, 0.01)
        pos, _, acc, zmp = p.com(t)
        np.testing.assert_allclose(zmp, pos - acc / p.w**2, atol=1e-9)


@pytest.mark.parametrize("side, outer_sign", [("left", 1.0), ("right", -1.0)])
def test_sole_lateral_edges_put_the_outer_edge_on_the_foots_own_side(side, outer_sign):
    sole = GaitParameters().sole
    left_edge, right_edge = sole.lateral_edges(side)
    corners = sole.corners((0.0, 0.0), side)
    assert corners[:, 1].max() == pytest.approx(left_edge) and corners[:, 1].min() == pytest.approx(-right_edge)
    assert (left_edge if outer_sign > 0 else right_edge) == sole.outer
    assert (right_edge if outer_sign > 0 else left_edge) == sole.inner


def test_zmp_offset_moves_the_single_support_zmp_forward_in_the_sole():
    """``zmp_offset`` puts every single support's ZMP that far ahead of its ankle (along a turned foot's
    heading too), the pattern still satisfies eq. 4 and ends at rest between the feet; 0 is the
    paper's pattern to the bit; an offset outside the sole is refused, naming the field."""
    base = NominalPattern(GaitParameters())
    same = NominalPattern(GaitParameters(zmp_offset=0.0))
    t = np.arange(0.0, base.end_time + 0.5, 0.005)
    for a, b in zip(base.com(t), same.com(t)):
        assert np.array_equal(a, b)
    for turn, offset in ((0.0, 0.04), (15.0, 0.04)):
        pattern = NominalPattern(GaitParameters(zmp_offset=offset, turn=turn))
        for step in pattern.steps[1:-1]:
            mid = 0.5 * (step["liftoff"] + step["touchdown"])
            state = pattern.state(mid)
            side = state.support_foot
            yaw = state.feet_yaw[side]
            ahead = state.feet[side][:2] + offset * np.array([np.cos(yaw), np.sin(yaw)])
            np.testing.assert_allclose(state.zmp, ahead, atol=1e-9)
        pos, vel, _, zmp = pattern.com(t)
        for axis in (0, 1):
            assert lipm_tracking_error(t, pos[:, axis], vel[:, axis], zmp[:, axis], pattern.w) < 1e-3
        assert np.abs(vel[-1]).max() < 1e-8
    for bad in (0.135, -0.105, float("nan")):
        with pytest.raises(ValueError, match="zmp_offset"):
            GaitParameters(zmp_offset=bad)
