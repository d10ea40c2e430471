"""Any-hit queries settled by the scene's few large primitives before the walk.

A primitive that covers much of the scene (a ground plane, the walls of a room) is met by a large
share of all rays, yet a walk only reaches it after the cells or leaves that lie before it on the
ray: a kd-tree, a grid or an octree references it from every cell it crosses (a BVH meets it
near its root and is left as it is). Testing those few primitives first and walking only the rays
they leave unsettled is the idea of Haines & Greenberg's light buffer ("The Light Buffer: A Shadow-Testing
Accelerator", IEEE CG&A 6(9), 1986), which tests first the occluders most likely to answer a
shadow ray, applied to every any-hit query; which ones are likely follows from the geometric
probability behind the surface area heuristic (Goldsmith & Salmon, IEEE CG&A 7(5), 1987; MacDonald
& Booth, The Visual Computer 6(3), 1990): a convex object inside a box is met by the share
``area / box_area`` of the lines through the box, counting both faces of a flat one.

Measured on forest-small-chair (2**19 incoherent rays, the kd-tree, one thread): 43 % of the rays
meet its ground, and their any-hit walk took 35 % of the batch's time; a batch is settled this way
only when a sample of its rays shows that enough of them meet a large primitive to pay for testing
every ray (camera rays, 84 % of which miss the forest's box, and shadow rays leaving the ground do
not).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .._jit import chunk_kernel, inline_kernel, kernel, on_threads
from .._validate import unusable_ray
from ..geometry.kinds import TRIANGLE
from ..geometry.primitive import intersect_prim, ray_setup
from ..rays import RayBatch, ray_at, ray_limit, result_row
from .actions import NEAREST, finish_ray_in_mode, hit_flags

__all__ = ["LARGE_SHARE", "MAX_LARGE", "SAMPLED_RAYS", "MIN_SETTLED_SHARE", "LargePrimitives", "large_primitives",
           "unsettled_rays"]

LARGE_SHARE = 1 / 8
"""Share of the lines through the scene's box a primitive must meet to be tested first."""

MAX_LARGE = 8
"""Most primitives tested first (the largest, when more are large)."""

SAMPLED_RAYS = 256
"""Fewest rays of a batch, evenly spaced, tested first to decide whether all of them are (a batch of
fewer rays is left to the walk)."""

MIN_SETTLED_SHARE = 1 / 4
"""Share of the sampled rays that must meet a large primitive for the whole batch to be tested."""


class LargePrimitives(NamedTuple):
    """The primitives tested first: their indices ``prims`` (k,) and their rows ``geom`` in the
    scene's layout (triangles (k, 9), spheres (k, 4)), largest first."""

    prims: np.ndarray
    geom: np.ndarray


def large_primitives(scene, scene_lo, scene_hi) -> LargePrimitives:
    """The primitives of ``scene`` met by :data:`LARGE_SHARE` or more of the lines through the box
    ``scene_lo, scene_hi``, at most :data:`MAX_LARGE`: a triangle's two faces, ``2 * area``, or a
    sphere's ``4 pi r**2``, against the box's area."""
    extent = np.asarray(scene_hi, dtype=np.float64) - np.asarray(scene_lo, dtype=np.float64)
    box_area = 2.0 * (extent[0] * extent[1] + extent[1] * extent[2] + extent[2] * extent[0])
    if scene.kind == TRIANGLE:
        surface = np.empty(len(scene))
        _triangle_surfaces(scene.faces, scene.vertices, surface)
    else:
        surface = 4.0 * np.pi * scene.radii ** 2
    large = np.flatnonzero(surface >= LARGE_SHARE * box_area)
    prims = large[np.argsort(-surface[large], kind="stable")][:MAX_LARGE]
    if scene.kind == TRIANGLE:
        geom = np.ascontiguousarray(scene.vertices[scene.faces[prims]].reshape(-1, 9))
    else:
        geom = np.ascontiguousarray(scene.geometry[prims])
    return LargePrimitives(prims.astype(np.int64), geom)


