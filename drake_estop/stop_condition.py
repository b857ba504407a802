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

import math
from dataclasses import dataclass

import numpy as np

from drake_estop import lipm

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
        return cls(com + com_vel / w - zmp, com - com_vel / w - zmp, zmp_rate, zmp_accel)


def _moments(kappa: float) -> np.ndarray:
    """Rows: basis; columns: L, L', L'', R, R', R'' (derivatives in kappa)."""
    grow = np.exp(kappa * _U)
    decay = 1.0 / grow
    cols = np.stack([grow, grow * _U, grow * _U * _U, decay, decay * _U, decay * _U * _U], axis=1)
    m = _BASIS @ cols  # (3, 6): M0 M1 M2 P0 P1 P2
    out = np.empty((3, 6))
    out[:, 0] = kappa * m[:, 0]
    out[:, 1] = m[:, 0] + kappa * m[:, 1]
    out[:, 2] = 2.0 * m[:, 1] + kappa * m[:, 2]
    out[:, 3] = kappa * m[:, 3]
    out[:, 4] = m[:, 3] - kappa * m[:, 4]
    out[:, 5] = -2.0 * m[:, 4] + kappa * m[:, 5]
    return out


def _scaled(value, d1, d2, kappa, power):
    """kappa^power * f and its first two kappa-derivatives."""
    if power == 0:
        return value, d1, d2
    k_p = kappa**power
    k_p1 = power * kappa ** (power - 1)
    k_p2 = power * (power - 1) * kappa ** (power - 2) if power > 1 else 0.0
    return k_p * value, k_p1 * value + k_p * d1, k_p2 * value + 2 * k_p1 * d1 + k_p * d2


def target_zmp(start: StopStart, w: float, landing: float, transition: float, slowdown: float,
               derivatives: bool = True):
    """ZMP target ``Z`` meeting the stop condition, with gradient and Hessian.

    Returns ``(Z, grad, hess)`` over (landing, transition, slowdown); with
    ``derivatives=False`` returns ``Z`` only.
    """
    kappa = w * transition
    mom = _moments(kappa)
    e12 = math.exp(w * (landing + transition))
    e3sq = math.exp(2.0 * w * slowdown)
    p_fwd = e12 * start.dcm
    p_bwd = start.ccm / e12
    # transition responses to the initial ZMP rate / acceleration (rate * T2 * h1 + accel * T2^2 * h2)
    c1, c2 = start.zmp_rate / w, start.zmp_accel / (w * w)
    sl = [0.0, 0.0, 0.0]
    sr = [0.0, 0.0, 0.0]
    for row, coef, power in ((1, c1, 1), (2, c2, 2)):
        if coef != 0.0:
            lv = _scaled(mom[row, 0], mom[row, 1], mom[row, 2], kappa, power)
            rv = _scaled(mom[row, 3], mom[row, 4], mom[row, 5], kappa, power)
            for i in range(3):
                sl[i] += coef * lv[i]
                sr[i] += coef * rv[i]
    big_a = p_fwd - sl[0]
    big_b = p_bwd + sr[0]
    f0, f1, f2 = mom[0, 0] + 1.0, mom[0, 1], mom[0, 2]
    g0, g1, g2 = mom[0, 3], mom[0, 4], mom[0, 5]
    num = e3sq * big_a - big_b
    den = e3sq * f0 + g0 - 1.0
    z = num / den
    if not derivatives:
        return z
    ww = w * w
    # partials of A, B: index 0 landing, 1 transition (d/dT2 = w d/dkappa)
    a_1 = [w * p_fwd, w * p_fwd - w * sl[1]]
    a_2 = [[ww * p_fwd, ww * p_fwd], [ww * p_fwd, ww * p_fwd - ww * sl[2]]]
    b_1 = [-w * p_bwd, -w * p_bwd + w * sr[1]]
    b_2 = [[ww * p_bwd, ww * p_bwd], [ww * p_bwd, ww * p_bwd + ww * sr[2]]]
    e_1 = 2.0 * w * e3sq
    e_2 = 4.0 * ww * e3sq
    num_g = np.array([e3sq * a_1[0] - b_1[0], e3sq * a_1[1] - b_1[1], e_1 * big_a])
    num_h = np.array([
        [e3sq * a_2[0][0] - b_2[0][0], e3sq * a_2[0][1] - b_2[0][1], e_1 * a_1[0]],
        [e3sq * a_2[1][0] - b_2[1][0], e3sq * a_2[1][1] - b_2[1][1], e_1 * a_1[1]],
        [e_1 * a_1[0], e_1 * a_1[1], e_2 * big_a],
    ])
    den_g = np.array([0.0, e3sq * w * f1 + w * g1, e_1 * f0])
    den_h = np.array([
        [0.0, 0.0, 0.0],
        [0.0, e3sq * ww * f2 + ww * g2, e_1 * w * f1],
        [0.0, e_1 * w * f1, e_2 * f0],
    ])
    grad = (num_g - z * den_g) / den
    hess = (num_h - np.outer(grad, den_g) - np.outer(den_g, grad) - z * den_h) / den
    return z, grad, hess


