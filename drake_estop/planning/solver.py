"""The phase-parameter solver (III.A, III.B): grid start, interior-point Newton, servo quantisation.

Decision variables ``y = (landing, transition, target)`` (the landing duration is
fixed at zero in double support). The stop condition (eq. 21) is solved for the
slowdown duration, ``T3 = f(y)`` (closed form, :mod:`drake_estop.planning.stop_condition`),
which makes the step-length and ZMP limits simple bounds; it is the same equation the
paper solves for ``l_s`` (eq. 22). The costs are J_ss (eq. 24) and J_ds (eq. 30); the
limits are the variable bounds, the slowdown-duration range, and in single support the
mean swing-ankle speed and the fore-leg reach at touchdown, in both the rear-leg reach
where the COG comes to rest.

Steps of :func:`solve`:

1. :func:`grid_start`: the cheapest strictly feasible point of a grid of durations, the
   target sampled inside its feasible interval for each pair of durations;
2. :data:`barrier_newton`, the interior-point Newton method on :func:`point` (eq. 25-26, 31);
3. :func:`quantise`: every duration on a servo tick, the ZMP value re-solved from the stop
   condition with the snapped times (``quantisation="resolve"``; "round" keeps it).

Written once, in the numba subset (:func:`~drake_estop.planning.backend.jit`; plain Python
without numba or with ``DRAKE_ESTOP_PURE_PYTHON=1``, same results). The problem is one
float64 vector (:meth:`drake_estop.planning.problems.StopProblem.data`, layout below).
Failures come back as status codes (never NaN results); the Python entry points at the end
(:func:`solve_continuous`, :func:`solve_phases`) raise :class:`InfeasibleStop` for them.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from drake_estop.planning.backend import jit
from drake_estop.planning.newton import INFEASIBLE_START as _NEWTON_INFEASIBLE_START
from drake_estop.planning.newton import barrier_newton_for
from drake_estop.planning.plan import InfeasibleStop, PhaseSolution, snap_to_tick
from drake_estop.planning.stop_condition import (
    TERMS,
    closed_form,
    exp_or_inf,
    rest,
    rest_derivatives,
    slowdown,
    slowdown_derivatives,
    stop_zmp,
    terms_at,
    transition_terms,
)

# the problem vector
KIND, DCM, CCM, RATE, ACCEL, W = 0, 1, 2, 3, 4, 5  # KIND 0: single support, 1: double support
A_W, B_W, MIN_T3, MAX_T3, REAR_REACH, REAR_ANKLE = 6, 7, 8, 9, 10, 11
SWING_SPEED, FORE_REACH, ZMP_OFFSET, SUPPORT_X, SWING_X, SWING_Y, LANDING_Y = 12, 13, 14, 15, 16, 17, 18
BOUNDS = 19  # (landing, transition, target) x (low, high), row-major
DT, COST_TOL, RESOLVE = 25, 26, 27
SIZE = 28

# status of solve()
OK, NO_GRID_START, NO_QUANTISATION, INFEASIBLE_START, NO_SLOWDOWN = 0, 1, 2, 3, 4


@jit
def _npmax(a, b):
    """np.maximum (NaN propagates)."""
    if a != a or b != b:
        return math.nan
    return a if a >= b else b


@jit
def _npmin(a, b):
    """np.minimum (NaN propagates)."""
    if a != a or b != b:
        return math.nan
    return a if a <= b else b


@jit
def dims(d):
    """(n free variables, m constraints, index of the first free variable in y)."""
    if d[KIND] == 0.0:
        return 3, 11, 0
    return 2, 7, 1


@jit
def full(d, x):
    """y = (landing, transition, target) from the free variables."""
    n, _, first = dims(d)
    y = np.zeros(3)
    for i in range(n):
        y[first + i] = x[i]
    return y


# ---------------------------------------------------------------------------
# cost (eq. 24 / 30) and limits at one point
# ---------------------------------------------------------------------------

@jit
def cost(d, t1, t2, z, t3):
    """J_ss (eq. 24): ``a (l_s / t_i)^2 + b (t_ii + t_iii)^2``; J_ds (eq. 30): ``a ZMP_max^2 + b (t_ii + t_iii)^2``.
    Infinite for a single-support landing duration <= 0 (outside the bounds)."""
    s = t2 + t3
    if d[KIND] == 0.0:
        if not t1 > 0.0:
            return math.inf
        q = (z - d[ZMP_OFFSET]) / t1
        return d[A_W] * (q * q) + d[B_W] * (s * s)
    return d[A_W] * (z * z) + d[B_W] * (s * s)


@jit
def cost_derivatives(d, y, t3, tg, th, cg, ch):
    """Gradient and Hessian of :func:`cost` in (t_i, t_ii, target) into ``cg``, ``ch`` (T3 eliminated:
    ``tg``, ``th`` from :func:`~drake_estop.planning.stop_condition.slowdown_derivatives`)."""
    a, b = d[A_W], d[B_W]
    sg = (tg[0], tg[1] + 1.0, tg[2])
    span = y[1] + t3
    ks = 2.0 * b * span
    if d[KIND] == 0.0:  # eq. 24: u = l_s / t_i (mean swing speed)
        t1 = y[0]
        step = y[2] - d[ZMP_OFFSET]
        u = step / t1
        t1sq = t1 * t1
        ug = (-step / t1sq, 0.0, 1.0 / t1)
        uh = np.zeros((3, 3))
        uh[0, 0] = 2.0 * step / (t1 * t1sq)
        uh[0, 2] = -1.0 / t1sq
        uh[2, 0] = -1.0 / t1sq
        ku = 2.0 * a * u
        for i in range(3):
            cg[i] = ku * ug[i] + ks * sg[i]
        for i in range(3):
            for j in range(3):
                hu = ug[i] * ug[j] + u * uh[i, j]
                hs = sg[i] * sg[j] + span * th[i, j]
                ch[i, j] = 2.0 * a * hu + 2.0 * b * hs
    else:  # eq. 30-31
        zg = (0.0, 0.0, 1.0)
        kz = 2.0 * a * y[2]
        for i in range(3):
            cg[i] = kz * zg[i] + ks * sg[i]
        for i in range(3):
            for j in range(3):
                hs = sg[i] * sg[j] + span * th[i, j]
                ch[i, j] = 2.0 * a * zg[i] * zg[j] + 2.0 * b * hs


@jit
def swing_distance(d, z):
    """Single support: ``(distance, dx, dy)`` from the swing ankle to the landing point of ZMP target ``z``
    (step length ``z - landing_zmp_offset`` from the support ankle, eq. 20)."""
    step = z - d[ZMP_OFFSET]
    dx = d[SUPPORT_X] + step - d[SWING_X]
    dy = d[LANDING_Y] - d[SWING_Y]
    return math.sqrt(dx * dx + dy * dy), dx, dy


@jit
def _ahead(d, t1):
    """COG of phase (i) (constant ZMP, eq. 6) ahead of the start ZMP at touchdown and its rate:
    ``(xi0 exp(w t_i) + zeta0 exp(-w t_i)) / 2``. NaN where exp(w t_i) over- or underflows."""
    w = d[W]
    grow = exp_or_inf(w * t1)
    if not (grow > 0.0 and grow < math.inf):
        return math.nan, math.nan
    return 0.5 * (d[DCM] * grow + d[CCM] / grow), 0.5 * w * (d[DCM] * grow - d[CCM] / grow)


@jit
def limits(d, t1, z, t3, x_rest, g, offset):
    """The limits other than the variable bounds, as ``g >= 0``, into ``g[offset:]``; returns their number.

    Slowdown duration ``t3`` above its minimum and below its maximum (-1 where ``t3`` is not
    finite); single support: mean swing-ankle speed to the landing point, ``v_max t_i - distance``,
    and the fore-leg reach at touchdown, ``reach - (l_s - x_G(t_i))``; both: rear-leg reach where
    the COG comes to rest, ``reach - (x_rest - rear ankle)`` (-1 where ``x_rest`` is not finite:
    no slowdown stops the COG with target ``z``).
    """
    finite = math.isfinite(t3)
    g[offset] = t3 - d[MIN_T3] if finite else -1.0
    g[offset + 1] = d[MAX_T3] - t3 if finite else -1.0
    k = offset + 2
    if d[KIND] == 0.0:
        dist, _, _ = swing_distance(d, z)
        g[k] = d[SWING_SPEED] * t1 - dist
        ahead, _ = _ahead(d, t1)
        g[k + 1] = d[FORE_REACH] - (z - d[ZMP_OFFSET]) + ahead if ahead == ahead else -1.0
        k += 2
    g[k] = d[REAR_REACH] - x_rest + d[REAR_ANKLE] if math.isfinite(x_rest) else -1.0
    return k + 1 - offset


@jit
def _limit_derivatives(d, y, rg, rh, eg, eh):
    """Gradients and Hessians of the extra limits of :func:`limits` (rows of ``eg``, ``eh``) in full
    (t_i, t_ii, target); ``rg``, ``rh``: the rest position's."""
    k = 0
    if d[KIND] == 0.0:
        dist, dx, dy = swing_distance(d, y[2])
        eg[0, 0] = d[SWING_SPEED]
        if dist > 0.0:  # the cone's tip (landing on the swing ankle): subgradient 0
            eg[0, 2] = -dx / dist
            eh[0, 2, 2] = -dy * dy / (dist * (dist * dist))
        ahead, rate = _ahead(d, y[0])
        eg[1, 2] = -1.0
        if ahead == ahead:
            eg[1, 0] = rate
            eh[1, 0, 0] = d[W] * d[W] * ahead
        k = 2
    for i in range(3):
        eg[k, i] = -rg[i]
        for j in range(3):
            eh[k, i, j] = -rh[i, j]


