"""The compiled solver core (drake_estop.planning.fastcore) against the pure-Python reference path."""

import math

import numpy as np
import pytest

pytest.importorskip("numba")

from drake_estop.planning import fastcore, planner
from drake_estop.planning.gait import GaitParameters, NominalPattern  # noqa: E402
from drake_estop.planning.planner import InfeasibleStop, StopParameters, plan_stop, stop_problem  # noqa: E402
from drake_estop.planning.rollout import stride_ticks  # noqa: E402

REL = 1e-9

GAITS = {
    "default": GaitParameters(),
    "short-fast": GaitParameters(step_length=0.2, step_time=0.6),
    "long-slow": GaitParameters(step_length=0.35, step_time=1.0, double_support_ratio=0.3),
    "in-place": GaitParameters(step_length=0.0),
    "short": GaitParameters(step_length=0.02),
}
PARAMS = {
    "paper": StopParameters(),
    "round": StopParameters(quantisation="round"),
    "offset": StopParameters(landing_zmp_offset=0.05, a_ss=20.0, b_ds=500.0),
}


def _close(a, b, rel=REL):
    return abs(a - b) <= rel * max(abs(a), abs(b), 1e-12)


def _paths(monkeypatch, fn):
    """``fn()`` with the compiled path and with the Python path: (result or exception) each."""
    out = []
    for compiled in (True, False):
        monkeypatch.setattr(planner, "COMPILED", compiled)
        try:
            out.append(fn())
        except (InfeasibleStop, ValueError) as exc:
            out.append(type(exc))
    return out


def _problems(gait_name, every=1):
    pattern = NominalPattern(GAITS[gait_name])
    for name, params in PARAMS.items():
        for t in stride_ticks(pattern, params)[::every]:
            state = pattern.state(planner.snap_to_tick(t, params.servo_period))
            if state.support not in ("single", "double"):
                continue
            yield name, t, stop_problem(pattern, state, params)


@pytest.mark.parametrize("gait_name,every", [("default", 1), ("short-fast", 3), ("long-slow", 3), ("in-place", 5),
                                             ("short", 5)])
def test_solve_matches_python(monkeypatch, gait_name, every):
    compared = infeasible = 0
    for name, t, (problem, kind, _) in _problems(gait_name, every):
        fast, slow = _paths(monkeypatch, lambda: planner._solve(problem, kind))
        if isinstance(slow, type):  # the Python path raised: the compiled one raises the same
            assert fast is slow, (gait_name, name, t)
            infeasible += 1
            continue
        assert not isinstance(fast, type), (gait_name, name, t, fast)
        # quantised durations are servo ticks: equal; Z and the cost to 1e-9
        for field in ("landing", "transition", "slowdown"):
            assert _close(getattr(fast, field), getattr(slow, field), 1e-12), (gait_name, name, t, field)
        assert _close(fast.target, slow.target), (gait_name, name, t, fast.target, slow.target)
        assert _close(fast.cost, slow.cost), (gait_name, name, t)
        assert fast.iterations == slow.iterations, (gait_name, name, t)
        for a, b in zip(fast.continuous, slow.continuous):
            assert _close(a, b), (gait_name, name, t, fast.continuous, slow.continuous)
        compared += 1
    assert compared > 50
    if gait_name == "default":
        assert infeasible > 0  # the next-step fallback's first attempts: exception path exercised


def test_solve_continuous_matches_python(monkeypatch, pattern, params, stride_times):
    for t in stride_times[::5]:
        problem, kind, _ = stop_problem(pattern, pattern.state(t), params)
        fast, slow = _paths(monkeypatch, lambda: planner.solve_continuous(problem, kind))
        if isinstance(slow, type):
            assert fast is slow
            continue
        np.testing.assert_allclose(fast[0], slow[0], rtol=REL, atol=1e-12)
        assert _close(fast[1], slow[1]) and _close(fast[2], slow[2]) and fast[3] == slow[3], t


