"""Per-primitive bounding boxes and centroids, the only view of a scene that builders get.

The boxes and the scene's box come from one pass: each chunk of primitives,
one per thread, reduces its own part of the scene box, so the scene box costs
no second pass over the boxes. Centroids are a separate kernel, as only the BVH
builders read them. Each primitive kind has its own small serial kernel (the
kind a module constant, so Numba compiles only that kind's branch), run on
Python threads since the kernels release the GIL: a first build compiles one
kind's pass, not a ``prange`` kernel with both kinds in it.
"""

from __future__ import annotations

import numpy as np

from .._jit import inline_kernel, kernel, on_threads, thread_count
from .gather import corner, prim_count, sphere_rows
from .kinds import SPHERE, TRIANGLE

__all__ = ["primitive_extent", "primitive_bounds", "triangle_centroids", "sphere_centroids"]


@inline_kernel
def primitive_extent(kind, geometry, p, k):
    """``(lo, hi)`` of primitive ``p`` on axis ``k``."""
    if kind == SPHERE:
        spheres = sphere_rows(geometry)
        return spheres[p, k] - spheres[p, 3], spheres[p, k] + spheres[p, 3]
    a, b, c = corner(geometry, p, 0, k), corner(geometry, p, 1, k), corner(geometry, p, 2, k)
    return min(a, b, c), max(a, b, c)


@kernel
def _triangle_boxes(geometry, first, end, lo, hi, box):
    """Boxes of triangles ``first:end`` into ``lo``, ``hi``; ``box`` (6,) grown to their union."""
    _boxes(TRIANGLE, geometry, first, end, lo, hi, box)


@kernel
def _sphere_boxes(geometry, first, end, lo, hi, box):
    """Boxes of spheres ``first:end`` into ``lo``, ``hi``; ``box`` (6,) grown to their union."""
    _boxes(SPHERE, geometry, first, end, lo, hi, box)


@inline_kernel
def _boxes(kind, geometry, first, end, lo, hi, box):
    """The pass of the two kernels above, for primitives of ``kind``; ``box`` comes in empty
    (``inf`` lows, ``-inf`` highs) or holding boxes it grows to cover."""
    for p in range(first, end):
        for k in range(3):
            lo[p, k], hi[p, k] = primitive_extent(kind, geometry, p, k)
            box[k] = min(box[k], lo[p, k])
            box[k + 3] = max(box[k + 3], hi[p, k])


@kernel
def _triangle_centroids(geometry, first, end, centroid):
    """Vertex means of triangles ``first:end`` into ``centroid``."""
    for p in range(first, end):
        for k in range(3):
            centroid[p, k] = (corner(geometry, p, 0, k) + corner(geometry, p, 1, k) + corner(geometry, p, 2, k)) / 3.0


def primitive_bounds(kind: int, geometry):
    """``(lo, hi, scene_lo, scene_hi)``: the boxes (n, 3) of the primitives, and the box (3,)
    around them all. Triangles are in a layout of :mod:`.gather` or in rows of 9 floats
    (a mesh's ``(faces, vertices)`` is the indexed layout), spheres in rows ``x, y, z, r``."""
    n = prim_count(geometry)
    lo = np.empty((n, 3))
    hi = np.empty((n, 3))
    chunk_box = np.empty((max(thread_count(), 1), 6))  # on_threads makes at most one chunk per thread
    chunk_box[:, :3] = np.inf
    chunk_box[:, 3:] = -np.inf
    boxes = _sphere_boxes if kind == SPHERE else _triangle_boxes
    on_threads(lambda first, end, c: boxes(geometry, first, end, lo, hi, chunk_box[c]), n)
    return lo, hi, chunk_box[:, :3].min(axis=0), chunk_box[:, 3:].max(axis=0)


def triangle_centroids(geometry) -> np.ndarray:
    """(n, 3) vertex means of triangles, in the layouts :func:`primitive_bounds` takes."""
    n = prim_count(geometry)
    centroid = np.empty((n, 3))
    on_threads(lambda first, end, c: _triangle_centroids(geometry, first, end, centroid), n)
    return centroid


def sphere_centroids(geometry: np.ndarray) -> np.ndarray:
    """(n, 3) centres of spheres stored as rows ``x, y, z, r``, as a new array (builders reorder it)."""
    return geometry[:, :3].copy()
