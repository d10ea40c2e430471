"""Robust ray-sphere intersection.

The quadratic ``a t^2 - 2 b t + c = 0`` with ``a = d.d``, ``b = -f.d``,
``c = f.f - r^2`` (``f`` = origin - centre) is solved as in Haines, Guenther &
Akenine-Moeller, "Precision Improvements for Ray/Sphere Intersection", Ray
Tracing Gems, 2019: the discriminant ``b^2 - a c`` is formed as
``a (r^2 - |f - (f.d / a) d|^2)``, which does not cancel catastrophically for
distant spheres, and the two roots come from ``q = b + sign(b) sqrt(disc)`` as
``q / a`` and ``c / q``, which avoids subtracting nearly equal numbers.
"""

from __future__ import annotations

import math

import numpy as np
from numba import prange

from .._jit import inline_kernel, parallel_kernel

__all__ = ["sphere_span", "intersect_sphere", "cross_sphere", "sphere_hit_coords"]


@inline_kernel
def sphere_span(cx, cy, cz, r, ox, oy, oz, dx, dy, dz):
    """``(t_near, t_far)`` where the ray's line meets the sphere, or ``(inf, -inf)`` when it
    misses it."""
    fx = ox - cx
    fy = oy - cy
    fz = oz - cz
    a = dx * dx + dy * dy + dz * dz
    b = -(fx * dx + fy * dy + fz * dz)
    s = b / a
    lx = fx + s * dx
    ly = fy + s * dy
    lz = fz + s * dz
    disc = a * (r * r - (lx * lx + ly * ly + lz * lz))
    if disc < 0.0:
        return np.inf, -np.inf
    c = fx * fx + fy * fy + fz * fz - r * r
    root = math.sqrt(disc)
    q = b + root if b >= 0.0 else b - root
    if q == 0.0:
        return 0.0, 0.0
    t_near = c / q
    t_far = q / a
    if t_near > t_far:
        return t_far, t_near
    return t_near, t_far


@inline_kernel
def intersect_sphere(geom, prim, ox, oy, oz, dx, dy, dz, t_min, t_max):
    """Nearest ``t`` in ``[t_min, t_max]`` where the ray meets sphere ``geom[prim]``
    (cx, cy, cz, r), or ``inf``. A ray starting inside hits the far side."""
    t_near, t_far = sphere_span(geom[prim, 0], geom[prim, 1], geom[prim, 2], geom[prim, 3],
                                ox, oy, oz, dx, dy, dz)
    if t_near >= t_min and t_near <= t_max:
        return t_near
    if t_far >= t_min and t_far <= t_max:
        return t_far
    return np.inf


@inline_kernel
def cross_sphere(geom, prim, ox, oy, oz, dx, dy, dz, t_min, t_max):
    """``(n, t_first, t_second)``: the ray's ``n`` crossings (0, 1 or 2) of sphere ``geom[prim]``
    within ``[t_min, t_max]``, nearest first; entering and leaving each count, and a tangent ray
    crosses twice at the same ``t`` (so that crossings from outside stay even)."""
    t_near, t_far = sphere_span(geom[prim, 0], geom[prim, 1], geom[prim, 2], geom[prim, 3],
                                ox, oy, oz, dx, dy, dz)
    if t_near > t_far:
        return 0, np.inf, np.inf
    near_in = t_near >= t_min and t_near <= t_max
    far_in = t_far >= t_min and t_far <= t_max
    if near_in and far_in:
        return 2, t_near, t_far
    if near_in:
        return 1, t_near, np.inf
    if far_in:
        return 1, t_far, np.inf
    return 0, np.inf, np.inf


@parallel_kernel
def sphere_hit_coords(geom, origins, directions, t, prim, u, v):
    """Texture coordinates of each ray's hit on its sphere, written into ``u`` and ``v``:
    ``u = azimuth / 2pi`` in [0, 1), ``v = polar angle / pi`` in [0, 1] of the hit point
    seen from the sphere's centre; NaN where ``prim`` is -1 (a miss)."""
    for i in prange(prim.shape[0]):
        p = prim[i]
        if p < 0:
            u[i] = np.nan
            v[i] = np.nan
            continue
        inverse_r = 1.0 / geom[p, 3]
        nx = (origins[i, 0] + t[i] * directions[i, 0] - geom[p, 0]) * inverse_r
        ny = (origins[i, 1] + t[i] * directions[i, 1] - geom[p, 1]) * inverse_r
        nz = (origins[i, 2] + t[i] * directions[i, 2] - geom[p, 2]) * inverse_r
        turn = math.atan2(ny, nx) / (2.0 * math.pi)
        if turn < 0.0:
            turn += 1.0
        u[i] = turn if turn < 1.0 else 0.0
        v[i] = math.acos(min(max(nz, -1.0), 1.0)) / math.pi
