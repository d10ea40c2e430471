"""Closest point on a primitive to a query point.

Triangles: region classification of Ericson, "Real-Time Collision Detection"
(Morgan Kaufmann 2005), section 5.1.5: the point is tested against the
Voronoi regions of the three vertices, then of the three edges, and
otherwise projects into the face. A degenerate triangle (zero area, or so
thin that the face region's barycentrics would divide by rounding noise) is
answered as the closest of its three edges. The result's barycentrics
``u, v`` follow :class:`rayaccel.Hits`: the point is
``(1 - u - v) * v0 + u * v1 + v * v2``.

Spheres: the point on the surface along the ray from the centre through the
query point, ``u, v`` the texture coordinates of
:func:`rayaccel.geometry.sphere.sphere_hit_coords`. A query point exactly at
the centre has every surface point at distance ``r``; the north pole
``centre + (0, 0, r)`` (``u = v = 0``) is reported.
"""

from __future__ import annotations

import math

from .._jit import inline_kernel, kernel
from .gather import corner, sphere_rows
from .kinds import TRIANGLE

__all__ = ["closest_on_triangle", "closest_on_sphere", "closest_on_prim", "distance2_to_prim"]

# Below this ratio |ab x ac|^2 / (|ab|^2 |ac|^2) (the squared sine of the triangle's angle
# at a) the face region is not trusted and the three edges answer instead.
_THIN = 1e-20


@inline_kernel
def _closest_on_segment(ax, ay, az, bx, by, bz, px, py, pz):
    """``(t, d2)``: the parameter of the closest point ``a + t (b - a)`` and its squared distance."""
    ex, ey, ez = bx - ax, by - ay, bz - az
    ee = ex * ex + ey * ey + ez * ez
    t = 0.0
    if ee > 0.0:
        t = ((px - ax) * ex + (py - ay) * ey + (pz - az) * ez) / ee
        t = min(max(t, 0.0), 1.0)
    dx = ax + t * ex - px
    dy = ay + t * ey - py
    dz = az + t * ez - pz
    return t, dx * dx + dy * dy + dz * dz


@inline_kernel
def _closest_on_edges(ax, ay, az, bx, by, bz, cx, cy, cz, px, py, pz):
    """Closest point of the three edges, as ``(u, v)``."""
    t, d2 = _closest_on_segment(ax, ay, az, bx, by, bz, px, py, pz)
    u, v = t, 0.0
    t, e2 = _closest_on_segment(ax, ay, az, cx, cy, cz, px, py, pz)
    if e2 < d2:
        d2, u, v = e2, 0.0, t
    t, e2 = _closest_on_segment(bx, by, bz, cx, cy, cz, px, py, pz)
    if e2 < d2:
        u, v = 1.0 - t, t
    return u, v


@inline_kernel
def closest_on_triangle(ax, ay, az, bx, by, bz, cx, cy, cz, px, py, pz):
    """``(d2, x, y, z, u, v)``: squared distance, closest point and its barycentrics."""
    abx, aby, abz = bx - ax, by - ay, bz - az
    acx, acy, acz = cx - ax, cy - ay, cz - az
    apx, apy, apz = px - ax, py - ay, pz - az
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    bpx, bpy, bpz = px - bx, py - by, pz - bz
    d3 = abx * bpx + aby * bpy + abz * bpz
    d4 = acx * bpx + acy * bpy + acz * bpz
    cpx, cpy, cpz = px - cx, py - cy, pz - cz
    d5 = abx * cpx + aby * cpy + abz * cpz
    d6 = acx * cpx + acy * cpy + acz * cpz
    nx = aby * acz - abz * acy
    ny = abz * acx - abx * acz
    nz = abx * acy - aby * acx
    nn = nx * nx + ny * ny + nz * nz
    thin = nn <= _THIN * (abx * abx + aby * aby + abz * abz) * (acx * acx + acy * acy + acz * acz)
    if thin:
        u, v = _closest_on_edges(ax, ay, az, bx, by, bz, cx, cy, cz, px, py, pz)
    elif d1 <= 0.0 and d2 <= 0.0:
        u, v = 0.0, 0.0
    elif d3 >= 0.0 and d4 <= d3:
        u, v = 1.0, 0.0
    elif d6 >= 0.0 and d5 <= d6:
        u, v = 0.0, 1.0
    else:
        vc = d1 * d4 - d3 * d2
        vb = d5 * d2 - d1 * d6
        va = d3 * d6 - d5 * d4
        if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
            u, v = d1 / (d1 - d3), 0.0
        elif vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
            u, v = 0.0, d2 / (d2 - d6)
        elif va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
            w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
            u, v = 1.0 - w, w
        else:
            denom = 1.0 / (va + vb + vc)
            u, v = vb * denom, vc * denom
    x = ax + u * abx + v * acx
    y = ay + u * aby + v * acy
    z = az + u * abz + v * acz
    dx, dy, dz = x - px, y - py, z - pz
    return dx * dx + dy * dy + dz * dz, x, y, z, u, v


@inline_kernel
def closest_on_sphere(cx, cy, cz, r, px, py, pz):
    """``(d2, x, y, z, u, v)`` for the sphere's surface (see the module docstring)."""
    fx, fy, fz = px - cx, py - cy, pz - cz
    length = math.sqrt(fx * fx + fy * fy + fz * fz)
    if length == 0.0:
        return r * r, cx, cy, cz + r, 0.0, 0.0
    nx, ny, nz = fx / length, fy / length, fz / length
    gap = length - r
    turn = math.atan2(ny, nx) / (2.0 * math.pi)
    if turn < 0.0:
        turn += 1.0
    u = turn if turn < 1.0 else 0.0
    v = math.acos(min(max(nz, -1.0), 1.0)) / math.pi
    return gap * gap, cx + r * nx, cy + r * ny, cz + r * nz, u, v


@inline_kernel
def closest_on_prim(kind, geom, row, px, py, pz):
    """``(d2, x, y, z, u, v)`` for primitive row ``row`` of ``geom``, whatever the scene's kind."""
    if kind == TRIANGLE:
        return closest_on_triangle(corner(geom, row, 0, 0), corner(geom, row, 0, 1), corner(geom, row, 0, 2),
                                   corner(geom, row, 1, 0), corner(geom, row, 1, 1), corner(geom, row, 1, 2),
                                   corner(geom, row, 2, 0), corner(geom, row, 2, 1), corner(geom, row, 2, 2),
                                   px, py, pz)
    spheres = sphere_rows(geom)
    return closest_on_sphere(spheres[row, 0], spheres[row, 1], spheres[row, 2], spheres[row, 3], px, py, pz)


@kernel
def distance2_to_prim(kind, geom, row, px, py, pz):
    """Squared distance from the point to primitive row ``row``: :func:`closest_on_prim`'s first
    value, without a sphere's texture coordinates. Not inlined at Numba's IR level: every
    walk calls it from several places, and inlining it there multiplied their compile times."""
    if kind == TRIANGLE:
        return closest_on_prim(kind, geom, row, px, py, pz)[0]
    spheres = sphere_rows(geom)
    fx, fy, fz = px - spheres[row, 0], py - spheres[row, 1], pz - spheres[row, 2]
    length = math.sqrt(fx * fx + fy * fy + fz * fz)
    if length == 0.0:
        return spheres[row, 3] * spheres[row, 3]
    gap = length - spheres[row, 3]
    return gap * gap
