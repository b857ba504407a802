"""Each robot's stop over a stride, through the kinematic Drake diagram (trigger, planner, whole-body IK).

    python benchmarks/bench_robots.py [--robots default g1 talos] [--every 1] [--json out.json]

Imports the installed ``drake_estop`` (the G1 and TALOS need ``pip install -e '.[robots]'``).
For every ``--every``-th servo tick of the robot's stride (single then double support of its third
step), runs one stop through one diagram (:func:`drake_estop.systems.stride.sweep_stride`) and
prints a table: signals, one-step share, the IK's worst COG and sole errors, ticks over the IK's
bounds (1 mm, 1 mm, 0.01 rad), joint-ticks over a speed limit, time to rest (median, worst), the
whole body's ZMP in the stops (its least margin in the soles, the limbs' momentum included, and the
signals whose stop puts it outside), the same ZMP in the walk without a stop (its largest shift from
the plan and least margin, the LIPM's COG against :func:`drake_estop.systems.whole_body_walk.corrected_walk`'s
corrected one), the signals that do not stop in one step, and the robot's gait and limits.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

from drake_estop.robots.parameters import as_robot, gait_parameters, stop_parameters
from drake_estop.systems.stride import rows_as_dicts, stride_summary, sweep_stride
from drake_estop.systems.whole_body_walk import corrected_walk, walk_zmp_shift

HEADER = ("| robot | signals | one-step | IK COG max [mm] | IK sole max [mm] | ticks over IK bounds | "
          "joint-speed violations | time to rest median / worst [s] | whole-body ZMP margin min [mm] / "
          "stops outside the soles | walk's whole-body ZMP off the plan max [mm] / margin min [mm]: LIPM COG -> "
          "corrected COG | run [s] |")


def run_robot(name: str, every: int) -> dict:
    """The sweep of robot ``name``: its summary, rows, gait, stop limits and wall time [s]."""
    description = as_robot(name)
    start = time.perf_counter()
    rows = sweep_stride(robot=description, every=every)
    gait, stop = gait_parameters(description), stop_parameters(description)
    walk = corrected_walk(description, gait)  # its first pass measures the LIPM's walk
    walks = {"lipm": walk.lipm_shift, "corrected": walk_zmp_shift(walk.pattern, description)}
    return {"robot": name, "summary": stride_summary(rows), "rows": rows_as_dicts(rows),
            "walk": {kind: {"zmp_shift_max_m": walk.largest, "zmp_margin_min_m": walk.least_margin}
                     for kind, walk in walks.items()},
            "gait": {"com_height": gait.com_height, "step_length": gait.step_length, "step_width": gait.step_width,
                     "step_time": gait.step_time, "lift_height": gait.lift_height},
            "stop": {"max_fore_reach": stop.max_fore_reach, "max_rear_reach": stop.max_rear_reach,
                     "crouch_depth": stop.crouch_depth}, "wall_time": time.perf_counter() - start}


def table(results: list) -> str:
    """A markdown table of the results of :func:`run_robot`, then each robot's signals that take two steps."""
    lines = [HEADER, "| --- " * (HEADER.count("|") - 1) + "|"]
    for result in results:
        s = result["summary"]
        lines.append(f"| {result['robot']} | {s['signals']} | {s['one_step']} ({100 * s['one_step_share']:.0f} %) | "
                     f"{s['ik_com_error_max_m'] * 1e3:.3f} | {s['ik_foot_error_max_m'] * 1e3:.3f} | "
                     f"{s['ik_ticks_over_bounds']} | {s['velocity_limit_violations']} | "
                     f"{s['time_to_rest_median_s']:.3f} / {s['time_to_rest_max_s']:.3f} | "
                     f"{_mm(s['stop_multibody_zmp_margin_min_m'])} / {s['signals_with_multibody_zmp_outside']} | "
                     f"{_walk(result['walk'])} | {result['wall_time']:.0f} |")
    for result in results:
        others = [row for row in result["rows"] if row["case"] != "one-step"]
        gait, stop = result["gait"], result["stop"]
        lines.append(f"\n{result['robot']}: gait {gait}, stop {stop}; not one-step: "
                     + (", ".join(f"{row['signal_time']:.3f} s ({row['support']}, {row['case']})" for row in others)
                        or "none"))
    return "\n".join(lines)


def _mm(value) -> str:
    """A length [m] in mm, or "none" (no stop with a sole on the floor to measure it in)."""
    return "none" if value is None or value != value else f"{value * 1e3:.1f}"


def _walk(walk: dict) -> str:
    return " -> ".join(f"{walk[kind]['zmp_shift_max_m'] * 1e3:.1f} / {_mm(walk[kind]['zmp_margin_min_m'])}"
                       for kind in ("lipm", "corrected"))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", nargs="+", default=["default", "g1", "talos"], help="robot names or files")
    parser.add_argument("--every", type=int, default=1, help="signal spacing in servo ticks (default %(default)s)")
    parser.add_argument("--json", help="write the summaries and every row here")
    args = parser.parse_args(argv)
    if args.every < 1:
        parser.error("--every must be >= 1")
    results = [run_robot(name, args.every) for name in args.robots]
    print(table(results))
    if args.json:
        with open(args.json, "w") as handle:
            json.dump(results, handle, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
