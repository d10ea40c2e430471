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

from .._jit import inline_kernel

__all__ = ["sphere_span", "intersect_sphere"]


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
