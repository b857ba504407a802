"""Analytic linear-inverted-pendulum (LIPM) solutions for polynomial ZMP segments.

Pure numpy; no Drake import. Used for the sagittal (x) and lateral (y) axes alike.

Paper: Morisawa et al., "Emergency Stop Algorithm for Walking Humanoid Robots",
IROS 2005. Equation numbers in comments refer to it.

Conventions
-----------
A segment ``k`` starts at ``start_times[k]`` and lasts ``durations[k]``; on it the
ZMP is ``sum_i a_i tau^i`` with ``tau = t - start_times[k]`` (eq. 1). The COG is

    x(tau) = V cosh(w tau) + W sinh(w tau) + sum_i A_i tau^i            (eq. 6)

with ``A`` from the ZMP coefficients by the recursion of eq. 7-8 and ``V, W``
from the COG state at the segment start. Chaining segments with the COG state at
each boundary enforces the continuity conditions of eq. 10-11; the ZMP
polynomials are built to be continuous (eq. 12-14) by the callers.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass

import numpy as np

GRAVITY = 9.80665
POLY_DEGREE = 7  # highest ZMP degree used anywhere (halt BVP: 3 + 2 bumps)
N_COEFFS = POLY_DEGREE + 1


def omega(com_height: float) -> float:
    """Natural frequency sqrt(g / z) of the LIPM (eq. 6)."""
    return math.sqrt(GRAVITY / com_height)


def cog_particular_coeffs(zmp_coeffs: np.ndarray, w: float) -> np.ndarray:
    """Polynomial part ``A`` of the COG from the ZMP coefficients ``a`` (eq. 7-8).

    ``a_i = A_i - (i+1)(i+2) A_{i+2} / w^2``, solved backwards from the top
    degree where ``A_n = a_n`` and ``A_{n-1} = a_{n-1}``.
    """
    big_a = np.asarray(zmp_coeffs, dtype=float).tolist()
    ww = w * w
    for i in range(len(big_a) - 3, -1, -1):
        big_a[i] = big_a[i] + (i + 1) * (i + 2) * big_a[i + 2] / ww
    return np.array(big_a)


def poly_eval(coeffs: np.ndarray, tau, derivative: int = 0):
    """Evaluate ``sum_i c_i tau^i`` or its derivative (coefficients low to high).

    Scalars take a plain-float Horner loop with numpy's operation order (same
    result, no array overhead: the planner evaluates many scalars per plan).
    """
    c = np.asarray(coeffs, dtype=float)
    for _ in range(derivative):
        c = c[1:] * np.arange(1, len(c))
    if len(c) == 0:
        return np.zeros_like(np.asarray(tau, dtype=float))
    if isinstance(tau, (float, int, np.floating)):
        return np.float64(horner(c.tolist(), float(tau)))
    return np.polynomial.polynomial.polyval(tau, c)


_EXPONENTS = np.arange(N_COEFFS)


def _sum(terms) -> float:
    """``np.sum`` of a row of at most ``N_COEFFS`` (8) terms in numpy's own order (bit for bit):
    sequential from 0.0 below 8 terms, and 8 terms summed as a pairwise tree (numpy's unrolled
    pairwise summation)."""
    terms = list(terms)
    if len(terms) == 8:
        a = terms
        return ((a[0] + a[1]) + (a[2] + a[3])) + ((a[4] + a[5]) + (a[6] + a[7]))
    total = 0.0
    for term in terms:
        total += term
    return total


def horner(terms, x: float) -> float:
    """``sum_i terms[i] x^i`` in numpy polyval's operation order, on plain floats."""
    value = terms[-1] + x * 0.0
    for ci in reversed(terms[:-1]):
        value = ci + value * x
    return value


def _derivative(terms):
    """Coefficients of the derivative (numpy's ``c[1:] * arange(1, n)`` products)."""
    return [c * i for i, c in enumerate(terms)][1:]


def pad(coeffs, n: int = N_COEFFS) -> np.ndarray:
    out = np.zeros(n)
    c = np.atleast_1d(np.asarray(coeffs, dtype=float))
    out[: len(c)] = c
    return out


