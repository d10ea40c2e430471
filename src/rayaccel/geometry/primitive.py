"""One entry point for ray-primitive tests, whatever the scene's primitive kind."""

from __future__ import annotations

import numpy as np

from .._jit import inline_kernel
from .gather import sphere_rows
from .kinds import TRIANGLE
from .sphere import cross_sphere, intersect_sphere
from .triangle import axis_value, cross_triangle, intersect_triangle, shear_setup

__all__ = ["ray_setup", "RAY_FLOATS", "RAY_INTS", "store_ray", "load_ray", "intersect_prim", "cross_prim"]

RAY_FLOATS = 12
"""Floats of :func:`ray_setup`'s constants, as :func:`store_ray` keeps them."""
RAY_INTS = 3
"""Integers of :func:`ray_setup`'s constants (the shear's axes)."""


@inline_kernel
def ray_setup(ox, oy, oz, dx, dy, dz):
    """The per-ray constants :func:`intersect_prim` takes, computed once per ray: the ray, the
    axes and shear of :func:`.triangle.shear_setup`, and the origin's coordinates on those axes."""
    kx, ky, kz, sx, sy, sz = shear_setup(dx, dy, dz)
    return (ox, oy, oz, dx, dy, dz, kx, ky, kz, sx, sy, sz, axis_value(kx, ox, oy, oz), axis_value(ky, ox, oy, oz),
            axis_value(kz, ox, oy, oz))


@inline_kernel
def store_ray(ray, floats, ints, slot):
    """Keep :func:`ray_setup`'s constants in row ``slot`` of ``floats`` (its first
    :data:`RAY_FLOATS` columns) and of ``ints`` (its first :data:`RAY_INTS`), for a walk that
    puts a ray aside and takes it up again (:func:`load_ray`)."""
    ox, oy, oz, dx, dy, dz, kx, ky, kz, sx, sy, sz, okx, oky, okz = ray
    floats[slot, 0], floats[slot, 1], floats[slot, 2] = ox, oy, oz
    floats[slot, 3], floats[slot, 4], floats[slot, 5] = dx, dy, dz
    floats[slot, 6], floats[slot, 7], floats[slot, 8] = sx, sy, sz
    floats[slot, 9], floats[slot, 10], floats[slot, 11] = okx, oky, okz
    ints[slot, 0], ints[slot, 1], ints[slot, 2] = kx, ky, kz


@inline_kernel
def load_ray(floats, ints, slot):
    """The constants :func:`store_ray` kept in row ``slot``."""
    return (floats[slot, 0], floats[slot, 1], floats[slot, 2], floats[slot, 3], floats[slot, 4], floats[slot, 5],
            ints[slot, 0], ints[slot, 1], ints[slot, 2], floats[slot, 6], floats[slot, 7], floats[slot, 8],
            floats[slot, 9], floats[slot, 10], floats[slot, 11])


@inline_kernel
def intersect_prim(kind, geom, prim, ray, t_min, t_max):
    """``(t, u, v)`` of the ray's hit with primitive ``prim`` in ``[t_min, t_max]``,
    ``t = inf`` on a miss; ``u, v`` are triangle barycentrics (0 for spheres)."""
    ox, oy, oz, dx, dy, dz, kx, ky, kz, sx, sy, sz, okx, oky, okz = ray
    if kind == TRIANGLE:
        return intersect_triangle(geom, prim, okx, oky, okz, kx, ky, kz, sx, sy, sz, t_min, t_max)
    return intersect_sphere(sphere_rows(geom), prim, ox, oy, oz, dx, dy, dz, t_min, t_max), 0.0, 0.0


@inline_kernel
def cross_prim(kind, geom, prim, ray, t_min, t_max):
    """``(n, t_first, t_second, u, v, side)``: the ray's ``n`` crossings of primitive ``prim`` in
    ``[t_min, t_max]``, nearest first (``inf`` where absent). A triangle is crossed at most
    once, under the tie rule of :func:`.triangle.cross_triangle`, with barycentrics ``u, v``
    and ``side`` +1 where the ray leaves through its front, -1 through its back; a sphere up
    to twice (:func:`.sphere.cross_sphere`), ``u = v = 0``, ``side`` +1."""
    ox, oy, oz, dx, dy, dz, kx, ky, kz, sx, sy, sz, okx, oky, okz = ray
    if kind == TRIANGLE:
        t, u, v, det = cross_triangle(geom, prim, okx, oky, okz, kx, ky, kz, sx, sy, sz, t_min, t_max)
        return (0 if t == np.inf else 1), t, np.inf, u, v, (1 if det < 0.0 else -1)
    n, t_first, t_second = cross_sphere(sphere_rows(geom), prim, ox, oy, oz, dx, dy, dz, t_min, t_max)
    return n, t_first, t_second, 0.0, 0.0, 1
