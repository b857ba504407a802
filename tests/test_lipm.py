"""Analytic LIPM (eq. 6-14): particular solution, chaining, boundary-value solves."""

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from drake_estop.planning import lipm

W = lipm.omega(0.814)


def _integrate(traj, t_end):
    """Independent check: integrate x'' = w^2 (x - p(t)) from the trajectory's ZMP."""
    pos, vel, _, _ = traj.evaluate(traj.start_time)

    def rhs(t, s):
        zmp = traj.evaluate(t)[3][0]
        return [s[1], W * W * (s[0] - zmp)]

    return solve_ivp(rhs, (traj.start_time, t_end), [pos[0], vel[0]], rtol=1e-11, atol=1e-12,
                     max_step=0.01, dense_output=True)


def test_particular_coefficients_satisfy_eq4():
    rng = np.random.default_rng(0)
    a = rng.normal(size=8)
    big_a = lipm.cog_particular_coeffs(a, W)
    tau = np.linspace(0, 1, 7)
    x = lipm.poly_eval(big_a, tau)
    xdd = lipm.poly_eval(big_a, tau, 2)
    np.testing.assert_allclose(x - xdd / W**2, lipm.poly_eval(a, tau), atol=1e-10)


def test_chain_is_continuous_and_matches_numerical_integration():
    coeffs = [lipm.pad([0.0]), lipm.transition_coeffs(0.0, 0.3, 0.2), lipm.pad([0.3])]
    traj = lipm.LipmTrajectory.from_zmp(1.0, [0.5, 0.2, 0.4], coeffs, -0.05, 0.3, W)
    eps = 1e-9
    for b in traj.breaks[1:-1]:
        before = np.array(traj.evaluate(b - eps)).ravel()
        after = np.array(traj.evaluate(b + eps)).ravel()
        np.testing.assert_allclose(before, after, atol=1e-6)  # eq. 10-12 (and acceleration)
    sol = _integrate(traj, traj.end_time)
    t = np.linspace(traj.start_time, traj.end_time, 50)
    np.testing.assert_allclose(sol.sol(t)[0], traj.evaluate(t)[0], atol=1e-7)


def test_transition_has_zero_end_derivatives():
    c = lipm.transition_coeffs(0.1, 0.4, 0.25, start_rate=0.5, start_accel=-3.0)
    assert lipm.poly_eval(c, 0.0) == pytest.approx(0.1)
    assert lipm.poly_eval(c, 0.0, 1) == pytest.approx(0.5)
    assert lipm.poly_eval(c, 0.0, 2) == pytest.approx(-3.0)
    assert lipm.poly_eval(c, 0.25) == pytest.approx(0.4)
    assert lipm.poly_eval(c, 0.25, 1) == pytest.approx(0.0, abs=1e-9)  # eq. 14
    assert lipm.poly_eval(c, 0.25, 2) == pytest.approx(0.0, abs=1e-8)


def test_required_start_dcm_gives_bounded_solution():
    durations = [0.64, 0.16, 0.64]
    coeffs = [lipm.pad([0.0]), lipm.transition_coeffs(0.0, 0.3, 0.16), lipm.pad([0.3])]
    dcm = lipm.required_start_dcm(durations, coeffs, 0.3, W)
    x0 = 0.05
    traj = lipm.LipmTrajectory.from_zmp(0.0, durations + [3.0], coeffs + [lipm.pad([0.3])],
                                        x0, (dcm - x0) * W, W)
    pos = traj.evaluate(np.linspace(0, traj.end_time, 200))[0]
    assert np.abs(pos - 0.15).max() < 0.3  # no divergence
    assert traj.evaluate(traj.end_time)[0][0] == pytest.approx(0.3, abs=1e-4)


def test_chain_bvp_ends_exactly_at_rest():
    base = [lipm.pad([0.3]), lipm.pad(lipm.scale_unit_poly(lipm.SMOOTHSTEP, 0.6)) * 0.15]
    unknowns = [[lipm.pad([0.0]), lipm.scale_unit_poly(lipm.BUMP_A, 0.6)],
                [lipm.pad([0.0]), lipm.scale_unit_poly(lipm.BUMP_B, 0.6)]]
    coeffs = lipm.solve_chain_bvp([0.1, 0.6], base, unknowns, 0.2, -0.1, W, 0.15, 0.0)
    x, v = lipm.chain_end_state([0.1, 0.6], coeffs, 0.2, -0.1, W)
    assert x == pytest.approx(0.15, abs=1e-9)
    assert v == pytest.approx(0.0, abs=1e-9)


