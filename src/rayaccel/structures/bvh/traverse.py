"""Stack traversal of the flat BVH: closest hit and any hit, and the walk of the other actions.

At an inner node both children's volumes are tested; the ray descends into
the nearer one that it enters before its best hit so far and pushes the
farther one with its entry distance (front-to-back order, as in pbrt's
``BVHAggregate::Intersect``, but ordered by the actual entry distances rather
than by the split axis). A popped node whose entry distance lies beyond the
best hit found since it was pushed is skipped. Stacks are preallocated per
thread, one row as deep as the tree, so no ray allocates memory.

The slab tests stay free of NaN trouble for zero direction components (an
origin on a slab plane makes ``0 * inf`` NaN): comparisons are written so
that a NaN never replaces the running entry or exit distance, which is the
ordering pbrt-v4 uses in ``Bounds3::IntersectP``.
"""

from __future__ import annotations

import numpy as np

from ..._jit import chunk_kernel, inline_kernel
from ...geometry.kdop import KDOP_NORMALS
from ...geometry.primitive import ray_setup
from ...geometry.sphere import sphere_span
from ...rays import ray_at, ray_limit, result_row
from ..actions import NEAREST, finish_ray_in_mode, visit_prim_in_mode

__all__ = ["BOX", "SPHERE_VOLUME", "KDOP", "KDOP_NORMALS", "tighten", "enter_box", "volume_ray_setup",
           "bvh_closest_kernel", "bvh_crossings_kernel"]

BOX = 0
SPHERE_VOLUME = 1
KDOP = 2

@inline_kernel
def _slab(lo, hi, o, inv, enter, exit_):
    t0 = (lo - o) * inv
    t1 = (hi - o) * inv
    if inv < 0.0:
        t0, t1 = t1, t0
    if t0 > enter:
        enter = t0
    if t1 < exit_:
        exit_ = t1
    return enter, exit_


@inline_kernel
def tighten(near, far, enter, exit_):
    """The span ``enter..exit_`` cut to one slab's ``near..far``; a NaN (0 * inf for an origin
    on a slab plane) never replaces a bound."""
    if near > enter:
        enter = near
    if far < exit_:
        exit_ = far
    return enter, exit_


@inline_kernel
def enter_box(box, node, ox, oy, oz, ix, iy, iz, near_x, near_y, near_z, t_min, t_max):
    """Slab test with the near face of each axis chosen once per ray (``near_* = 3`` where the
    direction is negative), as in pbrt's ``dirIsNeg``: no swap per node."""
    enter, exit_ = tighten((box[node, near_x] - ox) * ix, (box[node, 3 - near_x] - ox) * ix, t_min, t_max)
    enter, exit_ = tighten((box[node, near_y] - oy) * iy, (box[node, 5 - near_y] - oy) * iy, enter, exit_)
    enter, exit_ = tighten((box[node, near_z] - oz) * iz, (box[node, 7 - near_z] - oz) * iz, enter, exit_)
    return enter if enter <= exit_ else np.inf


@inline_kernel
def _enter_kdop(volume, node, proj_o, proj_inv, t_min, t_max):
    enter = t_min
    exit_ = t_max
    for j in range(7):
        enter, exit_ = _slab(volume[node, j], volume[node, j + 7], proj_o[j], proj_inv[j], enter, exit_)
    return enter if enter <= exit_ else np.inf


@inline_kernel
def _enter_sphere(volume, node, ox, oy, oz, dx, dy, dz, t_min, t_max):
    near, far = sphere_span(volume[node, 0], volume[node, 1], volume[node, 2], volume[node, 3],
                            ox, oy, oz, dx, dy, dz)
    if far < t_min or near > t_max:
        return np.inf
    return max(near, t_min)


@inline_kernel
def _enter(bounds_kind, box, volume, node, ray, proj_o, proj_inv, near, t_min, t_max):
    """Entry distance of the ray into ``node``'s volume within ``[t_min, t_max]``; inf if it misses."""
    if bounds_kind == BOX:
        return enter_box(box, node, ray[0], ray[1], ray[2], proj_inv[0], proj_inv[1], proj_inv[2],
                          near[0], near[1], near[2], t_min, t_max)
    if bounds_kind == KDOP:
        return _enter_kdop(volume, node, proj_o, proj_inv, t_min, t_max)
    return _enter_sphere(volume, node, ray[0], ray[1], ray[2], ray[3], ray[4], ray[5], t_min, t_max)


@inline_kernel
def _project(x, y, z, normals, j):
    return x * normals[j, 0] + y * normals[j, 1] + z * normals[j, 2]


@inline_kernel
def volume_ray_setup(ox, oy, oz, dx, dy, dz, normals, with_diagonals):
    """Per-ray constants of the volume tests: origin projections and reciprocal direction
    projections on the slab normals (only the three axes unless ``with_diagonals``), and the
    near face of each axis for the box test (3, 4, 5 where the reciprocal is negative, -0 included)."""
    proj_o = (ox, oy, oz, 0.0, 0.0, 0.0, 0.0)
    proj_inv = (1.0 / dx, 1.0 / dy, 1.0 / dz, 0.0, 0.0, 0.0, 0.0)
    if with_diagonals:
        proj_o = (ox, oy, oz, _project(ox, oy, oz, normals, 3), _project(ox, oy, oz, normals, 4),
                  _project(ox, oy, oz, normals, 5), _project(ox, oy, oz, normals, 6))
        proj_inv = (proj_inv[0], proj_inv[1], proj_inv[2], 1.0 / _project(dx, dy, dz, normals, 3),
                    1.0 / _project(dx, dy, dz, normals, 4), 1.0 / _project(dx, dy, dz, normals, 5),
                    1.0 / _project(dx, dy, dz, normals, 6))
    near_faces = (0 if proj_inv[0] >= 0.0 else 3, 1 if proj_inv[1] >= 0.0 else 4, 2 if proj_inv[2] >= 0.0 else 5)
    return proj_o, proj_inv, near_faces


