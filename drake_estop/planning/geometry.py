"""Support polygons: convex hulls of sole rectangles and signed margins."""

from __future__ import annotations

import numpy as np


def convex_hull(points: np.ndarray) -> np.ndarray:
    """Counter-clockwise hull (Andrew's monotone chain) of 2-D points."""
    pts = sorted(map(tuple, np.asarray(points, float)))
    if len(pts) <= 2:
        return np.array(pts)

    def cross(o, a, b):
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    lower, upper = [], []
    for p in pts:
        while len(lower) >= 2 and cross(lower[-2], lower[-1], p) <= 0:
            lower.pop()
        lower.append(p)
    for p in reversed(pts):
        while len(upper) >= 2 and cross(upper[-2], upper[-1], p) <= 0:
            upper.pop()
        upper.append(p)
    return np.array(lower[:-1] + upper[:-1])


class SupportPolygon:
    """Convex polygon with ``margin(p)``: distance inside (positive) or outside (negative)."""

    def __init__(self, points):
        self.vertices = convex_hull(points)
        v = self.vertices
        edges = np.roll(v, -1, axis=0) - v
        normals = np.stack([edges[:, 1], -edges[:, 0]], axis=1)  # outward for CCW
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)
        self._normals = normals
        self._offsets = np.sum(normals * v, axis=1)

    def margin(self, points) -> np.ndarray:
        """Signed distance to the nearest edge line (exact inside; a lower bound on depth outside)."""
        p = np.atleast_2d(np.asarray(points, float))
        return np.min(self._offsets[None, :] - p @ self._normals.T, axis=1)

    def contains(self, points, margin: float = 0.0) -> np.ndarray:
        return self.margin(points) >= margin



def stack_halfplanes(polygons):
    """The edges of ``polygons`` as stacked half-planes ``(normals (k, e, 2), offsets (k, e))`` for
    :func:`stacked_margin` (padded with half-planes that never bind)."""
    edges = max(len(polygon._offsets) for polygon in polygons)
    normals = np.zeros((len(polygons), edges, 2))
    offsets = np.full((len(polygons), edges), np.inf)
    for i, polygon in enumerate(polygons):
        normals[i, :len(polygon._offsets)] = polygon._normals
        offsets[i, :len(polygon._offsets)] = polygon._offsets
    return normals, offsets


def stacked_margin(halfplanes, points) -> np.ndarray:
    """:meth:`SupportPolygon.margin` of ``points[i]`` ((k, n, 2)) in the i-th of k polygons at once,
    given as :func:`stack_halfplanes`; (k, n), NaN for non-finite points."""
    normals, offsets = halfplanes
    return np.min(offsets[:, None, :] - np.matmul(points, normals.transpose(0, 2, 1)), axis=2)