@jit
def _bounds(d, x, g):
    """Lower and upper bound of each free variable, as ``g >= 0``, into ``g[:2n]``."""
    n, _, first = dims(d)
    for i in range(n):
        g[2 * i] = x[i] - d[BOUNDS + 2 * (first + i)]
        g[2 * i + 1] = d[BOUNDS + 2 * (first + i) + 1] - x[i]


@jit
def _point_values(d, x, g):
    """:func:`point` without derivatives."""
    n, m, _ = dims(d)
    y = full(d, x)
    w = d[W]
    t = np.empty(TERMS)
    t3 = slowdown(t, w, y[2]) if terms_at(d[DCM], d[CCM], d[RATE], d[ACCEL], w, y[0], y[1], t) else math.nan
    if not math.isfinite(t3):
        for k in range(m):
            g[k] = -1.0
        return math.inf
    _bounds(d, x, g)
    limits(d, y[0], y[2], t3, rest(t, w, y[2], t3), g, 2 * n)
    return cost(d, y[0], y[1], y[2], t3)


@jit
def _point_derivatives(d, x, jg, jh, g, gg, gh):
    """:func:`point` with derivatives."""
    n, m, first = dims(d)
    y = full(d, x)
    w = d[W]
    t = np.empty(TERMS)
    have_terms = terms_at(d[DCM], d[CCM], d[RATE], d[ACCEL], w, y[0], y[1], t)
    t3 = slowdown(t, w, y[2]) if have_terms else math.nan
    tg = np.zeros(3)
    th = np.zeros((3, 3))
    rg = np.zeros(3)
    rh = np.zeros((3, 3))
    x_rest = math.nan
    if t3 == t3:
        if slowdown_derivatives(t, w, y[2], t3, tg, th):
            x_rest = rest_derivatives(t, w, y[2], t3, tg, th, rg, rh)
        else:  # Z independent of T3 here (0/0): no derivatives, reported infeasible
            t3 = math.nan
    _bounds(d, x, g)
    r = 2 * n
    if have_terms:
        limits(d, y[0], y[2], t3, x_rest, g, r)
    else:
        for k in range(r, m):
            g[k] = -1.0
    cg = np.zeros(3)
    ch = np.zeros((3, 3))
    value = math.inf
    if math.isfinite(t3):
        value = cost(d, y[0], y[1], y[2], t3)
        cost_derivatives(d, y, t3, tg, th, cg, ch)
    eg = np.zeros((3, 3))
    eh = np.zeros((3, 3, 3))
    _limit_derivatives(d, y, rg, rh, eg, eh)
    for i in range(n):
        jg[i] = cg[first + i]
        for j in range(n):
            jh[i, j] = ch[first + i, first + j]
    gg[:, :] = 0.0
    gh[:, :, :] = 0.0
    for i in range(n):
        gg[2 * i, i] = 1.0
        gg[2 * i + 1, i] = -1.0
        gg[r, i] = tg[first + i]
        gg[r + 1, i] = -tg[first + i]
        for j in range(n):
            gh[r, i, j] = th[first + i, first + j]
            gh[r + 1, i, j] = -th[first + i, first + j]
    for e in range(m - r - 2):
        for i in range(n):
            gg[r + 2 + e, i] = eg[e, first + i]
            for j in range(n):
                gh[r + 2 + e, i, j] = eh[e, first + i, first + j]
    return value


