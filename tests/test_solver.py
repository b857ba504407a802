"""The one solver source: compiled by numba against the same source run as plain Python, status codes,
and the problem data."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from drake_estop.planning import backend, solver
from drake_estop.planning.assembly import stop_problem
from drake_estop.planning.gait import GaitParameters, NominalPattern
from drake_estop.planning.planner import InfeasibleStop, StopParameters, plan_stop
from drake_estop.planning.rollout import stride_ticks
from drake_estop.planning.solver import solve_phases

ROOT = Path(__file__).resolve().parents[1]
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
# (gait, parameters, every k-th tick of the stride): the default gait with every parameter set, the
# others with the paper's; short steps exercise the lateral re-solves, stepping in place the at-rest case
SOLVES = [("default", name, 4) for name in PARAMS] + [(gait, "paper", 9) for gait in GAITS if gait != "default"]
PLANS = [("default", 12), ("short", 16), ("in-place", 16), ("long-slow", 20)]


def _solutions():
    """Phase solutions (or the exception's type and message), Newton-problem evaluations and whole plans,
    as exact float lists: run in this process and, un-jitted, in a subprocess."""
    out = {"solve": [], "point": [], "plan": []}
    rng = np.random.default_rng(0)
    for gait, name, every in SOLVES:
        pattern, params = NominalPattern(GAITS[gait]), PARAMS[name]
        for t in stride_ticks(pattern, params)[::every]:
            problem, kind, _ = stop_problem(pattern, pattern.state(float(t)), params)
            try:
                s = solve_phases(problem, kind)
                out["solve"].append([s.landing, s.transition, s.slowdown, s.target, s.cost, s.iterations,
                                     *s.continuous])
            except (InfeasibleStop, ValueError) as error:  # (any InfeasibleStop, whatever its subclass)
                out["solve"].append(["InfeasibleStop" if isinstance(error, InfeasibleStop) else "ValueError",
                                     str(error)])
            if name == "paper" and gait == "default" and out["solve"][-1][0] != "InfeasibleStop":
                free = list(problem.free)  # near the continuous optimum, off the active limits
                x = np.array(out["solve"][-1][6:])[[0, 1, 3]][free] * rng.uniform(0.97, 0.99, len(free)) + 0.001
                cost, *arrays = problem.evaluate(x)
                out["point"].append([cost, *np.concatenate([a.ravel() for a in arrays]).tolist(),
                                     *problem.values(x)[1].tolist(), problem.values(x)[0]])
    for gait, every in PLANS:
        pattern = NominalPattern(GAITS[gait])
        for t in stride_ticks(pattern, PARAMS["paper"])[::every]:
            plan = plan_stop(pattern, float(t))
            out["plan"].append([plan.case, plan.landing_time, plan.transition_end, plan.slowdown_end,
                                plan.halt_end, plan.step_length, plan.zmp_max, plan.newton_iterations,
                                plan.cost, plan.min_zmp_margin, *plan.x.zmp.ravel().tolist(),
                                *plan.y.zmp.ravel().tolist()])
    return out


def _close(a, b, rel):
    if isinstance(a, float) and isinstance(b, float):
        return a == b or abs(a - b) <= rel * max(abs(a), abs(b), 1e-12) or (a != a and b != b)
    return a == b


@pytest.mark.skipif(not backend.COMPILED, reason="numba missing or DRAKE_ESTOP_PURE_PYTHON set: nothing compiled")
def test_compiled_equals_the_same_source_run_as_python():
    """Phase solutions (durations, Z, cost, Newton iterations, continuous optimum), the Newton problem's
    cost, constraints and derivatives, and whole plans (phase times, step length / ZMP_max, ZMP
    polynomials of every phase, halt included): compiled against ``DRAKE_ESTOP_PURE_PYTHON=1`` (the
    same functions, not compiled), which shows that the guarded source means the same in both.
    Measured: equal to the bit; checked to 1e-12 relative."""
    script = ("import json, sys; sys.path[:0] = [sys.argv[1], sys.argv[2]]; import test_solver; "
              "from drake_estop.planning import backend; assert not backend.COMPILED; "
              "print(json.dumps(test_solver._solutions()))")
    env = dict(os.environ, DRAKE_ESTOP_PURE_PYTHON="1")
    run = subprocess.run([sys.executable, "-c", script, str(ROOT), str(ROOT / "tests")], env=env,
                         capture_output=True, text=True, timeout=300, check=True)
    python = json.loads(run.stdout)
    compiled = json.loads(json.dumps(_solutions()))
    infeasible = 0
    for key in ("solve", "point", "plan"):
        assert len(compiled[key]) == len(python[key]), key
        for i, (a, b) in enumerate(zip(compiled[key], python[key])):
            assert len(a) == len(b) and all(_close(x, y, 1e-12) for x, y in zip(a, b)), (key, i, a, b)
            infeasible += key == "solve" and a[0] == "InfeasibleStop"
    assert len(compiled["solve"]) > 100 and len(compiled["point"]) > 20 and len(compiled["plan"]) > 30
    assert infeasible > 0  # the next-step fallback's first attempts: the status path is compared too


def test_infeasible_start_is_reported_not_solved(pattern, params, stride_times):
    problem, kind, _ = stop_problem(pattern, pattern.state(stride_times[0]), params)
    n, m, _ = solver.dims(problem.data)
    x0 = problem.bounds()[list(problem.free), 1] + 1.0  # above every upper bound
    newton = backend.python_function(solver.barrier_newton)  # called from Python it would compile on every run
    *_, status = newton(problem.data, x0, m, 1e-2, 1e-8, 0.1, 100, 1e-8)
    assert status == -1 and len(x0) == n
    with pytest.raises(ValueError, match="strictly feasible"):
        solver._raise_for(solver.INFEASIBLE_START, problem, kind)


def test_points_where_no_slowdown_stops_the_cog_are_infeasible_not_nan(pattern, params, stride_times):
    """Far outside the bounds (negative or absurd durations, where exp over- or underflows and
    plain Python would raise): cost inf, every constraint -1, no NaN."""
    problem, kind, _ = stop_problem(pattern, pattern.state(stride_times[10]), params)
    assert kind == "single"
    for x in ([0.3, 0.2, 5.0], [-1e3, 0.2, 0.3], [0.3, -1e3, 0.3], [1e3, 1e3, 0.3]):
        cost, g = problem.values(np.array(x))
        assert cost == np.inf and np.all(g == -1.0), x
        _, jg, jh, g, gg, gh = problem.evaluate(np.array(x))
        assert np.all(g[6:8] == -1.0) and g[10] == -1.0, x  # slowdown limits and rear reach
        assert not any(np.any(np.isnan(a)) for a in (g, gg, gh)), x


def test_problem_data_must_be_finite(pattern, params):
    state = pattern.state(pattern.stride()[0] + 0.1)
    problem, kind, _ = stop_problem(pattern, state, params)
    problem.start = type(problem.start)(float("nan"), 0.0)
    with pytest.raises(ValueError, match="finite"):
        problem.data  # noqa: B018


def test_stride_solves_use_the_compiled_solver_when_numba_is_there():
    assert backend.COMPILED == (backend.numba is not None and not os.environ.get("DRAKE_ESTOP_PURE_PYTHON")
                                and not backend.numba.config.DISABLE_JIT)
    if backend.COMPILED:
        assert hasattr(solver.solve, "py_func") and hasattr(solver.barrier_newton, "py_func")
