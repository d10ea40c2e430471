"""Bounds of the part of a primitive that lies inside an axis-aligned box.

Triangles are clipped as polygons against the box's six planes
(Sutherland & Hodgman, "Reentrant Polygon Clipping", CACM 1974); the bounds of
what is left are the tight box that the kd-tree's "perfect splits" need (Havran
2000; Wald & Havran 2006). A vertex created on a plane gets the plane's
coordinate exactly, so clipped bounds never drift past the box.

Spheres keep the conservative answer: their box intersected with the clip
box, kept only when the sphere really meets it (Arvo's distance test).

The clip box is grown by ``slack`` (in scene units) before clipping and the
result is then clamped to the unpadded box: a primitive that touches the box
only within rounding error is kept rather than lost, which is the safe side
for a structure whose cells must reference everything they overlap.
"""

from __future__ import annotations

import numpy as np

from .._jit import inline_kernel, kernel
from ..scene import TRIANGLE
from .overlap import sphere_overlaps_box

__all__ = ["CLIP_VERTICES", "clipped_bounds", "split_clipped_bounds"]

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


@kernel
def _clip_triangle_polygon(geom, prim, box, slack, poly):
    """Clip triangle ``prim`` to ``box`` grown by ``slack``; returns the side of ``poly``
    holding the polygon and its size (0 when nothing is left)."""
    for j in range(3):
        for c in range(3):
            poly[0, j, c] = geom[prim, 3 * j + c]
    n = 3
    src = 0
    for axis in range(3):
        src, n = _clip_polygon(poly, src, n, axis, box[axis] - slack, 1.0)
        if n == 0:
            return src, 0
        src, n = _clip_polygon(poly, src, n, axis, box[axis + 3] + slack, -1.0)
        if n == 0:
            return src, 0
    return src, n


@inline_kernel
def _include(out, x, y, z):
    out[0] = min(out[0], x)
    out[1] = min(out[1], y)
    out[2] = min(out[2], z)
    out[3] = max(out[3], x)
    out[4] = max(out[4], y)
    out[5] = max(out[5], z)


@inline_kernel
def _empty_box(out):
    for c in range(3):
        out[c] = np.inf
        out[c + 3] = -np.inf


@inline_kernel
def _clamp_box(out, box):
    for c in range(3):
        out[c] = min(max(out[c], box[c]), box[c + 3])
        out[c + 3] = min(max(out[c + 3], box[c]), box[c + 3])


@kernel
def _clip_triangle(geom, prim, box, slack, poly, out):
    src, n = _clip_triangle_polygon(geom, prim, box, slack, poly)
    if n == 0:
        return False
    _empty_box(out)
    for j in range(n):
        _include(out, poly[src, j, 0], poly[src, j, 1], poly[src, j, 2])
    _clamp_box(out, box)
    return True


@kernel
def _clip_sphere(geom, prim, box, slack, out):
    hx = 0.5 * (box[3] - box[0]) + slack
    hy = 0.5 * (box[4] - box[1]) + slack
    hz = 0.5 * (box[5] - box[2]) + slack
    if not sphere_overlaps_box(geom, prim, 0.5 * (box[0] + box[3]), 0.5 * (box[1] + box[4]),
                               0.5 * (box[2] + box[5]), hx, hy, hz):
        return False
    r = geom[prim, 3]
    for c in range(3):
        out[c] = min(max(geom[prim, c] - r, box[c]), box[c + 3])
        out[c + 3] = min(max(geom[prim, c] + r, box[c]), box[c + 3])
    return True


@kernel
def _split_triangle(geom, prim, box, axis, plane, slack, poly, out):
    src, n = _clip_triangle_polygon(geom, prim, box, slack, poly)
    if n == 0:
        return 0
    _empty_box(out[0])
    _empty_box(out[1])
    for j in range(n):
        k = j + 1 if j + 1 < n else 0
        a = poly[src, j, axis]
        b = poly[src, k, axis]
        if a <= plane + slack:
            _include(out[0], poly[src, j, 0], poly[src, j, 1], poly[src, j, 2])
        if a >= plane - slack:
            _include(out[1], poly[src, j, 0], poly[src, j, 1], poly[src, j, 2])
        if (a < plane < b) or (b < plane < a):
            s = (plane - a) / (b - a)
            x = poly[src, j, 0] + s * (poly[src, k, 0] - poly[src, j, 0])
            y = poly[src, j, 1] + s * (poly[src, k, 1] - poly[src, j, 1])
            z = poly[src, j, 2] + s * (poly[src, k, 2] - poly[src, j, 2])
            x = plane if axis == 0 else x
            y = plane if axis == 1 else y
            z = plane if axis == 2 else z
            for side in range(2):
                _include(out[side], x, y, z)
    sides = 0
    for side in range(2):
        if out[side, 0] <= out[side, 3]:
            sides |= 1 << side
    return sides


@inline_kernel
def _half_box(box, axis, plane, side, half):
    """``half`` = the part of ``box`` below (side 0) or above (side 1) ``plane`` on ``axis``."""
    half[:] = box
    half[axis + 3 * (1 - side)] = plane


@kernel
def split_clipped_bounds(kind, geom, prim, box, axis, plane, slack, poly, half, out):
    """:func:`clipped_bounds` for the two halves of ``box`` (6,: lo, hi) below and above
    ``plane`` on ``axis``, into ``out[0]`` and ``out[1]``, from one clip of a triangle
    instead of two: the triangle is clipped to ``box`` and its polygon's vertices and
    crossings of the plane are gathered per side. ``half`` is (6,) scratch. Returns a bit
    mask of the halves the primitive meets (1 below, 2 above)."""
    sides = 0
    if kind == TRIANGLE:
        sides = _split_triangle(geom, prim, box, axis, plane, slack, poly, out)
    for side in range(2):
        _half_box(box, axis, plane, side, half)
        if kind == TRIANGLE:
            if sides & (1 << side):
                _clamp_box(out[side], half)
        elif _clip_sphere(geom, prim, half, slack, out[side]):
            sides |= 1 << side
    return sides


@kernel
def clipped_bounds(kind, geom, prim, box, slack, poly, out):
    """Write into ``out`` (6,) the bounds of primitive ``prim`` inside ``box`` (6,: lo, hi);
    return False when it does not meet the box. ``poly`` is (2, CLIP_VERTICES, 3) scratch."""
    if kind == TRIANGLE:
        return _clip_triangle(geom, prim, box, slack, poly, out)
    return _clip_sphere(geom, prim, box, slack, out)