def target_zmp_grid(start: StopStart, w: float, landing, transition, slowdown) -> np.ndarray:
    """Vectorised value of :func:`target_zmp` over arrays of durations (broadcast)."""
    landing, transition, slowdown = np.broadcast_arrays(
        np.asarray(landing, float), np.asarray(transition, float), np.asarray(slowdown, float)
    )
    kappa = w * transition
    grow = np.exp(kappa[..., None] * _U)
    decay = 1.0 / grow
    lm = kappa[..., None] * (grow @ _BASIS.T)  # (..., 3)
    rm = kappa[..., None] * (decay @ _BASIS.T)
    e12 = np.exp(w * (landing + transition))
    e3sq = np.exp(2.0 * w * slowdown)
    c1, c2 = start.zmp_rate / w, start.zmp_accel / (w * w)
    big_a = e12 * start.dcm - c1 * kappa * lm[..., 1] - c2 * kappa**2 * lm[..., 2]
    big_b = start.ccm / e12 + c1 * kappa * rm[..., 1] + c2 * kappa**2 * rm[..., 2]
    return (e3sq * big_a - big_b) / (e3sq * (lm[..., 0] + 1.0) + rm[..., 0] - 1.0)


def _terms_grid(start: StopStart, w: float, landing, transition):
    """A, B, F = L_sigma + 1, G = R_sigma of the closed form, vectorised."""
    kappa = w * np.asarray(transition, float)
    grow = np.exp(kappa[..., None] * _U)
    lm = kappa[..., None] * (grow @ _BASIS.T)
    rm = kappa[..., None] * ((1.0 / grow) @ _BASIS.T)
    e12 = np.exp(w * (np.asarray(landing, float) + np.asarray(transition, float)))
    c1, c2 = start.zmp_rate / w, start.zmp_accel / (w * w)
    big_a = e12 * start.dcm - c1 * kappa * lm[..., 1] - c2 * kappa**2 * lm[..., 2]
    big_b = start.ccm / e12 + c1 * kappa * rm[..., 1] + c2 * kappa**2 * rm[..., 2]
    return big_a, big_b, lm[..., 0] + 1.0, rm[..., 0]


def slowdown_time_grid(start: StopStart, w: float, landing, transition, target):
    """Slowdown duration that meets the stop condition (eq. 21) for a given ZMP target.

    The same closed form solved for ``exp(2 w T3) = (B + Z (G - 1)) / (A - Z F)``;
    NaN where no non-negative duration stops the COG with that target.
    """
    landing, transition, target = np.broadcast_arrays(
        np.asarray(landing, float), np.asarray(transition, float), np.asarray(target, float))
    big_a, big_b, f, g = _terms_grid(start, w, landing, transition)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = (big_b + target * (g - 1.0)) / (big_a - target * f)
        return np.where(ratio >= 1.0, np.log(np.where(ratio > 0, ratio, 1.0)) / (2.0 * w), np.nan)


def slowdown_time(start: StopStart, w: float, landing: float, transition: float, target: float):
    """:func:`slowdown_time_grid` at one point, with gradient and Hessian in
    (landing, transition, target) by implicit differentiation of Z(T1, T2, T3) = target.

    Returns ``(T3, grad, hess)``; ``T3`` is NaN (and the derivatives zero) where infeasible.
    """
    t3 = float(slowdown_time_grid(start, w, landing, transition, target))
    if not math.isfinite(t3):
        return t3, np.zeros(3), np.zeros((3, 3))
    _, zg, zh = target_zmp(start, w, landing, transition, t3)
    z3 = zg[2]
    fg = np.array([zg[0], zg[1], -1.0])
    f3 = np.array([zh[0, 2], zh[1, 2], 0.0])
    fh = np.zeros((3, 3))
    fh[:2, :2] = zh[:2, :2]
    grad = -fg / z3
    hess = -(fh + np.outer(f3, grad) + np.outer(grad, f3) + zh[2, 2] * np.outer(grad, grad)) / z3
    return t3, grad, hess
