"""Stopping quality and speed of this planner against the alternatives, in one run.

Same gait, same signal instants (every servo tick of one stride, single and
double support):

* this planner (Morisawa et al. 2005, as implemented here), with the paper's
  objective (J_ss, J_ds) and with ``objective="time"`` (the soonest rest between
  the feet, drake_estop/planning/brake.py);
* "finish the step": nominal landing, then a double-support stop with the ZMP
  anywhere in the fore sole (hrpsys-base / IHMC / lipm_walking_controller style);
* Drake's ZmpPlanner re-plan that stops at the next footstep, with its default
  weights and tuned for tight tracking of its ZMP reference (a sweep of R,
  reported with the results);
* the capture-point bound (one-step capturability, Koolen et al. 2012).

Writes benchmarks/RESULTS.md (table, machine, command) and a figure.

    python benchmarks/compare_methods.py [--every 1] [--out benchmarks]

Imports the installed ``drake_estop`` (``pip install -e .`` or ``pip install .``);
no path set-up.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import sys
import time
from dataclasses import replace
from pathlib import Path

import alternatives
import bench_planner
import numpy as np
from reference import reference_solve

from drake_estop.planning.assembly import stop_problem
from drake_estop.planning.gait import GaitParameters, NominalPattern
from drake_estop.planning.planner import InfeasibleStop, StopParameters, plan_stop
from drake_estop.planning.rollout import rollout, stride_ticks
from drake_estop.planning.solver import solve_continuous


def _progress(iterable, **kwargs):
    try:
        from tqdm import tqdm

        return tqdm(iterable, **kwargs)
    except ImportError:  # pragma: no cover - tqdm is a dependency
        return iterable


def plan_metrics(plan):
    """Metrics of a StopPlan: steps, time to rest, COG travel after the signal, ZMP margin."""
    data = rollout(plan, after_halt=0.0, start=plan.signal_time)
    travel = float(np.sum(np.linalg.norm(np.diff(data.com[:, :2], axis=0), axis=1)))
    return {
        "steps": plan.steps_after_signal,
        "time_to_rest": plan.halt_end - plan.signal_time,
        "travel": travel,
        "margin": plan.min_zmp_margin,
        "compute": plan.compute_time,
        "case": plan.case,
    }


# ZmpPlanner tuned for tracking its ZMP reference: LQR weights on the ZMP error (Qy) and on the COG
# acceleration (R); only their ratio matters. R = 1e-4 is where tighter weights stop changing the plan
# (the sweep in zmp_planner_tuning, written to RESULTS.md); its default is Qy = I, R = 0.1 I.
TUNED_QY = np.eye(2)
TUNED_R = 1e-4 * np.eye(2)
TUNING_R = (1.0, 0.1, 1e-2, 1e-3, 1e-4, 1e-6)
TRACKING = 0.01  # [m] the tracking the tuning aims at


def tracking(z):
    """ZmpPlanner: the largest distance [m] of its ZMP from its reference, and the time [s] from the
    signal after which it stays within TRACKING (inf if it never does within the horizon)."""
    error = np.linalg.norm(z.zmp - z.zmp_reference, axis=1)
    off = np.nonzero(error > TRACKING)[0]
    rel = z.times - z.times[0]
    within = 0.0 if not len(off) else (rel[off[-1] + 1] if off[-1] + 1 < len(rel) else math.inf)
    return float(error.max()), float(within)


def zmp_planner_row(z):
    error, within = tracking(z)
    return {"steps": z.steps, "time_to_rest": z.time_to_rest, "travel": z.cog_travel, "margin": z.min_zmp_margin,
            "compute": z.compute_time, "case": "next-footstep", "tracking": error, "tracking_within": within}


def zmp_planner_tuning(times, pattern, params):
    """Lines for RESULTS.md: ZmpPlanner's tracking of its reference against R (Qy = I)."""
    lines = ["| R (Qy = I) | largest ZMP error median / worst [m] | within 1 cm after median / worst [s] |"
             " stopped within one step |", "| --- | --- | --- | --- |"]
    for r in TUNING_R:
        rows = [zmp_planner_row(alternatives.zmp_planner_stop(pattern, t, params, qy=np.eye(2), r=r * np.eye(2)))
                for t in times]
        error = [row["tracking"] for row in rows]
        within = [row["tracking_within"] for row in rows]
        ok = sum(row["steps"] <= 1 and math.isfinite(row["time_to_rest"]) and row["margin"] >= 0 for row in rows)
        lines.append(f"| {r:g} | {np.median(error):.3f} / {max(error):.3f} | {np.median(within):.2f} /"
                     f" {max(within):.2f} | {ok}/{len(rows)} |")
    return lines


