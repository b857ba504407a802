"""Benchmark the closed-loop physics diagram (humanoid + contact + PD servos + CoP estimator).

Run from the repository root:

    python benchmarks/bench_physics.py [--estop-time 3.4] [--contact point]

Imports the installed ``drake_estop`` (``pip install -e .`` or ``pip install .``);
no path set-up.

Prints the real-time factor of the physics simulation (simulated seconds per
wall-clock second of ``Simulator.AdvanceTo``), the one-off cost of the joint
reference (whole-body IK at every 5 ms tick plus the dynamics filter), the
real-time factor including it, and the success criteria of the run.
"""

import argparse

from drake_estop.physics.offline import run_physics
from drake_estop.physics.plant import PhysicsParameters
from drake_estop.planning.gait import GaitParameters, NominalPattern
from drake_estop.planning.planner import StopParameters


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--estop-time", type=float, default=3.4)
    parser.add_argument("--contact", choices=("point", "hydroelastic"), default="point")
    parser.add_argument("--time-step", type=float, default=1e-3)
    parser.add_argument("--repeats", type=int, default=2)
    args = parser.parse_args()
    physics = PhysicsParameters(contact=args.contact, time_step=args.time_step)
    pattern = NominalPattern(GaitParameters())
    # first run warms the caches (IK plant, nominal-walk filter errors)
    results = [run_physics(GaitParameters(), StopParameters(), args.estop_time, physics=physics,
                           pattern=pattern) for _ in range(args.repeats)]
    best = max(results, key=lambda r: r.realtime_factor)
    last = results[-1]
    print(f"physics diagram, {args.contact} contact, time step {args.time_step * 1e3:g} ms, "
          f"stop at {args.estop_time} s ({last.plan.case}, {last.plan.support} support)")
    print(f"  simulated {best.sim_time:.2f} s in {best.sim_wall_time:.2f} s of AdvanceTo: "
          f"real-time factor {best.realtime_factor:.2f} (best of {args.repeats}; "
          f"{', '.join(f'{r.realtime_factor:.2f}' for r in results)})")
    print(f"  joint reference (IK every tick + dynamics filter): {last.ik_wall_time:.2f} s; "
          f"real-time factor including it {last.realtime_factor_with_ik:.2f}")
    print(f"  criteria: {last.criteria}  success={last.success}")


if __name__ == "__main__":
    main()
