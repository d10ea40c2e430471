"""Watertight ray-triangle intersection.

Woop, Benthin & Wald, "Watertight Ray/Triangle Intersection", Journal of
Computer Graphics Techniques 2(1), 2013. The ray is sheared so that it runs
along +z through the origin; each edge function is then a 2D cross product of
two sheared vertices, computed bit-identically for both triangles that share
the edge (with opposite sign), so a ray through a shared edge or vertex of a
closed mesh always hits at least one of them. For the closest hit
(:func:`intersect_triangle`) edge functions that are exactly zero count as
inside; for counting crossings (:func:`cross_triangle`) a tie rule gives each
crossing of a shared edge or vertex to exactly one triangle. Everything is float64, which the paper's fallback for
zero edge functions asks for anyway; the corners are read through :func:`.gather.corner`, from either
layout of :mod:`.gather` or from the scene's (n, 9) float64 rows. A triangle whose projected area (det) is
within rounding error of zero is degenerate and never hit, so that no
structure can disagree with another about a hit computed from noise.
"""

from __future__ import annotations

import numpy as np

from .._jit import inline_kernel
from .gather import corner

__all__ = ["axis_value", "shear_setup", "intersect_triangle", "cross_triangle", "DEGENERATE"]

DEGENERATE = 1e-13
"""Relative size of ``det`` (to the sum of its six products' magnitudes) at or below which a
triangle counts as degenerate."""


@inline_kernel
def axis_value(k, x, y, z):
    """``(x, y, z)[k]`` for an axis ``k`` known only at run time, as selects: indexing the tuple
    by ``k`` compiles to a jump table whose branches spill the ray's values to the stack."""
    return x if k == 0 else (y if k == 1 else z)


@inline_kernel
def shear_setup(dx, dy, dz):
    """Per-ray constants ``(kx, ky, kz, sx, sy, sz)``: the dominant axis ``kz`` of the
    direction, the two others ordered to keep the winding, and the shear."""
    ax, ay, az = abs(dx), abs(dy), abs(dz)
    x_largest = (ax >= ay) & (ax >= az)
    kz = 0 if x_largest else (1 if ay >= az else 2)
    kx = kz + 1 if kz < 2 else 0
    ky = kx + 1 if kx < 2 else 0
    d_kz = axis_value(kz, dx, dy, dz)
    flip = d_kz < 0.0
    kx, ky = (ky if flip else kx), (kx if flip else ky)
    sz = 1.0 / d_kz
    return kx, ky, kz, axis_value(kx, dx, dy, dz) * sz, axis_value(ky, dx, dy, dz) * sz, sz


@inline_kernel
def _sheared_vertices(geom, prim, okx, oky, okz, kx, ky, kz, sx, sy):
    """The triangle's vertices relative to the ray origin (``okx, oky, okz``: its coordinates
    on the axes ``kx, ky, kz``), sheared so that the ray runs along +z: ``(ax, ay, bx, by, cx,
    cy, az, bz, cz)``, z not yet scaled by ``sz``."""
    az_ = corner(geom, prim, 0, kz) - okz
    bz_ = corner(geom, prim, 1, kz) - okz
    cz_ = corner(geom, prim, 2, kz) - okz
    ax_ = (corner(geom, prim, 0, kx) - okx) - sx * az_
    ay_ = (corner(geom, prim, 0, ky) - oky) - sy * az_
    bx_ = (corner(geom, prim, 1, kx) - okx) - sx * bz_
    by_ = (corner(geom, prim, 1, ky) - oky) - sy * bz_
    cx_ = (corner(geom, prim, 2, kx) - okx) - sx * cz_
    cy_ = (corner(geom, prim, 2, ky) - oky) - sy * cz_
    return ax_, ay_, bx_, by_, cx_, cy_, az_, bz_, cz_


@inline_kernel
def _hit_from_edges(e0, e1, e2, ax_, ay_, bx_, by_, cx_, cy_, az_, bz_, cz_, sz, t_min, t_max):
    """``(t, u, v, det)`` of a ray inside the triangle's edges, or ``(inf, 0, 0, 0)`` when the
    triangle is degenerate or the hit lies outside ``[t_min, t_max]``; ``det < 0`` where the ray
    leaves through the triangle's front (the side its counter-clockwise normal points to)."""
    det = e0 + e1 + e2
    # A triangle that is degenerate (collinear vertices) has det = 0 exactly, but its rounded
    # edge functions can leave a tiny det of either sign and a meaningless t; any det within
    # the rounding error of its six products counts as zero.
    size = (abs(cx_ * by_) + abs(cy_ * bx_) + abs(ax_ * cy_) + abs(ay_ * cx_) + abs(bx_ * ay_)
            + abs(by_ * ax_))
    if abs(det) <= DEGENERATE * size:
        return np.inf, 0.0, 0.0, 0.0
    t = sz * (e0 * az_ + e1 * bz_ + e2 * cz_) / det
    if t >= t_min and t <= t_max:
        return t, e1 / det, e2 / det, det
    return np.inf, 0.0, 0.0, 0.0


