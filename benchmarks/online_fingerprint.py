"""Fingerprint of online physics runs, to check that a change leaves the closed loop unchanged to the bit.

Runs four online stops that exercise the whole loop (the paper's 3.4 s stop; a 17 N s push to the
right at 2.95 s with sensor noise and one tick of latency, which re-plans; a 25 N s forward push
in double support with the masses x1.1, which takes a recovery step; a 29 N s forward push at
3.15 s with the torso COM 2 cm forward) and keeps every measured and commanded series of each
(the robot's COG, CoP, pelvis height, torso tilt and soles, the plan's COG and ZMP, the IK's joint
positions, the estimated COG, the per-tick one-step feasibility).

    python benchmarks/online_fingerprint.py dump before.npz      # with the installed package
    python benchmarks/online_fingerprint.py compare before.npz after.npz

``compare`` exits 0 when every series is equal to the last bit, else 1 and names the first series
that differs, where and by how much. The bits depend on the machine (numpy's BLAS kernels are
chosen per processor), so compare dumps made on one machine: before and after a change (a speed-up
that must not change behaviour, for example).
"""

from __future__ import annotations

import argparse
import sys
from concurrent.futures import ProcessPoolExecutor

import numpy as np

SCENARIOS = {
    "paper_3.4": (3.4, {}),
    "push_right_noise_latency": (2.95, {"pushes": [(2.95, 0.0, -170.0, 0.1)], "sensor_noise": True,
                                        "latency_ticks": 1, "seed": 3}),
    "double_support_forward_mass": (3.55, {"pushes": [(3.55, 250.0, 0.0, 0.1)], "mass_scale": 1.1}),
    "forward_29_torso_com": (3.15, {"pushes": [(3.15, 290.0, 0.0, 0.1)], "torso_com_offset": 0.02}),
}


def series(name: str) -> dict:
    """Run scenario ``name``; its series by field name (arrays)."""
    from drake_estop.physics.online import controller_stop_parameters, run_online
    from drake_estop.physics.perturbations import Perturbations, Push
    from drake_estop.planning.gait import NominalPattern

    estop_time, options = SCENARIOS[name]
    options = dict(options)
    pushes = tuple(Push(*push) for push in options.pop("pushes", ()))
    result = run_online(estop_time=estop_time, pattern=NominalPattern(), stop_params=controller_stop_parameters(),
                        perturbations=Perturbations(pushes=pushes, **options))
    out = {field: np.asarray(getattr(result, field)) for field in (
        "times", "cop_x", "cop_y", "normal_force", "pelvis_z", "com_meas_x", "com_meas_y", "com_meas_z",
        "com_plan", "zmp_plan", "torso_tilt", "cop_margin_plan")}
    for side, values in result.feet_meas.items():
        out[f"feet_meas_{side}"] = np.asarray(values)
    out["ik_q"] = np.asarray(result.reference.q)
    out["com_est"] = np.asarray(result.online["com_est"])
    out["one_step_feasible"] = np.asarray(result.online["one_step_feasible"])
    return out


def dump(path: str, workers: int = 2) -> None:
    with ProcessPoolExecutor(workers) as pool:
        runs = dict(zip(SCENARIOS, pool.map(series, SCENARIOS)))
    np.savez(path, **{f"{name}/{field}": values for name, fields in runs.items() for field, values in fields.items()})
    print(f"{path}: {sum(len(fields) for fields in runs.values())} series of {len(runs)} runs")


def compare(path_a: str, path_b: str) -> int:
    """0 if every series of the two dumps is equal to the bit (NaN equal to NaN), else 1 (printed why)."""
    a, b = np.load(path_a), np.load(path_b)
    if set(a.files) != set(b.files):
        print(f"different series: only in {path_a}: {sorted(set(a.files) - set(b.files))}, "
              f"only in {path_b}: {sorted(set(b.files) - set(a.files))}")
        return 1
    for key in sorted(a.files):
        x, y = a[key], b[key]
        if x.shape != y.shape:
            print(f"{key}: shape {x.shape} against {y.shape}")
            return 1
        if not np.array_equal(x, y, equal_nan=True):
            differ = np.flatnonzero(~((x == y) | (np.isnan(x) & np.isnan(y))).ravel())
            print(f"{key}: {len(differ)} of {x.size} values differ, the first at flat index {differ[0]}, "
                  f"largest difference {np.nanmax(np.abs(x - y)):.3g}")
            return 1
    print(f"every one of the {len(a.files)} series is equal to the bit")
    return 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    commands = parser.add_subparsers(dest="command", required=True)
    dump_parser = commands.add_parser("dump", help="run the scenarios and write their series")
    dump_parser.add_argument("path")
    dump_parser.add_argument("--workers", type=int, default=2)
    compare_parser = commands.add_parser("compare", help="exit 0 if two dumps are equal to the bit")
    compare_parser.add_argument("a")
    compare_parser.add_argument("b")
    args = parser.parse_args(argv)
    if args.command == "dump":
        if args.workers < 1:
            parser.error(f"--workers must be >= 1, got {args.workers}")
        dump(args.path, args.workers)
        return 0
    return compare(args.a, args.b)


if __name__ == "__main__":
    sys.exit(main())
