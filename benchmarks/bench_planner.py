"""Planner speed and quality over every servo tick of one stride of the default gait.

Prints, measured in this one run: plan compute time (median, max), parameter
solve time, Newton iterations, the generic-solver (scipy SLSQP) time on the
same problems and the ratio, the share of next-step fallbacks, and the
quantisation residual with and without re-solving the ZMP value
(``--objective time``: the plan times, fallbacks and times to rest of the time
objective, the largest backward COG speed along the walk, and next to the times to
rest the LIPM's own lower bound, :func:`lipm_rest_bound`, on the plan's footholds).

    python benchmarks/bench_planner.py [--repeats 3] [--objective paper|time] [--bound-every 4] [--table]

``--table`` prints instead one markdown table of both objectives (the paper's, with the default and with
eq. 20's slowdown ZMP, and the time objective): fallbacks, monotonicity, plan time, time to rest, backward
COG speed and the LIPM bound (:func:`planner_table`, the table of benchmarks/RESULTS.md).

Imports the installed ``drake_estop`` (``pip install -e .`` or ``pip install .``);
no path set-up.
"""

from __future__ import annotations

import argparse
import math
import platform
import time

import numpy as np
import scipy.sparse
from reference import reference_solve
from scipy.optimize import linprog

from drake_estop.planning.assembly import stop_problem
from drake_estop.planning.brake import rest_points
from drake_estop.planning.gait import NominalPattern
from drake_estop.planning.planner import StopParameters, plan_stop, warm_up
from drake_estop.planning.rollout import stride_ticks
from drake_estop.planning.solver import solve_continuous


def sweep(pattern, params, repeats, every=1):
    warm_up(pattern, params)  # load the compiled solver first, as the stop-planner system does
    times = stride_ticks(pattern, params)[::every]
    plans, compute, solve = [], [], []
    for t in times:
        best = None
        for _ in range(repeats):  # min over repeats per instant: machine noise out, plan unchanged
            plan = plan_stop(pattern, t, params)
            if best is None or plan.compute_time < best.compute_time:
                best = plan
        plans.append(best)
        compute.append(best.compute_time)
        solve.append(best.solve_time)
    return times, plans, np.array(compute), np.array(solve)


MAX_ZMP_RATE = 3.0  # [m/s] the ZMP's speed limit of the LIPM bound


def lipm_rest_bound(com, com_vel, zmp, midpoint, polygon_at, w, dt, margin, max_zmp_rate=MAX_ZMP_RATE,
                    monotone=False, max_ticks=600, rest_to=None):
    """The least time [s] in which the LIPM can come to rest at ``midpoint``, or anywhere on the segment
    from ``midpoint`` to ``rest_to``: a time-optimal LP over the ZMP.

    The ZMP ``p_k`` is held over each servo tick ``[k dt, (k + 1) dt)`` (zero-order hold) and the COG
    follows x'' = w^2 (x - p) (eq. 4) exactly over it; per axis, with the divergent and convergent
    components ``xi = x + v/w``, ``zeta = x - v/w``, ``xi_{k+1} - p_k = e^a (xi_k - p_k)`` and
    ``zeta_{k+1} - p_k = e^-a (zeta_k - p_k)``, ``a = w dt``. The LIPM is at rest at ``midpoint`` after
    N ticks iff ``xi_N = zeta_N = midpoint`` and the ZMP is there from then on. Constraints: ``p_k``
    at least ``margin`` inside ``polygon_at(k)``; ``|p_{k+1} - p_k| <= max_zmp_rate dt`` per axis, from
    the start ZMP ``zmp`` to ``p_0`` and from ``p_{N-1}`` to the midpoint; with ``monotone``, the COG
    velocity along x never negative. The smallest feasible N (LP feasibility, bisection on N: at rest
    after N ticks is at rest after N + 1) times ``dt``; inf if none up to ``max_ticks``.

    Parameters
    ----------
    com, com_vel, zmp, midpoint : array_like, (2,)
        The COG position [m] and velocity [m/s] and the ZMP [m] at the start; the rest point [m].
    rest_to : array_like, (2,), optional
        With it, the rest point is free on the segment from ``midpoint`` to it (one more LP variable).
    polygon_at : callable
        ``polygon_at(k)``: the support polygon (:class:`~drake_estop.planning.geometry.SupportPolygon`)
        over tick ``k``.
    w, dt, margin : float
        LIPM natural frequency sqrt(g / z) [1/s], tick [s], ZMP distance kept from the edges [m].
    max_zmp_rate : float
        Largest ZMP speed per axis [m/s].
    monotone : bool
        Also require the COG velocity along x to stay non-negative (no backing up).
    max_ticks : int
        Longest horizon searched.

    Returns
    -------
    float
        The least time to rest [s] (a multiple of ``dt``), or inf.
    """
    com, com_vel, zmp, midpoint = (np.asarray(v, float)[:2] for v in (com, com_vel, zmp, midpoint))
    if np.allclose(com, midpoint, atol=1e-12) and np.allclose(com_vel, 0.0, atol=1e-12) and np.allclose(
            zmp, midpoint, atol=1e-12):
        return 0.0
    polygons = {}

    def polygon(k):
        if k not in polygons:
            polygons[k] = polygon_at(k)
        return polygons[k]

    span = np.zeros(2) if rest_to is None else np.asarray(rest_to, float)[:2] - midpoint

    def feasible(ticks):
        return _rest_lp(com, com_vel, zmp, midpoint, [polygon(k) for k in range(ticks)], w, dt, margin,
                        max_zmp_rate, monotone, span)

    low, high = 0, 8
    while not feasible(high):
        low, high = high, 2 * high
        if high > max_ticks:
            return math.inf
    while high - low > 1:
        middle = (low + high) // 2
        low, high = (low, middle) if feasible(middle) else (middle, high)
    return high * dt


