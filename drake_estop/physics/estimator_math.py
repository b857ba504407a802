"""Small numerics of the state estimator, plain numpy (the per-tick cost matters): quaternions
(w, x, y, z) and one step of a two-state Kalman filter.

Used by :class:`drake_estop.physics.estimation.StateEstimator` and
:class:`drake_estop.physics.sensors.FootForceTorqueSensors`.
"""

from __future__ import annotations

import math

import numpy as np


def quat_to_matrix(q):
    """Rotation matrix of the unit quaternion ``q`` = (w, x, y, z)."""
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def cross(a, b):
    """Cross product ``a x b`` of two 3-vectors."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def quat_multiply(a, b):
    """Hamilton product ``a b`` of two quaternions (w, x, y, z)."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return np.array([aw * bw - ax * bx - ay * by - az * bz,
                     aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw])


def quat_exp(phi):
    """Unit quaternion of the rotation vector ``phi`` [rad] (first order below 1e-12 rad)."""
    angle = math.sqrt(phi[0] ** 2 + phi[1] ** 2 + phi[2] ** 2)
    if angle < 1e-12:
        return np.array([1.0, 0.5 * phi[0], 0.5 * phi[1], 0.5 * phi[2]])
    s = math.sin(0.5 * angle) / angle
    return np.array([math.cos(0.5 * angle), s * phi[0], s * phi[1], s * phi[2]])


def kf_step(mean, cov, A, B, u, Q, z, r):
    """One predict (x' = A x + B u, P' = A P A^T + Q) + update with a position measurement z (variance r).

    ``mean`` (2), ``cov`` as (p00, p01, p11). Returns the new mean and cov (3).
    """
    m = A @ mean + B * u
    P = np.array([[cov[0], cov[1]], [cov[1], cov[2]]])
    P = A @ P @ A.T + Q
    if z is not None and math.isfinite(z):
        s = P[0, 0] + r
        k = P[:, 0] / s
        m = m + k * (z - m[0])
        P = P - np.outer(k, P[0, :])
    return m, np.array([P[0, 0], 0.5 * (P[0, 1] + P[1, 0]), P[1, 1]])
