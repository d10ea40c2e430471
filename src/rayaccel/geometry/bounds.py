"""Per-primitive bounding boxes and centroids, the only view of a scene that builders get."""

from __future__ import annotations

import numpy as np
from numba import prange

from .._jit import parallel_kernel

__all__ = ["triangle_bounds", "sphere_bounds"]


@parallel_kernel
def triangle_bounds(geometry):
    """``(lo, hi, centroid)``, each (n, 3), of triangles stored as rows of 9 floats."""
    n = geometry.shape[0]
    lo = np.empty((n, 3))
    hi = np.empty((n, 3))
    centroid = np.empty((n, 3))
    for p in prange(n):
        for k in range(3):
            a, b, c = geometry[p, k], geometry[p, 3 + k], geometry[p, 6 + k]
            lo[p, k] = min(a, b, c)
            hi[p, k] = max(a, b, c)
            centroid[p, k] = (a + b + c) / 3.0
    return lo, hi, centroid


@parallel_kernel
def sphere_bounds(geometry):
    """``(lo, hi, centroid)``, each (n, 3), of spheres stored as rows ``x, y, z, r``."""
    n = geometry.shape[0]
    lo = np.empty((n, 3))
    hi = np.empty((n, 3))
    centroid = np.empty((n, 3))
    for p in prange(n):
        r = geometry[p, 3]
        for k in range(3):
            lo[p, k] = geometry[p, k] - r
            hi[p, k] = geometry[p, k] + r
            centroid[p, k] = geometry[p, k]
    return lo, hi, centroid