def _rest_lp(com, com_vel, zmp, midpoint, polygons, w, dt, margin, max_zmp_rate, monotone, span):
    """Whether a ZMP sequence over ``len(polygons)`` ticks brings the LIPM to rest at ``midpoint + s span``
    for some ``s`` in [0, 1] (:func:`lipm_rest_bound`'s LP; variables: ``p_x`` then ``p_y`` per tick, then ``s``)."""
    n = len(polygons)
    size = 2 * n + 1
    a = w * dt
    xi0, zeta0 = com + com_vel / w, com - com_vel / w
    ticks = np.arange(n)
    # the terminal conditions, scaled by e^-Na (xi) so that both rows are of order one
    xi_row = (1.0 - math.exp(a)) * np.exp(-(ticks + 1) * a)  # e^-Na xi_N = xi0 + sum xi_row p
    zeta_row = (1.0 - math.exp(-a)) * np.exp(-(n - 1 - ticks) * a)  # zeta_N = e^-Na zeta0 + sum zeta_row p
    equality, rhs = [], []
    for axis in range(2):
        for row, value, rest_gain in ((xi_row, midpoint[axis] * math.exp(-n * a) - xi0[axis], math.exp(-n * a)),
                                      (zeta_row, midpoint[axis] - math.exp(-n * a) * zeta0[axis], 1.0)):
            full = np.zeros(size)
            full[axis * n:(axis + 1) * n] = row
            full[2 * n] = -rest_gain * span[axis]
            equality.append(full)
            rhs.append(value)
    # the support polygons: n . p_k <= offset - margin
    rows, cols, values, bounds = [], [], [], []
    count = 0
    for k, poly in enumerate(polygons):
        for normal, offset in zip(poly._normals, poly._offsets):
            rows += [count, count]
            cols += [k, n + k]
            values += [normal[0], normal[1]]
            bounds.append(offset - margin)
            count += 1
    # the ZMP rate: |p_k - p_{k-1}| <= max_zmp_rate dt, p_{-1} the start ZMP, and p_{n-1} to the midpoint
    step = max_zmp_rate * dt
    for axis in range(2):
        for k in range(n + 1):
            for sign in (1.0, -1.0):
                known = 0.0
                if k < n:
                    rows.append(count)
                    cols.append(axis * n + k)
                    values.append(sign)
                else:
                    known += sign * midpoint[axis]
                    rows.append(count)
                    cols.append(2 * n)
                    values.append(sign * span[axis])
                if k > 0:
                    rows.append(count)
                    cols.append(axis * n + k - 1)
                    values.append(-sign)
                else:
                    known -= sign * zmp[axis]
                bounds.append(step - known)
                count += 1
    upper = scipy.sparse.csr_matrix((values, (rows, cols)), shape=(count, size))
    bounds = np.array(bounds)
    if monotone:  # v_k = w (xi_k - zeta_k) / 2 >= 0 along x, k = 1..n
        k = ticks[:, None] + 1
        j = ticks[None, :]
        before = j < k
        xi_gain = np.where(before, (1.0 - math.exp(a)) * np.exp((k - 1 - j) * a), 0.0)
        zeta_gain = np.where(before, (1.0 - math.exp(-a)) * np.exp(-(k - 1 - j) * a), 0.0)
        speed = np.zeros((n, size))
        speed[:, :n] = -(xi_gain - zeta_gain)
        upper = scipy.sparse.vstack([upper, scipy.sparse.csr_matrix(speed)]).tocsr()
        bounds = np.concatenate([bounds, np.exp(k[:, 0] * a) * xi0[0] - np.exp(-k[:, 0] * a) * zeta0[0]])
    result = linprog(np.zeros(size), A_ub=upper, b_ub=bounds, A_eq=np.array(equality), b_eq=np.array(rhs),
                     bounds=[(None, None)] * (2 * n) + [(0.0, 1.0)], method="highs")
    return result.status == 0


