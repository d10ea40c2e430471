"""Watertight ray-triangle intersection.

Woop, Benthin & Wald, "Watertight Ray/Triangle Intersection", Journal of
Computer Graphics Techniques 2(1), 2013. The ray is sheared so that it runs
along +z through the origin; each edge function is then a 2D cross product of
two sheared vertices, computed bit-identically for both triangles that share
the edge (with opposite sign), so a ray through a shared edge or vertex of a
closed mesh always hits at least one of them. Edge functions that are exactly
zero count as inside. Everything is float64, which the paper's fallback for
zero edge functions asks for anyway. A triangle whose projected area (det) is
within rounding error of zero is degenerate and never hit, so that no
structure can disagree with another about a hit computed from noise.
"""

from __future__ import annotations

import numpy as np

from .._jit import inline_kernel

__all__ = ["shear_setup", "intersect_triangle"]

_DEGENERATE = 1e-13  # relative size of det below which a triangle counts as degenerate


@inline_kernel
def shear_setup(dx, dy, dz):
    """Per-ray constants ``(kx, ky, kz, sx, sy, sz)``: the dominant axis ``kz`` of the
    direction, the two others ordered to keep the winding, and the shear."""
    ax, ay, az = abs(dx), abs(dy), abs(dz)
    if ax >= ay and ax >= az:
        kz = 0
    elif ay >= az:
        kz = 1
    else:
        kz = 2
    kx = kz + 1 if kz < 2 else 0
    ky = kx + 1 if kx < 2 else 0
    d = (dx, dy, dz)
    if d[kz] < 0.0:
        kx, ky = ky, kx
    sz = 1.0 / d[kz]
    return kx, ky, kz, d[kx] * sz, d[ky] * sz, sz


@inline_kernel
def intersect_triangle(geom, prim, ox, oy, oz, kx, ky, kz, sx, sy, sz, t_min, t_max):
    """Hit of the ray with triangle ``geom[prim]`` (v0, v1, v2 as 9 floats).

    Returns ``(t, u, v)`` with the hit point ``(1-u-v)*v0 + u*v1 + v*v2`` and
    ``t_min <= t <= t_max``, or ``(inf, 0, 0)`` when there is no such hit.
    Degenerate triangles and rays in the triangle's plane never hit.
    """
    origin = (ox, oy, oz)
    okx, oky, okz = origin[kx], origin[ky], origin[kz]
    az_ = geom[prim, kz] - okz
    bz_ = geom[prim, 3 + kz] - okz
    cz_ = geom[prim, 6 + kz] - okz
    ax_ = (geom[prim, kx] - okx) - sx * az_
    ay_ = (geom[prim, ky] - oky) - sy * az_
    bx_ = (geom[prim, 3 + kx] - okx) - sx * bz_
    by_ = (geom[prim, 3 + ky] - oky) - sy * bz_
    cx_ = (geom[prim, 6 + kx] - okx) - sx * cz_
    cy_ = (geom[prim, 6 + ky] - oky) - sy * cz_
    # Each edge function is p.x*q.y - p.y*q.x over the edge (p, q) taken in
    # cyclic order, so a shared edge gives exactly the negated value.
    e0 = cx_ * by_ - cy_ * bx_
    e1 = ax_ * cy_ - ay_ * cx_
    e2 = bx_ * ay_ - by_ * ax_
    if (e0 < 0.0 or e1 < 0.0 or e2 < 0.0) and (e0 > 0.0 or e1 > 0.0 or e2 > 0.0):
        return np.inf, 0.0, 0.0
    det = e0 + e1 + e2
    # A triangle that is degenerate (collinear vertices) has det = 0 exactly, but its rounded
    # edge functions can leave a tiny det of either sign and a meaningless t; any det within
    # the rounding error of its six products counts as zero.
    size = (abs(cx_ * by_) + abs(cy_ * bx_) + abs(ax_ * cy_) + abs(ay_ * cx_) + abs(bx_ * ay_)
            + abs(by_ * ax_))
    if abs(det) <= _DEGENERATE * size:
        return np.inf, 0.0, 0.0
    t = sz * (e0 * az_ + e1 * bz_ + e2 * cz_) / det
    if t >= t_min and t <= t_max:
        return t, e1 / det, e2 / det
    return np.inf, 0.0, 0.0