@jit
def point(d, x, derivatives, jg, jh, g, gg, gh):
    """The Newton evaluator (:func:`~drake_estop.planning.newton.barrier_newton_for`): J at the free variables
    ``x``, the constraints into ``g`` (lower / upper bound of each free variable, then :func:`limits`)
    and with ``derivatives`` their gradients and Hessians over the free variables. Where no
    slowdown stops the COG, J = inf and the slowdown limits are -1 (without derivatives every
    ``g = -1``: the line search rejects the point); no NaN."""
    if derivatives:
        return _point_derivatives(d, x, jg, jh, g, gg, gh)
    return _point_values(d, x, g)


barrier_newton = barrier_newton_for(point)
"""The interior-point Newton method (eq. 25-26, 31) on :func:`point`."""


# ---------------------------------------------------------------------------
# grid start, quantisation, the whole solve
# ---------------------------------------------------------------------------

@jit
def grid_start(d, landing_axis, transition_axis, samples):
    """Cheapest feasible point of a grid: ``(y (3,), cost, strict, found)``.

    Durations on a grid that includes their bounds; the ZMP target sampled (``samples``,
    fractions) inside its feasible interval for each pair of durations: the bounds, the
    slowdown-duration limits (Z falls as the slowdown lengthens) and in single support the
    swing-speed disc and the fore-leg reach, so thin feasible regions bounded by those
    limits are not missed. Strictly feasible points are preferred (the interior-point
    method needs one); ``strict=False`` means the feasible set has no interior on the grid
    (a corner of the limits). The first cheapest point in (landing, transition, target)
    order wins; the quadrature runs once per transition duration.
    """
    w = d[W]
    single = d[KIND] == 0.0
    nl, nt, nk = landing_axis.shape[0], transition_axis.shape[0], samples.shape[0]
    worst = np.full((nl, nt, nk), -math.inf)
    values = np.full((nl, nt, nk), math.inf)
    zs = np.zeros((nl, nt, nk))
    t = np.empty(TERMS)
    g = np.empty(5)
    lo2, hi2 = d[BOUNDS + 4], d[BOUNDS + 5]
    for jt in range(nt):
        t2 = transition_axis[jt]
        have_transition = transition_terms(w, t2, d[RATE], d[ACCEL], t)
        for il in range(nl):
            t1 = landing_axis[il]
            if not (have_transition and closed_form(d[DCM], d[CCM], w, t1, t2, t)):
                continue
            long = stop_zmp(t, w, d[MAX_T3])
            short = stop_zmp(t, w, d[MIN_T3])
            low = _npmax(lo2, _npmin(long, short))
            high = _npmin(hi2, _npmax(long, short))
            if single:  # the swing-speed disc and the fore-leg reach at touchdown
                dy = d[LANDING_Y] - d[SWING_Y]
                reach = d[SWING_SPEED] * t1
                radius = math.sqrt(_npmax(reach * reach - dy * dy, 0.0))
                offset = d[ZMP_OFFSET] - d[SUPPORT_X]
                low = _npmax(low, d[SWING_X] - radius + offset)
                high = _npmin(high, d[SWING_X] + radius + offset)
                ahead, _ = _ahead(d, t1)
                high = _npmin(high, d[FORE_REACH] + ahead + d[ZMP_OFFSET])
            for kz in range(nk):
                z = low + (high - low) * samples[kz]
                zs[il, jt, kz] = z
                t3 = slowdown(t, w, z)
                if not (high >= low and math.isfinite(t3)):
                    continue
                margin = math.inf
                for k in range(limits(d, t1, z, t3, rest(t, w, z, t3), g, 0)):
                    margin = _npmin(margin, g[k])
                if single:  # variable bounds
                    margin = _npmin(_npmin(margin, t1 - d[BOUNDS + 0]), d[BOUNDS + 1] - t1)
                margin = _npmin(_npmin(margin, t2 - d[BOUNDS + 2]), d[BOUNDS + 3] - t2)
                margin = _npmin(_npmin(margin, z - lo2), hi2 - z)
                worst[il, jt, kz] = margin
                values[il, jt, kz] = cost(d, t1, t2, z, t3)
    y = np.zeros(3)
    for strict in (True, False):
        threshold = 1e-9 if strict else -1e-12
        best_il = best_jt = best_kz = -1
        best_value = math.inf
        for il in range(nl):
            for jt in range(nt):
                for kz in range(nk):
                    if worst[il, jt, kz] > threshold and (best_il < 0 or values[il, jt, kz] < best_value):
                        best_il, best_jt, best_kz, best_value = il, jt, kz, values[il, jt, kz]
        if best_il >= 0:
            y[0], y[1], y[2] = landing_axis[best_il], transition_axis[best_jt], zs[best_il, best_jt, best_kz]
            return y, best_value, strict, True
    return y, math.nan, False, False


