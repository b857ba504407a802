"""Compiled (numba) phase-parameter solver: grid start, interior-point Newton, quantisation.

A line-by-line port of the pure-Python reference path (the readable one, with
the paper's equation numbers): :mod:`drake_estop.planning.stop_condition` (closed form
of the stop condition and its derivatives), the ``_SingleSupportProblem`` /
``_DoubleSupportProblem`` evaluators and ``_grid_start`` / ``_quantise`` of
:mod:`drake_estop.planning.planner`, and :func:`drake_estop.planning.newton.barrier_newton`
(same algorithm, tolerances and line search). The operations are kept in the
reference's order, so results agree to rounding (the quadrature sums and
``exp`` may differ in the last bit from numpy's BLAS / SIMD kernels).

Everything works on plain float64 arrays; the problem is packed by
:func:`pack` into one vector (indices below). ``error_model="numpy"``: division
by zero gives inf / nan as in numpy, no exception.

Import fails without numba; :mod:`drake_estop.planning.planner` then keeps the Python path.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from drake_estop.planning.stop_condition import _BASIS, _STACK, _U

_JIT = dict(cache=True, nogil=True, error_model="numpy")

# packed problem vector
KIND, DCM, CCM, RATE, ACCEL, W = 0, 1, 2, 3, 4, 5
A_W, B_W, MIN_T3, MAX_T3, REAR_REACH, REAR_ANKLE = 6, 7, 8, 9, 10, 11
SWING_SPEED, FORE_REACH, ZMP_OFFSET, SUPPORT_X, SWING_X, SWING_Y, LANDING_Y = 12, 13, 14, 15, 16, 17, 18
BOUNDS = 19  # 3 x 2, row-major
DT, COST_TOL, RESOLVE = 25, 26, 27
SIZE = 28

# status codes of solve()
OK, NO_GRID_START, NO_QUANTISATION, INFEASIBLE_START = 0, 1, 2, 3

_UA = np.ascontiguousarray(_U, dtype=np.float64)
_BASIS_A = np.ascontiguousarray(_BASIS, dtype=np.float64)
_STACK_A = np.ascontiguousarray(_STACK, dtype=np.float64)
_BIG = np.finfo(np.float64).max


def pack(problem, kind) -> np.ndarray:
    """The problem data as the float vector the compiled functions take."""
    p, s = problem.params, problem.start
    d = np.zeros(SIZE)
    d[KIND] = 0.0 if kind == "single" else 1.0
    d[DCM], d[CCM], d[RATE], d[ACCEL], d[W] = s.dcm, s.ccm, s.zmp_rate, s.zmp_accel, problem.w
    if kind == "single":
        d[A_W], d[B_W] = p.a_ss, p.b_ss
        d[SUPPORT_X] = problem.support_x
        d[SWING_X], d[SWING_Y] = problem.swing_xy[0], problem.swing_xy[1]
        d[LANDING_Y] = problem.landing_y
    else:
        d[A_W], d[B_W] = p.a_ds, p.b_ds
    d[MIN_T3], d[MAX_T3] = p.min_slowdown_time, p.max_slowdown_time
    d[REAR_REACH], d[REAR_ANKLE] = p.max_rear_reach, problem.rear_ankle
    d[SWING_SPEED], d[FORE_REACH], d[ZMP_OFFSET] = p.max_swing_speed, p.max_fore_reach, p.landing_zmp_offset
    d[BOUNDS:BOUNDS + 6] = np.asarray(problem.bounds(), float).ravel()
    d[DT], d[COST_TOL] = p.servo_period, p.cost_tolerance
    d[RESOLVE] = 1.0 if p.quantisation == "resolve" else 0.0
    return d


# ---------------------------------------------------------------------------
# numpy semantics on scalars
# ---------------------------------------------------------------------------

@numba.njit(**_JIT)
def _npmax(a, b):
    """np.maximum (NaN propagates)."""
    if a != a or b != b:
        return math.nan
    return a if a >= b else b


@numba.njit(**_JIT)
def _npmin(a, b):
    """np.minimum (NaN propagates)."""
    if a != a or b != b:
        return math.nan
    return a if a <= b else b


@numba.njit(**_JIT)
def _nan_to_num(v, nan):
    if v != v:
        return nan
    if v == math.inf:
        return _BIG
    if v == -math.inf:
        return -_BIG
    return v


# ---------------------------------------------------------------------------
# closed form at one point (stop_condition._terms and friends)
# ---------------------------------------------------------------------------

@numba.njit(**_JIT)
def terms_point(d, landing, transition):
    """:func:`stop_condition._terms`: ``[A (6), B (6), F (3), G (3)]``."""
    w = d[W]
    kappa = w * transition
    n = _UA.shape[0]
    grow = np.empty(n)
    inv = np.empty(n)
    for q in range(n):
        grow[q] = math.exp(kappa * _UA[q])
        inv[q] = 1.0 / grow[q]
    mp = np.zeros(9)
    mm = np.zeros(9)
    for r in range(9):
        sp = 0.0
        sm = 0.0
        for q in range(n):
            sp += _STACK_A[r, q] * grow[q]
            sm += _STACK_A[r, q] * inv[q]
        mp[r] = sp
        mm[r] = sm
    ww = w * w
    lval = np.empty(3)
    ld1 = np.empty(3)
    ld2 = np.empty(3)
    rval = np.empty(3)
    rd1 = np.empty(3)
    rd2 = np.empty(3)
    for b in range(3):
        lval[b] = kappa * mp[b]
        ld1[b] = mp[b] + kappa * mp[3 + b]
        ld2[b] = 2.0 * mp[3 + b] + kappa * mp[6 + b]
        rval[b] = kappa * mm[b]
        rd1[b] = mm[b] - kappa * mm[3 + b]
        rd2[b] = -2.0 * mm[3 + b] + kappa * mm[6 + b]
    sl0 = sl1 = sl2 = sr0 = sr1 = sr2 = 0.0
    for power in (1, 2):
        b = power
        coef = d[RATE] / w if power == 1 else d[ACCEL] / ww
        if coef != 0.0:
            if power == 1:
                k_p, k_p1, k_p2 = kappa, 1.0, 0.0
            else:
                k_p, k_p1, k_p2 = kappa ** 2, 2.0 * kappa, 2.0
            sl0 += coef * k_p * lval[b]
            sl1 += coef * (k_p1 * lval[b] + k_p * ld1[b])
            sl2 += coef * (k_p2 * lval[b] + 2.0 * k_p1 * ld1[b] + k_p * ld2[b])
            sr0 += coef * k_p * rval[b]
            sr1 += coef * (k_p1 * rval[b] + k_p * rd1[b])
            sr2 += coef * (k_p2 * rval[b] + 2.0 * k_p1 * rd1[b] + k_p * rd2[b])
    e12 = math.exp(w * (landing + transition))
    p_fwd = e12 * d[DCM]
    p_bwd = d[CCM] / e12
    t = np.empty(18)
    t[0] = p_fwd - sl0
    t[1] = w * p_fwd
    t[2] = w * p_fwd - w * sl1
    t[3] = ww * p_fwd
    t[4] = ww * p_fwd
    t[5] = ww * p_fwd - ww * sl2
    t[6] = p_bwd + sr0
    t[7] = -w * p_bwd
    t[8] = -w * p_bwd + w * sr1
    t[9] = ww * p_bwd
    t[10] = ww * p_bwd
    t[11] = ww * p_bwd + ww * sr2
    t[12] = lval[0] + 1.0
    t[13] = w * ld1[0]
    t[14] = ww * ld2[0]
    t[15] = rval[0]
    t[16] = w * rd1[0]
    t[17] = ww * rd2[0]
    return t


@numba.njit(**_JIT)
def zmp_point(t, w, slowdown, grad, hess):
    """:func:`stop_condition._zmp_point`; gradient and Hessian written into ``grad``, ``hess``."""
    e3sq = math.exp(2.0 * w * slowdown)
    a0, a1, a2, a11, a12, a22 = t[0], t[1], t[2], t[3], t[4], t[5]
    b0, b1, b2, b11, b12, b22 = t[6], t[7], t[8], t[9], t[10], t[11]
    f0, f1, f2 = t[12], t[13], t[14]
    g0, g1, g2 = t[15], t[16], t[17]
    den = e3sq * f0 + g0 - 1.0
    z = (e3sq * a0 - b0) / den
    e_1 = 2.0 * w * e3sq
    e_2 = 2.0 * w * e_1
    d2 = e3sq * f1 + g1
    d3 = e_1 * f0
    z1 = (e3sq * a1 - b1) / den
    z2 = (e3sq * a2 - b2 - z * d2) / den
    z3 = (e_1 * a0 - z * d3) / den
    h11 = (e3sq * a11 - b11) / den
    h12 = (e3sq * a12 - b12 - z1 * d2) / den
    h13 = (e_1 * a1 - z1 * d3) / den
    h22 = (e3sq * a22 - b22 - z2 * d2 - z2 * d2 - z * (e3sq * f2 + g2)) / den
    h23 = (e_1 * a2 - z2 * d3 - z3 * d2 - z * (e_1 * f1)) / den
    h33 = (e_2 * a0 - z3 * d3 - z3 * d3 - z * (e_2 * f0)) / den
    grad[0], grad[1], grad[2] = z1, z2, z3
    hess[0, 0], hess[0, 1], hess[0, 2] = h11, h12, h13
    hess[1, 0], hess[1, 1], hess[1, 2] = h12, h22, h23
    hess[2, 0], hess[2, 1], hess[2, 2] = h13, h23, h33
    return z


@numba.njit(**_JIT)
def slowdown_point(t, w, target):
    """:func:`stop_condition._slowdown_point` value (NaN where infeasible)."""
    denominator = t[0] - target * t[12]
    ratio = (t[6] + target * (t[15] - 1.0)) / denominator if denominator != 0.0 else -1.0
    if not ratio >= 1.0:
        return math.nan
    return math.log(ratio) / (2.0 * w)


@numba.njit(**_JIT)
def slowdown_derivatives(t, w, target, t3, grad, hess):
    """Gradient and Hessian of T3 in (landing, transition, target) (implicit differentiation)."""
    zg = np.empty(3)
    zh = np.empty((3, 3))
    zmp_point(t, w, t3, zg, zh)
    z1, z2, z3 = zg[0], zg[1], zg[2]
    grad[0] = -z1 / z3
    grad[1] = -z2 / z3
    grad[2] = 1.0 / z3
    f3 = (zh[0, 2], zh[1, 2], 0.0)
    h33 = zh[2, 2]
    for i in range(3):
        for j in range(i, 3):
            fh = zh[i, j] if (i < 2 and j < 2) else 0.0
            value = -(fh + f3[i] * grad[j] + f3[j] * grad[i] + h33 * (grad[i] * grad[j])) / z3
            hess[i, j] = value
            hess[j, i] = value


@numba.njit(**_JIT)
def rest_value(t, w, target, t3):
    u = t[6] + target * (t[15] - 1.0)
    decay = math.exp(-w * t3)
    return target + u * decay


@numba.njit(**_JIT)
def rest_derivatives(t, w, target, t3, tg, th, grad, hess):
    """:func:`stop_condition._rest_point` with derivatives; returns the value."""
    b0, b1, b2, b11, b12, b22 = t[6], t[7], t[8], t[9], t[10], t[11]
    g0, g1, g2 = t[15], t[16], t[17]
    u = b0 + target * (g0 - 1.0)
    decay = math.exp(-w * t3)
    value = target + u * decay
    ug = (b1, b2 + target * g1, g0 - 1.0)
    uh = np.empty((3, 3))
    uh[0, 0], uh[0, 1], uh[0, 2] = b11, b12, 0.0
    uh[1, 0], uh[1, 1], uh[1, 2] = b12, b22 + target * g2, g1
    uh[2, 0], uh[2, 1], uh[2, 2] = 0.0, g1, 0.0
    wd = w * decay
    eg = np.empty(3)
    for i in range(3):
        eg[i] = -wd * tg[i]
    for i in range(3):
        grad[i] = (1.0 if i == 2 else 0.0) + decay * ug[i] + u * eg[i]
    for i in range(3):
        for j in range(i, 3):
            eh = w * wd * (tg[i] * tg[j]) - wd * th[i, j]
            v = decay * uh[i, j] + ug[i] * eg[j] + ug[j] * eg[i] + u * eh
            hess[i, j] = v
            hess[j, i] = v
    return value


# ---------------------------------------------------------------------------
# the problems at one point (planner._StopProblem.evaluate / values)
# ---------------------------------------------------------------------------

@numba.njit(**_JIT)
def _dims(d):
    """(n free variables, m constraints, first free index)."""
    if d[KIND] == 0.0:
        return 3, 11, 0
    return 2, 7, 1


@numba.njit(**_JIT)
def _full(d, x):
    n, _, first = _dims(d)
    y = np.zeros(3)
    for i in range(n):
        y[first + i] = x[i]
    return y


@numba.njit(**_JIT)
def cost_value(d, y0, y1, y2, t3):
    """``cost_grid`` at one point (eq. 24 / 30)."""
    if d[KIND] == 0.0:
        q = (y2 - d[ZMP_OFFSET]) / y0
        s = y1 + t3
        return d[A_W] * (q * q) + d[B_W] * (s * s)
    s = y1 + t3
    return d[A_W] * (y2 * y2) + d[B_W] * (s * s)


@numba.njit(**_JIT)
def evaluate(d, x, jg, jh, g, gg, gh):
    """``_StopProblem.evaluate``: fills gradients / Hessians over the free variables, returns J."""
    n, m, first = _dims(d)
    y = _full(d, x)
    w = d[W]
    t = terms_point(d, y[0], y[1])
    t3 = slowdown_point(t, w, y[2])
    tg = np.zeros(3)
    th = np.zeros((3, 3))
    rg = np.zeros(3)
    rh = np.zeros((3, 3))
    if t3 == t3:
        slowdown_derivatives(t, w, y[2], t3, tg, th)
        rest = rest_derivatives(t, w, y[2], t3, tg, th, rg, rh)
    else:
        rest = math.nan
    # cost terms (full 3-space)
    cg = np.zeros(3)
    ch = np.zeros((3, 3))
    a, b = d[A_W], d[B_W]
    sg = (tg[0], tg[1] + 1.0, tg[2])
    if d[KIND] == 0.0:
        t1 = y[0]
        step = y[2] - d[ZMP_OFFSET]
        u = step / t1
        t1sq = t1 * t1
        ug = (-step / t1sq, 0.0, 1.0 / t1)
        uh = np.zeros((3, 3))
        uh[0, 0] = 2.0 * step / t1 ** 3
        uh[0, 2] = -1.0 / t1sq
        uh[2, 0] = -1.0 / t1sq
        span = y[1] + t3
        cost = a * u * u + b * span * span
        ku, ks = 2.0 * a * u, 2.0 * b * span
        for i in range(3):
            cg[i] = ku * ug[i] + ks * sg[i]
        for i in range(3):
            for j in range(3):
                hu = ug[i] * ug[j] + u * uh[i, j]
                hs = sg[i] * sg[j] + span * th[i, j]
                ch[i, j] = 2.0 * a * hu + 2.0 * b * hs
    else:
        span = y[1] + t3
        zg = (0.0, 0.0, 1.0)
        cost = a * (y[2] * y[2]) + b * span * span
        kz, ks = 2.0 * a * y[2], 2.0 * b * span
        for i in range(3):
            cg[i] = kz * zg[i] + ks * sg[i]
        for i in range(3):
            for j in range(3):
                hs = sg[i] * sg[j] + span * th[i, j]
                ch[i, j] = 2.0 * a * zg[i] * zg[j] + 2.0 * b * hs
    # extras (full 3-space): single: speed, reach, rear; double: rear
    ne = 3 if d[KIND] == 0.0 else 1
    ev = np.zeros(3)
    eg = np.zeros((3, 3))
    eh = np.zeros((3, 3, 3))
    k = 0
    if d[KIND] == 0.0:
        step = y[2] - d[ZMP_OFFSET]
        dx = d[SUPPORT_X] + step - d[SWING_X]
        dy = d[LANDING_Y] - d[SWING_Y]
        dist = math.sqrt(dx * dx + dy * dy)
        ev[0] = d[SWING_SPEED] * y[0] - dist
        grow = math.exp(w * y[0])
        ahead = 0.5 * (d[DCM] * grow + d[CCM] / grow)
        ev[1] = d[FORE_REACH] - step + ahead
        eg[0, 0], eg[0, 1], eg[0, 2] = d[SWING_SPEED], 0.0, -dx / dist
        eh[0, 2, 2] = -dy * dy / dist ** 3
        eg[1, 0], eg[1, 1], eg[1, 2] = 0.5 * w * (d[DCM] * grow - d[CCM] / grow), 0.0, -1.0
        eh[1, 0, 0] = w * w * ahead
        k = 2
    ev[k] = d[REAR_REACH] - rest + d[REAR_ANKLE] if math.isfinite(rest) else -1.0
    for i in range(3):
        eg[k, i] = -rg[i]
        for j in range(3):
            eh[k, i, j] = -rh[i, j]
    # assemble over the free variables
    for i in range(n):
        jg[i] = cg[first + i]
        for j in range(n):
            jh[i, j] = ch[first + i, first + j]
    gg[:, :] = 0.0
    gh[:, :, :] = 0.0
    for i in range(n):
        lo, hi = d[BOUNDS + 2 * (first + i)], d[BOUNDS + 2 * (first + i) + 1]
        g[2 * i] = x[i] - lo
        g[2 * i + 1] = hi - x[i]
        gg[2 * i, i] = 1.0
        gg[2 * i + 1, i] = -1.0
    r = 2 * n
    finite = math.isfinite(t3)
    g[r] = t3 - d[MIN_T3] if finite else -1.0
    g[r + 1] = d[MAX_T3] - t3 if finite else -1.0
    for i in range(n):
        gg[r, i] = tg[first + i]
        gg[r + 1, i] = -tg[first + i]
        for j in range(n):
            gh[r, i, j] = th[first + i, first + j]
            gh[r + 1, i, j] = -th[first + i, first + j]
    for e in range(ne):
        g[r + 2 + e] = ev[e]
        for i in range(n):
            gg[r + 2 + e, i] = eg[e, first + i]
            for j in range(n):
                gh[r + 2 + e, i, j] = eh[e, first + i, first + j]
    return cost


@numba.njit(**_JIT)
def values(d, x, g):
    """``_StopProblem.values``: constraint values into ``g``, returns the cost (inf if infeasible)."""
    n, m, first = _dims(d)
    y = _full(d, x)
    w = d[W]
    t = terms_point(d, y[0], y[1])
    t3 = slowdown_point(t, w, y[2])
    if not math.isfinite(t3):
        for k in range(m):
            g[k] = -1.0
        return math.inf
    rest = rest_value(t, w, y[2], t3) if t3 == t3 else math.nan
    for i in range(n):
        g[2 * i] = x[i] - d[BOUNDS + 2 * (first + i)]
        g[2 * i + 1] = d[BOUNDS + 2 * (first + i) + 1] - x[i]
    r = 2 * n
    g[r] = t3 - d[MIN_T3]
    g[r + 1] = d[MAX_T3] - t3
    k = r + 2
    if d[KIND] == 0.0:
        step = y[2] - d[ZMP_OFFSET]
        dx = d[SUPPORT_X] + step - d[SWING_X]
        dy = d[LANDING_Y] - d[SWING_Y]
        dist = math.sqrt(dx * dx + dy * dy)
        g[k] = d[SWING_SPEED] * y[0] - dist
        grow = math.exp(w * y[0])
        ahead = 0.5 * (d[DCM] * grow + d[CCM] / grow)
        g[k + 1] = d[FORE_REACH] - step + ahead
        k += 2
    g[k] = d[REAR_REACH] - rest + d[REAR_ANKLE] if math.isfinite(rest) else -1.0
    return cost_value(d, y[0], y[1], y[2], t3)


# ---------------------------------------------------------------------------
# interior-point Newton (newton.barrier_newton)
# ---------------------------------------------------------------------------

@numba.njit(**_JIT)
def _cholesky_solve(a, b, out):
    n = b.shape[0]
    low = np.zeros((n, n))
    for i in range(n):
        for j in range(i + 1):
            dot = 0.0
            for k in range(j):
                dot += low[i, k] * low[j, k]
            acc = a[i, j] - dot
            if i == j:
                if acc <= 0.0:
                    return False
                low[i, i] = acc ** 0.5
            else:
                low[i, j] = acc / low[j, j]
    y = np.zeros(n)
    for i in range(n):
        dot = 0.0
        for k in range(i):
            dot += low[i, k] * y[k]
        y[i] = (b[i] - dot) / low[i, i]
    for i in range(n - 1, -1, -1):
        dot = 0.0
        for k in range(i + 1, n):
            dot += low[k, i] * out[k]
        out[i] = (y[i] - dot) / low[i, i]
    return True


@numba.njit(**_JIT)
def _newton_direction(hess, rhs, out):
    n = rhs.shape[0]
    scale = 0.0
    for i in range(n):
        v = abs(hess[i, i])
        if i == 0 or v > scale:
            scale = v
    scale = max(1e-12, scale)
    shift = 0.0
    shifted = hess.copy()
    for _ in range(40):
        for i in range(n):
            shifted[i, i] = hess[i, i] + shift if shift else hess[i, i]
        if _cholesky_solve(shifted, rhs, out):
            return
        shift = max(2.0 * shift, 1e-8 * scale)
    for i in range(n):
        out[i] = rhs[i] / scale


@numba.njit(**_JIT)
def barrier_newton(d, x0, mu0, mu_final, sigma=0.1, max_iterations=100, grad_tol=1e-8):
    """Returns ``(x, J, iterations, status)``; status 0 converged, 1 not converged,
    -1 infeasible start (the Python path raises ValueError)."""
    n, m, _ = _dims(d)
    x = x0.copy()
    jg = np.zeros(n)
    jh = np.zeros((n, n))
    g = np.zeros(m)
    gg = np.zeros((m, n))
    gh = np.zeros((m, n, n))
    j = evaluate(d, x, jg, jh, g, gg, gh)
    for k in range(m):
        if not g[k] > 0:
            return x, j, 0, -1
    lam = np.empty(m)
    for k in range(m):
        lam[k] = mu0 / g[k]
    mu = mu0
    grad_scale = 1.0
    for i in range(n):
        grad_scale = max(grad_scale, abs(jg[i]))
    hess = np.zeros((n, n))
    rhs = np.zeros(n)
    ratio = np.zeros(m)
    dx = np.zeros(n)
    dlam = np.zeros(m)
    trial = np.zeros(n)
    trial_g = np.zeros(m)
    curvature = np.zeros((n, n))
    for iteration in range(1, max_iterations + 1):
        gap = 0.0
        for k in range(m):
            gap += lam[k] * g[k]
        gap = gap / m
        worst = 0.0
        for i in range(n):
            s = 0.0
            for k in range(m):
                s += lam[k] * gg[k, i]
            r = abs(jg[i] - s)
            if i == 0 or r > worst:
                worst = r
        if gap <= mu_final and worst <= grad_tol * grad_scale:
            return x, j, iteration - 1, 0
        mu = max(min(mu, sigma * gap), 0.1 * mu_final)
        # KKT system (newton._kkt_system)
        for k in range(m):
            ratio[k] = lam[k] / g[k]
        for i in range(n):
            for jj in range(n):
                curvature[i, jj] = jh[i, jj]
        for k in range(m):
            lk = lam[k]
            for i in range(n):
                for jj in range(i, n):
                    curvature[i, jj] -= lk * gh[k, i, jj]
        for i in range(n):
            for jj in range(i, n):
                s = 0.0
                for k in range(m):
                    s += (gg[k, i] * ratio[k]) * gg[k, jj]
                hess[i, jj] = curvature[i, jj] + s
                hess[jj, i] = hess[i, jj]
        for i in range(n):
            s = 0.0
            for k in range(m):
                s += (mu / g[k]) * gg[k, i]
            rhs[i] = -(jg[i] - s)
        _newton_direction(hess, rhs, dx)
        for k in range(m):
            s = 0.0
            for i in range(n):
                s += gg[k, i] * dx[i]
            dlam[k] = mu / g[k] - lam[k] - ratio[k] * s
        alpha = 1.0
        for k in range(m):
            if dlam[k] < 0:
                alpha = min(alpha, -0.995 * lam[k] / dlam[k])
        logs = 0.0
        for k in range(m):
            logs += math.log(g[k])
        merit = j - mu * logs
        slope = 0.0
        for i in range(n):
            slope += rhs[i] * dx[i]
        slope = -slope
        accepted = False
        while alpha > 1e-14:
            for i in range(n):
                trial[i] = x[i] + alpha * dx[i]
            trial_cost = values(d, trial, trial_g)
            inside = True
            for k in range(m):
                if not trial_g[k] > 0.005 * g[k]:
                    inside = False
                    break
            if inside:
                logs = 0.0
                for k in range(m):
                    logs += math.log(trial_g[k])
                merit_new = trial_cost - mu * logs
                if merit_new <= merit + 1e-4 * alpha * min(slope, 0.0) + 1e-12 * abs(merit):
                    accepted = True
                    break
            alpha *= 0.5
        if not accepted:
            return x, j, iteration, 1
        x[:] = trial
        for k in range(m):
            lam[k] = max(lam[k] + alpha * dlam[k], 1e-16)
        j = evaluate(d, x, jg, jh, g, gg, gh)
    return x, j, max_iterations, 1


# ---------------------------------------------------------------------------
# grid evaluations (stop_condition._terms_grid etc.; planner._grid_start, _quantise)
# ---------------------------------------------------------------------------

@numba.njit(**_JIT)
def _quadrature_grid(kappa, out):
    """``kappa * (grow @ _BASIS.T)`` and ``kappa * ((1 / grow) @ _BASIS.T)`` -> out[0:3], out[3:6]."""
    n = _UA.shape[0]
    grow = np.empty(n)
    for q in range(n):
        grow[q] = math.exp(kappa * _UA[q])
    for b in range(3):
        sp = 0.0
        sm = 0.0
        for q in range(n):
            sp += grow[q] * _BASIS_A[b, q]
            sm += (1.0 / grow[q]) * _BASIS_A[b, q]
        out[b] = kappa * sp
        out[3 + b] = kappa * sm


@numba.njit(**_JIT)
def _terms_grid_point(d, landing, transition, quad):
    """``_terms_grid`` at one (landing, transition) with its quadrature: (A, B, F, G)."""
    w = d[W]
    kappa = w * transition
    e12 = math.exp(w * (landing + transition))
    c1, c2 = d[RATE] / w, d[ACCEL] / (w * w)
    big_a = e12 * d[DCM] - c1 * kappa * quad[1] - c2 * kappa ** 2 * quad[2]
    big_b = d[CCM] / e12 + c1 * kappa * quad[4] + c2 * kappa ** 2 * quad[5]
    return big_a, big_b, quad[0] + 1.0, quad[3]


@numba.njit(**_JIT)
def _grid_target(big_a, big_b, f, g, w, slowdown):
    e3sq = math.exp(2.0 * w * slowdown)
    return (e3sq * big_a - big_b) / (e3sq * f + g - 1.0)


@numba.njit(**_JIT)
def _grid_slowdown(big_a, big_b, f, g, w, target):
    ratio = (big_b + target * (g - 1.0)) / (big_a - target * f)
    if ratio >= 1.0:
        return math.log(ratio if ratio > 0 else 1.0) / (2.0 * w)
    return math.nan


@numba.njit(**_JIT)
def slowdown_grid(d, landing, transition, target):
    """``problem.slowdown(y)`` at one point (the grid formula)."""
    quad = np.empty(6)
    _quadrature_grid(d[W] * transition, quad)
    big_a, big_b, f, g = _terms_grid_point(d, landing, transition, quad)
    return _grid_slowdown(big_a, big_b, f, g, d[W], target)


@numba.njit(**_JIT)
def _grid_worst(d, big_a, big_b, f, g, t1, t2, z, t3):
    """Smallest margin of ``constraints_grid`` (without the variable bounds); NaN propagates."""
    w = d[W]
    worst = _nan_to_num(t3 - d[MIN_T3], -1.0)
    worst = _npmin(worst, _nan_to_num(d[MAX_T3] - t3, -1.0))
    if d[KIND] == 0.0:
        step = z - d[ZMP_OFFSET]
        dx = d[SUPPORT_X] + step - d[SWING_X]
        dy = d[LANDING_Y] - d[SWING_Y]
        dist = math.sqrt(dx * dx + dy * dy)
        worst = _npmin(worst, d[SWING_SPEED] * t1 - dist)
        grow = math.exp(w * t1)
        ahead = 0.5 * (d[DCM] * grow + d[CCM] / grow)
        worst = _npmin(worst, d[FORE_REACH] - step + ahead)
    rest_t3 = _grid_slowdown(big_a, big_b, f, g, w, z)
    rest = z + (big_b + z * (g - 1.0)) * math.exp(-w * rest_t3)
    worst = _npmin(worst, _nan_to_num(d[REAR_REACH] - rest + d[REAR_ANKLE], -1.0))
    return worst


@numba.njit(**_JIT)
def grid_start(d, landing_axis, transition_axis, samples):
    """``planner._grid_start``: ``(y (3,), cost, strict, found)``."""
    w = d[W]
    single = d[KIND] == 0.0
    nl, nt, nk = landing_axis.shape[0], transition_axis.shape[0], samples.shape[0]
    worst = np.empty((nl, nt, nk))
    cost = np.empty((nl, nt, nk))
    zs = np.empty((nl, nt, nk))
    quad = np.empty(6)
    lo2, hi2 = d[BOUNDS + 4], d[BOUNDS + 5]
    for jt in range(nt):
        t2 = transition_axis[jt]
        _quadrature_grid(w * t2, quad)
        for il in range(nl):
            t1 = landing_axis[il]
            big_a, big_b, f, g = _terms_grid_point(d, t1, t2, quad)
            long = _grid_target(big_a, big_b, f, g, w, d[MAX_T3])
            short = _grid_target(big_a, big_b, f, g, w, d[MIN_T3])
            low = _npmax(lo2, _npmin(long, short))
            high = _npmin(hi2, _npmax(long, short))
            if single:
                dy = d[LANDING_Y] - d[SWING_Y]
                reach = d[SWING_SPEED] * t1
                radius = math.sqrt(_npmax(reach ** 2 - dy * dy, 0.0))
                offset = d[ZMP_OFFSET] - d[SUPPORT_X]
                low = _npmax(low, d[SWING_X] - radius + offset)
                high = _npmin(high, d[SWING_X] + radius + offset)
                grow = math.exp(w * t1)
                ahead = 0.5 * (d[DCM] * grow + d[CCM] / grow)
                high = _npmin(high, d[FORE_REACH] + ahead + d[ZMP_OFFSET])
            for kz in range(nk):
                z = low + (high - low) * samples[kz]
                t3 = _grid_slowdown(big_a, big_b, f, g, w, z)
                m = _grid_worst(d, big_a, big_b, f, g, t1, t2, z, t3)
                # variable bounds: lower then upper, over the free variables
                if single:
                    m = _npmin(m, t1 - d[BOUNDS + 0])
                m = _npmin(m, t2 - d[BOUNDS + 2])
                m = _npmin(m, z - lo2)
                if single:
                    m = _npmin(m, d[BOUNDS + 1] - t1)
                m = _npmin(m, d[BOUNDS + 3] - t2)
                m = _npmin(m, hi2 - z)
                if not (high >= low and math.isfinite(t3)):
                    m = -math.inf
                worst[il, jt, kz] = m
                cost[il, jt, kz] = cost_value(d, t1, t2, z, _nan_to_num(t3, 0.0))
                zs[il, jt, kz] = z
    y = np.zeros(3)
    for strict in (True, False):
        threshold = 1e-9 if strict else -1e-12
        any_ok = False
        best = 0
        best_value = 0.0
        idx = 0
        for il in range(nl):
            for jt in range(nt):
                for kz in range(nk):
                    ok = worst[il, jt, kz] > threshold
                    any_ok = any_ok or ok
                    v = cost[il, jt, kz] if ok else math.inf
                    if idx == 0:
                        best, best_value = 0, v
                    elif best_value == best_value and (v != v or v < best_value):
                        best, best_value = idx, v
                    idx += 1
        if any_ok:
            il = best // (nt * nk)
            jt = (best // nk) % nt
            kz = best % nk
            y[0], y[1], y[2] = landing_axis[il], transition_axis[jt], zs[il, jt, kz]
            return y, cost[il, jt, kz], strict, True
    return y, math.nan, False, False


@numba.njit(**_JIT)
def solve_continuous(d, landing_axis, transition_axis, samples):
    """``planner.solve_continuous``: ``(y (3,), t3, cost, iterations, status)``."""
    y0, cost0, strict, found = grid_start(d, landing_axis, transition_axis, samples)
    if not found:
        return y0, math.nan, math.nan, 0, NO_GRID_START
    if not strict:
        return y0, slowdown_grid(d, y0[0], y0[1], y0[2]), cost0, 0, OK
    n, m, first = _dims(d)
    scale = max(cost0, 1.0)
    x0 = np.empty(n)
    for i in range(n):
        x0[i] = y0[first + i]
    x, _, iterations, status = barrier_newton(d, x0, 1e-1 * scale / m, d[COST_TOL] * scale / m)
    if status < 0:
        return y0, math.nan, math.nan, 0, INFEASIBLE_START
    y = _full(d, x)
    t3 = slowdown_grid(d, y[0], y[1], y[2])
    return y, t3, cost_value(d, y[0], y[1], y[2], t3), iterations, OK


@numba.njit(**_JIT)
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


@numba.njit(**_JIT)
def quantise(d, y, t3):
    """``planner._quantise``: ``(t1, t2, t3, z, cost, found)``."""
    w = d[W]
    dt = d[DT]
    if d[KIND] == 0.0:
        o1 = _tick_options(y[0], d[BOUNDS + 0], d[BOUNDS + 1], dt)
    else:
        o1 = np.zeros(1)
    o2 = _tick_options(y[1], d[BOUNDS + 2], d[BOUNDS + 3], dt)
    o3 = _tick_options(t3, d[MIN_T3], d[MAX_T3], dt)
    quads = np.empty((o2.shape[0], 6))
    for jt in range(o2.shape[0]):
        _quadrature_grid(w * o2[jt], quads[jt])
    best_value = math.inf
    best_i = best_j = best_k = -1
    best_z = 0.0
    for il in range(o1.shape[0]):  # C order over (landing, transition, slowdown): np.argmin's first minimum
        t1 = o1[il]
        for jt in range(o2.shape[0]):
            t2 = o2[jt]
            big_a, big_b, f, g = _terms_grid_point(d, t1, t2, quads[jt])
            for kz in range(o3.shape[0]):
                t3q = o3[kz]
                z = _grid_target(big_a, big_b, f, g, w, t3q) if d[RESOLVE] != 0.0 else y[2]
                ok = (t1 >= d[BOUNDS + 0] - 1e-12) and (t1 <= d[BOUNDS + 1] + 1e-12)
                ok = ok and (t2 >= d[BOUNDS + 2] - 1e-12) and (t2 <= d[BOUNDS + 3] + 1e-12)
                ok = ok and (z >= d[BOUNDS + 4] - 1e-12) and (z <= d[BOUNDS + 5] + 1e-12)
                ok = ok and _grid_worst(d, big_a, big_b, f, g, t1, t2, z, t3q) >= -1e-12
                if ok:
                    v = cost_value(d, t1, t2, z, t3q)
                    if best_i < 0 or v < best_value:
                        best_i, best_j, best_k, best_value, best_z = il, jt, kz, v, z
    if best_i < 0:
        return 0.0, 0.0, 0.0, 0.0, math.nan, False
    return o1[best_i], o2[best_j], o3[best_k], best_z, best_value, True


@numba.njit(**_JIT)
def solve(d, landing_axis, transition_axis, samples, snap):
    """Grid start, Newton and (``snap``) quantisation: ``(quantised (t1, t2, t3, z, cost),
    continuous (y0, y1, t3, y2, cost), iterations, status)``. One compiled entry point
    (each one costs seconds of cold compilation)."""
    y, t3, cost, iterations, status = solve_continuous(d, landing_axis, transition_axis, samples)
    q = np.full(5, math.nan)
    cont = np.array([y[0], y[1], t3, y[2], cost])
    if status != OK or not snap:
        return q, cont, iterations, status
    t1q, t2q, t3q, z, qcost, found = quantise(d, y, t3)
    if not found:
        return q, cont, iterations, NO_QUANTISATION
    q[0], q[1], q[2], q[3], q[4] = t1q, t2q, t3q, z, qcost
    return q, cont, iterations, OK
