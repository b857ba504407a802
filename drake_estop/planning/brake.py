"""The time objective: the shortest ZMP profile that brings the COG to rest between the feet.

The paper's objectives (J_ss, eq. 24; J_ds, eq. 30) weigh the swing speed, the ZMP
overshoot and the double-support time; they stop the COG behind the fore foot (slowdown,
eq. 17) and then move it back to the midpoint between the feet (halt, eq. 27-28). With
``StopParameters(objective="time")`` the planner takes instead the stop that reaches rest
soonest, within the same limits (swing speed and descent, fore and rear reach, step length,
landing time, transition durations, ``zmp_margin``), resting the COG at the feet's midpoint
or further on toward the fore ankle (:func:`rest_points`), never back against the walk:

* the ZMP is a chain of quintic transitions between levels (eq. 1, 12-14: value, rate and
  acceleration continuous, zero rate and acceleration where two transitions meet), each
  at least ``min_transition_time`` long, ending at a rest point ``m`` with the COG at rest
  there (eq. 27-28, Harada's two-point boundary-value method, as the halt);
* two levels of the chain are unknowns; the two end conditions of each axis fix them (a
  2x2 linear solve per axis). With the divergent and convergent components
  ``xi = x + v/w``, ``zeta = x - v/w`` (``xi' = w (xi - p)``, ``zeta' = -w (zeta - p)``,
  from eq. 4) and ``q = p - m``, the COG is at rest at ``m`` at ``T`` iff::

      w int_0^T exp(-w s) q(s) ds = xi(0) - m,    w int_0^T exp(-w (T - s)) q(s) ds = -(zeta(0) - m) exp(-w T);

* every other choice (durations on the servo grid, the landing time and step length, the rest
  point) is enumerated in numpy at once, and the shortest candidate whose ZMP keeps the margin
  inside the support polygon is taken; first among those along which the COG never moves
  backwards along the walk. A time-optimal LIPM stop holds the ZMP ahead of the COG until it
  rests (orbital energy, :func:`forward_stop_possible`): a chain that carries the COG past its
  rest point and back loses time. From double support and late in a swing the COG (0.4-0.55
  m/s) cannot stop on the midpoint without passing it, so the rest points further on are what
  keeps those stops monotone. The COG's velocity of the shortest candidates is checked at the
  servo ticks (eq. 6-9), at most ``FORWARD_CHECKS`` of them, and only where such a stop is
  possible at all; else the shortest. Transitions between levels run on straight segments when
  they start at rest, so in a convex polygon a level chain is inside iff its levels are;
  only a first transition that carries the walk's ZMP rate and acceleration (double
  support) curves, and it is checked at every servo tick.

The chains:

* :func:`stop_brake`, from a given state (double support)::

      ZMP --r1--> c (held h) --r2--> d --r3--> m

  ``c`` brakes the COG (the time-optimal LIPM stop holds the ZMP at the polygon's edge
  ahead of the COG), ``d`` catches it over the rest point ``m``;

* :func:`swing_brake`, single support: the landing time and step length are searched too
  (earliest touchdown the swing-speed and descent limits allow, for each step length on a
  grid), and the ZMP already brakes on the support sole while the foot swings::

      ZMP (the support ankle) --rA--> a (held to the touchdown) --r1--> c (held h) --r3--> m

  with ``a`` inside the support sole and ``c`` inside both soles' polygon; ``rA`` is half of
  ``min_transition_time`` (``SOLE_RAMP_FACTOR``), so that late in the swing the ZMP brakes on
  the sole before the touchdown;

* :func:`held_brake`, single support on a given landing (the paper's, where
  :func:`swing_brake` finds no stop): the ZMP held until the touchdown (eq. 19), then
  :func:`stop_brake`.

Where none fits, the planner plans with the paper's objective.

The integrals of the quintic shapes are Gauss-Legendre quadratures (exact to rounding),
tabulated once per (w, servo period, duration limits). Pure numpy; no Drake import.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from drake_estop.planning import lipm
from drake_estop.planning.geometry import stack_halfplanes, stacked_margin

_NODES, _WEIGHTS = np.polynomial.legendre.leggauss(20)
_U = 0.5 * (_NODES + 1.0)  # nodes on [0, 1]
# the unit shapes of a transition (eq. 12-14), columns of the moments: constant, smoothstep,
# start-rate carrier, start-acceleration carrier; quadrature weights folded in
_SHAPES = np.array([np.polynomial.polynomial.polyval(_U, s)
                    for s in ([1.0], lipm.SMOOTHSTEP, lipm.HERMITE_D1, lipm.HERMITE_D2)]) * (0.5 * _WEIGHTS)
ONE, SIGMA, RATE, ACCEL = range(4)

# durations of the transitions, in multiples of min_transition_time (the ones the stride's stops use)
RAMP_FACTORS = (1.0, 1.5)  # the first transition (to c)
CATCH_FACTORS = (1.0, 1.5, 2.0, 3.0)  # stop_brake: c to d
RETURN_FACTORS = (1.0, 1.5)  # the last transition (to the rest point)
# the ZMP's transition on the support sole (swing_brake), in multiples of min_transition_time: the
# double-support transition's floor would hold the braking ZMP back until after the touchdown, which
# from late in the swing leaves no stop without backing up (at most 0.125 m on the sole: <= 4.7 m/s)
SOLE_RAMP_FACTOR = 0.5
STOP_HOLD_MAX = 0.6  # [s] longest hold of c in stop_brake (the servo grid up to it)
SWING_HOLD_MAX = 0.25  # [s] longest hold of c in swing_brake
STEP_GRID = 0.02  # [m] step lengths searched by swing_brake
# where the COG may come to rest: on the segment from the feet's midpoint to the fore ankle, at these
# fractions of it (the segment is inside the support polygon: both ankles are inside their soles)
REST_FRACTIONS = (0.0, 0.25, 0.5, 0.75, 1.0)
SWING_FIRST = 0.05  # [s] swing_brake searches the step lengths whose touchdown is this close to the earliest first


@dataclass
class Brake:
    """A planned ZMP chain from the plan start.

    ``durations`` [s] and ``coeffs`` (per axis, per segment: ZMP coefficients, eq. 1) of its
    segments; ``ends`` [s]: the ends of the landing, transition, slowdown and halt phases from
    the plan start; ``landing_x`` [m]: the landing ankle's x (single support) or None;
    ``margin`` [m]: the smallest ZMP margin of the chain inside its polygons; ``peak`` [m]: the
    largest x of its ZMP (:func:`stop_brake`, at the servo ticks; NaN where not computed); ``rest``
    (2,) [m]: where the COG comes to rest (:func:`rest_points`)."""

    durations: list
    coeffs: list
    ends: tuple
    landing_x: float | None
    margin: float
    peak: float = math.nan
    rest: np.ndarray | None = None

    @property
    def duration(self) -> float:
        return float(self.ends[-1])


_E0 = np.eye(6)[0]
_POWERS = np.arange(6)


def _ramp(start, end, duration, rate=0.0, accel=0.0):
    """:func:`drake_estop.planning.lipm.transition_coeffs` (eq. 1, 12-14) with constant shape arrays."""
    unit = start * _E0 + (end - start) * lipm.SMOOTHSTEP
    if rate != 0.0 or accel != 0.0:
        unit = unit + rate * duration * lipm.HERMITE_D1 + accel * duration**2 * lipm.HERMITE_D2
    return unit / duration**_POWERS


def _ramps(levels, durations, rate, accel):
    """:func:`_ramp` from each of ``levels`` (n + 1, 2) to the next over ``durations`` (n,), the first
    carrying the ZMP ``rate`` and ``accel`` (2,): coefficients per axis, per segment."""
    unit = (levels[:-1, :, None] * _E0 + (levels[1:] - levels[:-1])[:, :, None] * lipm.SMOOTHSTEP)  # (n, axis, 6)
    unit[0] += (rate[:, None] * durations[0] * lipm.HERMITE_D1 + accel[:, None] * durations[0] ** 2 * lipm.HERMITE_D2)
    coeffs = unit / (durations[:, None] ** _POWERS)[:, None, :]
    return [list(coeffs[:, axis]) for axis in range(2)]


@functools.lru_cache(maxsize=64)
def _ramp_moments(w, duration):
    fwd, bwd = _moments(np.array([w * duration]))
    return fwd[0], bwd[0]


def _moments(kappa):
    """``kappa int_0^1 exp(-kappa u) f(u) du`` (forward) and ``kappa int_0^1 exp(-kappa (1 - u)) f(u) du``
    (backward) of the four unit shapes f (columns), for each ``kappa = w * duration`` (rows)."""
    kappa = np.asarray(kappa, float)[:, None]
    return kappa * (np.exp(-kappa * _U) @ _SHAPES.T), kappa * (np.exp(-kappa * (1.0 - _U)) @ _SHAPES.T)


def _down(m):
    """Moments of the shape ``1 - sigma`` (a transition's start level)."""
    return m[:, ONE] - m[:, SIGMA]


def _grid(dt, low, high):
    return dt * np.arange(max(1, math.ceil(low / dt - 1e-9)), math.floor(high / dt + 1e-9) + 1)


def _ticks(params, factors):
    """``factors`` x ``min_transition_time`` on the servo grid, at most ``max_transition_time``."""
    return _ticks_cached(params.servo_period, params.min_transition_time, params.max_transition_time, factors)


@functools.lru_cache(maxsize=64)
def _ticks_cached(dt, shortest, longest, factors):
    values = {max(1, round(k * shortest / dt)) * dt for k in factors}
    return tuple(sorted(v for v in values if v <= longest + 1e-9))


@functools.lru_cache(maxsize=16)
def _stop_table(w, dt, ramps, catches, returns, hold_min, hold_max):
    """Candidates of :func:`stop_brake`, sorted by total duration: durations ``r1, h, r2, r3`` and the
    coefficients of ``c, d`` and of the known start terms in the forward and backward conditions."""
    r1, h, r2, r3 = (g.ravel() for g in np.meshgrid(np.array(ramps), _grid(dt, hold_min, hold_max),
                                                     np.array(catches), np.array(returns), indexing="ij"))
    total = r1 + h + r2 + r3
    order = np.lexsort((r3, r2, r1, total))
    r1, h, r2, r3, total = r1[order], h[order], r2[order], r3[order], total[order]
    f1, b1 = _moments(w * r1)
    fh, bh = _moments(w * h)
    f2, b2 = _moments(w * r2)
    f3, b3 = _moments(w * r3)
    # segment starts 0, r1, r1 + h, r1 + h + r2: forward weights exp(-w start), backward exp(-w (T - end))
    s_h, s_2, s_3 = np.exp(-w * r1), np.exp(-w * (r1 + h)), np.exp(-w * (r1 + h + r2))
    e_1, e_h, e_2 = np.exp(-w * (h + r2 + r3)), np.exp(-w * (r2 + r3)), np.exp(-w * r3)
    fwd = (f1[:, SIGMA] + s_h * fh[:, ONE] + s_2 * _down(f2), s_2 * f2[:, SIGMA] + s_3 * _down(f3),
           np.stack([_down(f1), f1[:, RATE] * r1, f1[:, ACCEL] * r1 * r1]))
    bwd = (e_1 * b1[:, SIGMA] + e_h * bh[:, ONE] + e_2 * _down(b2), e_2 * b2[:, SIGMA] + _down(b3),
           np.stack([e_1 * _down(b1), e_1 * b1[:, RATE] * r1, e_1 * b1[:, ACCEL] * r1 * r1]))
    return {"r1": r1, "h": h, "r2": r2, "r3": r3, "total": total, "fwd": fwd, "bwd": bwd,
            "decay": np.exp(-w * total)}


def moving_zmp(rate, accel) -> bool:
    """Whether a ZMP rate [m/s] and acceleration [m/s^2] ((2,) each) are more than rounding noise."""
    rate, accel = (np.abs(np.asarray(v, float)[:2]) for v in (rate, accel))
    return bool(np.any(rate > 1e-9) or np.any(accel > 1e-7))


def _solve2(a11, a12, a21, a22, b1, b2):
    """``[[a11, a12], [a21, a22]] [u, v] = [b1, b2]`` elementwise (inf / nan where singular)."""
    det = a11 * a22 - a12 * a21
    return (b1 * a22 - a12 * b2) / det, (a11 * b2 - a21 * b1) / det


CHUNK = 1024  # candidates evaluated at once, shortest first
LAZY = 64  # swing_brake: candidates whose polygon margin is evaluated at once, soonest first


def stop_brake(com, com_vel, zmp, zmp_rate, zmp_accel, rests, polygons, params, w: float,
               required: float) -> tuple | None:
    """The shortest chain ``ZMP -> c (held) -> d -> m`` from the COG state ``com, com_vel`` and the ZMP
    ``zmp`` (rate ``zmp_rate``, acceleration ``zmp_accel``), all (2,) [m, m/s, m/s^2], that ends at rest
    at one of the rest points ``rests`` (k, 2) with its ZMP ``required`` [m] inside the matching one of
    ``polygons``: the shortest along which the COG never moves backwards (:func:`_backs_up`) where the
    LIPM can stop that way (:func:`forward_stop_possible`, and one of the first ``FORWARD_CHECKS``
    candidates), else the shortest. Returns ``(index of the rest point, Brake)``, among equally short ones
    the one with the larger margin, or None."""
    rests = np.atleast_2d(np.asarray(rests, float))
    rows = len(rests)
    com, com_vel = (np.broadcast_to(np.asarray(v, float)[:2], (rows, 2)) for v in (com, com_vel))
    ramp = _ticks(params, RAMP_FACTORS)[0]  # the quickest first transition
    braked = {}  # the strongest braking per start and polygon (the rest points of one landing share theirs)
    keys = [(id(polygons[i]), com[i].tobytes(), com_vel[i].tobytes()) for i in range(rows)]
    for i, key in enumerate(keys):
        if key not in braked:
            braked[key] = _strongest_brake(com[i], com_vel[i], polygons[i], w, zmp, ramp, zmp_rate, zmp_accel,
                                           required)
    forward = np.array([_rests_short_of(braked[key], com[i], com_vel[i], rests[i], w) for i, key in enumerate(keys)])
    levels = {}  # each chunk's levels and margins: the same for both passes
    if forward.any():
        try:
            found = _stop_search(com, com_vel, zmp, zmp_rate, zmp_accel, rests, polygons, params, w, required,
                                 _ForwardOnly(forward), levels)
        except _Spent:
            found = None
        if found is not None:
            return found
    return _stop_search(com, com_vel, zmp, zmp_rate, zmp_accel, rests, polygons, params, w, required, None,
                        levels)


def _stop_search(com, com_vel, zmp, zmp_rate, zmp_accel, rests, polygons, params, w, required, forward_only,
                 levels):
    """:func:`stop_brake`'s search; with ``forward_only`` (a :class:`_ForwardOnly`) only over its rows and
    the candidates along which the COG does not move backwards (:class:`_Spent` when its checks run out). ``levels``:
    a dict that keeps each chunk's levels ``c``, ``d`` and margins for a second pass (they do not depend on
    ``forward_only``)."""
    rows = len(rests)
    zmp = np.asarray(zmp, float)[:2]
    rate, accel = np.asarray(zmp_rate, float)[:2], np.asarray(zmp_accel, float)[:2]
    t = _stop_table(float(w), float(params.servo_period), _ticks(params, RAMP_FACTORS), _ticks(params, CATCH_FACTORS),
                    _ticks(params, RETURN_FACTORS), float(params.min_slowdown_time),
                    float(min(params.max_slowdown_time, STOP_HOLD_MAX)))
    planes = stack_halfplanes(polygons)
    start_margin = stacked_margin(planes, np.broadcast_to(zmp, (rows, 1, 2)))[:, 0]
    curved = moving_zmp(rate, accel)
    best = None
    for low in range(0, len(t["total"]), CHUNK):
        if best is not None and float(t["total"][low]) >= best[0] - 1e-9:
            break
        k = slice(low, low + CHUNK)
        if low not in levels:
            levels[low] = _stop_levels(t, k, com, com_vel, zmp, rate, accel, rests, polygons, planes,
                                       start_margin, w, required)
        c, d, margin = levels[low]
        if forward_only is not None:
            margin = margin.copy()
            margin[~forward_only.rows] = -np.inf
        total = np.broadcast_to(t["total"][k], margin.shape)
        for i, j in _shortest(margin, total, required):
            if best is not None and total[i, j] >= best[0] - 1e-9:
                break
            durations = [float(t[key][low + j]) for key in ("r1", "h", "r2", "r3")]
            chain = [zmp, c[i, j], c[i, j], d[i, j], rests[i]]
            coeffs = [[_ramp(chain[n][a], chain[n + 1][a], durations[n],  # eq. 12-14
                             rate[a] if n == 0 else 0.0, accel[a] if n == 0 else 0.0)
                       for n in range(4)] for a in range(2)]
            worst, peak = float(margin[i, j]), max(zmp[0], c[i, j, 0], d[i, j, 0])
            if curved:  # the first transition carries the walk's ZMP rate and acceleration: check its ticks
                points = _segment_points(coeffs, 0, durations[0], params.servo_period)
                worst, peak = min(worst, float(polygons[i].margin(points).min())), max(peak, points[:, 0].max())
            if worst >= required and forward_only is not None:
                if forward_only.backs_up(coeffs[0], durations, com[i, 0], com_vel[i, 0], w, params.servo_period):
                    continue
            if worst >= required:
                r1, h, r2, r3 = durations
                best = (float(total[i, j]), i, Brake(durations, coeffs, (0.0, r1, r1 + h + r2, r1 + h + r2 + r3),
                                                     None, worst, float(peak), rests[i].copy()))
                break
    return None if best is None else best[1:]


def _stop_levels(t, k, com, com_vel, zmp, rate, accel, rests, polygons, planes, start_margin, w, required):
    """:func:`_stop_search`'s chunk ``k`` of candidates: the levels ``c``, ``d`` (rows, candidates, 2) that bring
    the COG to rest at each rest point (two end conditions per axis, a 2x2 solve), and the ZMP margin of each
    chain: ``c``'s and the start's, and ``d``'s where ``c`` keeps ``required``."""
    (fc, fd, fk), (bc, bd, bk) = ((c[k], d[k], known[:, k]) for c, d, known in (t["fwd"], t["bwd"]))
    levels = []
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        for axis in range(2):
            m = rests[:, axis][:, None]  # rows: rests, columns: candidates
            start = (zmp[axis] - m, rate[axis], accel[axis])
            rhs_f = (com[:, axis] + com_vel[:, axis] / w)[:, None] - m - sum(s * c for s, c in zip(start, fk))
            rhs_b = (-((com[:, axis] - com_vel[:, axis] / w)[:, None] - m) * t["decay"][k]
                     - sum(s * c for s, c in zip(start, bk)))
            c, d = _solve2(fc, fd, bc, bd, rhs_f, rhs_b)
            levels.append((m + c, m + d))
    c = np.stack([levels[0][0], levels[1][0]], axis=-1)  # (rows, candidates, 2)
    d = np.stack([levels[0][1], levels[1][1]], axis=-1)
    margin = np.minimum(stacked_margin(planes, c), start_margin[:, None])
    for i in np.nonzero(np.any(margin >= required, axis=1))[0]:  # d only where c fits
        fits = margin[i] >= required
        margin[i, fits] = np.minimum(margin[i, fits], polygons[i].margin(d[i, fits]))
    return c, d, margin


BACKWARD_TOLERANCE = 1e-3  # [m/s] COG speed against the walk taken as rounding
# candidates checked for backing up per brake before taking the shortest one regardless: the stride's
# forward stops are among the first three; where none is, the search ends early instead of checking all
FORWARD_CHECKS = 12


class _ForwardOnly:
    """The forward-only pass of a brake search: the rows (rests) it covers and its check budget."""

    def __init__(self, rows=None):
        self.rows = rows
        self.left = FORWARD_CHECKS

    def backs_up(self, coeffs, durations, x0, v0, w, dt) -> bool:
        """:func:`_backs_up`, counted against the budget; :class:`_Spent` once it is used up."""
        self.left -= 1
        if self.left < 0:
            raise _Spent
        return _backs_up(coeffs, durations, x0, v0, w, dt)


def forward_stop_possible(com, com_vel, rest, polygon, w: float, zmp=None, ramp: float = 0.0,
                          zmp_rate=(0.0, 0.0), zmp_accel=(0.0, 0.0), required: float = 0.0) -> bool:
    """Whether the LIPM (eq. 4) could come to rest at ``rest`` without moving
    backwards along x: moving forward (or at rest) from behind it, and stopped short of it by the ZMP
    held at the front of ``polygon``, ``required`` [m] inside (the strongest braking). With the ZMP
    held at ``P`` the orbital energy ``v^2 - w^2 (x - P)^2`` is constant, so the COG comes to rest at
    ``P - sqrt((P - x)^2 - v^2 / w^2)``; a ZMP anywhere behind ``P`` brakes less (eq. 6-9: the COG's
    response to the ZMP is monotone). With ``zmp`` [m] (and its ``zmp_rate``, ``zmp_accel``) the ZMP
    first gets there by the quickest transition, ``ramp`` [s] (eq. 12-14): any chain's first transition
    is slower or goes less far. A necessary condition only (the later transitions and the landing come
    on top)."""
    braked = _strongest_brake(com, com_vel, polygon, w, zmp, ramp, zmp_rate, zmp_accel, required)
    return _rests_short_of(braked, com, com_vel, rest, w)


def _strongest_brake(com, com_vel, polygon, w, zmp, ramp, zmp_rate, zmp_accel, required):
    """:func:`forward_stop_possible`'s strongest braking from ``com, com_vel``: ``(x, v, front, at_rest)``, the
    COG along x once the ZMP is at the front ``front`` [m] of ``polygon`` (after the quickest transition from
    ``zmp``, if given) and whether it came to rest on the way. It does not depend on the rest point, so a
    search over rest points in one polygon computes it once."""
    x, v = float(com[0]), float(com_vel[0])
    front = float(np.max(polygon.vertices[:, 0])) - required
    if zmp is not None and ramp > 0.0 and v >= 0.0:
        coeffs = _ramp(float(zmp[0]), front, ramp, float(zmp_rate[0]), float(zmp_accel[0]))
        x, v, lowest = _segment_end(coeffs, ramp, x, v, w, ramp / 8.0)
        return x, v, front, lowest <= 0.0
    return x, v, front, False


def _rests_short_of(braked, com, com_vel, rest, w) -> bool:
    """:func:`forward_stop_possible` from the COG at the start (``com, com_vel``) and its strongest braking
    ``braked`` (:func:`_strongest_brake`)."""
    x, v, front, at_rest = braked
    m = float(rest[0])
    if float(com_vel[0]) < 0.0 or float(com[0]) > m + 1e-9:
        return False
    if at_rest:  # at rest during the transition already
        return x <= m + 1e-9
    return x <= m + 1e-9 and (front - x) ** 2 - (v / w) ** 2 >= (front - m) ** 2 - 1e-12


def _segment_end(coeffs, duration, x, v, w, dt):
    """The COG (along one axis, from ``x`` [m], ``v`` [m/s]) under one ZMP segment ``coeffs`` (eq. 1) of
    ``duration`` [s] (eq. 6-9: the particular polynomial plus its cosh and sinh parts): its position and
    velocity at the end, and its least velocity at the ticks ``dt`` apart."""
    poly = lipm.cog_particular_coeffs(coeffs, w)
    cosh_part, sinh_part = x - poly[0], (v - poly[1]) / w
    tau = dt * np.arange(1, int(round(duration / dt)) + 1)
    wt = w * tau
    speed = (np.polynomial.polynomial.polyval(tau, poly[1:] * _POWERS[1:len(poly)])
             + w * (cosh_part * np.sinh(wt) + sinh_part * np.cosh(wt)))
    end = float(np.polynomial.polynomial.polyval(tau[-1], poly) + cosh_part * math.cosh(wt[-1])
                + sinh_part * math.sinh(wt[-1]))
    return end, float(speed[-1]), float(speed.min())


def _backs_up(coeffs, durations, x0, v0, w, dt) -> bool:
    """Whether the COG (along x, from ``x0`` [m], ``v0`` [m/s]) under the ZMP chain ``coeffs`` (one
    axis's segments, eq. 1) of ``durations`` [s] moves backwards faster than ``BACKWARD_TOLERANCE`` at
    a servo tick (eq. 6-9 per segment, :func:`_segment_end`)."""
    x, v = float(x0), float(v0)
    for c, duration in zip(coeffs, durations):
        x, v, lowest = _segment_end(c, duration, x, v, w, dt)
        if lowest < -BACKWARD_TOLERANCE:
            return True
    return False


def _shortest(margin, total, required):
    """Indices of the candidates that keep ``required``, shortest first, the larger margin first among
    equally short ones."""
    rows, cols = np.nonzero(margin >= required)
    order = np.lexsort((-margin[rows, cols], np.round(total[rows, cols], 9)))
    return zip(rows[order], cols[order])


def _segment_points(coeffs, j, duration, dt):
    """The ZMP (n, 2) of segment ``j`` of a chain at its servo ticks."""
    tau = dt * np.arange(int(round(duration / dt)) + 1)
    return (tau[:, None] ** _POWERS) @ np.stack([coeffs[0][j], coeffs[1][j]], axis=1)


def rest_points(rear, fore, max_rear_reach: float) -> np.ndarray:
    """Where the COG may come to rest between two feet, ``rear`` and ``fore`` (2,) their ankles [m]
    (``fore`` ahead along the walk): on the segment from their midpoint to the fore ankle, at
    ``REST_FRACTIONS`` of it and at the rear leg's reach, ``max_rear_reach`` ahead of the rear ankle,
    if that comes first; the midpoint first, and alone where ``fore`` is not ahead or the midpoint
    is already out of the rear leg's reach. (k, 2).

    A time-optimal stop does not come back: from double support, and late in a swing, the COG
    moving at 0.4-0.55 m/s cannot stop on the midpoint without passing it (its capture point
    ``x + v / w`` is 0.1-0.18 m past it), so the objective rests it further on, between the feet."""
    rear, fore = (np.asarray(v, float)[:2] for v in (rear, fore))
    fractions, keep = _rest_fractions(np.array([fore[0] - rear[0]]), max_rear_reach)
    return 0.5 * (rear + fore) + np.outer(fractions[0][keep[0]], 0.5 * (fore - rear))


def _rest_fractions(spans, max_rear_reach):
    """:func:`rest_points`'s fractions of the half segments for feet ``spans`` (n,) [m] apart along the walk:
    ``(fractions (n, k), keep (n, k))``, the midpoint (0) first."""
    spans = np.asarray(spans, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        reach = np.where(spans > 1e-9, (max_rear_reach - 0.5 * spans) / (0.5 * spans), 0.0)
    grid = np.broadcast_to(np.array(REST_FRACTIONS), (len(spans), len(REST_FRACTIONS)))
    fractions = np.concatenate([grid, reach[:, None]], axis=1)
    keep = np.concatenate([grid < reach[:, None] - 1e-9, ((reach > 0.0) & (reach < 1.0))[:, None]], axis=1)
    keep[:, 0] = True  # the midpoint
    return fractions, keep


def _landings(ankle, swing_xy, landing_y, min_landing, params, centred=False):
    """Landing choices: step lengths on the grid within the step-length and rear-reach limits (the COG
    rests at least at the midpoint, half a step ahead of the support ``ankle``), each with the rest
    points :func:`rest_points` allows, their landing ankles, the earliest touchdown on the servo grid
    each allows (``min_landing_time``, ``min_landing``, the mean swing speed from ``swing_xy``), at
    most ``max_landing_time``: ``(landing (n, 2), t1 (n,), rest (n, 2))``, a row per landing and rest
    (``centred``: the midpoint only)."""
    dt = params.servo_period
    steps = np.arange(params.min_step_length, params.max_step_length + 1e-9, STEP_GRID)
    steps = steps[0.5 * steps <= params.max_rear_reach]
    landing = np.stack([ankle[0] + steps, np.full_like(steps, landing_y)], axis=1)
    swing = np.hypot(*(landing - swing_xy).T) / params.max_swing_speed
    t1 = np.ceil(np.maximum(swing, max(params.min_landing_time, min_landing)) / dt - 1e-9) * dt
    keep = t1 <= params.max_landing_time + 1e-9
    steps, landing, t1 = steps[keep], landing[keep], t1[keep]
    fractions, kept = _rest_fractions(steps, params.max_rear_reach)
    if centred:
        kept[:, 1:] = False
    row, column = np.nonzero(kept)
    half = 0.5 * (landing - ankle)
    return landing[row], t1[row], ankle + half[row] * (1.0 + fractions[row, column])[:, None]


def held_brake(com, com_vel, zmp, ankle, landing, touchdown, polygon, params, w: float,
               required: float) -> Brake | None:
    """Single support with a given landing (the paper's: ``landing`` (2,) the landing ankle [m] at
    ``touchdown`` [s] from the start): the ZMP held where it is, ``zmp``, until the touchdown
    (eq. 19), then :func:`stop_brake` to rest between the support ``ankle`` and the landing
    (:func:`rest_points`) with the ZMP ``required`` [m] inside ``polygon`` (both soles'). ``com, com_vel``
    (2,): the COG at the start. None if no candidate fits."""
    com, com_vel, zmp, ankle, landing = (np.asarray(v, float)[:2] for v in (com, com_vel, zmp, ankle, landing))
    ch, sh = math.cosh(w * touchdown), math.sinh(w * touchdown)  # the COG at the touchdown (eq. 6, 9)
    rests = rest_points(ankle, landing, params.max_rear_reach)
    found = stop_brake(zmp + (com - zmp) * ch + com_vel / w * sh, (com - zmp) * w * sh + com_vel * ch, zmp,
                       np.zeros(2), np.zeros(2), rests, [polygon] * len(rests), params, w, required)
    if found is None:
        return None
    brake = found[1]
    coeffs = [[lipm.pad([zmp[a]])] + brake.coeffs[a] for a in range(2)]
    return Brake([float(touchdown)] + brake.durations, coeffs, tuple(touchdown + e for e in brake.ends),
                 float(landing[0]), brake.margin, rest=brake.rest)


@functools.lru_cache(maxsize=16)
def _swing_table(w, dt, ramps, returns, hold_min, hold_max):
    """The after-touchdown part of :func:`swing_brake`'s candidates (durations ``r1, h, r3``): the
    coefficients of ``a`` and ``c`` in the forward condition (from the touchdown, to be scaled by
    ``exp(-w t1)``) and in the backward condition."""
    r1, h, r3 = (g.ravel() for g in np.meshgrid(np.array(ramps), _grid(dt, hold_min, hold_max),
                                                 np.array(returns), indexing="ij"))
    total = r1 + h + r3
    order = np.lexsort((r3, r1, total))
    r1, h, r3, total = r1[order], h[order], r3[order], total[order]
    f1, b1 = _moments(w * r1)
    fh, bh = _moments(w * h)
    f3, b3 = _moments(w * r3)
    e_1 = np.exp(-w * (h + r3))
    fwd = (_down(f1), f1[:, SIGMA] + np.exp(-w * r1) * fh[:, ONE] + np.exp(-w * (r1 + h)) * _down(f3))
    bwd = (e_1 * _down(b1), e_1 * b1[:, SIGMA] + np.exp(-w * r3) * bh[:, ONE] + _down(b3))
    return {"r1": r1, "h": h, "r3": r3, "total": total, "fwd": fwd, "bwd": bwd, "decay": np.exp(-w * total)}


def swing_brake(com, com_vel, zmp, zmp_rate, zmp_accel, ankle, swing_xy, landing_y, min_landing, support_polygon,
                polygon_for, params, w: float, required: float) -> Brake | None:
    """Single support: the soonest rest over the landing choices (step lengths on a grid, the earliest
    touchdown each allows) with the ZMP chain ``ZMP -> a (held) -> touchdown -> c (held) -> m``: the
    soonest along which the COG never moves backwards (:func:`_backs_up`, among the first
    ``FORWARD_CHECKS`` candidates that fit), resting at the feet's midpoint if it can and else at
    the soonest over :func:`rest_points`, if the COG moves forward; else the soonest.

    ``com, com_vel, zmp, zmp_rate, zmp_accel`` (2,): the COG and the ZMP at the plan start (the ZMP
    on the support sole: at the ankle and at rest where the walk is interrupted, eq. 19);
    ``ankle``: the support ankle; ``swing_xy``: the swing ankle; ``landing_y``: the landing ankle's
    y [m]; ``min_landing`` [s]: the shortest touchdown the swing foot's height allows;
    ``support_polygon``: the support sole's; ``polygon_for(landing_xy)``: both soles' with the swing
    foot landed there. Limits: ``min/max_step_length`` (from the support ankle),
    ``min/max_landing_time``, ``max_swing_speed``, ``max_fore_reach`` (landing ankle ahead of the COG
    at touchdown), ``max_rear_reach`` (the COG at rest at most this far ahead of the support ankle),
    ``min_transition_time`` (every transition after the touchdown). Returns None where no candidate keeps
    ``required`` [m]."""
    args = (com, com_vel, zmp, zmp_rate, zmp_accel, ankle, swing_xy, landing_y, min_landing, support_polygon,
            polygon_for, params, w, required)
    levels = {}  # the candidates' levels and margins by landing rows: the same for both passes
    if float(np.asarray(com_vel, float)[0]) >= 0.0:
        # the feet's midpoint first (the centred stance), then the rest points further on
        found = _swing_search(*args, _ForwardOnly(), {}, centred=True)
        if found is None:
            found = _swing_search(*args, _ForwardOnly(), levels)
        if found is not None:
            return found
    return _swing_search(*args, None, levels)


def _swing_search(com, com_vel, zmp, zmp_rate, zmp_accel, ankle, swing_xy, landing_y, min_landing, support_polygon,
                  polygon_for, params, w, required, forward_only, levels, centred=False):
    """:func:`swing_brake`'s search; with ``forward_only`` (a :class:`_ForwardOnly`) only the candidates
    along which the COG does not move backwards (None when its checks run out). ``levels``: a dict that
    keeps each set of step lengths' candidate levels, margins and order for a second pass (they do not
    depend on ``forward_only``). ``centred``: the COG rests at the feet's midpoint only."""
    com, com_vel, zmp, rate, accel, ankle, swing_xy = (np.asarray(v, float)[:2] for v in (
        com, com_vel, zmp, zmp_rate, zmp_accel, ankle, swing_xy))
    dt = params.servo_period
    ramp = _ticks(params, (SOLE_RAMP_FACTOR,))[0]  # the ZMP's transition on the support sole
    landing, t1, rests = _landings(ankle, swing_xy, landing_y, max(min_landing, ramp + dt), params, centred)
    if not len(t1):
        return None
    t = _swing_table(float(w), float(dt), _ticks(params, RAMP_FACTORS), _ticks(params, RETURN_FACTORS[:1]),
                     float(params.min_slowdown_time), float(min(params.max_slowdown_time, SWING_HOLD_MAX)))
    start_margin = float(np.min(support_polygon._offsets - support_polygon._normals @ zmp))
    ramp_fwd, ramp_bwd = _ramp_moments(float(w), float(ramp))
    # the start ZMP's rate and acceleration ride on the first transition (eq. 12-14): per axis, their
    # part of the forward and backward integrals (the backward one to be scaled by exp(-w hold))
    carried = rate * ramp, accel * ramp * ramp
    carried_fwd = carried[0] * ramp_fwd[RATE] + carried[1] * ramp_fwd[ACCEL]
    carried_bwd = carried[0] * ramp_bwd[RATE] + carried[1] * ramp_bwd[ACCEL]
    curved = moving_zmp(rate, accel)
    support_planes = support_polygon._normals, support_polygon._offsets

    def candidates(rows):
        """The levels ``a``, ``c`` of every candidate of the step lengths ``rows``, and those that keep
        ``required`` on the support sole and the fore reach, soonest first."""
        land, xy, mid = t1[rows], landing[rows], rests[rows]
        # before the touchdown: the transition to a over `ramp`, a held for `hold` (moments of its shapes)
        hold = land - ramp
        grow, decay_hold, decay_t1 = np.exp(w * land), np.exp(-w * hold), np.exp(-w * land)
        pre_a_fwd = ramp_fwd[SIGMA] + math.exp(-w * ramp) * (1.0 - decay_hold)
        pre_a_bwd = decay_hold * ramp_bwd[SIGMA] + (1.0 - decay_hold)
        (fa, fc), (ba, bc) = t["fwd"], t["bwd"]
        decay = t["decay"][None, :]
        a11 = pre_a_fwd[:, None] + decay_t1[:, None] * fa[None, :]
        a12 = decay_t1[:, None] * fc[None, :]
        a21 = decay * pre_a_bwd[:, None] + ba[None, :]
        # both axes at once: (axis, step length, candidate), relative to the rest point
        m = mid.T[:, :, None]
        q0 = zmp[:, None, None] - m
        rhs_f = (com + com_vel / w - carried_fwd)[:, None, None] - m - q0 * (ramp_fwd[ONE] - ramp_fwd[SIGMA])
        rhs_b = (-((com - com_vel / w)[:, None, None] - m) * decay_t1[None, :, None]
                 - (q0 * (ramp_bwd[ONE] - ramp_bwd[SIGMA]) + carried_bwd[:, None, None])
                 * decay_hold[None, :, None]) * decay
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            qa, qc = _solve2(a11, a12, a21, bc[None, :], rhs_f, rhs_b)
        a, c = m + qa, m + qc
        # fore reach: the COG at the touchdown (eq. 6; from rest, the response to the ZMP q is
        # -w int sinh(w (t1 - s)) q(s) ds = -(exp(w t1) F - B) / 2, F and B its forward and
        # backward integrals) at most max_fore_reach behind the landing ankle
        free = (zmp[0] + (com[0] - zmp[0]) * np.cosh(w * land) + com_vel[0] / w * np.sinh(w * land)
                - 0.5 * (grow * carried_fwd[0] - decay_hold * carried_bwd[0]))
        gain = -0.5 * (grow * pre_a_fwd - pre_a_bwd)  # the COG at the touchdown per metre of a ahead of the ZMP (< 0)
        # landing x - (free + gain (a_x - ZMP x)) <= max_fore_reach: a_x at most this far ahead (per step length)
        farthest = zmp[0] + (xy[:, 0] - params.max_fore_reach - free) / gain
        normals, offsets = support_planes
        margin = np.minimum(np.min(offsets[:, None, None] - normals[:, 0, None, None] * a[0]
                                   - normals[:, 1, None, None] * a[1], axis=0), start_margin)
        i, k = np.nonzero((margin >= required) & (a[0] <= farthest[:, None]))
        total = land[i] + t["total"][k]
        order = np.argsort(total, kind="stable")
        return land, xy, mid, hold, a, c, margin, i[order], k[order], total[order]

    polygons = {}  # both soles' polygon by landing x: the rows of one step length share it

    def polygon_of(landing_xy):
        key = float(landing_xy[0])
        if key not in polygons:
            polygons[key] = polygon_for(landing_xy)
        return polygons[key]

    def search(rows):
        """The soonest candidate of the landing rows ``rows`` (a Brake) or None."""
        key = rows.tobytes()
        if key not in levels:
            levels[key] = candidates(rows)
        land, xy, mid, hold, a, c, margin, i, k, total = levels[key]
        # c inside both soles' polygon: checked lazily, soonest first (the polygon differs per step length)
        best = None
        for low in range(0, len(i), LAZY):
            if best is not None and total[low] > best[0] + 1e-9:
                break
            n = slice(low, low + LAZY)
            rows_n, index = np.unique(i[n], return_inverse=True)
            normals, offsets = stack_halfplanes([polygon_of(xy[r]) for r in rows_n])
            inside = np.min(offsets[index] - np.einsum("dn,ned->ne", c[:, i[n], k[n]], normals[index]), axis=1)
            both = np.minimum(margin[i[n], k[n]], inside)
            fits = np.nonzero(both >= required)[0]
            for j in fits[np.lexsort((-both[fits], total[low + fits]))]:  # soonest, then the largest margin
                if best is not None and (total[low + j] > best[0] + 1e-9 or both[j] <= best[1]):
                    break
                brake = _swing_chain(t, ramp, i[low + j], k[low + j], land, hold, xy, mid, zmp, rate, accel, a, c,
                                     float(both[j]))
                if curved:  # the first transition carries the ZMP's rate and acceleration: check its ticks
                    points = _segment_points(brake.coeffs, 0, ramp, dt)
                    brake.margin = min(brake.margin, float(support_polygon.margin(points).min()))
                if brake.margin >= required and forward_only is not None:
                    if forward_only.backs_up(brake.coeffs[0], brake.durations, com[0], com_vel[0], w, dt):
                        continue
                if brake.margin >= required:
                    best = (float(total[low + j]), float(both[j]), brake)
                    break
        return None if best is None else best[2]

    # the step lengths with the earliest touchdowns first; the later ones only if they can still be sooner
    order = np.argsort(t1, kind="stable")
    first = order[t1[order] <= t1[order[0]] + SWING_FIRST + 1e-9]
    try:
        best = search(first)
        rest = order[len(first):]
        if best is not None:
            rest = rest[t1[rest] + t["total"][0] < best.duration - 1e-9]
        if len(rest):
            other = search(rest)
            if other is not None and (best is None or other.duration < best.duration - 1e-9):
                best = other
    except _Spent:
        return None
    return best


class _Spent(Exception):
    """A forward-only pass (:class:`_ForwardOnly`) ran out of checks."""


def _swing_chain(t, ramp, i, k, land, hold, xy, mid, zmp, rate, accel, a, c, margin) -> Brake:
    """The :class:`Brake` of :func:`swing_brake`'s candidate ``k`` for step length ``i``."""
    r1, h, r3 = float(t["r1"][k]), float(t["h"][k]), float(t["r3"][k])
    durations = [ramp, float(hold[i]), r1, h, r3]
    chain = np.stack([zmp, a[:, i, k], a[:, i, k], c[:, i, k], c[:, i, k], mid[i]])  # (levels, axis)
    coeffs = _ramps(chain, np.array(durations), rate, accel)
    touchdown = float(land[i])
    return Brake(durations, coeffs, (touchdown, touchdown + r1, touchdown + r1 + h, touchdown + r1 + h + r3),
                 float(xy[i, 0]), margin, rest=mid[i].copy())