@jit
def slowdown_at(d, y):
    """Slowdown duration (eq. 21) at y (NaN where none stops the COG)."""
    t = np.empty(TERMS)
    if not terms_at(d[DCM], d[CCM], d[RATE], d[ACCEL], d[W], y[0], y[1], t):
        return math.nan
    return slowdown(t, d[W], y[2])


@jit
def solve_continuous_core(d, landing_axis, transition_axis, samples):
    """Grid start, then the interior-point Newton method: ``(y (3,), t3, cost, iterations, status)``."""
    y0, cost0, strict, found = grid_start(d, landing_axis, transition_axis, samples)
    if not found:
        return y0, math.nan, math.nan, 0, NO_GRID_START
    if not strict:  # no interior: the corner of the limits is the only candidate
        return y0, slowdown_at(d, y0), cost0, 0, OK
    n, m, first = dims(d)
    scale = max(cost0, 1.0)
    x0 = np.empty(n)
    for i in range(n):
        x0[i] = y0[first + i]
    x, _, iterations, status = barrier_newton(d, x0, m, 1e-1 * scale / m, d[COST_TOL] * scale / m, 0.1, 100, 1e-8)
    if status == _NEWTON_INFEASIBLE_START:
        return y0, math.nan, math.nan, 0, INFEASIBLE_START
    y = full(d, x)
    t3 = slowdown_at(d, y)
    return y, t3, cost(d, y[0], y[1], y[2], t3), iterations, OK


