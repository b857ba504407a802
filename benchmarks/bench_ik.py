"""Benchmark the warm-started whole-body IK along a walking-like motion.

Run from the repository root:

    python benchmarks/bench_ik.py [--steps 2000]

Imports the installed ``drake_estop`` (``pip install -e .`` or ``pip install .``);
no path set-up.

Prints median / 95th percentile / max solve time of ``WholeBodyIkSolver``
(each solve warm-started from the previous solution, targets 5 ms apart)
and of one ``WholeBodyIK`` discrete update, plus the worst errors.
"""

import argparse
import math
import time

import numpy as np
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.multibody.plant import MultibodyPlant
from pydrake.systems.analysis import Simulator

from drake_estop.model import UPPER_BODY_JOINTS, load_humanoid, nominal_standing_configuration
from drake_estop.systems.ik import WholeBodyIK, WholeBodyIkSolver, pose_vector

PERIOD = 0.005


def walking_targets(steps, *, stride=0.2, cycle=1.6, com_height=0.814):
    """COG / sole / arm targets of a 0.25 m/s walk with 5 cm foot lift."""
    for k in range(steps):
        t = k * PERIOD
        phase = (t % cycle) / cycle
        swing = math.sin(2 * math.pi * phase)
        x = stride / (cycle / 2) * t
        com = np.array([x, 0.06 * math.sin(2 * math.pi * t / cycle),
                        com_height + 0.005 * math.sin(4 * math.pi * t / cycle)])
        left = RigidTransform(RollPitchYaw(0.0, 0.0, 0.05 * swing),
                              [x + 0.1 * swing, 0.095, max(0.0, 0.05 * swing)])
        right = RigidTransform(RollPitchYaw(0.0, 0.0, 0.0),
                               [x - 0.1 * swing, -0.095,
                                max(0.0, -0.05 * swing)])
        upper = {"l_shoulder_pitch": -0.3 * swing, "r_shoulder_pitch": 0.3 * swing,
                 "l_elbow": -0.3, "r_elbow": -0.3}
        yield com, left, right, upper


def bench_solver(plant, steps):
    """Time ``steps`` consecutive warm-started solves; return stats."""
    solver = WholeBodyIkSolver(plant)
    q = nominal_standing_configuration(plant)
    times, worst, iters, failures = [], np.zeros(3), [], 0
    for com, left, right, upper in walking_targets(steps):
        start = time.perf_counter()
        result = solver.solve(q, com, left, right, None, upper)
        times.append(time.perf_counter() - start)
        q = result.q
        iters.append(result.iterations)
        failures += not result.success
        worst = np.maximum(worst, [result.com_error, result.foot_position_error,
                                   result.foot_rotation_error])
    return np.array(times[1:]) * 1e3, worst, np.array(iters), failures


def bench_system(plant, steps):
    """Time ``steps`` discrete updates of the WholeBodyIK System."""
    system = WholeBodyIK(plant=plant, servo_period=PERIOD)
    context = system.CreateDefaultContext()
    simulator = Simulator(system, context)
    index = {n: i for i, n in enumerate(UPPER_BODY_JOINTS)}
    times = []
    for k, (com, left, right, upper) in enumerate(walking_targets(steps)):
        vector = np.zeros(len(UPPER_BODY_JOINTS))
        for name, angle in upper.items():
            vector[index[name]] = angle
        system.com_port.FixValue(context, com)
        system.left_foot_port.FixValue(context, pose_vector(left))
        system.right_foot_port.FixValue(context, pose_vector(right))
        system.upper_body_port.FixValue(context, vector)
        start = time.perf_counter()
        simulator.AdvanceTo((k + 1) * PERIOD)
        times.append(time.perf_counter() - start)
    return np.array(times[1:]) * 1e3


def main():
    """Parse arguments, run both benchmarks, print a summary."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=2000)
    args = parser.parse_args()
    plant = MultibodyPlant(0.0)
    load_humanoid(plant)
    plant.Finalize()
    times, worst, iters, failures = bench_solver(plant, args.steps)
    print(f"WholeBodyIkSolver.solve over {args.steps} walking-like targets:")
    print(f"  median {np.median(times):.3f} ms  p95 "
          f"{np.percentile(times, 95):.3f} ms  max {times.max():.3f} ms")
    print(f"  iterations mean {iters.mean():.2f} max {iters.max()}  "
          f"failures {failures}")
    print(f"  worst errors: COG {worst[0] * 1e3:.4f} mm, foot "
          f"{worst[1] * 1e3:.4f} mm, foot rot {worst[2]:.2e} rad")
    sys_times = bench_system(plant, min(args.steps, 1000))
    print(f"WholeBodyIK discrete update (Simulator.AdvanceTo one period): "
          f"median {np.median(sys_times):.3f} ms  max {sys_times.max():.3f} ms")


if __name__ == "__main__":
    main()
