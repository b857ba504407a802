"""Small numerics of the state estimator, plain numpy (the per-tick cost matters): quaternions
(w, x, y, z) and one step of a two-state Kalman filter: :func:`kf_step` for one axis, the definition that
:func:`kf_step_axes`, the estimator's three COG axes in one call, keeps to the bit.

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


def kf_step_axes(mean, cov, A, B, u, Q, z, r):
    """:func:`kf_step` of several independent axes at once, each axis the bits of its own call: ``mean``
    (n, 2), ``cov`` (n, 3) as (p00, p01, p11), ``A`` (n, 2, 2), ``B`` (n, 2), ``u`` (n), ``Q`` (n, 2, 2),
    ``z`` (n) position measurements (NaN: none), ``r`` their variance. Returns the new ``(mean (n, 2), cov
    (n, 3))``. (numpy's matmul of a stack runs its 2 x 2 product slice by slice, as one call does; a 2-D
    ``A`` broadcast over the stack would round otherwise.)"""
    m = np.matmul(A, mean[:, :, None])[:, :, 0] + B * u[:, None]
    P = cov[:, [0, 1, 1, 2]].reshape(-1, 2, 2)
    P = A @ P @ A.transpose(0, 2, 1) + Q
    measured = np.isfinite(z)
    if measured.any():
        s = P[:, 0, 0] + r
        k = P[:, :, 0] / s[:, None]
        m_new = m + k * (z - m[:, 0])[:, None]
        P_new = P - k[:, :, None] * P[:, None, 0, :]
        if measured.all():
            m, P = m_new, P_new
        else:
            m, P = np.where(measured[:, None], m_new, m), np.where(measured[:, None, None], P_new, P)
    return m, np.stack([P[:, 0, 0], 0.5 * (P[:, 0, 1] + P[:, 1, 0]), P[:, 1, 1]], axis=1)