@jit
def _tick_options(value, lo_limit, hi_limit, dt):
    """Sorted distinct clamped ticks floor-1 .. ceil+1 of ``value``, times ``dt``."""
    lo = math.ceil(lo_limit / dt - 1e-9)
    hi = math.floor(hi_limit / dt + 1e-9)
    base = math.floor(value / dt + 1e-9)
    vals = np.empty(4)
    count = 0
    for nn in range(base - 1, base + 3):  # increasing, so the clamped values are non-decreasing
        v = float(min(max(nn, lo), hi))
        if count == 0 or vals[count - 1] != v:
            vals[count] = v
            count += 1
    return vals[:count] * dt


@jit
def quantise(d, y, t3):
    """Snap the durations to servo ticks; re-solve Z so eq. 17 holds exactly: ``(t1, t2, t3, z, cost, found)``.

    Tries floor-1 .. ceil+1 ticks of each duration and keeps the cheapest combination that
    meets every limit with the re-solved Z (the first in (landing, transition, slowdown)
    order). With ``quantisation="round"`` Z keeps its continuous value (the paper's
    behaviour, for comparison): the stop condition then no longer holds.
    """
    w = d[W]
    dt = d[DT]
    if d[KIND] == 0.0:
        o1 = _tick_options(y[0], d[BOUNDS + 0], d[BOUNDS + 1], dt)
    else:
        o1 = np.zeros(1)
    o2 = _tick_options(y[1], d[BOUNDS + 2], d[BOUNDS + 3], dt)
    o3 = _tick_options(t3, d[MIN_T3], d[MAX_T3], dt)
    terms = np.empty((o2.shape[0], TERMS))
    have = np.zeros(o2.shape[0], dtype=np.bool_)
    for jt in range(o2.shape[0]):
        have[jt] = transition_terms(w, o2[jt], d[RATE], d[ACCEL], terms[jt])
    g = np.empty(5)
    best_value = math.inf
    best_i = best_j = best_k = -1
    best_z = 0.0
    for il in range(o1.shape[0]):
        t1 = o1[il]
        for jt in range(o2.shape[0]):
            t2 = o2[jt]
            t = terms[jt]
            if not (have[jt] and closed_form(d[DCM], d[CCM], w, t1, t2, t)):
                continue
            for kz in range(o3.shape[0]):
                t3q = o3[kz]
                z = stop_zmp(t, w, t3q) if d[RESOLVE] != 0.0 else y[2]  # eq. 22 / 29 at the ticks
                ok = (t1 >= d[BOUNDS + 0] - 1e-12) and (t1 <= d[BOUNDS + 1] + 1e-12)
                ok = ok and (t2 >= d[BOUNDS + 2] - 1e-12) and (t2 <= d[BOUNDS + 3] + 1e-12)
                ok = ok and (z >= d[BOUNDS + 4] - 1e-12) and (z <= d[BOUNDS + 5] + 1e-12)
                if not ok:
                    continue
                t3_rest = slowdown(t, w, z)  # where the re-solved (or kept) Z brings the COG to rest
                x_rest = rest(t, w, z, t3_rest) if t3_rest == t3_rest else math.nan
                for k in range(limits(d, t1, z, t3q, x_rest, g, 0)):
                    ok = ok and g[k] >= -1e-12
                if ok:
                    v = cost(d, t1, t2, z, t3q)
                    if best_i < 0 or v < best_value:
                        best_i, best_j, best_k, best_value, best_z = il, jt, kz, v, z
    if best_i < 0:
        return 0.0, 0.0, 0.0, 0.0, math.nan, False
    return o1[best_i], o2[best_j], o3[best_k], best_z, best_value, True


