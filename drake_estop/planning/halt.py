"""The halt (eq. 27-28): the ZMP segment that brings the COG to rest between the feet.

After the slowdown the COG is at rest only sagittally, to rounding, and the lateral plane
still moves; the halt is Harada's two-point boundary-value ZMP segment that ends with the
COG at rest over the midpoint of the feet. Its duration is chosen so that the ZMP keeps
``zmp_margin`` inside the support polygon (:func:`choose_halt`).
"""

from __future__ import annotations

import functools
import math

import numpy as np

from drake_estop.planning import lipm

HALT_PROBE = np.linspace(0.0, 1.0, 41)


def halt_candidates(params):
    """(shift, settle) duration pairs on servo ticks, shortest halt first."""
    dt = params.servo_period
    ticks = lambda t: max(1, round(t / dt)) * dt  # noqa: E731
    shifts = sorted({ticks(params.min_transition_time), ticks(2 * params.min_transition_time)})
    pairs = [(a, ticks(b)) for a in shifts for b in params.halt_durations]
    return sorted(pairs, key=lambda pair: (pair[0] + pair[1], pair[0]))


@functools.lru_cache(maxsize=256)
def halt_basis(w: float, shift: float, settle: float):
    """Unit responses of the halt ZMP shapes (cached: they depend on durations only).

    Shapes over the two halt segments: [from the slowdown ZMP, to the target,
    free point q, bump A, bump B]. Returns their ZMP coefficients per segment,
    the COG end state each produces from rest (plain floats), the homogeneous
    transition matrix, ``S^T`` and the normal matrix ``S S^T`` (nested lists)
    of the least-norm boundary-value problem (eq. 27-28; ``S``: weighted
    responses of the unknowns) and the shapes sampled at the probe points.
    """
    zero = lipm.pad(np.zeros(1))
    one = lipm.pad([1.0])
    rise = lipm.pad(lipm.scale_unit_poly(lipm.SMOOTHSTEP, shift))
    settle_rise = lipm.pad(lipm.scale_unit_poly(lipm.SMOOTHSTEP, settle))
    shapes = [
        [one - rise, zero],
        [zero, settle_rise],
        [rise, one - settle_rise],
        [zero, lipm.pad(lipm.scale_unit_poly(lipm.BUMP_A, settle))],
        [zero, lipm.pad(lipm.scale_unit_poly(lipm.BUMP_B, settle))],
    ]
    durations = (shift, settle)
    responses = np.array([lipm.chain_end_state(durations, shape, 0.0, 0.0, w) for shape in shapes])
    total = shift + settle
    ch, sh = math.cosh(w * total), math.sinh(w * total)
    homogeneous = np.array([[ch, sh / w], [w * sh, ch]])
    scaled = responses[2:].T * HALT_WEIGHTS
    normal = scaled @ scaled.T  # badly conditioned for long settles: solved per call, not inverted
    samples = np.array([np.concatenate([lipm.poly_eval(c, HALT_PROBE * d) for d, c in zip(durations, shape)])
                        for shape in shapes])
    return np.array(shapes), responses, homogeneous, (np.ascontiguousarray(scaled.T), normal.tolist()), samples


HALT_WEIGHTS = np.array([10.0, 1.0, 1.0])  # q, bump A, bump B: bumps penalised


def halt_axis(x3, v3, zmp3, target, shift, settle, w):
    """Halt ZMP of one axis (eq. 27-28): a quick shift from the slowdown ZMP to a
    free point ``q``, then a settle segment from ``q`` to ``target`` with two
    bumps. ``q`` and the bump heights solve Harada's two-point boundary-value
    problem (COG at ``target`` at rest) in the weighted least-norm sense, so
    the ZMP moves as little as the COG allows. Returns (shape weights ``mix``,
    ZMP samples at the probe points); coefficients per segment are
    the shapes weighted by ``mix`` (:func:`halt_coeffs`)."""
    _, responses, homogeneous, (scaled_t, normal), samples = halt_basis(w, shift, settle)
    free = homogeneous @ np.array([x3, v3]) + zmp3 * responses[0] + target * responses[1]
    # weighted least norm: u = W S^T (S S^T)^-1 (end state wanted - end state without the unknowns)
    u = HALT_WEIGHTS * (scaled_t @ np.array(_solve2(normal, (np.array([target, 0.0]) - free).tolist())))
    mix = np.concatenate([[zmp3, target], u])
    return mix, mix @ samples


def _solve2(matrix, rhs):
    """2x2 linear solve by Gaussian elimination with partial pivoting, plain floats; the
    operations of LAPACK's gesv (multiplier by the pivot's reciprocal), so the result
    equals ``np.linalg.solve`` to the bit even on the badly conditioned halt systems."""
    (a, b), (c, d) = matrix
    r0, r1 = rhs
    if abs(c) > abs(a):
        a, b, c, d, r0, r1 = c, d, a, b, r1, r0
    factor = c * (1.0 / a)
    second = (r1 - factor * r0) / (d - factor * b)
    return (r0 - b * second) / a, second


