"""Fingerprint of the stop planner's output, to check that a refactoring leaves the plans unchanged.

For several gaits and every servo tick of one stride, plans the stop and records the case,
the support, the phase times, step length / ZMP_max, the Newton iterations, the cost, the
ZMP margin and the COG / ZMP / feet sampled over the stop; a few re-plans after a push too.

    python benchmarks/plan_fingerprint.py dump out.json       # plans of the installed package
    python benchmarks/plan_fingerprint.py compare a.json b.json [--tol 1e-9]

``compare`` prints the largest absolute difference of the numbers (and any differing case,
support or number of entries) and exits non-zero above ``--tol``. Run ``dump`` once with the
compiled solver and once with ``DRAKE_ESTOP_PURE_PYTHON=1`` to fingerprint both paths.
"""

from __future__ import annotations

import argparse
import json
import math
import sys

import numpy as np

from drake_estop.planning.gait import GaitParameters, NominalPattern
from drake_estop.planning.planner import InfeasibleStop, StopParameters, plan_stop, replan_stop
from drake_estop.planning.rollout import stride_ticks

GAITS = {
    "default": GaitParameters(),
    "short": GaitParameters(step_length=0.02),
    "in-place": GaitParameters(step_length=0.0),
    "long-slow": GaitParameters(step_length=0.35, step_time=1.0, double_support_ratio=0.3),
}
PARAMS = {
    "paper": StopParameters(),
    "round": StopParameters(quantisation="round"),
    "offset": StopParameters(landing_zmp_offset=0.05, a_ss=20.0, b_ds=500.0),
}
CASES = [(g, "paper") for g in GAITS] + [("default", "round"), ("default", "offset")]
SAMPLES = 25  # COG / ZMP samples from the signal to 0.3 s past the halt end


def _number(value):
    if value is None:
        return None
    value = float(value)
    return value if math.isfinite(value) else str(value)


def _fingerprint(plan):
    times = np.linspace(plan.signal_time, max(plan.halt_end, plan.signal_time) + 0.3, SAMPLES)
    pos, vel, _, zmp = plan.com(times)
    feet = [plan.feet(t) for t in times[::4]]
    record = {
        "case": plan.case, "support": plan.support, "start_support": plan.start_support,
        "landing_foot": plan.landing_foot,
        "numbers": [_number(v) for v in (plan.start_time, plan.landing_time, plan.transition_end,
                                         plan.slowdown_end, plan.halt_end, plan.step_length, plan.zmp_max,
                                         plan.newton_iterations, plan.cost, plan.min_zmp_margin)],
        "continuous": [_number(v) for v in (plan.continuous_solution or ())],
        "samples": [_number(v) for v in np.concatenate([pos.ravel(), vel.ravel(), zmp.ravel()])],
        "feet": [_number(v) for f in feet for side in ("left", "right") for v in f[side]],
    }
    return record


def dump(path):
    out = {}
    for gait_name, params_name in CASES:
        pattern, params = NominalPattern(GAITS[gait_name]), PARAMS[params_name]
        entries = []
        for i, t in enumerate(stride_ticks(pattern, params)):
            try:
                plan = plan_stop(pattern, float(t), params)
            except InfeasibleStop as error:
                entries.append({"t": float(t), "infeasible": str(error)})
                continue
            entry = {"t": float(t), **_fingerprint(plan)}
            if gait_name == "default" and i % 6 == 0 and plan.x is not None:
                # a push 0.1 s into the stop: re-plan from a COG 1 cm / 5 cm/s off the plan
                tick = plan.start_time + 20 * params.servo_period
                pos, vel, _, _ = plan.com([tick])
                try:
                    new = replan_stop(plan, tick, pos[0] + [0.01, -0.005], vel[0] + [0.05, 0.02])
                    entry["replan"] = None if new is None else _fingerprint(new)
                except InfeasibleStop as error:
                    entry["replan"] = {"infeasible": str(error)}
            entries.append(entry)
        out[f"{gait_name}/{params_name}"] = entries
    with open(path, "w") as handle:
        json.dump(out, handle)
    print(f"{path}: {sum(len(v) for v in out.values())} plans")


def _diff(a, b, where, report):
    """Largest absolute difference between two fingerprint entries (inf on a structural change)."""
    if isinstance(a, dict) and isinstance(b, dict):
        if set(a) != set(b):
            report.append(f"{where}: keys {sorted(a)} vs {sorted(b)}")
            return math.inf
        return max([_diff(a[k], b[k], f"{where}/{k}", report) for k in a] or [0.0])
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            report.append(f"{where}: {len(a)} vs {len(b)} entries")
            return math.inf
        return max([_diff(x, y, f"{where}[{i}]", report) for i, (x, y) in enumerate(zip(a, b))] or [0.0])
    if isinstance(a, float) and isinstance(b, float):
        return abs(a - b)
    if a != b:
        report.append(f"{where}: {a!r} vs {b!r}")
        return math.inf
    return 0.0


def compare(path_a, path_b, tol):
    with open(path_a) as handle:
        a = json.load(handle)
    with open(path_b) as handle:
        b = json.load(handle)
    report = []
    worst = 0.0
    for key in a:
        if key not in b:
            report.append(f"{key}: missing")
            worst = math.inf
            continue
        value = _diff(a[key], b[key], key, report)
        print(f"{key:20s} {len(a[key]):4d} plans  max abs difference {value:.3e}")
        worst = max(worst, value)
    for line in report[:20]:
        print("  " + line)
    print(f"max abs difference over all plans: {worst:.3e} (tolerance {tol:.0e})")
    return 0 if worst <= tol else 1


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("dump").add_argument("path")
    cmp = sub.add_parser("compare")
    cmp.add_argument("a")
    cmp.add_argument("b")
    cmp.add_argument("--tol", type=float, default=1e-9)
    args = parser.parse_args(argv)
    if args.command == "dump":
        dump(args.path)
        return 0
    return compare(args.a, args.b, args.tol)


if __name__ == "__main__":
    sys.exit(main())
