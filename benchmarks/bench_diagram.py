"""Real-time factor of the e-stop diagram (no live Meshcat).

    python benchmarks/bench_diagram.py [--runs 5] [--signal 3.4]

Imports the installed ``drake_estop`` (``pip install -e .`` or ``pip install .``);
no path set-up.

Simulates a ~6 s scenario (walk, stop signal, stop, 1 s standing; the run is
extended to 6 s after the halt if needed) and prints the median real-time
factor over ``--runs`` runs, plus a per-tick cost breakdown: the planner's
reference evaluation, one WholeBodyIK update, and the one-off plan_stop.
"""

import argparse
import statistics
import sys
import time
import warnings

import numpy as np

from drake_estop.planning.gait import GaitParameters
from drake_estop.planning.planner import StopParameters
from drake_estop.systems.diagram import build_diagram, run
from drake_estop.systems.reference import reference_vector


def one_run(signal, duration):
    """(simulated seconds, wall seconds, handles, context) of one run."""
    handles = build_diagram(gait_params=GaitParameters(), stop_params=StopParameters(),
                            estop_time=signal)
    plan_end = signal + 1.2  # rough halt end; run() extends to halt + after_halt
    simulator, wall = run(handles, after_halt=max(1.0, duration - plan_end))
    return simulator.get_context().get_time(), wall, handles, simulator.get_context()


def tick_costs(handles, context, samples=400):
    """Median cost [ms] of the reference evaluation and of one IK solve."""
    planner_context = handles.planner.GetMyContextFromRoot(context)
    plan = handles.planner.plan(planner_context)
    times = np.linspace(0.0, plan.halt_end, samples)
    start = time.perf_counter()
    for t in times:
        reference_vector(t, pattern=handles.pattern, plan=plan)
    reference_ms = (time.perf_counter() - start) / samples * 1e3
    ik_context = handles.ik.GetMyContextFromRoot(context)
    solver = handles.ik.solver
    q = handles.ik.q_port.Eval(ik_context)
    ref = reference_vector(plan.halt_end, pattern=handles.pattern, plan=plan)
    durations = []
    for _ in range(samples // 4):
        tick = time.perf_counter()
        solver.solve(q, ref[:3], ref[8:15], ref[15:22])
        durations.append(time.perf_counter() - tick)
    return reference_ms, statistics.median(durations) * 1e3, plan.compute_time * 1e3


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--signal", type=float, default=3.4)
    parser.add_argument("--duration", type=float, default=6.0)
    args = parser.parse_args(argv)
    warnings.simplefilter("ignore", RuntimeWarning)
    factors = []
    for _ in range(args.runs):
        sim, wall, handles, context = one_run(args.signal, args.duration)
        factors.append(sim / wall)
    ticks = sim / handles.planner.params.servo_period
    print(f"{sim:.2f} s simulated, {ticks:.0f} servo ticks; real-time factor median "
          f"{statistics.median(factors):.2f} (min {min(factors):.2f}, max {max(factors):.2f}) "
          f"over {args.runs} runs; {wall / ticks * 1e3:.3f} ms per tick (last run)")
    reference_ms, ik_ms, plan_ms = tick_costs(handles, context)
    print(f"per tick: reference evaluation {reference_ms:.3f} ms, IK solve (converged "
          f"warm start) {ik_ms:.3f} ms; plan_stop once {plan_ms:.2f} ms")
    return 0


if __name__ == "__main__":
    sys.exit(main())