def _segment_step(cog_poly, duration, x0, v0, w):
    """One segment of eq. 6 and 9 in plain floats: from the COG state (x0, v0) at its start
    and the particular solution ``cog_poly`` (a list, eq. 7-8), the coefficients V, W and
    the COG state at its end: ``(V, W, x, v)``."""
    cosh_part = x0 - cog_poly[0]
    sinh_part = (v0 - cog_poly[1]) / w
    ch, sh = math.cosh(w * duration), math.sinh(w * duration)
    x = cosh_part * ch + sinh_part * sh + horner(cog_poly, duration)
    v = w * (cosh_part * sh + sinh_part * ch) + horner(_derivative(cog_poly), duration)
    return cosh_part, sinh_part, x, v


def segment_end_state(zmp_coeffs, duration, x0, v0, w):
    """COG position and velocity at the end of one segment (eq. 6, 9)."""
    cog_poly = cog_particular_coeffs(pad(zmp_coeffs), w).tolist()
    return _segment_step(cog_poly, float(duration), float(x0), float(v0), w)[2:]


# ---------------------------------------------------------------------------
# ZMP shape functions on the unit interval s in [0, 1]. Each has zero first and
# second derivatives at both ends unless stated, so joined segments meet eq. 14.
# ---------------------------------------------------------------------------

# quintic smoothstep 10 s^3 - 15 s^4 + 6 s^5: 0 -> 1, zero vel./acc. at both ends
SMOOTHSTEP = np.array([0.0, 0.0, 0.0, 10.0, -15.0, 6.0])
# quintic Hermite bases carrying an initial first / second derivative to zero
HERMITE_D1 = np.array([0.0, 1.0, 0.0, -6.0, 8.0, -3.0])
HERMITE_D2 = np.array([0.0, 0.0, 0.5, -1.5, 1.5, -0.5])
# bumps: zero value, first and second derivative at both ends
BUMP_A = np.polynomial.polynomial.polymul([0, 0, 0, 1], np.polynomial.polynomial.polypow([1, -1], 3))
BUMP_B = np.polynomial.polynomial.polymul([0, 0, 0, 0, 1], np.polynomial.polynomial.polypow([1, -1], 3))


def scale_unit_poly(unit_coeffs, duration: float) -> np.ndarray:
    """Coefficients in tau = s * duration of a polynomial given in s."""
    c = np.asarray(unit_coeffs, dtype=float)
    return c / duration ** np.arange(len(c))


def transition_coeffs(start, end, duration, start_rate=0.0, start_accel=0.0):
    """ZMP transition (eq. 1) from (start, rate, accel) to ``end`` at rest (eq. 14)."""
    unit = (
        start * np.eye(6)[0]
        + (end - start) * SMOOTHSTEP
        + start_rate * duration * HERMITE_D1
        + start_accel * duration**2 * HERMITE_D2
    )
    return scale_unit_poly(unit, duration)


