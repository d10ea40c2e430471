"""Exact primitive-box overlap tests, for inserting objects into the cells they touch.

* Triangle-box: the separating axis theorem with the 13 candidate axes (three
  box normals, the triangle normal, nine edge cross products), after
  Akenine-Moeller, "Fast 3D Triangle-Box Overlap Testing", JGT 6(1), 2001.
* Sphere-box: the squared distance from the centre to the box against r^2,
  after Arvo, "A Simple Method for Box-Sphere Intersection Testing", Graphics
  Gems, 1990.

Both tests treat the box as closed; callers pad it for a conservative answer.
"""

from __future__ import annotations

from .._jit import kernel
from .kinds import TRIANGLE

__all__ = ["prim_overlaps_box"]


@kernel
def _separated_on_axis(axis_x, axis_y, axis_z, p0, p1, p2, hx, hy, hz):
    d0 = axis_x * p0[0] + axis_y * p0[1] + axis_z * p0[2]
    d1 = axis_x * p1[0] + axis_y * p1[1] + axis_z * p1[2]
    d2 = axis_x * p2[0] + axis_y * p2[1] + axis_z * p2[2]
    radius = hx * abs(axis_x) + hy * abs(axis_y) + hz * abs(axis_z)
    return min(d0, d1, d2) > radius or max(d0, d1, d2) < -radius


@kernel
def triangle_overlaps_box(geom, prim, cx, cy, cz, hx, hy, hz):
    """Whether triangle ``geom[prim]`` meets the box with centre c and half-sizes h."""
    p0 = (geom[prim, 0] - cx, geom[prim, 1] - cy, geom[prim, 2] - cz)
    p1 = (geom[prim, 3] - cx, geom[prim, 4] - cy, geom[prim, 5] - cz)
    p2 = (geom[prim, 6] - cx, geom[prim, 7] - cy, geom[prim, 8] - cz)
    half = (hx, hy, hz)
    for axis in range(3):
        if min(p0[axis], p1[axis], p2[axis]) > half[axis] or max(p0[axis], p1[axis], p2[axis]) < -half[axis]:
            return False
    edges = (
        (p1[0] - p0[0], p1[1] - p0[1], p1[2] - p0[2]),
        (p2[0] - p1[0], p2[1] - p1[1], p2[2] - p1[2]),
        (p0[0] - p2[0], p0[1] - p2[1], p0[2] - p2[2]),
    )
    for e in edges:
        # unit_x x e, unit_y x e, unit_z x e
        if _separated_on_axis(0.0, -e[2], e[1], p0, p1, p2, hx, hy, hz):
            return False
        if _separated_on_axis(e[2], 0.0, -e[0], p0, p1, p2, hx, hy, hz):
            return False
        if _separated_on_axis(-e[1], e[0], 0.0, p0, p1, p2, hx, hy, hz):
            return False
    e0, e1 = edges[0], edges[1]
    nx = e0[1] * e1[2] - e0[2] * e1[1]
    ny = e0[2] * e1[0] - e0[0] * e1[2]
    nz = e0[0] * e1[1] - e0[1] * e1[0]
    return not _separated_on_axis(nx, ny, nz, p0, p1, p2, hx, hy, hz)


@kernel
def sphere_overlaps_box(geom, prim, cx, cy, cz, hx, hy, hz):
    """Whether sphere ``geom[prim]`` meets the box with centre c and half-sizes h."""
    dx = max(abs(geom[prim, 0] - cx) - hx, 0.0)
    dy = max(abs(geom[prim, 1] - cy) - hy, 0.0)
    dz = max(abs(geom[prim, 2] - cz) - hz, 0.0)
    r = geom[prim, 3]
    return dx * dx + dy * dy + dz * dz <= r * r


@kernel
def prim_overlaps_box(kind, geom, prim, cx, cy, cz, hx, hy, hz):
    """Exact overlap of primitive ``prim`` of the given kind with an axis-aligned box."""
    if kind == TRIANGLE:
        return triangle_overlaps_box(geom, prim, cx, cy, cz, hx, hy, hz)
    return sphere_overlaps_box(geom, prim, cx, cy, cz, hx, hy, hz)
