"""What a walk by distance does at a leaf or cell, shared by every structure's point walk.

A structure's distance walk (``nearest.py`` in its folder) visits leaves or
cells nearest first and skips those whose box lies farther than the best
primitive so far; at each it calls :func:`nearest_in_refs`. The walks keep
only ``(d2, prim)``; :func:`finish_closest` then computes the point and its
coordinates once per query point, from the scene's own geometry.

Ties: at equal squared distance the lower primitive index wins, as
:func:`rayaccel.structures.base.is_closer` rules for rays, so every structure
reports the same primitive as brute force. A node is skipped only when its box
is strictly farther than the best, so an equally near primitive of lower index
in it is still found.
"""

from __future__ import annotations

import math

import numpy as np
from numba import prange

from .._jit import inline_kernel, parallel_kernel
from ..geometry.closest_point import closest_on_prim, distance2_to_prim

__all__ = ["closer_point", "nearest_in_refs", "box_distance2", "finish_closest", "empty_closest"]


@inline_kernel
def closer_point(d2, prim, best_d2, best_prim):
    """Whether primitive ``prim`` at squared distance ``d2`` replaces the best so far; ``best_d2``
    starts as the squared search radius with ``best_prim = -1``."""
    return d2 < best_d2 or (d2 == best_d2 and (best_prim < 0 or prim < best_prim))


@inline_kernel
def nearest_in_refs(kind, geom, refs, first, end, in_leaf_order, px, py, pz, best_d2, best_prim):
    """Test the primitives ``refs[first:end]``; returns the best ``(d2, prim)``, updated. With
    ``in_leaf_order`` the geometry is stored in reference order (row ``k`` is primitive
    ``refs[k]``, as in a BVH); otherwise row ``refs[k]`` of the scene's geometry is read."""
    for k in range(first, end):
        prim = refs[k]
        row = k if in_leaf_order else prim
        d2 = distance2_to_prim(kind, geom, row, px, py, pz)
        if closer_point(d2, prim, best_d2, best_prim):
            best_d2, best_prim = d2, prim
    return best_d2, best_prim


@inline_kernel
def box_distance2(lx, ly, lz, hx, hy, hz, px, py, pz):
    """Squared distance from the point to the box ``l..h`` (0 inside)."""
    dx = max(lx - px, 0.0, px - hx)
    dy = max(ly - py, 0.0, py - hy)
    dz = max(lz - pz, 0.0, pz - hz)
    return dx * dx + dy * dy + dz * dz


@parallel_kernel
def finish_closest(kind, geom, points, prim, out_point, out_distance, out_u, out_v):
    """Fill each found point's closest point, distance and coordinates from its primitive
    (rows with ``prim = -1`` keep NaN, inf, NaN, NaN)."""
    for i in prange(points.shape[0]):
        p = prim[i]
        if p < 0:
            continue
        d2, x, y, z, u, v = closest_on_prim(kind, geom, p, points[i, 0], points[i, 1], points[i, 2])
        out_point[i, 0] = x
        out_point[i, 1] = y
        out_point[i, 2] = z
        out_distance[i] = math.sqrt(d2)
        out_u[i] = u
        out_v[i] = v


def empty_closest(n: int):
    """Output arrays of :func:`finish_closest` for ``n`` points, all 'nothing found'."""
    return (np.full((n, 3), np.nan), np.full(n, np.inf), np.full(n, -1, dtype=np.int64), np.full(n, np.nan),
            np.full(n, np.nan))
