"""Per-primitive bounding boxes and centroids, the only view of a scene that builders get.

The boxes and the scene's box come from one parallel pass: each chunk of
primitives reduces its own part of the scene box, so the scene box costs no
second pass over the boxes. Centroids are a separate kernel, as only the BVH
builders read them.
"""

from __future__ import annotations

import numpy as np
from numba import prange

from .._jit import inline_kernel, parallel_kernel, thread_count
from ..counting_sort import chunk_range
from .kinds import SPHERE

__all__ = ["primitive_extent", "primitive_bounds", "triangle_centroids", "sphere_centroids"]


@inline_kernel
def primitive_extent(kind, geometry, p, k):
    """``(lo, hi)`` of primitive ``p`` on axis ``k``."""
    if kind == SPHERE:
        return geometry[p, k] - geometry[p, 3], geometry[p, k] + geometry[p, 3]
    a, b, c = geometry[p, k], geometry[p, 3 + k], geometry[p, 6 + k]
    return min(a, b, c), max(a, b, c)


@parallel_kernel
def _primitive_bounds(kind, geometry, n_chunks):
    n = geometry.shape[0]
    lo = np.empty((n, 3))
    hi = np.empty((n, 3))
    chunk_box = np.empty((n_chunks, 6))
    for c in prange(n_chunks):
        chunk_box[c, :3] = np.inf
        chunk_box[c, 3:] = -np.inf
        first, end = chunk_range(n, n_chunks, c)
        for p in range(first, end):
            for k in range(3):
                lo[p, k], hi[p, k] = primitive_extent(kind, geometry, p, k)
                chunk_box[c, k] = min(chunk_box[c, k], lo[p, k])
                chunk_box[c, k + 3] = max(chunk_box[c, k + 3], hi[p, k])
    scene_lo = np.empty(3)
    scene_hi = np.empty(3)
    for k in range(3):
        scene_lo[k] = chunk_box[:, k].min()
        scene_hi[k] = chunk_box[:, k + 3].max()
    return lo, hi, scene_lo, scene_hi


def primitive_bounds(kind: int, geometry: np.ndarray):
    """``(lo, hi, scene_lo, scene_hi)``: the boxes (n, 3) of the primitives, triangles stored as
    rows of 9 floats or spheres as rows ``x, y, z, r``, and the box (3,) around them all."""
    return _primitive_bounds(kind, geometry, thread_count())


@parallel_kernel
def triangle_centroids(geometry):
    """(n, 3) vertex means of triangles stored as rows of 9 floats."""
    n = geometry.shape[0]
    centroid = np.empty((n, 3))
    for p in prange(n):
        for k in range(3):
            centroid[p, k] = (geometry[p, k] + geometry[p, 3 + k] + geometry[p, 6 + k]) / 3.0
    return centroid


def sphere_centroids(geometry: np.ndarray) -> np.ndarray:
    """(n, 3) centres of spheres stored as rows ``x, y, z, r``, as a new array (builders reorder it)."""
    return geometry[:, :3].copy()