def test_omega_is_sqrt_g_over_height():
    """eq. 6: w = sqrt(g / z); a self-consistent wrong w (e.g. sqrt(g z)) passes every
    chained test, so the value is pinned (HRP-2's 0.814 m: 3.47 rad/s)."""
    assert lipm.omega(0.814) == pytest.approx(math.sqrt(9.80665 / 0.814), rel=1e-12)
    assert lipm.omega(0.814) == pytest.approx(3.4710, abs=1e-3)


@pytest.mark.parametrize("coeffs, x0, v0", [
    ([0.0], 0.01, 0.0),  # 1 cm off the final ZMP: diverges
    ([0.0], 0.0, 1.5e-4),  # 0.15 mm/s: velocity residue above 1e-4
    ([0.0, 0.01], 0.0, 0.01),  # follows a moving ZMP exactly: no residue, but the ZMP is not at rest
])
def test_rest_tail_refuses_a_cog_not_at_rest(coeffs, x0, v0):
    w = lipm.omega(0.814)
    with pytest.raises(ValueError, match="does not arrive at rest"):
        lipm.LipmTrajectory.from_zmp(0.0, [1.0], [lipm.pad(coeffs)], x0, v0, w, rest_tail=True)
    lipm.LipmTrajectory.from_zmp(0.0, [1.0], [lipm.pad([0.0])], 1e-6, 0.0, w, rest_tail=True)  # rounding: fine


def test_chain_bvp_weighted_least_norm():
    """The weights of solve_chain_bvp: min sum (u_k / weight_k)^2 subject to the end state."""
    w = lipm.omega(0.814)
    durations = [0.3, 0.4, 0.5]
    zero, one = lipm.pad([0.0]), lipm.pad([1.0])
    base = [lipm.pad([0.02]), zero, zero]
    unknowns = [[zero, one, zero], [zero, zero, one], [one, zero, zero]]
    weights = np.array([1.0, 0.5, 0.01])
    out = lipm.solve_chain_bvp(durations, base, unknowns, 0.01, 0.1, w, 0.05, 0.0, weights=weights)
    assert lipm.chain_end_state(durations, out, 0.01, 0.1, w) == pytest.approx((0.05, 0.0), abs=1e-12)
    matrix = np.array([lipm.chain_end_state(durations, u, 0.0, 0.0, w) for u in unknowns]).T
    rhs = np.array([0.05, 0.0]) - np.array(lipm.chain_end_state(durations, base, 0.01, 0.1, w))
    u = (weights**2) * (matrix.T @ np.linalg.solve(matrix * weights**2 @ matrix.T, rhs))
    found = [out[1][0], out[2][0], out[0][0] - 0.02]
    np.testing.assert_allclose(found, u, rtol=1e-9, atol=1e-12)
    assert abs(found[2]) < 0.01 * max(abs(found[0]), abs(found[1]))  # the light-weight unknown barely moves


def test_per_tick_evaluation_equals_vectorised_one_everywhere():
    """``evaluate_at`` (the servo-tick path) against ``evaluate`` and the ZMP polynomials' derivatives:
    all six outputs, inside every segment, on the breaks (the later segment wins) and outside the chain."""
    w = lipm.omega(0.814)
    coeffs = [lipm.pad([0.0]), lipm.transition_coeffs(0.0, 0.1, 0.4, 0.2, -1.0), lipm.pad([0.1])]
    traj = lipm.LipmTrajectory.from_zmp(1.0, [0.3, 0.4, 0.5], coeffs, 0.02, 0.3, w)
    times = [0.5, 1.0, 1.1, 1.3, 1.45, 1.7, 1.9, 2.2, 2.5]
    pos, vel, acc, zmp = traj.evaluate(times)
    k = np.clip(np.searchsorted(traj.breaks, times, side="right") - 1, 0, len(traj.zmp) - 1)
    tau = np.asarray(times) - traj.breaks[k]
    rate, accel = ([lipm.poly_eval(traj.zmp[i], s, order) for i, s in zip(k, tau)] for order in (1, 2))
    for i, t in enumerate(times):
        np.testing.assert_allclose(traj.evaluate_at(t), [pos[i], vel[i], acc[i], zmp[i], rate[i], accel[i]],
                                   rtol=1e-12, atol=1e-12, err_msg=str(t))
    # eq. 4: the COG acceleration is w^2 (x - ZMP)
    np.testing.assert_allclose(acc, w * w * (pos - zmp), rtol=1e-9, atol=1e-12)
    step = lipm.LipmTrajectory.from_zmp(0.0, [0.3, 0.3], [lipm.pad([0.0]), lipm.pad([0.1])], 0.0, 0.0, w)
    assert step.evaluate([0.3])[3][0] == pytest.approx(0.1) and step.evaluate_at(0.3)[3] == pytest.approx(0.1)
    assert step.evaluate([-0.1])[3][0] == pytest.approx(0.0) and step.evaluate([0.7])[3][0] == pytest.approx(0.1)


