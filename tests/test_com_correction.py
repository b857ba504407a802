"""The COG correction that moves the LIPM's ZMP by a given shift: eq. 4 for the shift, the bounded
convolution, at rest where the shift is, and on the pattern's COG but not its ZMP."""

import numpy as np
import pytest

from drake_estop.planning.com_correction import ComCorrection, lipm_correction
from drake_estop.planning.gait import NominalPattern

W = 3.5  # [1/s], the default humanoid's LIPM
STEP = 0.005


def _shift(times):
    """A 3 cm bump forward and a 1 cm lateral wobble, both zero a second from the ends."""
    return np.stack([0.03 * np.exp(-((times - 3.0) / 0.3) ** 2),
                     0.01 * np.sin(2 * np.pi * times / 0.8) * np.exp(-((times - 3.0) / 0.8) ** 4)], axis=1)


@pytest.fixture(scope="module")
def correction():
    times = np.arange(0.0, 6.0, STEP)
    return times, _shift(times), lipm_correction(times, _shift(times), W)


def test_the_correction_moves_the_lipm_zmp_by_minus_the_shift(correction):
    times, shift, c = correction
    acceleration = np.gradient(np.gradient(c.offset, STEP, axis=0), STEP, axis=0)
    zmp_of_offset = c.offset - acceleration / W**2  # eq. 4
    np.testing.assert_allclose(zmp_of_offset[2:-2], -shift[2:-2], atol=2e-5)
    np.testing.assert_allclose(np.gradient(c.offset, STEP, axis=0)[1:-1], c.velocity[1:-1], atol=1e-5)
    np.testing.assert_allclose(np.gradient(c.velocity, STEP, axis=0)[1:-1], c.acceleration[1:-1], atol=1e-4)


def test_the_correction_is_the_bounded_convolution(correction):
    times, shift, c = correction
    lag = times[:, None] - times[None, :]
    weights = np.exp(-W * np.abs(lag)) * STEP
    weights[:, [0, -1]] *= 0.5  # trapezoids
    np.testing.assert_allclose(c.offset, -0.5 * W * weights @ shift, atol=2e-6)
    assert np.abs(c.offset).max() > 0.01


def test_the_cog_is_at_rest_where_the_shift_is_zero(correction):
    _, _, c = correction
    for end in (0, -1):
        assert np.abs(c.offset[end]).max() < 1e-5 and np.abs(c.velocity[end]).max() < 1e-5


def test_a_correction_evaluates_to_zero_outside_its_times_and_adds(correction):
    times, shift, c = correction
    offset, velocity, acceleration = c.evaluate([-1.0, 3.0, 7.0])
    assert not offset[[0, 2]].any() and not velocity[[0, 2]].any() and not acceleration[[0, 2]].any()
    np.testing.assert_allclose(offset[1], c.offset[600])
    np.testing.assert_allclose((c + c).offset, 2 * c.offset)
    with pytest.raises(ValueError, match="different times"):
        c + lipm_correction(times[:-1], shift[:-1], W)


@pytest.mark.parametrize("kwargs, name", [
    ({"times": [0.0]}, "times"), ({"times": [0.0, 0.1, 0.3]}, "uniform"),
    ({"zmp_shift": np.full((3, 2), np.nan)}, "zmp_shift"), ({"zmp_shift": np.zeros((3, 3))}, "zmp_shift"),
    ({"omega": 0.0}, "omega"), ({"omega": float("nan")}, "omega")])
def test_bad_input_names_the_parameter(kwargs, name):
    args = {"times": [0.0, 0.1, 0.2], "zmp_shift": np.zeros((3, 2)), "omega": W, **kwargs}
    with pytest.raises(ValueError, match=name):
        lipm_correction(**args)


def test_the_pattern_moves_its_cog_and_keeps_its_zmp(pattern):
    times = np.arange(0.0, pattern.end_time, STEP)
    shift = _shift(times)
    c = lipm_correction(times, shift, pattern.w)
    moved = NominalPattern(pattern.params, com_correction=c)
    before, after = pattern.com(times), moved.com(times)
    for k in range(3):  # position, velocity, acceleration
        np.testing.assert_allclose(after[k] - before[k], c.evaluate(times)[k], atol=1e-12)
    np.testing.assert_array_equal(after[3], before[3])
    state, plain = moved.state(3.0), pattern.state(3.0)
    np.testing.assert_allclose(state.com - plain.com, c.evaluate([3.0])[0][0], atol=1e-12)
    np.testing.assert_allclose(state.com_vel - plain.com_vel, c.evaluate([3.0])[1][0], atol=1e-12)
    np.testing.assert_array_equal(state.zmp, plain.zmp)
    assert isinstance(moved.com_correction, ComCorrection) and pattern.com_correction is None