@jit
def solve(d, landing_axis, transition_axis, samples, snap):
    """Grid start, Newton and (``snap``) quantisation: ``(quantised (t1, t2, t3, z, cost),
    continuous (y0, y1, t3, y2, cost), iterations, status)``; NaN rows with a status other
    than :data:`OK`. One compiled entry point for the planner."""
    y, t3, value, iterations, status = solve_continuous_core(d, landing_axis, transition_axis, samples)
    q = np.full(5, math.nan)
    if status == OK and not math.isfinite(t3):
        status = NO_SLOWDOWN  # guard: the grid start and the Newton iterates all stop the COG
    cont = np.array([y[0], y[1], t3, y[2], value])
    if status != OK or not snap:
        return q, cont, iterations, status
    t1q, t2q, t3q, z, qcost, found = quantise(d, y, t3)
    if not found:
        return q, cont, iterations, NO_QUANTISATION
    q[0], q[1], q[2], q[3], q[4] = t1q, t2q, t3q, z, qcost
    return q, cont, iterations, OK


@jit
def infeasible_limits(d, landing_axis, transition_axis, targets):
    """Why no grid point is feasible: ``(stops, blocking, violated_nowhere)`` over the limits of
    :func:`limits` then the target's lower and upper bound. ``stops``: some grid point has a
    slowdown that stops the COG (else the stop condition itself is the limit); ``blocking[k]``:
    dropping limit k alone leaves a feasible point; ``violated_nowhere[k]``: limit k holds at
    some point that stops the COG."""
    w = d[W]
    total = (5 if d[KIND] == 0.0 else 3) + 2
    blocking = np.zeros(total, dtype=np.bool_)
    holds = np.zeros(total, dtype=np.bool_)
    stops = False
    t = np.empty(TERMS)
    g = np.empty(total)
    for t2 in transition_axis:
        if not transition_terms(w, t2, d[RATE], d[ACCEL], t):
            continue
        for t1 in landing_axis:
            if not closed_form(d[DCM], d[CCM], w, t1, t2, t):
                continue
            for z in targets:
                t3 = slowdown(t, w, z)
                if not math.isfinite(t3):
                    continue
                stops = True
                count = limits(d, t1, z, t3, rest(t, w, z, t3), g, 0)
                g[count] = z - d[BOUNDS + 4]
                g[count + 1] = d[BOUNDS + 5] - z
                violated = 0
                last = -1
                for k in range(total):
                    if g[k] >= 0.0:
                        holds[k] = True
                    else:
                        violated += 1
                        last = k
                if violated == 0:
                    blocking[:] = True
                elif violated == 1:
                    blocking[last] = True
    return stops, blocking, holds


