"""The stop condition (eq. 17-22, 29) in closed form, with analytic derivatives.

Coordinates are relative to the ZMP at the instant the stop plan starts. Work in
the divergent / convergent components of the LIPM, ``xi = x + v/w`` and
``zeta = x - v/w``, which decouple: ``xi' = w (xi - p)``, ``zeta' = -w (zeta - p)``;
the COG velocity is ``w (xi - zeta) / 2``.

Phases (durations ``landing``, ``transition``, ``slowdown``):

(i)   Landing: ZMP constant (eq. 19).                      (single support only)
(ii)  ZMP transition: quintic from the current ZMP, rate and acceleration to
      the target ``Z`` with zero rate and acceleration (eq. 12-14).
(iii) Slowdown: ZMP constant at ``Z`` (eq. 20); COG velocity zero at its end (eq. 17).

The LIPM is linear, so the stop condition is affine in ``Z`` and gives it
explicitly (eq. 22 for the step length ``l_s = Z`` in single support; eq. 29
for ``ZMP_max`` in double support)::

    Z = (E3^2 A - B) / (E3^2 (L_sigma + 1) + R_sigma - 1)
    A = E1 E2 xi0 - S_L(kappa),   B = zeta0 / (E1 E2) + S_R(kappa)

with ``Ek = exp(w Tk)``, ``kappa = w T2`` and ``S_L, S_R, L_sigma, R_sigma``
integrals of the transition shape against ``exp(+-kappa (1-s))`` computed by
Gauss-Legendre quadrature (exact to rounding for these smooth integrands).
Gradient and Hessian in the durations follow by the quotient rule (used by the
Newton method of eq. 25-26 and 31).

The one source of the closed form: the solver's grid start, Newton iterations and
quantisation (:mod:`drake_estop.planning.solver`) and the planner's lateral plane all call
these functions. They are written in the numba subset and compiled by
:func:`~drake_estop.planning.backend.jit` (plain Python without numba). The closed form is
split where its data split: :func:`transition_terms` depends on the transition duration
only (the quadrature, once per transition duration of a grid), :func:`closed_form` adds
the landing duration and the start state. Both write into one float64 terms vector
(:data:`TERMS`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from drake_estop.planning import lipm
from drake_estop.planning.backend import jit

_NODES, _WEIGHTS = np.polynomial.legendre.leggauss(20)
_S = 0.5 * (_NODES + 1.0)
_W = 0.5 * _WEIGHTS
_U = np.ascontiguousarray(1.0 - _S)
# shapes on the unit interval: target step (sigma), initial rate, initial acceleration (eq. 12-14)
_BASIS = np.array(
    [np.polynomial.polynomial.polyval(_S, b) for b in (lipm.SMOOTHSTEP, lipm.HERMITE_D1, lipm.HERMITE_D2)]
) * _W  # (3, nodes), quadrature weights folded in
# moments of the three shapes against u^k, k = 0, 1, 2 (rows: 3 shapes x 3 powers)
_STACK = np.ascontiguousarray(np.vstack([_BASIS, _BASIS * _U, _BASIS * _U * _U]))

TERMS = 24
"""Size of the terms vector of the closed form: ``A, A_1, A_2, A_11, A_12, A_22`` (index 1: landing,
2: transition duration), ``B`` likewise (from :func:`closed_form`), then ``F, F', F''``
(``F = L_sigma + 1``, primes ``d/dT2``), ``G, G', G''`` (``G = R_sigma``), ``S_L, S_L', S_L''`` and
``S_R, S_R', S_R''`` (the responses to the start ZMP rate and acceleration; from
:func:`transition_terms`)."""
_EXP_MAX = 709.78  # math.exp overflows above log(max float)


@dataclass(frozen=True)
class StopStart:
    """LIPM state where the stop begins, relative to the ZMP there."""

    dcm: float  # xi0 = x + v/w - p0
    ccm: float  # zeta0 = x - v/w - p0
    zmp_rate: float = 0.0
    zmp_accel: float = 0.0

    @classmethod
    def from_state(cls, com, com_vel, zmp, w, zmp_rate=0.0, zmp_accel=0.0):
        return cls(float(com + com_vel / w - zmp), float(com - com_vel / w - zmp), float(zmp_rate),
                   float(zmp_accel))


@jit
def exp_or_inf(x):
    """``math.exp``, inf above the float range (where plain Python raises OverflowError)."""
    if x > _EXP_MAX:
        return math.inf
    return math.exp(x)


@jit
def transition_terms(w, transition, rate, accel, t):
    """The transition-only part of the closed form into ``t[12:24]`` (:data:`TERMS`).

    ``L_b = kappa M0_b``, ``L' = M0 + kappa M1``, ``L'' = 2 M1 + kappa M2`` with ``Mk_b`` the
    moments of shape ``b`` against ``u^k exp(kappa u)``; ``R`` likewise against
    ``exp(-kappa u)`` (``R' = P0 - kappa P1``, ``R'' = -2 P1 + kappa P2``). The responses to
    the start ZMP rate and acceleration (``rate T2 h1 + accel T2^2 h2``, eq. 12-14) are the
    ``S`` terms. False where the quadrature over- or underflows (absurd durations).
    """
    kappa = w * transition
    n = _U.shape[0]
    grow = np.empty((2, n))  # exp(kappa u), exp(-kappa u) at the nodes
    for q in range(n):
        grow[0, q] = exp_or_inf(kappa * _U[q])
        if not (grow[0, q] > 0.0 and grow[0, q] < math.inf):
            return False
        grow[1, q] = 1.0 / grow[0, q]
    moments = np.zeros((2, 9))  # M, P: 3 shapes x 3 powers
    for r in range(9):
        sp = 0.0
        sm = 0.0
        for q in range(n):
            sp += _STACK[r, q] * grow[0, q]
            sm += _STACK[r, q] * grow[1, q]
        moments[0, r] = sp
        moments[1, r] = sm
    mp, mm = moments[0], moments[1]
    ww = w * w
    lr = np.empty((6, 3))  # L, L', L'', R, R', R'' per shape
    for b in range(3):
        lr[0, b] = kappa * mp[b]
        lr[1, b] = mp[b] + kappa * mp[3 + b]
        lr[2, b] = 2.0 * mp[3 + b] + kappa * mp[6 + b]
        lr[3, b] = kappa * mm[b]
        lr[4, b] = mm[b] - kappa * mm[3 + b]
        lr[5, b] = -2.0 * mm[3 + b] + kappa * mm[6 + b]
    sl0 = sl1 = sl2 = sr0 = sr1 = sr2 = 0.0
    for power in (1, 2):  # shape b = power: h1 (rate), h2 (acceleration)
        coef = rate / w if power == 1 else accel / ww
        if coef != 0.0:
            if power == 1:
                k_p, k_p1, k_p2 = kappa, 1.0, 0.0
            else:
                k_p, k_p1, k_p2 = kappa * kappa, 2.0 * kappa, 2.0
            lval, ld1, ld2 = lr[0, power], lr[1, power], lr[2, power]
            rval, rd1, rd2 = lr[3, power], lr[4, power], lr[5, power]
            sl0 += coef * k_p * lval
            sl1 += coef * (k_p1 * lval + k_p * ld1)
            sl2 += coef * (k_p2 * lval + 2.0 * k_p1 * ld1 + k_p * ld2)
            sr0 += coef * k_p * rval
            sr1 += coef * (k_p1 * rval + k_p * rd1)
            sr2 += coef * (k_p2 * rval + 2.0 * k_p1 * rd1 + k_p * rd2)
    t[12], t[13], t[14] = lr[0, 0] + 1.0, w * lr[1, 0], ww * lr[2, 0]
    t[15], t[16], t[17] = lr[3, 0], w * lr[4, 0], ww * lr[5, 0]
    t[18], t[19], t[20], t[21], t[22], t[23] = sl0, sl1, sl2, sr0, sr1, sr2
    return True


@jit
def closed_form(dcm, ccm, w, landing, transition, t):
    """The closed form's ``A = E1 E2 xi0 - S_L``, ``B = zeta0 / (E1 E2) + S_R`` and their partials at
    (landing, transition) into ``t[:12]``, from the start state and :func:`transition_terms`
    (``t[12:24]``, for this transition). False where ``E1 E2`` over- or underflows."""
    e12 = exp_or_inf(w * (landing + transition))
    if not (e12 > 0.0 and e12 < math.inf):
        return False
    ww = w * w
    p_fwd = e12 * dcm
    p_bwd = ccm / e12
    t[0] = p_fwd - t[18]
    t[1] = w * p_fwd
    t[2] = w * p_fwd - w * t[19]
    t[3] = ww * p_fwd
    t[4] = ww * p_fwd
    t[5] = ww * p_fwd - ww * t[20]
    t[6] = p_bwd + t[21]
    t[7] = -w * p_bwd
    t[8] = -w * p_bwd + w * t[22]
    t[9] = ww * p_bwd
    t[10] = ww * p_bwd
    t[11] = ww * p_bwd + ww * t[23]
    return True


@jit
def terms_at(dcm, ccm, rate, accel, w, landing, transition, t):
    """:func:`transition_terms` and :func:`closed_form` at one point into ``t`` (False: no terms there)."""
    if not transition_terms(w, transition, rate, accel, t):
        return False
    return closed_form(dcm, ccm, w, landing, transition, t)


@jit
def _zmp_parts(t, w, slowdown):
    """``(E3^2, den, Z)`` of :func:`stop_zmp`."""
    e3sq = exp_or_inf(2.0 * w * slowdown)
    den = e3sq * t[12] + t[15] - 1.0
    if den == 0.0:
        return e3sq, den, math.nan
    return e3sq, den, (e3sq * t[0] - t[6]) / den


@jit
def stop_zmp(t, w, slowdown):
    """ZMP target ``Z`` of the slowdown that meets the stop condition (eq. 17): eq. 22 in single
    support (step length), eq. 29 in double support (ZMP_max). NaN where the closed form is 0/0."""
    return _zmp_parts(t, w, slowdown)[2]


@jit
def stop_zmp_derivatives(t, w, slowdown, grad, hess):
    """:func:`stop_zmp` with its gradient and Hessian in (T1, T2, T3) into ``grad`` (3,), ``hess``
    (3, 3), by the quotient rule: ``Z = num / den``, ``num = E3^2 A - B``, ``den = E3^2 F + G - 1``
    (free of T1). Returns Z (NaN, derivatives untouched, where the closed form is 0/0)."""
    e3sq, den, z = _zmp_parts(t, w, slowdown)
    if z != z:
        return z
    a0, a1, a2, a11, a12, a22 = t[0], t[1], t[2], t[3], t[4], t[5]
    b1, b2, b11, b12, b22 = t[7], t[8], t[9], t[10], t[11]
    f0, f1, f2 = t[12], t[13], t[14]
    g1, g2 = t[16], t[17]
    e_1 = 2.0 * w * e3sq  # d(E3^2)/dT3
    e_2 = 2.0 * w * e_1
    d2 = e3sq * f1 + g1  # den_2, den_3 (den_1 = 0)
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


@jit
def slowdown(t, w, target):
    """Slowdown duration that meets the stop condition (eq. 21) with ZMP target ``target``: the
    closed form solved for ``exp(2 w T3) = (B + Z (G - 1)) / (A - Z F)``. NaN where no
    non-negative duration stops the COG with that target."""
    denominator = t[0] - target * t[12]
    ratio = (t[6] + target * (t[15] - 1.0)) / denominator if denominator != 0.0 else -1.0
    if not ratio >= 1.0:
        return math.nan
    return math.log(ratio) / (2.0 * w)


@jit
def slowdown_derivatives(t, w, target, t3, grad, hess):
    """Gradient and Hessian of :func:`slowdown` ``t3`` in (landing, transition, target) into
    ``grad``, ``hess``, by implicit differentiation of ``Z(T1, T2, T3) = target``. False (nothing
    written) where Z does not depend on T3 there (the stop condition's 0/0 case)."""
    zg = np.zeros(3)
    zh = np.zeros((3, 3))
    stop_zmp_derivatives(t, w, t3, zg, zh)
    z1, z2, z3 = zg[0], zg[1], zg[2]
    if not (z3 != 0.0 and math.isfinite(z3)):
        return False
    grad[0] = -z1 / z3
    grad[1] = -z2 / z3
    grad[2] = 1.0 / z3
    # F(y, T3) = Z(T1, T2, T3) - target = 0: F_yy = zh[:2, :2], F_y3 = zh[:2, 2], F_33 = zh[2, 2]
    f3 = (zh[0, 2], zh[1, 2], 0.0)
    h33 = zh[2, 2]
    for i in range(3):
        for j in range(i, 3):
            fh = zh[i, j] if (i < 2 and j < 2) else 0.0
            value = -(fh + f3[i] * grad[j] + f3[j] * grad[i] + h33 * (grad[i] * grad[j])) / z3
            hess[i, j] = value
            hess[j, i] = value
    return True


@jit
def _rest_parts(t, w, target, t3):
    """``(zeta_ii - Z, exp(-w T3), rest position)`` of :func:`rest`."""
    u = t[6] + target * (t[15] - 1.0)
    decay = exp_or_inf(-w * t3)
    return u, decay, target + u * decay


@jit
def rest(t, w, target, t3):
    """COG position where it comes to rest at the slowdown end (relative to the start ZMP): with
    zero velocity there, ``x = zeta = Z + (zeta_ii - Z) exp(-w T3)``, ``zeta_ii = B + Z G``."""
    return _rest_parts(t, w, target, t3)[2]


@jit
def rest_derivatives(t, w, target, t3, tg, th, grad, hess):
    """:func:`rest` with its gradient and Hessian in (landing, transition, target) into ``grad``,
    ``hess``, the slowdown eliminated (``tg``, ``th``: :func:`slowdown_derivatives`). Returns the rest
    position."""
    b1, b2, b11, b12, b22 = t[7], t[8], t[9], t[10], t[11]
    g0, g1, g2 = t[15], t[16], t[17]
    u, decay, value = _rest_parts(t, w, target, t3)
    ug = (b1, b2 + target * g1, g0 - 1.0)
    uh = np.empty((3, 3))
    uh[0, 0], uh[0, 1], uh[0, 2] = b11, b12, 0.0
    uh[1, 0], uh[1, 1], uh[1, 2] = b12, b22 + target * g2, g1
    uh[2, 0], uh[2, 1], uh[2, 2] = 0.0, g1, 0.0
    wd = w * decay
    eg = np.empty(3)  # d exp(-w T3)
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
# from Python: one point of a StopStart
# ---------------------------------------------------------------------------

def terms(start: StopStart, w: float, landing: float, transition: float):
    """:func:`terms_at` for ``start``: the terms vector, or None where there are none."""
    if not w > 0:
        raise ValueError(f"the LIPM frequency w must be positive, got {w!r}")
    t = np.empty(TERMS)
    ok = terms_at(float(start.dcm), float(start.ccm), float(start.zmp_rate), float(start.zmp_accel), float(w),
                  float(landing), float(transition), t)
    return t if ok else None


def target_zmp(start: StopStart, w: float, landing: float, transition: float, slowdown: float,
               derivatives: bool = True):
    """ZMP target ``Z`` meeting the stop condition (eq. 22 / 29), with gradient and Hessian.

    Returns ``(Z, grad, hess)`` over (landing, transition, slowdown); with
    ``derivatives=False`` returns ``Z`` only. NaN where undefined.
    """
    t = terms(start, w, landing, transition)
    if not derivatives:
        return math.nan if t is None else float(stop_zmp(t, float(w), float(slowdown)))
    grad, hess = np.zeros(3), np.zeros((3, 3))
    z = math.nan if t is None else float(stop_zmp_derivatives(t, float(w), float(slowdown), grad, hess))
    return z, grad, hess


def slowdown_time(start: StopStart, w: float, landing: float, transition: float, target: float,
                  derivatives: bool = True):
    """Slowdown duration that meets the stop condition (eq. 21) for a given ZMP target, with its
    gradient and Hessian in (landing, transition, target) by implicit differentiation.

    Returns ``(T3, grad, hess)`` (``T3`` alone with ``derivatives=False``); ``T3`` is NaN
    (and the derivatives zero) where infeasible.
    """
    t = terms(start, w, landing, transition)
    t3 = math.nan if t is None else float(slowdown(t, float(w), float(target)))
    if not derivatives:
        return t3
    grad, hess = np.zeros(3), np.zeros((3, 3))
    if t3 == t3 and not slowdown_derivatives(t, float(w), float(target), t3, grad, hess):
        t3 = math.nan
    return t3, grad, hess