@inline_kernel
def _edge_sign(e, px, py, qx, qy):
    """The sign (+1 or -1) of the edge function ``e = p x q``, where ``e`` is exactly zero
    resolved as ``e`` at the ray moved by ``(eps, eps^2)``: ``e + eps (p - q).y - eps^2 (p - q).x``."""
    if e > 0.0:
        return 1
    if e < 0.0:
        return -1
    wy = py - qy
    if wy > 0.0 or (wy == 0.0 and px - qx < 0.0):
        return 1
    return -1


@inline_kernel
def _triangle_hit(geom, prim, okx, oky, okz, kx, ky, kz, sx, sy, sz, t_min, t_max, one_owner):
    """The test behind :func:`intersect_triangle` (``one_owner`` False: zero edge functions count
    as inside) and :func:`cross_triangle` (True: they are resolved by :func:`_edge_sign`)."""
    ax_, ay_, bx_, by_, cx_, cy_, az_, bz_, cz_ = _sheared_vertices(geom, prim, okx, oky, okz, kx, ky, kz, sx, sy)
    # Each edge function is p.x*q.y - p.y*q.x over the edge (p, q) taken in
    # cyclic order, so a shared edge gives exactly the negated value.
    e0 = cx_ * by_ - cy_ * bx_
    e1 = ax_ * cy_ - ay_ * cx_
    e2 = bx_ * ay_ - by_ * ax_
    # Bitwise, not short-circuit: one branch for the verdict instead of up to six, each hard to
    # predict (full dragon, one thread: 1.06-1.11 in every column; the forest 0.93-1.04).
    if ((e0 < 0.0) | (e1 < 0.0) | (e2 < 0.0)) & ((e0 > 0.0) | (e1 > 0.0) | (e2 > 0.0)):
        return np.inf, 0.0, 0.0, 0.0
    if one_owner and (e0 == 0.0 or e1 == 0.0 or e2 == 0.0):
        s0 = _edge_sign(e0, cx_, cy_, bx_, by_)
        s1 = _edge_sign(e1, ax_, ay_, cx_, cy_)
        s2 = _edge_sign(e2, bx_, by_, ax_, ay_)
        if s0 != s1 or s1 != s2:
            return np.inf, 0.0, 0.0, 0.0
    return _hit_from_edges(e0, e1, e2, ax_, ay_, bx_, by_, cx_, cy_, az_, bz_, cz_, sz, t_min, t_max)


@inline_kernel
def intersect_triangle(geom, prim, okx, oky, okz, kx, ky, kz, sx, sy, sz, t_min, t_max):
    """Hit of the ray with triangle ``geom[prim]`` (v0, v1, v2 as 9 floats); the ray is given by
    :func:`shear_setup`'s axes and shear and by its origin's coordinates on those axes
    (``okx, oky, okz``), all computed once per ray.

    Returns ``(t, u, v)`` with the hit point ``(1-u-v)*v0 + u*v1 + v*v2`` and
    ``t_min <= t <= t_max``, or ``(inf, 0, 0)`` when there is no such hit.
    Degenerate triangles and rays in the triangle's plane never hit. A ray through
    an edge or vertex hits every triangle there (see :func:`cross_triangle` for
    the test that gives each crossing to one triangle).
    """
    t, u, v, _ = _triangle_hit(geom, prim, okx, oky, okz, kx, ky, kz, sx, sy, sz, t_min, t_max, False)
    return t, u, v


@inline_kernel
def cross_triangle(geom, prim, okx, oky, okz, kx, ky, kz, sx, sy, sz, t_min, t_max):
    """:func:`intersect_triangle` with each crossing given to exactly one triangle.

    Where an edge function is exactly zero (the ray passes through an edge or a
    vertex), the triangle owns the point only if it would contain the ray moved
    by an infinitesimal ``(eps, eps^2)`` in the sheared plane (:func:`_edge_sign`):
    a simulation of simplicity (Edelsbrunner & Muecke, ACM TOG 9(1), 1990) that
    amounts to the top-left fill rule of rasterisers (Pineda, "A Parallel
    Algorithm for Polygon Rasterization", SIGGRAPH 1988; Direct3D's rasterisation
    rules), whose edge tests hold by the edge's direction alone. The two triangles
    of a shared edge see it with the interior on opposite sides, so one owns it;
    the triangles around a vertex tile its neighbourhood, so one owns it; a
    silhouette edge or vertex is owned by both triangles or by neither. A closed
    mesh is therefore crossed an odd number of times from inside and an even
    number from outside, whatever the mesh's orientation. Both triangles of a
    shared edge compute the same sheared vertices bit for bit, so they decide alike.
    Returns ``(t, u, v, det)``: ``det < 0`` where the ray leaves through the triangle's
    front, so that the crossings signed by it sum to the winding number.
    """
    return _triangle_hit(geom, prim, okx, oky, okz, kx, ky, kz, sx, sy, sz, t_min, t_max, True)