@dataclass
class LipmTrajectory:
    """A chain of LIPM segments for one horizontal axis.

    Build with :meth:`from_zmp` from the COG state at the first breakpoint and
    the ZMP polynomials; evaluate with :meth:`evaluate` at any times (arrays).
    Before the first breakpoint and after the last the trajectory is held by
    extrapolating the first/last segment (the last ZMP is constant when the
    robot is at rest, so the hold is exact).
    """

    breaks: np.ndarray  # (n+1,)
    zmp: np.ndarray  # (n, N_COEFFS)
    cog_poly: np.ndarray  # (n, N_COEFFS) particular solution A
    cosh_coef: np.ndarray  # (n,) V
    sinh_coef: np.ndarray  # (n,) W
    w: float

    @classmethod
    def from_zmp(cls, start_time, durations, zmp_coeffs, x0, v0, w, rest_tail=False):
        """Chain segments from the COG state (x0, v0) at ``start_time``.

        ``rest_tail=True`` states that a boundary-value solve (eq. 27-28) put
        the COG at rest on the last segment's constant ZMP: its homogeneous
        part is then set to zero so the rest is exact forever (the unstable
        LIPM would otherwise amplify the rounding residue by ``exp(w t)``).
        A residue above 1e-4 (m, m/s) means the solve did not reach rest and
        raises instead of being hidden.
        """
        durations = np.asarray(durations, dtype=float)
        breaks = start_time + np.concatenate([[0.0], np.cumsum(durations)])
        zmp = np.array([pad(c) for c in zmp_coeffs])
        cog_poly = np.array([cog_particular_coeffs(c, w) for c in zmp])
        n = len(durations)
        big_v, big_w = np.zeros(n), np.zeros(n)
        x, v = float(x0), float(v0)
        for k, (poly, duration) in enumerate(zip(cog_poly.tolist(), durations.tolist())):
            big_v[k], big_w[k], x, v = _segment_step(poly, duration, x, v, w)
        if rest_tail:
            residue = max(abs(big_v[-1]), abs(big_w[-1]) * w)
            if np.any(zmp[-1, 1:] != 0.0) or residue > 1e-4:
                raise ValueError(f"COG does not arrive at rest on the final ZMP (residue {residue:.2e})")
            big_v[-1] = big_w[-1] = 0.0
        return cls(breaks, zmp, cog_poly, big_v, big_w, w)

    @staticmethod
    def rotated(x: LipmTrajectory, y: LipmTrajectory, yaw: float):
        """The x and y trajectories of the same motion seen in axes turned by ``yaw`` [rad]:
        ``(c x - s y, s x + c y)``. The LIPM is linear and the same in every horizontal direction
        (eq. 4), so a rotated chain is a chain with rotated coefficients. The two axes must share
        their breakpoints."""
        if x.breaks.shape != y.breaks.shape or not np.array_equal(x.breaks, y.breaks) or x.w != y.w:
            raise ValueError("rotated: the two axes must share breakpoints and w")
        c, s = math.cos(yaw), math.sin(yaw)

        def mix(a, b):
            return LipmTrajectory(x.breaks.copy(), a * x.zmp + b * y.zmp, a * x.cog_poly + b * y.cog_poly,
                                  a * x.cosh_coef + b * y.cosh_coef, a * x.sinh_coef + b * y.sinh_coef, x.w)

        return mix(c, -s), mix(s, c)

    @property
    def start_time(self) -> float:
        return float(self.breaks[0])

    @property
    def end_time(self) -> float:
        return float(self.breaks[-1])

    def _locate(self, t):
        t = np.atleast_1d(np.asarray(t, dtype=float))
        k = np.clip(np.searchsorted(self.breaks, t, side="right") - 1, 0, len(self.zmp) - 1)
        return k, t - self.breaks[k]

    def evaluate(self, t):
        """COG position, velocity, acceleration and ZMP at times ``t`` (eq. 4, 6, 9)."""
        if np.ndim(t) == 0 or np.size(t) == 1:  # one instant (every servo tick asks): plain floats
            return self._evaluate_one(float(np.asarray(t, dtype=float).reshape(-1)[0]))
        k, tau = self._locate(t)
        w = self.w
        ch, sh = np.cosh(w * tau), np.sinh(w * tau)
        powers = tau[:, None] ** np.arange(N_COEFFS)
        d1 = np.arange(N_COEFFS)
        d2 = d1 * (d1 - 1)
        poly = self.cog_poly[k]
        pos = self.cosh_coef[k] * ch + self.sinh_coef[k] * sh + np.sum(poly * powers, axis=1)
        vel = w * (self.cosh_coef[k] * sh + self.sinh_coef[k] * ch) + np.sum(
            poly[:, 1:] * d1[1:] * powers[:, :-1], axis=1
        )
        acc = w * w * (self.cosh_coef[k] * ch + self.sinh_coef[k] * sh) + np.sum(
            poly[:, 2:] * d2[2:] * powers[:, :-2], axis=1
        )
        zmp = np.sum(self.zmp[k] * powers, axis=1)
        return pos, vel, acc, zmp

    def _segments(self):
        """Per segment, as plain-float lists: breaks, V, W, the COG polynomial and the ZMP's.
        Made once per trajectory (a trajectory is not changed after it is built)."""
        segments = self.__dict__.get("_segment_lists")
        if segments is None:
            segments = self.__dict__["_segment_lists"] = (
                self.breaks.tolist(), self.cosh_coef.tolist(), self.sinh_coef.tolist(),
                self.cog_poly.tolist(), self.zmp.tolist())
        return segments

    def _segment_at(self, t: float) -> int:
        """Index of the segment that holds ``t`` (the first / last outside the chain; a break
        belongs to the later segment)."""
        return min(max(bisect.bisect_right(self._segments()[0], t) - 1, 0), len(self.zmp) - 1)

    def _basis_one(self, t: float) -> tuple:
        """``(segment, cosh, sinh, powers of tau)`` at one instant ``t``: what :meth:`_evaluate_one` needs
        besides the coefficients, the same for every trajectory with these breakpoints and ``w``."""
        k = self._segment_at(t)
        tau = np.array([t - self._segments()[0][k]])
        w = self.w
        # numpy's cosh, sinh and power (its SIMD loops round differently from libm's)
        return k, np.cosh(w * tau).item(), np.sinh(w * tau).item(), (tau ** _EXPONENTS).tolist()

    def _shares_basis(self, other) -> bool:
        """Whether ``other`` has this trajectory's breakpoints and ``w`` (the x and y axes of a plan or a
        walk do): then one :meth:`_basis_one` serves both."""
        return other is self or (other.w == self.w and other._segments()[0] == self._segments()[0])

    def _evaluate_one(self, t: float, basis=None):
        """:meth:`evaluate` at one instant, in plain floats with numpy's operation order (the same
        bits as the array path, without its array overhead); 1-element arrays. ``basis``: this
        instant's :meth:`_basis_one`, if made already."""
        _, cosh_coef, sinh_coef, cog_poly, zmp = self._segments()
        k, ch, sh, powers = self._basis_one(t) if basis is None else basis
        w = self.w
        poly = cog_poly[k]
        big_v, big_w = cosh_coef[k], sinh_coef[k]
        pos = big_v * ch + big_w * sh + _sum(c * p for c, p in zip(poly, powers))
        vel = w * (big_v * sh + big_w * ch) + _sum(poly[i] * i * powers[i - 1] for i in range(1, N_COEFFS))
        acc = w * w * (big_v * ch + big_w * sh) + _sum(
            poly[i] * (i * (i - 1)) * powers[i - 2] for i in range(2, N_COEFFS))
        zmp_value = _sum(c * p for c, p in zip(zmp[k], powers))
        return np.array([pos]), np.array([vel]), np.array([acc]), np.array([zmp_value])

    @staticmethod
    def evaluate_axes(trajectories, t):
        """``[trajectory.evaluate(t) for trajectory in trajectories]``; at one instant the segment, cosh,
        sinh and powers are made once for the axes that share breakpoints (the same bits, half the work
        for a plan's or a walk's x and y, which every servo tick asks for)."""
        if not (np.ndim(t) == 0 or np.size(t) == 1):
            return [trajectory.evaluate(t) for trajectory in trajectories]
        t = float(np.asarray(t, dtype=float).reshape(-1)[0])
        first = trajectories[0]
        basis = first._basis_one(t)
        return [trajectory._evaluate_one(t, basis if first._shares_basis(trajectory) else None)
                for trajectory in trajectories]

    def evaluate_at(self, t: float):
        """:meth:`evaluate` at one instant in plain floats (position, velocity,
        acceleration, ZMP, ZMP rate, ZMP acceleration), for per-tick callers."""
        breaks, cosh_coef, sinh_coef, cog_poly, zmp = self._segments()
        k = self._segment_at(t)
        tau = t - breaks[k]
        w = self.w
        ch, sh = math.cosh(w * tau), math.sinh(w * tau)
        cosh_part, sinh_part = cosh_coef[k], sinh_coef[k]
        poly = cog_poly[k]
        rate = _derivative(poly)
        zmp = zmp[k]
        zmp_rate = _derivative(zmp)
        return (cosh_part * ch + sinh_part * sh + horner(poly, tau),
                w * (cosh_part * sh + sinh_part * ch) + horner(rate, tau),
                w * w * (cosh_part * ch + sinh_part * sh) + horner(_derivative(rate), tau),
                horner(zmp, tau), horner(zmp_rate, tau), horner(_derivative(zmp_rate), tau))


