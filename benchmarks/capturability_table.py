"""What each robot can catch: the largest impulsive push speed that leaves its walk N-step capturable
(N <= 3; drake_estop.planning.capturability), by direction and moment of the stride, with crossover steps as
far as the robot's legs allow (what the online verdict uses), as far as the soles alone allow, and without.
The LIPM's bound on what any controller can catch, not a simulation.

    python benchmarks/capturability_table.py [--robots default g1 talos] [--out benchmarks/CAPTURABILITY.md]

Moments (the third step's stride): early single support (0.1 s after lift-off), late single support
(0.1 s before touchdown), mid double support. Directions, in single support, relative to the foot
standing alone: inward (towards it: its sole's outer edge is the ankle's last hold, beyond it only a
crossover lands), outward, forward, backward; in double support inward is towards the rear foot's side.
Searched upwards in 0.01 m/s steps.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace

import numpy as np

from drake_estop.planning.capturability import largest_push_speed, state_capturability
from drake_estop.planning.gait import NominalPattern
from drake_estop.robots import gait_parameters, stepping_limits, stop_parameters
from drake_estop.robots.parameters import REFERENCE_CROSSOVER_REACH, as_robot, leg_scale

#: The crossover variants of the table: name -> the crossover reach [m] (None: the robot's legs decide)
CROSSOVERS = {"legs": None, "soles": REFERENCE_CROSSOVER_REACH, "none": 0.0}

DIRECTIONS = ("inward", "outward", "forward", "backward")


def moments(pattern: NominalPattern) -> dict:
    """Name -> time [s] of the third step's early and late single support and mid double support."""
    step = pattern.steps[2]
    return {"early single support": step["liftoff"] + 0.1, "late single support": step["touchdown"] - 0.1,
            "double support": (step["touchdown"] + step["step_end"]) / 2}


def direction(state, name: str) -> np.ndarray:
    """The world direction of ``name`` (:data:`DIRECTIONS`) for ``state``'s support."""
    side = state.support_foot or state.rear_foot or "left"
    lateral = np.array([0.0, 1.0 if side == "left" else -1.0])  # towards the stance (rear) foot's side
    return {"inward": lateral, "outward": -lateral, "forward": np.array([1.0, 0.0]),
            "backward": np.array([-1.0, 0.0])}[name]


def robot_rows(robot_name: str) -> list:
    """Table rows of one robot: (robot, moment, crossovers, its reach [m], speed per direction...)."""
    robot = as_robot(robot_name)
    pattern, params = NominalPattern(gait_parameters(robot)), stop_parameters(robot)
    limits = stepping_limits(robot, params)
    variants = {name: limits if reach is None else replace(limits, crossover_reach=round(reach * leg_scale(robot), 3))
                for name, reach in CROSSOVERS.items()}
    rows = []
    for moment, t in moments(pattern).items():
        state = pattern.state(t)
        assert state_capturability(state, omega=pattern.w, limits=limits, params=params).capturable
        for name, lim in variants.items():
            rows.append((robot.name, moment, name, f"{lim.crossover_reach:.3f}",
                         *(largest_push_speed(state, direction(state, d), omega=pattern.w, limits=lim, params=params)
                           for d in DIRECTIONS)))
    return rows


def markdown(rows: list, seconds: float) -> str:
    lines = ["# What each robot can catch", "",
             "The largest impulsive push speed [m/s] that leaves the walk capturable in at most three steps "
             "(LIPM with finite feet, `drake_estop.planning.capturability`), by direction and moment of the "
             "third step's stride. Crossovers: *legs*, landings past the stance ankle as far as the robot's legs "
             "keep clear (`drake_estop.robots.stepping_limits`: the online verdict's; the default humanoid's "
             "leg capsules allow none; the G1 and TALOS have no leg model, so theirs is the soles' reach); "
             "*soles*, up to 0.10 m past it (scaled with the leg), the soles 1 cm apart; *none*. A bound on what "
             "any controller catches, not a simulation. Made by `python benchmarks/capturability_table.py` in "
             f"{seconds:.1f} s.", "",
             "| robot | moment | crossovers | reach [m] | " + " | ".join(DIRECTIONS) + " |",
             "|---|---|---|---|" + "---|" * len(DIRECTIONS)]
    lines += ["| " + " | ".join([*row[:4], *(f"{v:.2f}" for v in row[4:])]) + " |" for row in rows]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", nargs="+", default=["default", "g1", "talos"])
    parser.add_argument("--out", default=None, help="write the table here (markdown) as well as to stdout")
    args = parser.parse_args(argv)
    start = time.perf_counter()
    rows = [row for name in args.robots for row in robot_rows(name)]
    text = markdown(rows, time.perf_counter() - start)
    print(text)
    if args.out:
        with open(args.out, "w") as out:
            out.write(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