def plan_rest_bound(plan, monotone=False, free_rest=True):
    """:func:`lipm_rest_bound` from ``plan``'s start state on its own footholds (the support sole until
    its landing time, then both soles at its landing position: ``plan.polygon`` at each tick's middle),
    with its ``zmp_margin``; from the signal [s] (the plan starts at the signal or, finishing the nominal
    step, at its touchdown). The rest anywhere the time objective may rest it (``free_rest``: on the
    segment from the feet's midpoint toward the fore ankle, within the rear leg's reach,
    :func:`~drake_estop.planning.brake.rest_points`), else at the midpoint."""
    state, dt = plan.start_state, plan.params.servo_period
    midpoint = 0.5 * (plan.final_feet["left"] + plan.final_feet["right"])
    rear, fore = sorted(plan.final_feet.values(), key=lambda xy: float(xy[0]))
    rest_to = rest_points(rear, fore, plan.params.max_rear_reach)[-1] if free_rest else None
    bound = lipm_rest_bound(state.com, state.com_vel, state.zmp, midpoint,
                            lambda k: plan.polygon(plan.start_time + (k + 0.5) * dt), plan.pattern.w, dt,
                            plan.params.zmp_margin, monotone=monotone, rest_to=rest_to)
    return plan.start_time - plan.signal_time + bound


def backward_speed(plan):
    """The largest COG speed backwards along the walk (negative x velocity) [m/s] at the servo ticks from
    the plan start to the rest, and the largest lateral overshoot: how far the COG passes the midpoint
    sideways, from the side it starts on [m]."""
    dt = plan.params.servo_period
    times = plan.start_time + dt * np.arange(int(round((plan.halt_end - plan.start_time) / dt)) + 1)
    pos, vel, _, _ = plan.com(times)
    midpoint = 0.5 * (plan.final_feet["left"] + plan.final_feet["right"])
    side = np.sign(pos[0, 1] - midpoint[1])
    return max(0.0, float(-vel[:, 0].min())), max(0.0, float((-side * (pos[:, 1] - midpoint[1])).max()))


def time_objective_report(plans, to_rest, bound_every):
    """The time objective's backward COG speed, and its times to rest next to the LIPM's own bound."""
    backward, lateral = np.array([backward_speed(p) for p in plans]).T
    swing = np.array([p.support == "single" and p.case == "one-step" for p in plans])
    print(f"COG backwards along the walk: max {backward.max() * 1e3:.1f} mm/s;"
          f" {int(np.sum(backward > 5e-3))}/{len(plans)} plans above 5 mm/s"
          f" (single-support one-step: {int(np.sum(backward[swing] > 5e-3))});"
          f" lateral overshoot of the midpoint max {lateral.max() * 1e3:.1f} mm")
    dt = plans[0].params.servo_period
    rates = [np.abs(np.diff(p.com(p.start_time + dt * np.arange(int(round((p.halt_end - p.start_time) / dt)) + 1))[3],
                            axis=0)).max() / dt for p in plans]
    sample = list(range(0, len(plans), bound_every))
    start = time.perf_counter()
    bound = np.array([plan_rest_bound(plans[i]) for i in sample])
    forward = np.array([plan_rest_bound(plans[i], monotone=True) for i in sample])
    elapsed = time.perf_counter() - start
    ours = to_rest[sample]
    single = np.array([plans[i].support == "single" for i in sample])
    print(f"LIPM bound (LP, ZMP {plans[0].params.zmp_margin * 1e3:.0f} mm inside the plan's footholds,"
          f" |dZMP/dt| <= {MAX_ZMP_RATE} m/s) at every {bound_every}th tick ({len(sample)}, {elapsed:.0f} s):"
          f" median {np.median(bound):.3f} s   max {bound.max():.3f} s;"
          f" the plans there: median {np.median(ours):.3f} s   max {ours.max():.3f} s")
    print(f"  single support ({int(single.sum())}): bound median {np.median(bound[single]):.3f} s,"
          f" plans {np.median(ours[single]):.3f} s; plans below the bound (their ZMP moves faster,"
          f" up to {max(rates):.1f} m/s): {int(np.sum(ours < bound - 1e-9))}")
    print(f"  without backing up (COG velocity along x >= 0): possible at {int(np.isfinite(forward).sum())}"
          f"/{len(sample)}; bound median {np.median(forward[np.isfinite(forward)]):.3f} s where possible")