def toe_params(pattern, params):
    """The planner with the single-support slowdown ZMP as far forward in the fore sole as the
    double-support stop may put it (``landing_zmp_offset`` = toe - margin; the paper's eq. 20 uses 0)."""
    return replace(params, landing_zmp_offset=pattern.params.sole.toe - params.zmp_margin)


def evaluate(times, pattern, params):
    # warm-up: the first plan of a process loads the compiled solver (numba cache, ~0.3 s)
    plan_stop(pattern, float(times[0]), params)
    plan_stop(pattern, float(times[0]), replace(params, objective="time"))
    rows = []
    for t in _progress(times, desc="instants", unit="tick"):
        row = {"t": float(t), "support": pattern.support_at(t)[0]}
        for name, planner, variant in (("planner", plan_stop, params),
                                       ("planner_eq20", plan_stop, replace(params, landing_zmp_offset=0.0)),
                                       ("planner_toe", plan_stop, toe_params(pattern, params)),
                                       ("planner_time", plan_stop, replace(params, objective="time")),
                                       ("finish_step", alternatives.finish_the_step, params)):
            try:
                row[name] = plan_metrics(planner(pattern, t, variant))
            except InfeasibleStop:
                row[name] = None
        row["zmp_planner"] = zmp_planner_row(alternatives.zmp_planner_stop(pattern, t, params))
        row["zmp_planner_tuned"] = zmp_planner_row(alternatives.zmp_planner_stop(pattern, t, params, qy=TUNED_QY,
                                                                                 r=TUNED_R))
        row["capturable"] = alternatives.one_step_capturable(pattern, t, params)
        rows.append(row)
    return rows


def scipy_ratio(times, pattern, params):
    ours, theirs = [], []
    for t in times:
        problem, kind, _ = stop_problem(pattern, pattern.state(t), params)
        start = time.perf_counter()
        try:
            solve_continuous(problem, kind)
        except InfeasibleStop:
            pass
        ours.append(time.perf_counter() - start)
        start = time.perf_counter()
        reference_solve(problem, kind)
        theirs.append(time.perf_counter() - start)
    return float(np.median(ours)), float(np.median(theirs))


DIAGRAM_SIGNALS = (3.2, 3.4, 3.485, 3.5)  # [s] mid and late single support (3.485: its last tick), double support


def diagram_rtfs(estop_time=3.4):
    """Real-time factors of the kinematic diagram and of the physics diagram on one paper scenario."""
    import warnings

    from drake_estop.physics.offline import run_physics
    from drake_estop.planning.gait import GaitParameters
    from drake_estop.systems.diagram import simulate_diagram

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        kinematic = simulate_diagram(GaitParameters(), StopParameters(), estop_time)
    physics = run_physics(GaitParameters(), StopParameters(), estop_time)
    latch = {}
    with warnings.catch_warnings():  # the plan's time in the diagram, mid and late single support, double support
        warnings.simplefilter("ignore", RuntimeWarning)
        for signal in DIAGRAM_SIGNALS:
            result = simulate_diagram(GaitParameters(), StopParameters(), signal)
            latch[signal] = (result.plan.compute_time, result.plan_wall_time)
    return [
        "Plan time in the kinematic diagram (the stop planner plans the stop of a signal at every walking tick, and"
        " the latch a tick later takes it; the plan's time, then the latch's): "
        + ", ".join(f"{t:.3f} s {1e3 * p:.2f} ms ({1e3 * v:.3f} ms)" for t, (p, v) in latch.items()) + ".",
        "",
        f"Diagram real-time factors (signal {estop_time} s, one run each): kinematic diagram (planner, whole-body IK,"
        f" posed humanoid) {kinematic.realtime_factor:.1f}x over {kinematic.sim_time:.1f} s simulated;"
        f" physics diagram (1 ms SAP plant with contact, PD servos) {physics.realtime_factor:.2f}x,"
        f" {physics.realtime_factor_with_ik:.2f}x including its reference IK and ZMP filter"
        f" ({physics.sim_time:.1f} s simulated; physics criteria met: {physics.success}).",
        "",
    ]


