"""Closed-form stop condition (eq. 17-22, 29) and its analytic derivatives."""

import numpy as np
import pytest

from drake_estop.planning import lipm
from drake_estop.planning.stop_condition import (
    StopStart,
    rest,
    rest_derivatives,
    slowdown,
    slowdown_derivatives,
    slowdown_time,
    target_zmp,
    terms,
)

W = lipm.omega(0.814)
STARTS = [StopStart.from_state(0.05, 0.4, 0.0, W), StopStart.from_state(0.08, 0.5, 0.02, W, 1.5, -20.0)]


def rest_position(start, w, landing, transition, target):
    """Rest position of the COG (the rear-reach limit's value) with gradient and Hessian in (landing,
    transition, target), the slowdown eliminated: the solver's own chain of closed-form functions."""
    t = terms(start, w, landing, transition)
    grad, hess, tg, th = np.zeros(3), np.zeros((3, 3)), np.zeros(3), np.zeros((3, 3))
    t3 = slowdown(t, w, target)
    if not (t3 == t3 and slowdown_derivatives(t, w, target, t3, tg, th)):
        return float("nan"), grad, hess
    value = rest_derivatives(t, w, target, t3, tg, th, grad, hess)
    assert value == rest(t, w, target, t3)
    return float(value), grad, hess


def _simulate_end_velocity(start_state, durations, target, rate=0.0, accel=0.0):
    x0, v0, p0 = start_state
    landing, transition, slowdown = durations
    coeffs = [lipm.pad([p0]), lipm.transition_coeffs(p0, p0 + target, transition, rate, accel),
              lipm.pad([p0 + target])]
    traj = lipm.LipmTrajectory.from_zmp(0.0, [landing, transition, slowdown], coeffs, x0, v0, W)
    return traj.evaluate(traj.end_time)[1][0]


@pytest.mark.parametrize("durations", [(0.3, 0.2, 0.25), (0.1, 0.1, 0.005), (0.6, 0.4, 0.8)])
def test_target_meets_stop_condition(durations):
    z = target_zmp(STARTS[0], W, *durations, derivatives=False)
    assert abs(_simulate_end_velocity((0.05, 0.4, 0.0), durations, z)) < 1e-8  # eq. 17


def test_target_with_moving_zmp_meets_stop_condition():
    z = target_zmp(STARTS[1], W, 0.0, 0.15, 0.2, derivatives=False)
    v = _simulate_end_velocity((0.08, 0.5, 0.02), (1e-12, 0.15, 0.2), z, 1.5, -20.0)
    assert abs(v) < 1e-9  # eq. 29 with the ZMP rate and acceleration at the signal


@pytest.mark.parametrize("start", STARTS)
def test_gradient_and_hessian_match_finite_differences(start):
    x = np.array([0.25 if start is STARTS[0] else 0.0, 0.2, 0.3])
    _, grad, hess = target_zmp(start, W, *x)
    eps = 1e-6
    for k in range(3):
        e = np.eye(3)[k] * eps
        num_grad = (target_zmp(start, W, *(x + e), derivatives=False)
                    - target_zmp(start, W, *(x - e), derivatives=False)) / (2 * eps)
        num_hess = (target_zmp(start, W, *(x + e))[1] - target_zmp(start, W, *(x - e))[1]) / (2 * eps)
        assert grad[k] == pytest.approx(num_grad, rel=1e-6, abs=1e-8)
        np.testing.assert_allclose(hess[k], num_hess, rtol=1e-5, atol=1e-6)