# ---------------------------------------------------------------------------
# from Python: a problem object (drake_estop.planning.problems) in, a solution or InfeasibleStop out
# ---------------------------------------------------------------------------

_GRID = {"single": (16, 4), "double": (1, 10)}  # landing and transition grid sizes
TARGET_SAMPLES = np.linspace(0.02, 0.98, 12)  # ZMP-target fractions of its feasible interval
AT_REST = 1e-12  # [m], [m/s], [m/s^2]: a sagittal start state this close to rest is at rest


@functools.lru_cache(maxsize=64)
def grid_axes(kind: str, bounds: tuple):
    """Landing and transition grids (include the bounds; cached: they depend on the limits only)."""
    axes = []
    for (lo, hi), count in zip(bounds, _GRID[kind]):
        inset = 1e-3 * (hi - lo)
        inner = np.linspace(lo + inset, hi - inset, count) if count > 1 else np.array([lo])
        axes.append(np.ascontiguousarray(np.unique(np.concatenate([[lo], inner])) if count > 1 else inner))
    return axes[0], axes[1]


def _arguments(problem, kind):
    d = problem.data
    bounds = tuple(tuple(float(v) for v in d[BOUNDS + 2 * k:BOUNDS + 2 * k + 2]) for k in range(2))
    return (d, *grid_axes(kind, bounds), TARGET_SAMPLES)


class NoFeasibleStart(InfeasibleStop):
    """No grid point meets the limits. The message, which names the limits (:func:`infeasible_reason`,
    a scan of the whole grid), is worked out when it is first read: a planner that tries another
    landing after a failure (the marginal case, III.C) does not pay for the messages it drops."""

    def __init__(self, problem, kind):
        super().__init__()
        self._problem, self._kind, self._message = problem, kind, None

    def __str__(self):
        if self._message is None:
            self._message = infeasible_reason(self._problem, self._kind)
        return self._message

    def __reduce__(self):  # pickled (a worker process's error) as the plain error with its message
        return InfeasibleStop, (str(self),)


def _raise_for(status, problem, kind):
    """:class:`InfeasibleStop` (ValueError: a bug) for the solver's status codes."""
    if status == NO_GRID_START:
        raise NoFeasibleStart(problem, kind)
    if status == NO_QUANTISATION:
        raise InfeasibleStop("no servo-tick quantisation of the optimum meets the limits")
    if status == NO_SLOWDOWN:
        raise InfeasibleStop("no slowdown duration stops the COG at the solver's optimum")
    if status == INFEASIBLE_START:
        raise ValueError("barrier_newton needs a strictly feasible start")


def solve_continuous(problem, kind):
    """Interior-point Newton optimum before quantisation: ``(y, t3, cost, iterations)``."""
    _, (y0, y1, t3, y2, value), iterations, status = solve(*_arguments(problem, kind), False)
    _raise_for(status, problem, kind)
    return np.array([y0, y1, y2]), float(t3), float(value), int(iterations)


def solve_phases(problem, kind) -> PhaseSolution:
    """Phase durations and ZMP value on servo ticks (:func:`solve`), or the at-rest solution."""
    at_rest = at_rest_solution(problem, kind)
    if at_rest is not None:
        return at_rest
    q, cont, iterations, status = solve(*_arguments(problem, kind), True)
    _raise_for(status, problem, kind)
    t1, t2, t3, z, value = q.tolist()
    return PhaseSolution(t1, t2, t3, z, value, int(iterations), tuple(cont.tolist()[:4]))