def summarise(rows, method):
    entries = [r[method] for r in rows]
    ok = [e for e in entries if e is not None]
    within = sum(1 for e in ok if e["steps"] <= 1 and math.isfinite(e["time_to_rest"]) and e["margin"] >= 0)
    rest = np.array([e["time_to_rest"] for e in ok])
    compute = np.array([e["compute"] for e in ok])
    return {
        "one_step_share": within / len(rows),
        "rest_median": float(np.median(rest)),
        "rest_worst": float(np.max(rest)),
        "travel_median": float(np.median([e["travel"] for e in ok])),
        "travel_worst": float(np.max([e["travel"] for e in ok])),
        "margin_min": float(np.min([e["margin"] for e in ok])),
        "compute_median": float(np.median(compute)),
        "compute_max": float(np.max(compute)),
        "no_plan": len(entries) - len(ok),
    }


def figure(rows, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = [r["t"] for r in rows]
    fig, axes = plt.subplots(3, 1, figsize=(9, 8), sharex=True)
    names = {"planner": "this planner", "planner_eq20": "this planner, eq. 20",
             "planner_toe": "this planner, ZMP to the toe",
             "planner_time": "this planner, objective 'time'", "finish_step": "finish the step",
             "zmp_planner": "Drake ZmpPlanner", "zmp_planner_tuned": "Drake ZmpPlanner, tuned"}
    for key, label in names.items():
        rest = [r[key]["time_to_rest"] if r[key] else np.nan for r in rows]
        travel = [r[key]["travel"] if r[key] else np.nan for r in rows]
        margin = [r[key]["margin"] if r[key] else np.nan for r in rows]
        axes[0].plot(t, np.where(np.isfinite(rest), rest, np.nan), label=label)
        axes[1].plot(t, travel, label=label)
        axes[2].plot(t, np.array(margin) * 100, label=label)
    cap = [r["t"] for r in rows if not r["capturable"]]
    for ax in axes:
        for x in cap:
            ax.axvspan(x - 0.0025, x + 0.0025, color="0.85", lw=0)
    axes[0].set_ylabel("time to rest [s]")
    axes[1].set_ylabel("COG travel [m]")
    axes[2].set_ylabel("min ZMP margin [cm]")
    axes[2].axhline(0, color="k", lw=0.8)
    axes[2].set_xlabel("stop signal time [s] (grey: not one-step capturable)")
    axes[0].legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def comparison_lines(rows, summaries):
    """The time objective against finishing the step, and ZmpPlanner's tracking of its reference."""
    time, finish = summaries["planner_time"], summaries["finish_step"]
    gain = [r["finish_step"]["time_to_rest"] - r["planner_time"]["time_to_rest"] for r in rows
            if r["finish_step"] and r["planner_time"]]
    lines = [
        f"`objective=\"time\"` against finishing the step: time to rest median {time['rest_median']:.3f} s vs"
        f" {finish['rest_median']:.3f} s ({100 * (1 - time['rest_median'] / finish['rest_median']):.0f} % sooner),"
        f" worst {time['rest_worst']:.3f} s vs {finish['rest_worst']:.3f} s; per signal"
        f" {np.median(gain):.3f} s sooner median ({min(gain):.3f} to {max(gain):.3f} s);"
        f" {sum(r['planner_time']['case'] == 'one-step' for r in rows if r['planner_time'])} of {len(rows)} signals"
        f" land once, replanned, the others finish the nominal step (where the paper's objective does too).",
        "",
    ]
    for key, name in (("zmp_planner", "default"), ("zmp_planner_tuned", "tuned")):
        error = [r[key]["tracking"] for r in rows]
        within = [r[key]["tracking_within"] for r in rows]
        lines.append(f"ZmpPlanner {name}: its ZMP's largest distance from its reference median"
                     f" {np.median(error):.3f} m, worst {max(error):.3f} m; within 1 cm of it from"
                     f" {np.median(within):.2f} s after the signal (median), {max(within):.2f} s worst.")
    lines += [
        "",
        "ZmpPlanner's tracking against its weight R (Qy = I; every 8th signal; the tuned row's R is where"
        " tighter weights stop changing the plan). No weight tracks the reference within 1 cm from the"
        " signal: the reference (the current ZMP, then the midpoint between the feet) ignores the COG's"
        " divergent component at the signal, so the LQR moves the ZMP by 0.2-0.35 m at once to make up for"
        " it, and the error decays with the LIPM's time constant.",
        "",
    ]
    return lines


TURNING_GAITS = {"turning +15 deg per step": dict(turn=15.0), "turning -15 deg per step": dict(turn=-15.0),
                 "side-stepping 4 cm per step, no step length": dict(step_length=0.0, side_step=0.04)}


def turning_lines(params, every=1):
    """The stop methods on turning and side-stepping walks: every tick of the third step's
    stride. The ZmpPlanner peer is left out here: its stop (benchmarks/alternatives.py) places level,
    unturned soles."""
    lines = ["Turning and side-stepping walks (the same stride of the third step, every"
             f" {'' if every == 1 else f'{every}th '}5 ms tick; ZMP margins against the turned soles):", "",
             "| walk | method | stopped within one step | one-step case | time to rest median / worst [s] |"
             " COG travel median / worst [m] | min ZMP margin [cm] | plan time median / max [ms] |",
             "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    methods = (("paper objective", plan_stop, params), ("`objective=\"time\"`", plan_stop,
                                                         replace(params, objective="time")),
               ("finish the step", alternatives.finish_the_step, params))
    for walk, kwargs in TURNING_GAITS.items():
        pattern = NominalPattern(GaitParameters(**kwargs))
        times = stride_ticks(pattern, params)[::every]
        for name, planner, variant in methods:
            planner(pattern, float(times[0]), variant)  # warm-up
            rows = []
            for t in times:
                try:
                    rows.append({"m": plan_metrics(planner(pattern, float(t), variant))})
                except InfeasibleStop:
                    rows.append({"m": None})
            s = summarise(rows, "m")
            one_step = sum(r["m"] is not None and r["m"]["case"] == "one-step" for r in rows)
            lines.append(f"| {walk} | {name} | {100 * s['one_step_share']:.1f} % | {one_step}/{len(rows)} |"
                         f" {s['rest_median']:.3f} / {s['rest_worst']:.3f} | {s['travel_median']:.3f} /"
                         f" {s['travel_worst']:.3f} | {100 * s['margin_min']:.2f} | {1e3 * s['compute_median']:.2f} /"
                         f" {1e3 * s['compute_max']:.2f} |")
    return lines + [""]