@inline_kernel
def _walk(ray_first, ray_end, tid, bounds_kind, node_box, node_volume, node_links, prim_order, kind, geom, normals,
          origins, directions, t_min, t_max, hit_slot, any_hit, stack_node, stack_t, mode, action, work):
    """Trace rays ``ray_first`` to ``ray_end - 1`` through the BVH; ``geom`` is in leaf order
    (``geom[prim_order]``).

    ``node_box`` is the packed float32 record array of :func:`.layout.pack_nodes`
    and ``node_links`` the same memory seen as int32 (columns 6 and 7: first, count). At a
    leaf each primitive gets the leaf action (:mod:`..actions`) in ``mode``.
    """
    count_work = work is not None
    for i in range(ray_first, ray_end):
        row = result_row(hit_slot, i)
        ray_t_min, ray_t_max = ray_limit(t_min, i), ray_limit(t_max, i)
        ox, oy, oz, dx, dy, dz = ray_at(origins, directions, i)
        ray = ray_setup(ox, oy, oz, dx, dy, dz)
        proj_o, proj_inv, near_faces = volume_ray_setup(ox, oy, oz, dx, dy, dz, normals, bounds_kind == KDOP)
        best_t = ray_t_max
        best_prim = -1
        best_u = 0.0
        best_v = 0.0
        n_nodes = 0
        n_tests = 0
        n_leaves = 0
        node = 0
        sp = 0
        root_entry = _enter(bounds_kind, node_box, node_volume, 0, ray, proj_o, proj_inv, near_faces, ray_t_min, best_t)
        if root_entry == np.inf:
            node = -1
        while node >= 0:
            n_nodes += 1
            count = node_links[node, 7]
            if count > 0:
                n_leaves += 1
                first = node_links[node, 6]
                for k in range(first, first + count):
                    n_tests += 1
                    best_t, best_prim, best_u, best_v, stop = visit_prim_in_mode(mode, action, row, kind, geom, k,
                                                                                 prim_order, k, ray, ray_t_min,
                                                                                 best_t, best_prim, best_u, best_v,
                                                                                 any_hit)
                    if stop:
                        break
                if any_hit and best_prim >= 0:
                    break
                node = -1
            else:
                near = node_links[node, 6]
                far = near + 1
                t_near = _enter(bounds_kind, node_box, node_volume, near, ray, proj_o, proj_inv, near_faces, ray_t_min,
                                best_t)
                t_far = _enter(bounds_kind, node_box, node_volume, far, ray, proj_o, proj_inv, near_faces, ray_t_min,
                               best_t)
                if t_far < t_near:
                    near, far = far, near
                    t_near, t_far = t_far, t_near
                if t_near == np.inf:
                    node = -1
                else:
                    node = near
                    if t_far != np.inf:
                        stack_node[tid, sp] = far
                        stack_t[tid, sp] = t_far
                        sp += 1
            while node < 0 and sp > 0:
                sp -= 1
                if stack_t[tid, sp] <= best_t:
                    node = stack_node[tid, sp]
        finish_ray_in_mode(mode, action, row, best_t, best_prim, best_u, best_v)
        if count_work:
            work[row, 0] = n_nodes
            work[row, 1] = n_tests
            work[row, 3] = n_leaves


@chunk_kernel
def bvh_closest_kernel(ray_first, ray_end, tid, bounds_kind, node_box, node_volume, node_links, prim_order, kind,
                       geom, normals, origins, directions, t_min, t_max, hit_slot, any_hit, stack_node, stack_t, action,
                       work):
    """The closest-hit and any-hit walk (an action of mode ``NEAREST``), the other modes' code
    pruned before it is compiled (:func:`..actions.visit_prim_in_mode`), as for the eight-wide
    walk (:func:`.traverse_wide.wide_nearest_kernel`)."""
    _walk(ray_first, ray_end, tid, bounds_kind, node_box, node_volume, node_links, prim_order, kind, geom, normals,
          origins, directions, t_min, t_max, hit_slot, any_hit, stack_node, stack_t, NEAREST, action, work)


@chunk_kernel
def bvh_crossings_kernel(ray_first, ray_end, tid, bounds_kind, node_box, node_volume, node_links, prim_order, kind,
                         geom, normals, origins, directions, t_min, t_max, hit_slot, any_hit, stack_node, stack_t,
                         action, work):
    """The walk for the other actions (counting, listing, winding), compiled at their first use."""
    _walk(ray_first, ray_end, tid, bounds_kind, node_box, node_volume, node_links, prim_order, kind, geom, normals,
          origins, directions, t_min, t_max, hit_slot, any_hit, stack_node, stack_t, action.mode, action, work)