def monotone_one_step(plans) -> bool:
    """Whether one-step feasibility is monotone over each single support: once a signal falls back to the
    next step (III.C), no later signal of that support phase stops in one step."""
    fell_back = False
    for previous, plan in zip([None, *plans], plans):
        if previous is None or plan.support != "single" or previous.support != "single":
            fell_back = False
        if plan.support != "single":
            continue
        if plan.case != "one-step":
            fell_back = True
        elif fell_back:
            return False
    return True


#: the rows of :func:`planner_table`: label, StopParameters overrides
TABLE_ROWS = (
    ("paper objective (J_ss, J_ds; slowdown ZMP 5 cm ahead of the landing ankle, the default)", {}),
    ("paper objective, slowdown ZMP at the landing ankle (eq. 20)", {"landing_zmp_offset": 0.0}),
    ('`objective="time"` (soonest rest between the feet)', {"objective": "time"}),
)


def planner_table(pattern, repeats=3, bound_every=4, every=1):
    """Markdown lines: both objectives over every servo tick of the stride, measured in this run. Per row:
    the next-step fallbacks (III.C) and where, whether feasibility is monotone over single support, the plan
    compute time (min of ``repeats`` per tick after :func:`warm_up`), the time to rest, the largest backward
    COG speed along the walk, and the LIPM's own least time to rest (:func:`plan_rest_bound`, every
    ``bound_every``-th tick, on each plan's own footholds); every ``every``-th tick of the stride."""
    lines = ["| planner | one-step (fallbacks) | monotone | plan median / max [ms] | rest median / worst [s] |"
             " COG backwards max [mm/s] (plans > 5 mm/s) | LIPM bound median / worst [s] |",
             "| --- | --- | --- | --- | --- | --- | --- |"]
    for label, overrides in TABLE_ROWS:
        params = StopParameters(**overrides)
        times, plans, compute, _ = sweep(pattern, params, repeats, every)
        fallbacks = [round(float(p.signal_time), 3) for p in plans if p.case != "one-step"]
        where = f" at {fallbacks[0]:.3f}-{fallbacks[-1]:.3f} s" if fallbacks else ""
        to_rest = np.array([p.halt_end - p.signal_time for p in plans])
        backward = np.array([backward_speed(p)[0] for p in plans])
        bound = np.array([plan_rest_bound(plans[i]) for i in range(0, len(plans), bound_every)])
        lines.append(
            f"| {label} | {len(plans) - len(fallbacks)}/{len(plans)} ({len(fallbacks)}{where}) |"
            f" {'yes' if monotone_one_step(plans) else 'no'} |"
            f" {np.median(compute) * 1e3:.2f} / {compute.max() * 1e3:.2f} |"
            f" {np.median(to_rest):.3f} / {to_rest.max():.3f} |"
            f" {backward.max() * 1e3:.0f} ({int(np.sum(backward > 5e-3))}) |"
            f" {np.median(bound):.3f} / {bound.max():.3f} |")
    return lines