def write_results(rows, summaries, ratio, path, figure_name, command, extra_lines):
    lines = [
        "# Stop methods compared",
        "",
        f"Made by `{command}` on {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()},"
        f" {time.strftime('%Y-%m-%d')}. Default gait (0.3 m, 0.8 s, 20 % double support, COG 0.814 m);"
        f" signal at every 5 ms servo tick of the stride {rows[0]['t']:.3f}-{rows[-1]['t']:.3f} s"
        f" ({sum(r['support'] == 'single' for r in rows)} single,"
        f" {sum(r['support'] == 'double' for r in rows)} double support).",
        "",
        "| method | stopped within one step | time to rest median / worst [s] | COG travel median / worst [m] |"
        " min ZMP margin [cm] | plan time median / max [ms] |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    labels = {"planner": "this planner (paper objective; slowdown ZMP 5 cm ahead of the landing ankle, the default)",
              "planner_eq20": "this planner, paper objective, slowdown ZMP at the landing ankle (eq. 20)",
              "planner_toe": "this planner, single-support slowdown ZMP at the fore toe (offset 0.125 m)",
              "planner_time": "this planner, `objective=\"time\"` (soonest rest between the feet)",
              "finish_step": "finish the step (nominal landing)",
              "zmp_planner": "Drake ZmpPlanner, stop at next footstep (default Qy = I, R = 0.1 I)",
              "zmp_planner_tuned": f"Drake ZmpPlanner, stop at next footstep, tuned (Qy = I, R = {TUNED_R[0, 0]:g} I)"}
    for key, label in labels.items():
        s = summaries[key]
        lines.append(
            f"| {label} | {100 * s['one_step_share']:.1f} % | {s['rest_median']:.3f} / {s['rest_worst']:.3f} |"
            f" {s['travel_median']:.3f} / {s['travel_worst']:.3f} | {100 * s['margin_min']:.2f} |"
            f" {1e3 * s['compute_median']:.2f} / {1e3 * s['compute_max']:.2f} |")
    cap = sum(r["capturable"] for r in rows) / len(rows)
    lines.append(f"| capture-point bound (one step) | {100 * cap:.1f} % capturable | - | - | - | - |")
    lines += [
        "",
        "Stopped within one step: at most one foot landing after the signal, the COG at rest"
        " (speed below 1 mm/s for ZmpPlanner, which converges only asymptotically; inf when not within its"
        " 4 s horizon) and the ZMP never outside the support polygon. ZMP margin: smallest distance of the"
        " planned ZMP inside the support polygon (negative: outside).",
        "",
        f"Newton solve of the stop parameters vs scipy SLSQP on the same problems (paper's variables,"
        f" multi-start): median {ratio[0] * 1e3:.2f} ms vs {ratio[1] * 1e3:.1f} ms, {ratio[1] / ratio[0]:.0f}x faster.",
        "",
        *extra_lines,
        f"![metrics against signal time]({figure_name})",
        "",
    ]
    Path(path).write_text("\n".join(lines))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--every", type=int, default=1, help="use every k-th servo tick of the stride")
    parser.add_argument("--out", default=str(Path(__file__).resolve().parent),
                        help="folder for RESULTS.md and the figure")
    parser.add_argument("--scipy-every", type=int, default=10)
    parser.add_argument("--tuning-every", type=int, default=8, help="signals of the ZmpPlanner weight sweep")
    parser.add_argument("--no-diagrams", action="store_true", help="skip the diagrams' real-time factors")
    args = parser.parse_args(argv)
    pattern = NominalPattern()
    params = StopParameters()
    times = stride_ticks(pattern, params)[:: args.every]
    rows = evaluate(times, pattern, params)
    summaries = {key: summarise(rows, key) for key in ("planner", "planner_eq20", "planner_toe", "planner_time",
                                                       "finish_step",
                                                       "zmp_planner", "zmp_planner_tuned")}
    ratio = scipy_ratio(times[:: args.scipy_every], pattern, params)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    figure(rows, out / "compare_methods.png")
    command = "python benchmarks/compare_methods.py " + " ".join(argv if argv is not None else sys.argv[1:])
    extra = ["The planner over the stride, both objectives (`bench_planner.planner_table`: plan time the least of"
             " 3 per tick after the warm-up; the LIPM bound is a time-optimal LP over the ZMP, held per servo tick,"
             f" {params.zmp_margin * 1e3:.0f} mm inside each plan's own footholds, |dZMP/dt| <="
             f" {bench_planner.MAX_ZMP_RATE:g} m/s, the COG at rest where the time objective may rest it: from the"
             " feet's midpoint toward the fore ankle within the rear leg's reach; at every 4th tick):", ""]
    extra += bench_planner.planner_table(pattern, every=args.every) + [""]
    extra += comparison_lines(rows, summaries) + zmp_planner_tuning(times[:: args.tuning_every], pattern, params)
    extra += [""] + turning_lines(params, args.every)
    extra += [""] + ([] if args.no_diagrams else diagram_rtfs())
    write_results(rows, summaries, ratio, out / "RESULTS.md", "compare_methods.png", command.strip(), extra)
    print((out / "RESULTS.md").read_text())
    return rows, summaries


if __name__ == "__main__":
    main()