def required_start_dcm(durations, zmp_coeffs, final_zmp, w):
    """DCM x + v/w at the start of a chain whose COG stays bounded afterwards.

    Backward recursion on the divergent component: after the chain the ZMP rests
    at ``final_zmp`` and the bounded solution has DCM equal to it. On a segment,
    ``xi(tau) - A(tau) - A'(tau)/w`` grows like ``exp(w tau)`` (from eq. 6, 9).
    """
    dcm = final_zmp
    for duration, coeffs in zip(reversed(list(durations)), reversed(list(zmp_coeffs))):
        big_a = cog_particular_coeffs(coeffs, w)
        at_end = float(poly_eval(big_a, duration) + poly_eval(big_a, duration, 1) / w)
        at_start = big_a[0] + (big_a[1] if len(big_a) > 1 else 0.0) / w
        dcm = (dcm - at_end) * math.exp(-w * duration) + at_start
    return dcm


def solve_bump_coeffs(base_unit, bumps_unit, duration, x0, v0, w, targets):
    """Coefficients of ZMP bumps so that the COG meets end conditions exactly.

    The ZMP on the segment is ``base + sum_j c_j bump_j`` (unit-interval
    polynomials, scaled to ``duration``). ``targets`` is a list of
    ``(kind, value)`` with kind ``"x"``, ``"v"`` or ``"dcm"`` at the segment
    end. The LIPM is linear, so this is a small linear solve (Harada's
    two-point boundary-value method, eq. 27-28). Returns the ZMP coefficients.
    """
    base = scale_unit_poly(base_unit, duration)
    cols = [scale_unit_poly(b, duration) for b in bumps_unit]

    def end_values(zmp, x_init, v_init):
        x, v = segment_end_state(zmp, duration, x_init, v_init, w)
        return {"x": x, "v": v, "dcm": x + v / w}

    free = end_values(base, x0, v0)
    matrix = np.zeros((len(targets), len(cols)))
    rhs = np.zeros(len(targets))
    for j, col in enumerate(cols):
        unit_response = end_values(col, 0.0, 0.0)
        for i, (kind, _) in enumerate(targets):
            matrix[i, j] = unit_response[kind]
    for i, (kind, value) in enumerate(targets):
        rhs[i] = value - free[kind]
    coeffs = np.linalg.solve(matrix, rhs)
    out = pad(base)
    for c, col in zip(coeffs, cols):
        out = out + c * pad(col)
    return out


