"""The stop condition (eq. 17-22, 29) in closed form, with analytic derivatives.

Pure numpy. Coordinates are relative to the ZMP at the instant the stop plan
starts. Work in the divergent / convergent components of the LIPM,
``xi = x + v/w`` and ``zeta = x - v/w``, which decouple: ``xi' = w (xi - p)``,
``zeta' = -w (zeta - p)``; the COG velocity is ``w (xi - zeta) / 2``.

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
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from drake_estop.planning import lipm

_NODES, _WEIGHTS = np.polynomial.legendre.leggauss(20)
_S = 0.5 * (_NODES + 1.0)
_W = 0.5 * _WEIGHTS
_U = 1.0 - _S
# shapes on the unit interval: target step (sigma), initial rate, initial acceleration
_BASIS = np.array(
    [np.polynomial.polynomial.polyval(_S, b) for b in (lipm.SMOOTHSTEP, lipm.HERMITE_D1, lipm.HERMITE_D2)]
) * _W  # (3, nodes), quadrature weights folded in


@dataclass(frozen=True)
class StopStart:
    """LIPM state where the stop begins, relative to the ZMP there."""

    dcm: float  # xi0 = x + v/w - p0
    ccm: float  # zeta0 = x - v/w - p0
    zmp_rate: float = 0.0
    zmp_accel: float = 0.0

    @classmethod
    def from_state(cls, com, com_vel, zmp, w, zmp_rate=0.0, zmp_accel=0.0):
        # plain floats: numpy scalars make the scalar arithmetic of the solver several times slower
        return cls(float(com + com_vel / w - zmp), float(com - com_vel / w - zmp), float(zmp_rate),
                   float(zmp_accel))


# moments of the three shapes against u^k, k = 0, 1, 2 (rows: 3 shapes x 3 powers)
_STACK = np.vstack([_BASIS, _BASIS * _U, _BASIS * _U * _U])


@functools.lru_cache(maxsize=16)
def _terms(start: StopStart, w: float, landing: float, transition: float):
    """Scalars of the closed form at (landing, transition), with the partials the
    derivatives need: ``(A, A_1, A_2, A_11, A_12, A_22, B, ..., F, F', F'', G, G', G'')``.

    Index 1 is the landing duration, 2 the transition duration; F and G depend
    on the transition only (primes: d/dT2). Cached (tuples of floats): the
    Newton method evaluates the accepted line-search point again with derivatives.
    """
    kappa = w * transition
    grow = np.exp(kappa * _U)
    mp = (_STACK @ grow).tolist()  # M0(sigma,h1,h2), M1(...), M2(...)
    mm = (_STACK @ (1.0 / grow)).tolist()
    ww = w * w
    # L_b = k M0, L' = M0 + k M1, L'' = 2 M1 + k M2 ; R_b = k P0, R' = P0 - k P1, R'' = -2 P1 + k P2
    lval = [kappa * mp[b] for b in range(3)]
    ld1 = [mp[b] + kappa * mp[3 + b] for b in range(3)]
    ld2 = [2.0 * mp[3 + b] + kappa * mp[6 + b] for b in range(3)]
    rval = [kappa * mm[b] for b in range(3)]
    rd1 = [mm[b] - kappa * mm[3 + b] for b in range(3)]
    rd2 = [-2.0 * mm[3 + b] + kappa * mm[6 + b] for b in range(3)]
    sl0 = sl1 = sl2 = sr0 = sr1 = sr2 = 0.0
    # transition responses to the initial ZMP rate / acceleration (rate T2 h1 + accel T2^2 h2)
    for b, coef, power in ((1, start.zmp_rate / w, 1), (2, start.zmp_accel / ww, 2)):
        if coef != 0.0:
            k_p = kappa**power
            k_p1 = power * kappa ** (power - 1)
            k_p2 = 2.0 if power == 2 else 0.0
            sl0 += coef * k_p * lval[b]
            sl1 += coef * (k_p1 * lval[b] + k_p * ld1[b])
            sl2 += coef * (k_p2 * lval[b] + 2 * k_p1 * ld1[b] + k_p * ld2[b])
            sr0 += coef * k_p * rval[b]
            sr1 += coef * (k_p1 * rval[b] + k_p * rd1[b])
            sr2 += coef * (k_p2 * rval[b] + 2 * k_p1 * rd1[b] + k_p * rd2[b])
    e12 = math.exp(w * (landing + transition))
    p_fwd = e12 * start.dcm
    p_bwd = start.ccm / e12
    big_a = (p_fwd - sl0, w * p_fwd, w * p_fwd - w * sl1, ww * p_fwd, ww * p_fwd, ww * p_fwd - ww * sl2)
    big_b = (p_bwd + sr0, -w * p_bwd, -w * p_bwd + w * sr1, ww * p_bwd, ww * p_bwd, ww * p_bwd + ww * sr2)
    f = (lval[0] + 1.0, w * ld1[0], ww * ld2[0])
    g = (rval[0], w * rd1[0], ww * rd2[0])
    return big_a, big_b, f, g


def _zmp_point(terms, w: float, slowdown: float):
    """``Z`` with its gradient and Hessian in (T1, T2, T3), plain floats (quotient rule).

    Z = num / den with num = E3^2 A - B, den = E3^2 F + G - 1; den is free of T1.
    Returns ``(z, [z_1, z_2, z_3], 3x3 nested list)``.
    """
    big_a, big_b, f, g = terms
    e3sq = math.exp(2.0 * w * slowdown)
    a0, a1, a2, a11, a12, a22 = big_a
    b0, b1, b2, b11, b12, b22 = big_b
    den = e3sq * f[0] + g[0] - 1.0
    z = (e3sq * a0 - b0) / den
    e_1 = 2.0 * w * e3sq  # d(E3^2)/dT3
    e_2 = 2.0 * w * e_1
    d2 = e3sq * f[1] + g[1]  # den_2, den_3 (den_1 = 0)
    d3 = e_1 * f[0]
    z1 = (e3sq * a1 - b1) / den
    z2 = (e3sq * a2 - b2 - z * d2) / den
    z3 = (e_1 * a0 - z * d3) / den
    h11 = (e3sq * a11 - b11) / den
    h12 = (e3sq * a12 - b12 - z1 * d2) / den
    h13 = (e_1 * a1 - z1 * d3) / den
    h22 = (e3sq * a22 - b22 - z2 * d2 - z2 * d2 - z * (e3sq * f[2] + g[2])) / den
    h23 = (e_1 * a2 - z2 * d3 - z3 * d2 - z * (e_1 * f[1])) / den
    h33 = (e_2 * a0 - z3 * d3 - z3 * d3 - z * (e_2 * f[0])) / den
    return z, [z1, z2, z3], [[h11, h12, h13], [h12, h22, h23], [h13, h23, h33]]


def _zmp_from_terms(terms, w: float, slowdown: float, derivatives: bool):
    if not derivatives:
        big_a, big_b, f, g = terms
        e3sq = math.exp(2.0 * w * slowdown)
        return (e3sq * big_a[0] - big_b[0]) / (e3sq * f[0] + g[0] - 1.0)
    z, grad, hess = _zmp_point(terms, w, slowdown)
    return z, np.array(grad), np.array(hess)


def target_zmp(start: StopStart, w: float, landing: float, transition: float, slowdown: float,
               derivatives: bool = True):
    """ZMP target ``Z`` meeting the stop condition, with gradient and Hessian.

    Returns ``(Z, grad, hess)`` over (landing, transition, slowdown); with
    ``derivatives=False`` returns ``Z`` only.
    """
    return _zmp_from_terms(_terms(start, w, landing, transition), w, slowdown, derivatives)


def _terms_grid(start: StopStart, w: float, landing, transition):
    """A, B, F = L_sigma + 1, G = R_sigma of the closed form, vectorised.

    Shaped like ``landing`` and ``transition`` broadcast together (not like the
    target or slowdown they are later combined with): callers pass grids as
    broadcastable axes so the quadrature runs once per transition duration.
    """
    kappa = w * np.asarray(transition, float)
    grow = np.exp(kappa[..., None] * _U)
    lm = kappa[..., None] * (grow @ _BASIS.T)
    rm = kappa[..., None] * ((1.0 / grow) @ _BASIS.T)
    e12 = np.exp(w * (np.asarray(landing, float) + np.asarray(transition, float)))
    c1, c2 = start.zmp_rate / w, start.zmp_accel / (w * w)
    big_a = e12 * start.dcm - c1 * kappa * lm[..., 1] - c2 * kappa**2 * lm[..., 2]
    big_b = start.ccm / e12 + c1 * kappa * rm[..., 1] + c2 * kappa**2 * rm[..., 2]
    return big_a, big_b, lm[..., 0] + 1.0, rm[..., 0]


def target_zmp_grid(start: StopStart, w: float, landing, transition, slowdown) -> np.ndarray:
    """Vectorised value of :func:`target_zmp` over arrays of durations (broadcast)."""
    return _target_from_grid_terms(_terms_grid(start, w, landing, transition), w, slowdown)


def _target_from_grid_terms(terms, w: float, slowdown):
    """:func:`target_zmp_grid` from precomputed :func:`_terms_grid` output."""
    big_a, big_b, f, g = terms
    e3sq = np.exp(2.0 * w * np.asarray(slowdown, float))
    return (e3sq * big_a - big_b) / (e3sq * f + g - 1.0)


def _slowdown_from_grid_terms(terms, w: float, target):
    """Slowdown duration from precomputed :func:`_terms_grid` output (NaN where infeasible)."""
    big_a, big_b, f, g = terms
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = (big_b + target * (g - 1.0)) / (big_a - target * f)
        return np.where(ratio >= 1.0, np.log(np.where(ratio > 0, ratio, 1.0)) / (2.0 * w), np.nan)


def slowdown_time_grid(start: StopStart, w: float, landing, transition, target):
    """Slowdown duration that meets the stop condition (eq. 21) for a given ZMP target.

    The same closed form solved for ``exp(2 w T3) = (B + Z (G - 1)) / (A - Z F)``;
    NaN where no non-negative duration stops the COG with that target.
    """
    landing, transition = np.broadcast_arrays(np.asarray(landing, float), np.asarray(transition, float))
    return _slowdown_from_grid_terms(_terms_grid(start, w, landing, transition), w, np.asarray(target, float))


def _slowdown_point(terms, w: float, target: float, derivatives: bool):
    """T3 from the closed form at one point; with derivatives, its gradient and Hessian in
    (landing, transition, target) by implicit differentiation of Z(T1, T2, T3) = target.
    Plain floats and nested lists; ``(nan, None, None)`` where infeasible."""
    big_a, big_b, f, g = terms
    denominator = big_a[0] - target * f[0]
    ratio = (big_b[0] + target * (g[0] - 1.0)) / denominator if denominator != 0.0 else -1.0
    if not ratio >= 1.0:
        return (math.nan, None, None) if derivatives else math.nan
    t3 = math.log(ratio) / (2.0 * w)
    if not derivatives:
        return t3
    _, (z1, z2, z3), zh = _zmp_point(terms, w, t3)
    grad = [-z1 / z3, -z2 / z3, 1.0 / z3]
    # F(y, T3) = Z(T1, T2, T3) - target = 0: F_yy = zh[:2, :2], F_y3 = zh[:2, 2], F_33 = zh[2, 2]
    f3 = (zh[0][2], zh[1][2], 0.0)
    h33 = zh[2][2]
    hess = [[0.0] * 3 for _ in range(3)]
    for i in range(3):
        for j in range(i, 3):
            fh = zh[i][j] if i < 2 and j < 2 else 0.0
            value = -(fh + f3[i] * grad[j] + f3[j] * grad[i] + h33 * (grad[i] * grad[j])) / z3
            hess[i][j] = hess[j][i] = value
    return t3, grad, hess


def slowdown_time(start: StopStart, w: float, landing: float, transition: float, target: float,
                  derivatives: bool = True):
    """:func:`slowdown_time_grid` at one point, with gradient and Hessian in
    (landing, transition, target) by implicit differentiation of Z(T1, T2, T3) = target.

    Returns ``(T3, grad, hess)`` (``T3`` alone with ``derivatives=False``);
    ``T3`` is NaN (and the derivatives zero) where infeasible.
    """
    result = _slowdown_point(_terms(start, w, landing, transition), w, target, derivatives)
    if not derivatives:
        return result
    t3, grad, hess = result
    if grad is None:
        return t3, np.zeros(3), np.zeros((3, 3))
    return t3, np.array(grad), np.array(hess)


def rest_position_grid(start: StopStart, w: float, landing, transition, target, slowdown):
    """COG position where it comes to rest at the slowdown end (relative to the start ZMP).

    With zero velocity there, x = zeta = Z + (zeta_ii - Z) exp(-w T3) and
    ``zeta_ii = B + Z G`` (the convergent component after the transition).
    """
    return _rest_from_grid_terms(_terms_grid(start, w, landing, transition), w, target, slowdown)


def _rest_from_grid_terms(terms, w: float, target, slowdown):
    """:func:`rest_position_grid` from precomputed :func:`_terms_grid` output."""
    _, big_b, _, g = terms
    target = np.asarray(target, float)
    with np.errstate(invalid="ignore"):
        return target + (big_b + target * (g - 1.0)) * np.exp(-w * np.asarray(slowdown, float))


def _rest_point(terms, w: float, target: float, t3: float, tg, th):
    """Rest position with gradient and Hessian (plain floats), the slowdown eliminated;
    ``tg``/``th`` are the derivatives of T3 (None: value only)."""
    _, big_b, _, g = terms
    b0, b1, b2, b11, b12, b22 = big_b
    u = b0 + target * (g[0] - 1.0)
    decay = math.exp(-w * t3)
    value = target + u * decay
    if tg is None:
        return value
    ug = (b1, b2 + target * g[1], g[0] - 1.0)
    uh = ((b11, b12, 0.0), (b12, b22 + target * g[2], g[1]), (0.0, g[1], 0.0))
    wd = w * decay
    eg = [-wd * t for t in tg]  # d exp(-w T3)
    grad = [(1.0 if i == 2 else 0.0) + decay * ug[i] + u * eg[i] for i in range(3)]
    hess = [[0.0] * 3 for _ in range(3)]
    for i in range(3):
        for j in range(i, 3):
            eh = w * wd * (tg[i] * tg[j]) - wd * th[i][j]
            hess[i][j] = hess[j][i] = decay * uh[i][j] + ug[i] * eg[j] + ug[j] * eg[i] + u * eh
    return value, grad, hess


def rest_position(start: StopStart, w: float, landing: float, transition: float, target: float):
    """Rest position of the COG (the rear-reach constraint's value) with gradient and Hessian in
    (landing, transition, target), the slowdown duration eliminated through the stop condition
    (:func:`slowdown_time`); the one-point view of :func:`stop_point` the derivative tests check."""
    point = stop_point(start, w, landing, transition, target)
    if point[1] is None:
        return float("nan"), np.zeros(3), np.zeros((3, 3))
    return point[3], np.array(point[4]), np.array(point[5])


def stop_point(start: StopStart, w: float, landing: float, transition: float, target: float,
               derivatives: bool = True):
    """Slowdown duration (eq. 21) and rest position at one point from one evaluation of
    the closed form: ``(T3, T3 grad, T3 hess, rest, rest grad, rest hess)`` in plain
    floats / nested lists over (landing, transition, target), or ``(T3, rest)`` without
    derivatives. Where infeasible T3 and rest are NaN (derivatives None).

    The interior-point solver's inner loop: numpy costs microseconds per call
    on 3-vectors, so everything after the quadrature is scalar arithmetic.
    """
    terms = _terms(start, w, landing, transition)
    if not derivatives:
        t3 = _slowdown_point(terms, w, target, False)
        return t3, (_rest_point(terms, w, target, t3, None, None) if t3 == t3 else math.nan)
    t3, tg, th = _slowdown_point(terms, w, target, True)
    if tg is None:
        return t3, None, None, math.nan, None, None
    return (t3, tg, th) + _rest_point(terms, w, target, t3, tg, th)