def scipy_comparison(pattern, params, times):
    ours, theirs, single_start, gaps = [], [], [], []
    for t in times:
        problem, kind, _ = stop_problem(pattern, pattern.state(t), params)
        start = time.perf_counter()
        try:
            _, _, cost, _ = solve_continuous(problem, kind)
        except Exception:
            cost = None
        ours.append(time.perf_counter() - start)
        start = time.perf_counter()
        ref = reference_solve(problem, kind)
        theirs.append(time.perf_counter() - start)
        start = time.perf_counter()
        reference_solve(problem, kind, starts_per_axis=1)
        single_start.append(time.perf_counter() - start)
        if cost is not None and ref is not None:
            gaps.append((cost - ref[0]) / ref[0])
    return np.array(ours), np.array(theirs), np.array(single_start), np.array(gaps)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--scipy-every", type=int, default=8, help="compare with scipy at every k-th tick")
    parser.add_argument("--objective", choices=("paper", "time"), default="paper",
                        help="StopParameters.objective of the plans timed")
    parser.add_argument("--bound-every", type=int, default=4,
                        help="--objective time: the LIPM's least time to rest (an LP) at every k-th tick")
    parser.add_argument("--table", action="store_true",
                        help="only the markdown table of both objectives (benchmarks/RESULTS.md's planner table)")
    args = parser.parse_args()
    pattern = NominalPattern()
    params = StopParameters(objective=args.objective)
    print(f"machine: {platform.processor() or platform.machine()}, python {platform.python_version()}")
    if args.table:
        print("\n".join(planner_table(pattern, args.repeats, args.bound_every)))
        return
    from drake_estop.planning import backend
    print("solver backend: " + (f"compiled (numba {backend.numba.__version__}, planning.solver)" if backend.COMPILED
                                else "plain Python (numba missing, DRAKE_ESTOP_PURE_PYTHON or NUMBA_DISABLE_JIT set)"))
    times, plans, compute, solve = sweep(pattern, params, args.repeats)
    iterations = np.array([p.newton_iterations for p in plans])
    fallback = [p for p in plans if p.case != "one-step"]
    single = sum(p.support == "single" for p in plans)
    print(f"stride: {len(plans)} servo ticks from {times[0]:.3f} s"
          f" ({single} single, {len(plans) - single} double support)")
    print(f"plan compute time   median {np.median(compute) * 1e3:.3f} ms   max {compute.max() * 1e3:.3f} ms"
          f"   (target: median < 0.5 ms, max < 5 ms)")
    print(f"parameter solve     median {np.median(solve) * 1e3:.3f} ms   max {solve.max() * 1e3:.3f} ms"
          "   (grid start + Newton + quantisation)")
    print(f"Newton iterations   median {np.median(iterations):.0f}   max {iterations.max()}")
    print(f"next-step fallback  {len(fallback)}/{len(plans)} = {100 * len(fallback) / len(plans):.1f} % "
          f"at {[round(p.signal_time, 3) for p in fallback]}")
    rest = np.array([np.linalg.norm(p.com([p.halt_end])[1]) for p in plans])
    print(f"COG speed at halt end: max {rest.max():.2e} m/s;"
          f" min ZMP margin {min(p.min_zmp_margin for p in plans):.4f} m")
    to_rest = np.array([p.halt_end - p.signal_time for p in plans])
    print(f"time to rest        median {np.median(to_rest):.3f} s   max {to_rest.max():.3f} s")
    if args.objective == "time":  # the rest is about the paper's phase-parameter solve
        time_objective_report(plans, to_rest, args.bound_every)
        return
    rounded = StopParameters(quantisation="round")
    residual = []
    for t in times[::4]:
        plan = plan_stop(pattern, t, rounded)
        residual.append(abs(plan.com([plan.slowdown_end])[1][0, 0]))
    resolved = [abs(p.com([p.slowdown_end])[1][0, 0]) for p in plans]
    print(f"quantisation: COG velocity at slowdown end, rounded times only: max {max(residual) * 1e3:.2f} mm/s;"
          f" re-solved: max {max(resolved) * 1e3:.2e} mm/s")
    sample = times[:: args.scipy_every]
    ours, theirs, single_start, gaps = scipy_comparison(pattern, params, sample)
    print(f"scipy SLSQP (paper's variables, multi-start) on {len(sample)} instants:"
          f" median {np.median(theirs) * 1e3:.1f} ms;"
          f" single start {np.median(single_start) * 1e3:.1f} ms;"
          f" ours (continuous solve) {np.median(ours) * 1e3:.2f} ms")
    print(f"speed-up: {np.median(theirs) / np.median(ours):.0f}x vs multi-start, "
          f"{np.median(single_start) / np.median(ours):.1f}x vs single start (target >= 20x)")
    print(f"cost gap to scipy: max {gaps.max():+.2e} (relative; negative = Newton better)")


if __name__ == "__main__":
    main()