def halt_coeffs(mix, shift, settle, w):
    """ZMP coefficients per halt segment of the shape weights from :func:`halt_axis`."""
    shapes = halt_basis(w, shift, settle)[0]
    # a vector-matrix product over the flattened shapes (measured: under 1 us a call, tensordot's 9 us)
    return list((mix @ shapes.reshape(len(shapes), -1)).reshape(shapes.shape[1:]))


#: halt candidates :func:`choose_halt` solves one at a time before it solves the rest in batches of
#: ``HALT_BATCH``, shortest first (the three shortest fit 60 % of the default stride's stops, the next six
#: nearly all the rest)
HALT_ONE_BY_ONE = 3
HALT_BATCH = 6


def choose_halt(ends, midpoint, polygon, params, w):
    """Shortest halt whose ZMP keeps ``zmp_margin`` inside the support polygon;
    else the one with the largest margin. ``ends``: COG position, velocity and
    ZMP per axis at the slowdown end. Returns (durations, coeffs per axis, margin).

    The shortest :data:`HALT_ONE_BY_ONE` candidates are tried one at a time (most
    stops fit one of them); the others are solved :data:`HALT_BATCH` at a time
    (:func:`_halt_batch`: the same least-norm problems, batched), so a long halt
    costs little more than a short one."""
    candidates = halt_candidates(params)
    best = None
    for shift, settle in candidates[:HALT_ONE_BY_ONE]:
        axes = [halt_axis(x3, v3, zmp3, midpoint[a], shift, settle, w) for a, (x3, v3, zmp3) in enumerate(ends)]
        margin = float(polygon.margin(np.stack([axes[0][1], axes[1][1]], axis=1)).min())
        if best is None or margin > best[2]:
            best = ((shift, settle), [axis[0] for axis in axes], margin)
        if margin >= params.zmp_margin:
            break
    for low in range(HALT_ONE_BY_ONE, len(candidates), HALT_BATCH):
        if best[2] >= params.zmp_margin:
            break
        chunk = tuple(candidates[low:low + HALT_BATCH])
        batch = _halt_batch(w, chunk)
        mixes, samples = zip(*(_halt_axes(batch, x3, v3, zmp3, midpoint[a]) for a, (x3, v3, zmp3) in enumerate(ends)))
        margins = polygon.margin(np.stack(samples, axis=2).reshape(-1, 2)).reshape(len(chunk), -1).min(axis=1)
        fits = np.flatnonzero(margins >= params.zmp_margin)
        index = int(fits[0]) if len(fits) else int(np.argmax(margins))
        if len(fits) or margins[index] > best[2]:
            best = (chunk[index], [mix[index] for mix in mixes], float(margins[index]))
    (shift, settle), mixes, margin = best
    return [shift, settle], [halt_coeffs(mix, shift, settle, w) for mix in mixes], margin


def prepare_halts(w: float, params) -> None:
    """Compute (and cache) the halt bases of every candidate duration for the LIPM frequency ``w``: a stop
    that first needs one of them then does not pay for it on its servo tick."""
    candidates = halt_candidates(params)
    for shift, settle in candidates:
        halt_basis(w, shift, settle)
    for low in range(HALT_ONE_BY_ONE, len(candidates), HALT_BATCH):
        _halt_batch(w, tuple(candidates[low:low + HALT_BATCH]))


@functools.lru_cache(maxsize=64)
def _halt_batch(w: float, candidates: tuple):
    """:func:`halt_basis` of every ``(shift, settle)`` candidate, stacked: homogeneous transition (c, 2, 2),
    responses to the slowdown ZMP and to the target (c, 2), ``S^T`` (c, 3, 2), normal matrices (c, 2, 2)
    and the shapes at the probe points (c, 5, probes)."""
    bases = [halt_basis(w, shift, settle) for shift, settle in candidates]
    return (np.array([b[2] for b in bases]), np.array([b[1][0] for b in bases]), np.array([b[1][1] for b in bases]),
            np.array([b[3][0] for b in bases]), np.array([b[3][1] for b in bases]), np.array([b[4] for b in bases]))


def _halt_axes(batch, x3, v3, zmp3, target):
    """:func:`halt_axis` for every candidate of ``batch`` at once: (mix (c, 5), ZMP at the probes (c, probes))."""
    homogeneous, from_zmp, to_target, scaled_t, normal, samples = batch
    free = homogeneous @ np.array([x3, v3]) + zmp3 * from_zmp + target * to_target
    wanted = np.array([target, 0.0]) - free
    u = HALT_WEIGHTS * np.einsum("cij,cj->ci", scaled_t, np.linalg.solve(normal, wanted[:, :, None])[:, :, 0])
    mix = np.concatenate([np.full((len(u), 1), zmp3), np.full((len(u), 1), target), u], axis=1)
    return mix, np.einsum("ck,ckp->cp", mix, samples)