@kernel
def _triangle_surfaces(faces, vertices, out):
    """Each triangle's two faces' area, ``|(b - a) x (c - a)|``, into ``out``: one pass without the
    temporary arrays of numpy's (100 ms on the full dragon)."""
    for f in range(faces.shape[0]):
        a, b, c = faces[f, 0], faces[f, 1], faces[f, 2]
        ex, ey, ez = vertices[b, 0] - vertices[a, 0], vertices[b, 1] - vertices[a, 1], vertices[b, 2] - vertices[a, 2]
        gx, gy, gz = vertices[c, 0] - vertices[a, 0], vertices[c, 1] - vertices[a, 1], vertices[c, 2] - vertices[a, 2]
        nx, ny, nz = ey * gz - ez * gy, ez * gx - ex * gz, ex * gy - ey * gx
        out[f] = np.sqrt(nx * nx + ny * ny + nz * nz)


@inline_kernel
def _first_large_hit(kind, geom, origins, directions, t_min, t_max, i):
    """``(k, t, u, v)``: the first of the large primitives (row ``k`` of ``geom``) ray ``i`` meets
    within its interval, ``k = -1`` when none or when the ray is unusable (left to the walk)."""
    ox, oy, oz, dx, dy, dz = ray_at(origins, directions, i)
    if unusable_ray(ox, oy, oz, dx, dy, dz):
        return -1, np.inf, 0.0, 0.0
    ray = ray_setup(ox, oy, oz, dx, dy, dz)
    ray_t_min, ray_t_max = ray_limit(t_min, i), ray_limit(t_max, i)
    for k in range(geom.shape[0]):
        t, u, v = intersect_prim(kind, geom, k, ray, ray_t_min, ray_t_max)
        if t != np.inf:
            return k, t, u, v
    return -1, np.inf, 0.0, 0.0


@chunk_kernel
def _settle_kernel(ray_first, ray_end, tid, kind, geom, prims, origins, directions, t_min, t_max, hit_slot, action,
                   settled):
    """Write the any-hit answer of each of the rays ``ray_first`` to ``ray_end - 1`` that meets a large
    primitive into the action's row for it, and mark those rays in ``settled``."""
    for i in range(ray_first, ray_end):
        k, t, u, v = _first_large_hit(kind, geom, origins, directions, t_min, t_max, i)
        settled[i] = k >= 0
        if k >= 0:
            finish_ray_in_mode(NEAREST, action, result_row(hit_slot, i), t, prims[k], u, v)


def unsettled_rays(large: LargePrimitives, kind: int, rays: RayBatch, action) -> RayBatch | None:
    """The rays of an any-hit query left for the walk once the large primitives have answered those
    that meet one (their rows of ``action`` written): ``rays`` itself when a sample of
    :data:`SAMPLED_RAYS` says too few would, a batch of the others (``hit_slot`` naming their rows)
    otherwise, ``None`` when none is left."""
    n = rays.size
    if not len(large.prims) or n < SAMPLED_RAYS:
        return rays
    sample = _rays_in_rows(rays, slice(None, None, n // SAMPLED_RAYS), rays.hit_slot[:0])
    sampled = sample.size
    settled = np.empty(sampled, dtype=np.bool_)
    _settle_kernel(0, sampled, 0, kind, large.geom, large.prims, *sample, hit_flags(np.empty(sampled, dtype=np.bool_)),
                   settled)
    if np.count_nonzero(settled) < MIN_SETTLED_SHARE * sampled:
        return rays
    settled = np.empty(n, dtype=np.bool_)
    on_threads(lambda first, end, tid: _settle_kernel(first, end, tid, kind, large.geom, large.prims, *rays, action,
                                                      settled), n)
    rest = np.flatnonzero(~settled)
    if not len(rest):
        return None
    return _rays_in_rows(rays, rest, rays.hit_slot[rest] if len(rays.hit_slot) else rest)


def _rays_in_rows(rays: RayBatch, index, hit_slot) -> RayBatch:
    """The rays ``index`` (a slice or an index array) of ``rays``, in contiguous copies, writing into the
    rows ``hit_slot``; an origin or a limit that ``rays`` shares among all rays stays shared."""
    origins = rays.origins if rays.shares_origin else _rows(rays.origins, index)
    return RayBatch(origins, _rows(rays.directions, index),
                    *(_rows(limit, index) if len(limit) == rays.size else limit for limit in (rays.t_min, rays.t_max)),
                    hit_slot)


def _rows(array, index):
    """The rows ``index`` (a slice or an index array) of ``array``, C-contiguous: by ``np.take`` for an
    index array, which gathered 2^19 of 2^20 float64 ray rows in 2.7 ms where ``array[index]`` took 9.5."""
    return np.ascontiguousarray(array[index]) if isinstance(index, slice) else np.take(array, index, axis=0)
