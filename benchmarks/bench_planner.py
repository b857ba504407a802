"""Planner speed and quality over every servo tick of one stride of the default gait.

Prints, measured in this one run: plan compute time (median, max), parameter
solve time, Newton iterations, the generic-solver (scipy SLSQP) time on the
same problems and the ratio, the share of next-step fallbacks, and the
quantisation residual with and without re-solving the ZMP value
(``--objective time``: the plan times, fallbacks and times to rest of the time
objective).

    python benchmarks/bench_planner.py [--repeats 3] [--objective paper|time]

Imports the installed ``drake_estop`` (``pip install -e .`` or ``pip install .``);
no path set-up.
"""

from __future__ import annotations

import argparse
import platform
import time

import numpy as np
from reference import reference_solve

from drake_estop.planning.gait import NominalPattern
from drake_estop.planning.planner import StopParameters, plan_stop, solve_continuous, stop_problem, warm_up
from drake_estop.planning.rollout import stride_ticks


def sweep(pattern, params, repeats):
    warm_up(pattern, params)  # load the compiled solver first, as the stop-planner system does
    times = stride_ticks(pattern, params)
    plans, compute, solve = [], [], []
    for t in times:
        best = None
        for _ in range(repeats):  # min over repeats per instant: machine noise out, plan unchanged
            plan = plan_stop(pattern, t, params)
            if best is None or plan.compute_time < best.compute_time:
                best = plan
        plans.append(best)
        compute.append(best.compute_time)
        solve.append(best.solve_time)
    return times, plans, np.array(compute), np.array(solve)


def scipy_comparison(pattern, params, times):
    ours, theirs, single_start, gaps = [], [], [], []
    for t in times:
        problem, kind, _ = stop_problem(pattern, pattern.state(t), params)
        start = time.perf_counter()
        try:
            _, _, cost, _ = solve_continuous(problem, kind)
        except Exception:
            cost = None
        ours.append(time.perf_counter() - start)
        start = time.perf_counter()
        ref = reference_solve(problem, kind)
        theirs.append(time.perf_counter() - start)
        start = time.perf_counter()
        reference_solve(problem, kind, starts_per_axis=1)
        single_start.append(time.perf_counter() - start)
        if cost is not None and ref is not None:
            gaps.append((cost - ref[0]) / ref[0])
    return np.array(ours), np.array(theirs), np.array(single_start), np.array(gaps)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--scipy-every", type=int, default=8, help="compare with scipy at every k-th tick")
    parser.add_argument("--objective", choices=("paper", "time"), default="paper",
                        help="StopParameters.objective of the plans timed")
    args = parser.parse_args()
    pattern = NominalPattern()
    params = StopParameters(objective=args.objective)
    print(f"machine: {platform.processor() or platform.machine()}, python {platform.python_version()}")
    from drake_estop.planning import backend
    print("solver backend: " + (f"compiled (numba {backend.numba.__version__}, planning.solver)" if backend.COMPILED
                                else "plain Python (numba missing, DRAKE_ESTOP_PURE_PYTHON or NUMBA_DISABLE_JIT set)"))
    times, plans, compute, solve = sweep(pattern, params, args.repeats)
    iterations = np.array([p.newton_iterations for p in plans])
    fallback = [p for p in plans if p.case != "one-step"]
    single = sum(p.support == "single" for p in plans)
    print(f"stride: {len(plans)} servo ticks from {times[0]:.3f} s"
          f" ({single} single, {len(plans) - single} double support)")
    print(f"plan compute time   median {np.median(compute) * 1e3:.3f} ms   max {compute.max() * 1e3:.3f} ms"
          f"   (target: median < 0.5 ms, max < 5 ms)")
    print(f"parameter solve     median {np.median(solve) * 1e3:.3f} ms   max {solve.max() * 1e3:.3f} ms"
          "   (grid start + Newton + quantisation)")
    print(f"Newton iterations   median {np.median(iterations):.0f}   max {iterations.max()}")
    print(f"next-step fallback  {len(fallback)}/{len(plans)} = {100 * len(fallback) / len(plans):.1f} % "
          f"at {[round(p.signal_time, 3) for p in fallback]}")
    rest = np.array([np.linalg.norm(p.com([p.halt_end])[1]) for p in plans])
    print(f"COG speed at halt end: max {rest.max():.2e} m/s;"
          f" min ZMP margin {min(p.min_zmp_margin for p in plans):.4f} m")
    to_rest = np.array([p.halt_end - p.signal_time for p in plans])
    print(f"time to rest        median {np.median(to_rest):.3f} s   max {to_rest.max():.3f} s")
    if args.objective == "time":  # the rest is about the paper's phase-parameter solve
        return
    rounded = StopParameters(quantisation="round")
    residual = []
    for t in times[::4]:
        plan = plan_stop(pattern, t, rounded)
        residual.append(abs(plan.com([plan.slowdown_end])[1][0, 0]))
    resolved = [abs(p.com([p.slowdown_end])[1][0, 0]) for p in plans]
    print(f"quantisation: COG velocity at slowdown end, rounded times only: max {max(residual) * 1e3:.2f} mm/s;"
          f" re-solved: max {max(resolved) * 1e3:.2e} mm/s")
    sample = times[:: args.scipy_every]
    ours, theirs, single_start, gaps = scipy_comparison(pattern, params, sample)
    print(f"scipy SLSQP (paper's variables, multi-start) on {len(sample)} instants:"
          f" median {np.median(theirs) * 1e3:.1f} ms;"
          f" single start {np.median(single_start) * 1e3:.1f} ms;"
          f" ours (continuous solve) {np.median(ours) * 1e3:.2f} ms")
    print(f"speed-up: {np.median(theirs) / np.median(ours):.0f}x vs multi-start, "
          f"{np.median(single_start) / np.median(ours):.1f}x vs single start (target >= 20x)")
    print(f"cost gap to scipy: max {gaps.max():+.2e} (relative; negative = Newton better)")


if __name__ == "__main__":
    main()