def test_one_instant_evaluates_to_the_same_bits_as_the_array_path():
    """``evaluate`` at one instant (every servo tick asks the pattern and the plan so) takes a plain-float
    path; it must give the array path's results bit for bit (a different rounding would change every
    physics run), in every segment, on the breaks and outside the chain; so must a plan's COG height."""
    from drake_estop.physics.online import controller_stop_parameters
    from drake_estop.planning.gait import NominalPattern
    from drake_estop.planning.planner import plan_stop

    pattern = NominalPattern()
    plan = plan_stop(pattern, 3.4, controller_stop_parameters())
    rng = np.random.default_rng(0)
    for traj in (*pattern.trajectories, plan.x, plan.y):
        times = np.concatenate([traj.breaks, rng.uniform(traj.breaks[0] - 0.5, traj.breaks[-1] + 0.5, 400)])
        many = traj.evaluate(times)
        for i, t in enumerate(times):
            for one, row in zip(traj.evaluate(t), many):
                assert one.shape == (1,) and one[0] == row[i], (t, one[0] - row[i])
            assert [v[0] for v in traj.evaluate([t])] == [v[i] for v in many]
    times = np.linspace(3.2, plan.halt_end + 0.3, 300)
    many = plan.com_height(times)
    for i, t in enumerate(times):
        assert [v[0] for v in plan.com_height([t])] == [v[i] for v in many], t
    assert plan.com_height([plan.halt_end - 0.3])[1][0] != 0.0  # crouching: the test sees a moving height


def test_poly_eval_past_the_degree_and_chain_bvp_defaults_to_rest():
    assert lipm.poly_eval([1.0, 2.0], np.array([0.1, 0.2]), 2).tolist() == [0.0, 0.0]
    w = lipm.omega(0.814)
    zero, one = lipm.pad([0.0]), lipm.pad([1.0])
    out = lipm.solve_chain_bvp([0.4, 0.4], [zero, zero], [[one, zero], [zero, one]], 0.0, 0.2, w, 0.05)
    assert lipm.chain_end_state([0.4, 0.4], out, 0.0, 0.2, w) == pytest.approx((0.05, 0.0), abs=1e-12)


def test_evaluate_axes_gives_each_axis_s_own_bits():
    """Axes that share breakpoints share one instant's segment, cosh, sinh and powers: the same bits as each
    axis evaluated alone, at one instant and at many; an axis with other breakpoints gets its own."""
    w = math.sqrt(9.81 / 0.8)
    zmp = [[0.0, 0.1], [0.05, 0.0, 0.2], [0.1]]
    x = lipm.LipmTrajectory.from_zmp(1.0, [0.3, 0.2, 0.4], zmp, 0.0, 0.3, w)
    y = lipm.LipmTrajectory.from_zmp(1.0, [0.3, 0.2, 0.4], [[0.02], [-0.03, 0.1], [0.0]], 0.05, -0.1, w)
    other = lipm.LipmTrajectory.from_zmp(1.05, [0.25, 0.3, 0.4], zmp, 0.0, 0.3, w)
    assert x._shares_basis(y) and not x._shares_basis(other)
    for t in [0.9, 1.0, 1.17, 1.3, 1.45, 1.5, 1.77, 2.5, np.array([1.23]), [1.61]]:
        together = lipm.LipmTrajectory.evaluate_axes((x, y, other), t)
        for traj, values in zip((x, y, other), together):
            assert all(np.array_equal(a, b) for a, b in zip(values, traj.evaluate(t)))
    times = np.linspace(0.9, 2.5, 33)
    for traj, values in zip((x, y), lipm.LipmTrajectory.evaluate_axes((x, y), times)):
        assert all(np.array_equal(a, b) for a, b in zip(values, traj.evaluate(times)))
