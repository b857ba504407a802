"""Benchmark the closed-loop physics diagram (planner -> DCM stabiliser -> IK -> PD servos, online).

Run from the repository root:

    python benchmarks/bench_closed_loop.py [--estop-time 3.4] [--sweep] [--no-preview]

Imports the installed ``drake_estop`` (``pip install -e .`` or ``pip install .``);
no path set-up.

Prints the real-time factor of ``Simulator.AdvanceTo`` of the closed-loop
diagram (median of ``--repeats`` runs, 3 by default) and the success
criteria of the run; with ``--sweep`` also runs a closed-loop stop for every
``--every`` s (20 ms) over the third step's stride (``NominalPattern().stride()``:
lift-off to the next lift-off) and prints the success share and each failure.

By default the run combines the online feedback with the OFFLINE
ZmpPreviewFilter COG feedforward (``run_closed_loop(use_preview_filter=True)``),
because the feedback alone does not keep the robot up (see
``drake_estop.physics.stabilizer``); ``--no-preview`` measures the feedback alone.
"""

import argparse
import statistics
import time

import numpy as np

from drake_estop.physics.plant import StabilizerParameters, run_closed_loop
from drake_estop.planning.gait import GaitParameters, NominalPattern
from drake_estop.planning.planner import StopParameters


def _failed(result):
    return [name for name, ok in result.criteria.items() if not ok]


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--estop-time", type=float, default=3.4)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--no-preview", action="store_true", help="feedback alone (no offline feedforward)")
    parser.add_argument("--open-loop", action="store_true", help="cut the feedback (online IK only)")
    parser.add_argument("--sweep", action="store_true")
    parser.add_argument("--every", type=float, default=0.02)
    args = parser.parse_args()
    gait, stop = GaitParameters(), StopParameters()
    pattern = NominalPattern(gait)
    preview = not args.no_preview
    stab = StabilizerParameters(enabled=not args.open_loop)
    label = (f"{'feedback cut' if args.open_loop else 'DCM feedback'}"
             f"{' + OFFLINE preview feedforward' if preview else ' alone'}")
    results = []
    for _ in range(args.repeats):
        results.append(run_closed_loop(gait, stop, args.estop_time, pattern=pattern,
                                       use_preview_filter=preview, stabilizer=stab))
    rtfs = [r.realtime_factor for r in results]
    last = results[-1]
    print(f"closed-loop physics diagram ({label}), stop at {args.estop_time} s "
          f"({last.plan.case}, {last.plan.support} support)")
    print(f"  simulated {last.sim_time:.2f} s; real-time factor median {statistics.median(rtfs):.2f} "
          f"of {args.repeats} ({', '.join(f'{r:.2f}' for r in rtfs)})")
    if preview:
        print(f"  offline preview feedforward (IK + filter, before the run): {last.ik_wall_time:.2f} s")
    print(f"  criteria: {last.criteria}  success={last.success}")
    if not args.sweep:
        return
    start, end = pattern.stride()
    times = start + args.every * np.arange(int(round((end - start) / args.every)))
    ok, rows, begin = 0, [], time.perf_counter()
    for t in times:
        try:
            r = run_closed_loop(gait, stop, float(t), pattern=pattern, use_preview_filter=preview, stabilizer=stab)
            n = r.numbers()
            rows.append((float(t), r.success, r.plan.case, r.plan.support, _failed(r), n))
            ok += r.success
        except Exception as error:  # noqa: BLE001 - reported
            rows.append((float(t), False, "-", "-", [f"{type(error).__name__}: {error}"], {}))
        t_, success, case, support, failed, n = rows[-1]
        detail = "" if success or not n else (
            f" pelvis_z_min {n['pelvis_z_min_m']:.3f} tilt_max {n['torso_tilt_max_rad']:.3f} "
            f"slip {max(n['slip_left_m'], n['slip_right_m']):.4f} rest_after_halt {n['rest_after_halt_s']:.2f} "
            f"final_offset {n['final_cog_offset_m']:.4f} cop_margin {n['cop_margin_plan_min_m']:.4f}")
        print(f"  t={t_:.2f} {case:>10s} {support:>6s} {'OK' if success else 'FAIL ' + ','.join(failed)}{detail}",
              flush=True)
    print(f"closed-loop sweep ({label}): {ok}/{len(times)} stops meet every criterion "
          f"({100.0 * ok / len(times):.0f} %), {time.perf_counter() - begin:.0f} s")


if __name__ == "__main__":
    main()