@pytest.mark.parametrize("gait_name", ["default", "short", "in-place"])
def test_plans_identical(monkeypatch, params, gait_name):
    """Whole plans: phase times, step length / ZMP_max and the ZMP polynomials (halt included)
    equal to the bit in "resolve" mode (Z is re-evaluated with numpy at the chosen ticks).
    Short steps exercise the lateral re-solves, stepping in place the at-rest solution."""
    pattern = NominalPattern(GAITS[gait_name])
    for t in stride_ticks(pattern, params)[::4 if gait_name == "default" else 8]:
        fast, slow = _paths(monkeypatch, lambda: plan_stop(pattern, t, params))
        assert fast.case == slow.case and fast.newton_iterations == slow.newton_iterations
        for field in ("start_time", "landing_time", "transition_end", "slowdown_end", "halt_end", "cost",
                      "min_zmp_margin"):
            assert getattr(fast, field) == getattr(slow, field), (t, field)
        assert fast.step_length == slow.step_length and fast.zmp_max == slow.zmp_max, t
        np.testing.assert_array_equal(fast.x.zmp, slow.x.zmp)
        np.testing.assert_array_equal(fast.y.zmp, slow.y.zmp)


def test_point_evaluators_match(pattern, params, stride_times):
    """evaluate / values at random interior points against the problem's Python evaluators."""
    rng = np.random.default_rng(0)
    checked = 0
    for t in stride_times[::7]:
        problem, kind, _ = stop_problem(pattern, pattern.state(t), params)
        d = fastcore.pack(problem, kind)
        n, m = (3, 11) if kind == "single" else (2, 7)
        bounds = problem.bounds()[list(problem.free)]
        start = planner._grid_start(problem, kind)
        if start is None:
            continue
        span = bounds[:, 1] - bounds[:, 0]
        for _ in range(5):  # around the grid start (most of the box is infeasible), inside the bounds
            x = np.clip(start[0][list(problem.free)] + 0.05 * span * rng.normal(size=n),
                        bounds[:, 0] + 1e-3 * span, bounds[:, 1] - 1e-3 * span)
            cost, g = problem.values(x)
            g_fast = np.zeros(m)
            cost_fast = fastcore.values(d, x, g_fast)
            if not math.isfinite(cost):
                assert not math.isfinite(cost_fast)
                continue
            assert _close(cost_fast, cost)
            np.testing.assert_allclose(g_fast, g, rtol=REL, atol=1e-12)
            j, jg, jh, g, gg, gh = problem.evaluate(x)
            out = np.zeros(n), np.zeros((n, n)), np.zeros(m), np.zeros((m, n)), np.zeros((m, n, n))
            j_fast = fastcore.evaluate(d, x, *out)
            assert _close(j_fast, j)
            scale = max(1.0, np.abs(jh).max())
            np.testing.assert_allclose(out[0], jg, rtol=REL, atol=1e-12 * max(1.0, np.abs(jg).max()))
            np.testing.assert_allclose(out[1], jh, rtol=REL, atol=1e-12 * scale)
            np.testing.assert_allclose(out[2], g, rtol=REL, atol=1e-12)
            np.testing.assert_allclose(out[3], gg, rtol=REL, atol=1e-12)
            gh_ref = np.array([np.zeros((n, n)) if h is None else h for h in gh], float)
            np.testing.assert_allclose(out[4], gh_ref, rtol=REL, atol=1e-12 * max(1.0, np.abs(gh_ref).max()))
            checked += 1
    assert checked > 30


def test_grid_start_matches_python(pattern, params, stride_times):
    for t in stride_times[::3]:
        problem, kind, _ = stop_problem(pattern, pattern.state(t), params)
        ref = planner._grid_start(problem, kind)
        y, cost, strict, found = fastcore.grid_start(*planner._compiled_args(problem, kind))
        assert found == (ref is not None), t
        if ref is None:
            continue
        np.testing.assert_allclose(y, ref[0], rtol=REL, atol=1e-12)
        assert _close(cost, ref[1]) and strict == ref[2], t


def test_infeasible_start_reported(pattern, params, stride_times):
    problem, kind, _ = stop_problem(pattern, pattern.state(stride_times[0]), params)
    d = fastcore.pack(problem, kind)
    n = 3 if kind == "single" else 2
    x0 = problem.bounds()[list(problem.free), 1] + 1.0  # above every upper bound
    *_, status = fastcore.barrier_newton(d, x0, 1e-2, 1e-8)
    assert status == -1
    with pytest.raises(ValueError):
        planner._compiled_status(fastcore.INFEASIBLE_START, kind, problem)
    assert len(x0) == n
