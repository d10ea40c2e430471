"""Bounds of the parts of a primitive on either side of a plane inside a box.

This is what the kd-tree's "perfect splits" need (Havran 2000; Wald & Havran
2006): when a split plane cuts a primitive, each child gets the tight box of
the part of the primitive inside the child's cell.

Triangles are clipped as polygons against the cell's six planes (Sutherland &
Hodgman, "Reentrant Polygon Clipping", CACM 1974); one pass over the
polygon's edges then gathers, for each side of the split plane, the vertices
on that side and the points where edges cross the plane. One clip thus serves
both children. A point created on a plane gets the plane's coordinate
exactly, so bounds never drift past the cell.

Spheres keep the conservative answer: their box intersected with each half
cell, kept only when the sphere really meets it (Arvo's distance test).

The cell is grown by ``slack`` (in scene units) before clipping, a vertex
within ``slack`` of the split plane counts on both sides, and the result is
clamped to the unpadded half cell: a primitive that touches a cell only
within rounding error is kept rather than lost, which is the safe side for a
structure whose cells must reference everything they overlap.
"""

from __future__ import annotations

import numpy as np

from .._jit import inline_kernel, kernel
from .kinds import TRIANGLE
from .overlap import sphere_overlaps_box

__all__ = ["CLIP_VERTICES", "split_clipped_bounds"]

CLIP_VERTICES = 10  # a triangle clipped by six planes has at most 3 + 6 vertices; one spare


@inline_kernel
def _clip_polygon(poly, src, n, axis, plane, sign):
    """Clip polygon ``poly[src, :n]`` to the half space ``sign * (x[axis] - plane) >= 0``.
    Returns the side of ``poly`` that holds the result and its size; a polygon wholly
    inside is left where it is, one wholly outside comes back with size 0."""
    inside = 0
    for j in range(n):
        inside += sign * (poly[src, j, axis] - plane) >= 0.0
    if inside == n or inside == 0:
        return src, (n if inside == n else 0)
    dst = 1 - src
    m = 0
    for j in range(n):
        k = j + 1 if j + 1 < n else 0
        da = sign * (poly[src, j, axis] - plane)
        db = sign * (poly[src, k, axis] - plane)
        if da >= 0.0:
            poly[dst, m, 0] = poly[src, j, 0]
            poly[dst, m, 1] = poly[src, j, 1]
            poly[dst, m, 2] = poly[src, j, 2]
            m += 1
        if (da < 0.0 < db) or (db < 0.0 < da):
            s = da / (da - db)
            for c in range(3):
                poly[dst, m, c] = poly[src, j, c] + s * (poly[src, k, c] - poly[src, j, c])
            poly[dst, m, axis] = plane
            m += 1
    return dst, m


@inline_kernel
def _include(out, side, x, y, z):
    out[side, 0] = min(out[side, 0], x)
    out[side, 1] = min(out[side, 1], y)
    out[side, 2] = min(out[side, 2], z)
    out[side, 3] = max(out[side, 3], x)
    out[side, 4] = max(out[side, 4], y)
    out[side, 5] = max(out[side, 5], z)


@kernel
def _split_triangle(geom, prim, box, axis, plane, slack, poly, out):
    for j in range(3):
        for c in range(3):
            poly[0, j, c] = geom[prim, 3 * j + c]
    n = 3
    src = 0
    for a in range(3):
        src, n = _clip_polygon(poly, src, n, a, box[a] - slack, 1.0)
        if n > 0:
            src, n = _clip_polygon(poly, src, n, a, box[a + 3] + slack, -1.0)
        if n == 0:
            return 0
    for side in range(2):
        for c in range(3):
            out[side, c] = np.inf
            out[side, c + 3] = -np.inf
    for j in range(n):
        k = j + 1 if j + 1 < n else 0
        a = poly[src, j, axis]
        b = poly[src, k, axis]
        if a <= plane + slack:
            _include(out, 0, poly[src, j, 0], poly[src, j, 1], poly[src, j, 2])
        if a >= plane - slack:
            _include(out, 1, poly[src, j, 0], poly[src, j, 1], poly[src, j, 2])
        if (a < plane < b) or (b < plane < a):
            s = (plane - a) / (b - a)
            x = plane if axis == 0 else poly[src, j, 0] + s * (poly[src, k, 0] - poly[src, j, 0])
            y = plane if axis == 1 else poly[src, j, 1] + s * (poly[src, k, 1] - poly[src, j, 1])
            z = plane if axis == 2 else poly[src, j, 2] + s * (poly[src, k, 2] - poly[src, j, 2])
            _include(out, 0, x, y, z)
            _include(out, 1, x, y, z)
    below = 1 if out[0, 0] <= out[0, 3] else 0
    above = 2 if out[1, 0] <= out[1, 3] else 0
    return below | above


@inline_kernel
def _half_bounds(box, axis, plane, side, c):
    """Bounds on axis ``c`` of the half of ``box`` below (side 0) or above (side 1) ``plane``."""
    lo = plane if c == axis and side == 1 else box[c]
    hi = plane if c == axis and side == 0 else box[c + 3]
    return lo, hi


@kernel
def _split_sphere(geom, prim, box, axis, plane, slack, out):
    sides = 0
    r = geom[prim, 3]
    for side in range(2):
        x0, x1 = _half_bounds(box, axis, plane, side, 0)
        y0, y1 = _half_bounds(box, axis, plane, side, 1)
        z0, z1 = _half_bounds(box, axis, plane, side, 2)
        if not sphere_overlaps_box(geom, prim, 0.5 * (x0 + x1), 0.5 * (y0 + y1), 0.5 * (z0 + z1),
                                   0.5 * (x1 - x0) + slack, 0.5 * (y1 - y0) + slack, 0.5 * (z1 - z0) + slack):
            continue
        sides |= 1 << side
        for c in range(3):
            lo, hi = _half_bounds(box, axis, plane, side, c)
            out[side, c] = min(max(geom[prim, c] - r, lo), hi)
            out[side, c + 3] = min(max(geom[prim, c] + r, lo), hi)
    return sides


@kernel
def split_clipped_bounds(kind, geom, prim, box, axis, plane, slack, poly, out):
    """Bounds of the parts of primitive ``prim`` inside ``box`` (6,: lo, hi) below and above
    ``plane`` on ``axis``, written to ``out[0]`` and ``out[1]`` ((2, 6) array); ``poly`` is
    (2, CLIP_VERTICES, 3) scratch. Returns a bit mask of the halves the primitive meets
    (1 below, 2 above)."""
    if kind != TRIANGLE:
        return _split_sphere(geom, prim, box, axis, plane, slack, out)
    sides = _split_triangle(geom, prim, box, axis, plane, slack, poly, out)
    for side in range(2):
        for c in range(3):
            lo, hi = _half_bounds(box, axis, plane, side, c)
            out[side, c] = min(max(out[side, c], lo), hi)
            out[side, c + 3] = min(max(out[side, c + 3], lo), hi)
    return sides