def chain_end_state(durations, coeffs, x0, v0, w):
    """COG position and velocity after a chain of ZMP segments (eq. 6, 9-11)."""
    x, v = x0, v0
    for duration, c in zip(durations, coeffs):
        x, v = segment_end_state(c, duration, x, v, w)
    return x, v


def solve_chain_bvp(durations, base, unknowns, x0, v0, w, target_x, target_v=0.0, weights=None):
    """Least-norm unknowns so a chain of ZMP segments ends with the COG at (x, v).

    ``base`` holds the ZMP coefficients of every segment; each entry of
    ``unknowns`` holds the coefficients (per segment) that one unknown scales.
    The LIPM is linear, so the end state is affine in the unknowns; with more
    unknowns than the two end conditions the weighted least-norm solution
    ``min sum (u_k / weight_k)^2`` is taken. Returns the segments' coefficients.
    """
    free = np.array(chain_end_state(durations, base, x0, v0, w))
    matrix = np.array([chain_end_state(durations, cols, 0.0, 0.0, w) for cols in unknowns]).T  # (2, k)
    rhs = np.array([target_x, target_v]) - free
    scale = np.ones(len(unknowns)) if weights is None else np.asarray(weights, float)
    scaled = matrix * scale
    u = scale * (scaled.T @ np.linalg.solve(scaled @ scaled.T, rhs))
    out = [pad(b) for b in base]
    for value, cols in zip(u, unknowns):
        out = [o + value * pad(c) for o, c in zip(out, cols)]
    return out
