"""A correction of the pattern's COG that moves its ZMP by a given shift: the LIPM solved backwards.

The walk is planned on the linear inverted pendulum (eq. 4): its ZMP is ``p = c - c''/w^2``. The whole body
puts the ZMP the floor must carry elsewhere, ``p + dp`` (its limbs' angular momentum, the COG's height
changes: :mod:`drake_estop.systems.multibody_zmp`). Moving the COG by ``dc`` with

    dc - dc''/w^2 = -dp                                                           (eq. 4, for the shift)

cancels it, and of that equation's solutions the one bounded both ways is the convolution

    dc(t) = -(w/2) int exp(-w |t - s|) dp(s) ds

(Kajita et al. 2003's compensation of the multibody ZMP by a second pass through the pendulum, here in its
non-causal form: the walk is known in full). It looks ahead and back one time constant ``1/w``, so a shift
that ends before the walk does leaves the COG at rest where it started and ended. Pure numpy, no Drake:
the shift is measured by the caller (:func:`drake_estop.systems.whole_body_walk.whole_body_pattern`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ComCorrection:
    """A COG offset sampled on a uniform grid: ``offset``, ``velocity``, ``acceleration`` (n, 2) at ``times``
    (n,) [s, m]; zero outside them. Linear between samples."""

    times: np.ndarray
    offset: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray

    def __add__(self, other: ComCorrection) -> ComCorrection:
        if self.times.shape != other.times.shape or not np.allclose(self.times, other.times):
            raise ValueError("corrections on different times cannot be added")
        return ComCorrection(self.times, self.offset + other.offset, self.velocity + other.velocity,
                             self.acceleration + other.acceleration)

    def evaluate(self, t) -> tuple:
        """(offset, velocity, acceleration), each (len(t), 2), at the times ``t`` [s]."""
        t = np.atleast_1d(np.asarray(t, float))
        return tuple(np.stack([np.interp(t, self.times, values[:, axis], left=0.0, right=0.0)
                               for axis in (0, 1)], axis=-1)
                     for values in (self.offset, self.velocity, self.acceleration))


def lipm_correction(times, zmp_shift, omega: float) -> ComCorrection:
    """The bounded COG correction that moves the LIPM's ZMP by ``-zmp_shift`` (the module docstring's
    convolution): ``times`` (n >= 2,) uniform [s], ``zmp_shift`` (n, 2) [m], zero outside ``times`` and linear
    between samples (the convolution is then exact: two exponential filters, forward and backward)."""
    times = np.asarray(times, float)
    shift = np.asarray(zmp_shift, float)
    if times.ndim != 1 or times.size < 2:
        raise ValueError(f"times must be a 1-D array of at least 2 samples, got shape {times.shape}")
    step = float(times[1] - times[0])
    if not (step > 0 and np.allclose(np.diff(times), step, rtol=1e-6, atol=1e-9)):
        raise ValueError("times must be increasing with a uniform step")
    if shift.shape != (times.size, 2) or not np.all(np.isfinite(shift)):
        raise ValueError(f"zmp_shift must be finite, shape ({times.size}, 2), got {shift.shape}")
    if not (math.isfinite(omega) and omega > 0):
        raise ValueError(f"omega must be positive, got {omega!r}")
    decay = math.exp(-omega * step)
    whole = (1.0 - decay) / omega  # int_0^h exp(-w u) du
    ramp = (step * whole - (1.0 - decay * (1.0 + omega * step)) / omega**2) / step  # int_0^h exp(-w u)(h-u)/h du
    past = np.zeros_like(shift)  # int_{s < t} exp(-w (t - s)) dp(s) ds
    future = np.zeros_like(shift)  # int_{s > t} exp(-w (s - t)) dp(s) ds
    for k in range(1, len(times)):
        past[k] = decay * past[k - 1] + shift[k - 1] * (whole - ramp) + shift[k] * ramp
    for k in range(len(times) - 2, -1, -1):
        future[k] = decay * future[k + 1] + shift[k + 1] * (whole - ramp) + shift[k] * ramp
    offset = -0.5 * omega * (past + future)
    velocity = 0.5 * omega**2 * (past - future)
    acceleration = omega**2 * (offset + shift)  # eq. 4 for the shift: dc'' = w^2 (dc + dp)
    return ComCorrection(times, offset, velocity, acceleration)
