"""Per-tick cost of the one-step feasibility check over every servo tick of one stride.

    python benchmarks/bench_feasibility.py [--repeats 3]

Imports the installed ``drake_estop`` (``pip install -e .`` or ``pip install .``);
no path set-up.

Prints median / p99 / max [ms] against the 5 ms servo tick (and a 1 ms one) of:

* ``one_step_feasible`` solved on the tick (the function; the planner's first attempt),
  per tick the fastest of ``--repeats`` calls (machine noise out, answer unchanged);
* the StopPlannerSystem update while walking, nominal walk (the answer looked up in the
  table computed at construction), timed by the diagram's TickTimer;
* the same update with a measured COG 5 cm/s faster than the reference (past a 5 mm
  ``replan_threshold``): the live solve from the measured state on every tick;
* the one-off construction cost of the nominal table (the whole walk).
"""

from __future__ import annotations

import argparse
import platform
import time

import numpy as np
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import Adder, ConstantVectorSource

from drake_estop.planning.gait import NominalPattern
from drake_estop.planning.planner import StopParameters, one_step_feasible, warm_up
from drake_estop.planning.rollout import stride_ticks
from drake_estop.systems.decision import StopPlannerConfig
from drake_estop.systems.reference import WalkingPatternSource
from drake_estop.systems.stop_controller import StopPlannerSystem
from drake_estop.systems.stop_numerics import _table
from drake_estop.timing import TickTimer


def stats(seconds):
    ms = np.asarray(seconds) * 1e3
    return np.median(ms), np.percentile(ms, 99), ms.max()


def line(label, seconds, servo=5.0):
    median, p99, worst = stats(seconds)
    return (f"{label:<46} median {median:7.3f}  p99 {p99:7.3f}  max {worst:7.3f} ms"
            f"   ({worst / servo * 100:5.1f} % of a {servo:g} ms tick at worst; 1 ms servo: "
            f"{'fits' if worst < 1.0 else 'p99 fits' if p99 < 1.0 else 'median fits' if median < 1.0 else 'no'})")


def function_costs(pattern, params, ticks, repeats):
    out, answers = [], []
    for t in ticks:
        best = np.inf
        for _ in range(repeats):
            start = time.perf_counter()
            answer = one_step_feasible(pattern, t, params)
            best = min(best, time.perf_counter() - start)
        out.append(best)
        answers.append(answer)
    return np.array(out), answers


def system_costs(pattern, params, ticks, velocity_offset=None):
    """Per-tick wall time of the planner's update over ``ticks`` (not latched)."""
    timer = TickTimer(params.servo_period)
    builder = DiagramBuilder()
    options = {} if velocity_offset is None else {"replan_threshold": 0.005}
    planner = builder.AddSystem(StopPlannerSystem(pattern=pattern, params=params, timer=timer,
                                                  config=StopPlannerConfig(**options)))
    builder.Connect(builder.AddSystem(ConstantVectorSource([0.0, np.nan])).get_output_port(), planner.stop_port)
    if velocity_offset is not None:  # measured = the reference + a constant COG velocity offset
        source = builder.AddSystem(WalkingPatternSource(pattern=pattern))
        builder.Connect(source.GetOutputPort("com"), planner.measured_com_port)
        adder = builder.AddSystem(Adder(2, 3))
        builder.Connect(source.GetOutputPort("com_vel"), adder.get_input_port(0))
        builder.Connect(builder.AddSystem(ConstantVectorSource([velocity_offset, 0.0, 0.0])).get_output_port(),
                        adder.get_input_port(1))
        builder.Connect(adder.get_output_port(), planner.measured_com_vel_port)
    simulator = Simulator(builder.Build())
    simulator.get_mutable_context().SetTime(ticks[0])
    simulator.Initialize()
    simulator.AdvanceTo(ticks[-1] + params.servo_period / 2)
    return timer.per_tick(since=ticks[0])


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    pattern, params = NominalPattern(), StopParameters()
    print(f"machine: {platform.processor() or platform.machine()}, python {platform.python_version()}")
    warm_up(pattern, params)
    ticks = stride_ticks(pattern, params)
    costs, answers = function_costs(pattern, params, ticks, args.repeats)
    print(f"stride: {len(ticks)} servo ticks from {ticks[0]:.3f} s, {sum(answers)} one-step, "
          f"{len(ticks) - sum(answers)} not")
    print(line("one_step_feasible (solved on the tick)", costs))
    one, other = costs[np.array(answers)], costs[~np.array(answers)]
    print(f"  one-step ticks median {np.median(one) * 1e3:.3f} ms, next-step ticks median "
          f"{np.median(other) * 1e3:.3f} ms (the failed first attempt)")
    print(line("planner update, nominal walk (table lookup)", system_costs(pattern, params, ticks)))
    print(line("planner update, measured +5 cm/s (live solve)", system_costs(pattern, params, ticks, 0.05)))
    start = time.perf_counter()
    table = _table(pattern, params)
    print(f"nominal table at construction: {len(table)} ticks ({pattern.end_time:.2f} s walk) in "
          f"{time.perf_counter() - start:.2f} s")


if __name__ == "__main__":
    main()
