"""Analytic LIPM (eq. 6-14): particular solution, chaining, boundary-value solves."""

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from drake_estop import lipm

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
