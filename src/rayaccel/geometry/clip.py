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

from .._jit import kernel
from ..scene import TRIANGLE
from .overlap import sphere_overlaps_box

__all__ = ["CLIP_VERTICES", "clipped_bounds"]

CLIP_VERTICES = 10  # a triangle clipped by six planes has at most 3 + 6 vertices; one spare


@kernel
def _clip_polygon(poly, src, n, axis, plane, keep_above):
    """Clip polygon ``poly[src, :n]`` to one half space; write it to ``poly[1 - src]``, return its size."""
    dst = 1 - src
    m = 0
    for j in range(n):
        k = j + 1 if j + 1 < n else 0
        da = poly[src, j, axis] - plane
        db = poly[src, k, axis] - plane
        if not keep_above:
            da = -da
            db = -db
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
    return m


@kernel
def _clip_triangle(geom, prim, box, slack, poly, out):
    for j in range(3):
        for c in range(3):
            poly[0, j, c] = geom[prim, 3 * j + c]
    n = 3
    src = 0
    for axis in range(3):
        n = _clip_polygon(poly, src, n, axis, box[axis] - slack, True)
        src = 1 - src
        if n == 0:
            return False
        n = _clip_polygon(poly, src, n, axis, box[axis + 3] + slack, False)
        src = 1 - src
        if n == 0:
            return False
    for c in range(3):
        lo = poly[src, 0, c]
        hi = lo
        for j in range(1, n):
            lo = min(lo, poly[src, j, c])
            hi = max(hi, poly[src, j, c])
        out[c] = min(max(lo, box[c]), box[c + 3])
        out[c + 3] = min(max(hi, box[c]), box[c + 3])
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
def clipped_bounds(kind, geom, prim, box, slack, poly, out):
    """Write into ``out`` (6,) the bounds of primitive ``prim`` inside ``box`` (6,: lo, hi);
    return False when it does not meet the box. ``poly`` is (2, CLIP_VERTICES, 3) scratch."""
    if kind == TRIANGLE:
        return _clip_triangle(geom, prim, box, slack, poly, out)
    return _clip_sphere(geom, prim, box, slack, out)