def test_slowdown_time_inverts_target_and_has_consistent_derivatives():
    y = np.array([0.3, 0.2, target_zmp(STARTS[0], W, 0.3, 0.2, 0.25, derivatives=False)])
    t3, grad, hess = slowdown_time(STARTS[0], W, *y)
    assert t3 == pytest.approx(0.25, abs=1e-12)
    eps = 1e-6
    for k in range(3):
        e = np.eye(3)[k] * eps
        num_grad = (slowdown_time(STARTS[0], W, *(y + e))[0] - slowdown_time(STARTS[0], W, *(y - e))[0]) / (2 * eps)
        num_hess = (slowdown_time(STARTS[0], W, *(y + e))[1] - slowdown_time(STARTS[0], W, *(y - e))[1]) / (2 * eps)
        assert grad[k] == pytest.approx(num_grad, rel=1e-6, abs=1e-8)
        np.testing.assert_allclose(hess[k], num_hess, rtol=1e-5, atol=1e-5)


def test_unreachable_target_gives_nan_not_garbage():
    t3, grad, _ = slowdown_time(STARTS[0], W, 0.3, 0.2, 5.0)
    assert np.isnan(t3) and np.all(grad == 0)


def test_slowdown_time_inverts_target_over_a_grid():
    """With the start ZMP moving (rate and acceleration), over a grid of durations."""
    for t1, t2, t3 in np.stack(np.meshgrid([0.1, 0.4], [0.1, 0.3], [0.05, 0.5], indexing="ij")).reshape(3, -1).T:
        z, grad, _ = target_zmp(STARTS[1], W, t1, t2, t3)
        assert z == target_zmp(STARTS[1], W, t1, t2, t3, derivatives=False)
        assert slowdown_time(STARTS[1], W, t1, t2, z, derivatives=False) == pytest.approx(t3, abs=1e-9)
        assert grad[2] < 0  # Z falls as the slowdown lengthens (the grid start's target interval)


@pytest.mark.parametrize("start", STARTS)
def test_rest_position_gradient_and_hessian_match_finite_differences(start):
    """The rear-reach constraint's rest position (slowdown eliminated): analytic derivatives in
    (landing, transition, target) against central differences; every Hessian entry is checked,
    so a dropped term of either the value's or the gradient's derivative shows."""
    landing = 0.25 if start is STARTS[0] else 0.0
    y = np.array([landing, 0.2, target_zmp(start, W, landing, 0.2, 0.3, derivatives=False)])
    value, grad, hess = rest_position(start, W, *y)
    assert np.isfinite(value) and np.all(np.isfinite(hess))
    eps = 1e-6
    for k in range(3):
        e = np.eye(3)[k] * eps
        plus, minus = rest_position(start, W, *(y + e)), rest_position(start, W, *(y - e))
        assert grad[k] == pytest.approx((plus[0] - minus[0]) / (2 * eps), rel=1e-6, abs=1e-9), k
        np.testing.assert_allclose(hess[k], (plus[1] - minus[1]) / (2 * eps), rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(hess, hess.T, rtol=1e-12, atol=1e-14)


def test_rest_position_is_where_the_simulated_cog_stops():
    y = (0.3, 0.2, target_zmp(STARTS[0], W, 0.3, 0.2, 0.25, derivatives=False))
    x0, v0, p0 = 0.05, 0.4, 0.0
    coeffs = [lipm.pad([p0]), lipm.transition_coeffs(p0, y[2], 0.2), lipm.pad([y[2]])]
    traj = lipm.LipmTrajectory.from_zmp(0.0, [0.3, 0.2, 0.25], coeffs, x0, v0, W)
    assert rest_position(STARTS[0], W, *y)[0] == pytest.approx(traj.evaluate(traj.end_time)[0][0], abs=1e-9)


def test_infeasible_points_give_nan_and_zero_derivatives_of_the_right_shape():
    """Where no slowdown stops the COG, the slowdown and the rest position are NaN with zero
    gradients (3,) and Hessians (3, 3) (mutation testing found these shapes unchecked)."""
    for function in (slowdown_time, rest_position):
        value, grad, hess = function(STARTS[0], W, 0.3, 0.2, 5.0)
        assert isinstance(value, float) and np.isnan(value), function
        assert grad.shape == (3,) and hess.shape == (3, 3), function
        assert not grad.any() and not hess.any(), function