def at_rest_solution(problem, kind):
    """Phase parameters when the sagittal COG is at rest over a ZMP at rest (stepping in place).

    Then the stop condition holds for every slowdown duration with the ZMP kept where it
    is (Z = 0 in eq. 22 / 29; its closed form is 0/0 in T3), so the slowdown cannot be
    found from Z and the barrier method has no interior: land as early as the swing-speed
    and landing-time limits allow, beside the support foot, with the shortest transition and
    slowdown; the planner lengthens the slowdown for the lateral plane. The touchdown is the
    nominal one when that is later (the foot lands as it would have; an early 0.1 s
    touchdown from mid-swing slams the foot down). None if the state is not at rest or
    Z = 0 breaks a limit.
    """
    s, p = problem.start, problem.params
    if max(abs(s.dcm), abs(s.ccm), abs(s.zmp_rate), abs(s.zmp_accel)) > AT_REST:
        return None
    bounds = problem.bounds()
    if not bounds[2, 0] <= 0.0 <= bounds[2, 1]:
        return None
    dt = p.servo_period
    landing = 0.0
    if kind == "single":
        distance = float(swing_distance(problem.data, 0.0)[0])
        nominal = problem.nominal_landing if math.isfinite(problem.nominal_landing) else 0.0
        landing = snap_to_tick(max(p.min_landing_time, distance / p.max_swing_speed,
                                   min(nominal, p.max_landing_time)), dt)
        if landing > p.max_landing_time + 1e-12:
            return None
    transition, slow = snap_to_tick(p.min_transition_time, dt), snap_to_tick(p.min_slowdown_time, dt)
    # the COG stays over the start ZMP: rear reach to it, and in single support the fore reach
    values = [p.max_rear_reach + problem.rear_ankle]
    if kind == "single":
        values.append(p.max_fore_reach - problem.step_length(0.0))
    if min(values) < 0 or transition > p.max_transition_time + 1e-12 or slow > p.max_slowdown_time + 1e-12:
        return None
    value = float(cost(problem.data, landing, transition, 0.0, slow))
    return PhaseSolution(landing, transition, slow, 0.0, value, 0, (landing, transition, slow, 0.0))


def _limit_names(kind):
    """Names of the limits of :func:`limits` (in its order), then the ZMP-target bounds."""
    names = ["min_slowdown_time", "max_slowdown_time"]
    names += ["max_swing_speed", "max_fore_reach", "max_rear_reach"] if kind == "single" else ["max_rear_reach"]
    if kind == "single":
        return names + ["min_step_length", "max_step_length"]
    return names + ["zmp_margin (ZMP_max behind the fore sole's heel)", "zmp_margin (ZMP_max past the fore sole's toe)"]


def infeasible_reason(problem, kind, samples=41):
    """Why no grid point is feasible, naming the limits (for the InfeasibleStop message).

    Evaluates every limit on the duration grid times ``samples`` ZMP targets across their
    bounds (:func:`infeasible_limits`): a limit is named if dropping it alone leaves a feasible
    point, or else if it is violated everywhere; "stop condition" if no non-negative slowdown
    stops the COG.
    """
    d, landing_axis, transition_axis, _ = _arguments(problem, kind)
    low, high = d[BOUNDS + 4], d[BOUNDS + 5]
    stops, blocking, holds = infeasible_limits(d, landing_axis, transition_axis, np.linspace(low, high, samples))
    names = _limit_names(kind)
    named = [name for name, flag in zip(names, blocking) if flag]
    if not stops:
        named = [(f"min_step_length/max_step_length: no step in [{low:.3f}, {high:.3f}] m "
                  "stops the COG (stop condition, eq. 22)") if kind == "single" else
                 "zmp_margin: no ZMP_max on the fore sole stops the COG (stop condition, eq. 29)"]
    elif not named:
        named = [name for name, flag in zip(names, holds) if not flag] or ["a combination of limits"]
    return f"no feasible {kind}-support stop from this state: limited by " + ", ".join(named)
