"""Front-to-back traversal of the adaptive octree, closest hit and any hit.

The parametric approach of Revelles, Urena & Lastra, "An Efficient Parametric
Algorithm for Octree Traversal", WSCG 2000: the ray's distances to the three
planes through a node's centre cut its interval ``[t0, t1]`` inside the node
into at most four pieces; the first lies in the octant containing the entry
point, and each plane crossing flips that octant's bit for its axis. The
pieces are pushed farthest first, so the nearest octant is visited next, and
empty octants are never pushed. A hit found in a leaf is kept as the best
candidate, and the walk ends once it lies before the leaf's exit
(:func:`settled_before`). Stacks are preallocated per thread.
"""

from __future__ import annotations

import numpy as np

from ..._jit import chunk_kernel, inline_kernel
from ...geometry.box import clip_to_box
from ...geometry.primitive import ray_setup
from ...rays import ray_limit, result_row
from ..actions import NEAREST, finish_ray_in_mode, intersect_references
from ..base import settled_before

__all__ = ["octree_closest_kernel", "octree_crossings_kernel"]


@inline_kernel
def _entry_bit(o, d, t_cross, t0, center):
    """Whether the ray is on the upper side of a centre plane at ``t0``."""
    if d > 0.0:
        return t_cross <= t0
    if d < 0.0:
        return t_cross > t0
    return o >= center


@inline_kernel
def _crossing(o, d, inv, center):
    return (center - o) * inv if d != 0.0 else np.inf


@inline_kernel
def _walk(ray_first, ray_end, tid, lo, hi, node_center, node_link, leaf_prims, kind, geom, origins, directions, t_min,
          t_max, hit_slot, any_hit, mailbox, ray_id_base, stack_node, stack_t, mode, action, work):
    """Trace rays ``ray_first`` to ``ray_end - 1`` (one chunk of :func:`rayaccel._jit.on_threads`), their
    stacks in row ``tid``; ``stack_node`` (threads, 3 * depth + 4) int32, ``stack_t`` (threads, same, 2);
    ``mailbox`` as in the uniform grid (empty for the closest hit, which needs none); the action in
    ``mode``, as in the uniform grid's walk."""
    count_work = work is not None
    for i in range(ray_first, ray_end):
        row = result_row(hit_slot, i)
        ray_t_min, ray_t_max = ray_limit(t_min, i), ray_limit(t_max, i)
        ox, oy, oz = origins[i, 0], origins[i, 1], origins[i, 2]
        dx, dy, dz = directions[i, 0], directions[i, 1], directions[i, 2]
        t0, t1 = clip_to_box(lo, hi, ox, oy, oz, dx, dy, dz, ray_t_min, ray_t_max)
        if t0 > t1:
            finish_ray_in_mode(mode, action, row, np.inf, -1, 0.0, 0.0)
            continue
        ix, iy, iz = 1.0 / dx, 1.0 / dy, 1.0 / dz
        ray = ray_setup(ox, oy, oz, dx, dy, dz)
        best_t = ray_t_max
        best_prim = -1
        best_u = 0.0
        best_v = 0.0
        n_nodes = 0
        n_leaves = 0
        n_tests = 0
        node = 0
        sp = 0
        while node >= 0:
            n_nodes += 1
            count = node_link[node, 1]
            if count < 0:
                cx, cy, cz = node_center[node, 0], node_center[node, 1], node_center[node, 2]
                tx = _crossing(ox, dx, ix, cx)
                ty = _crossing(oy, dy, iy, cy)
                tz = _crossing(oz, dz, iz, cz)
                octant = (_entry_bit(ox, dx, tx, t0, cx) | (_entry_bit(oy, dy, ty, t0, cy) << 1)
                          | (_entry_bit(oz, dz, tz, t0, cz) << 2))
                # the three plane crossings in order, sorted by hand
                c0, c1, c2 = tx, ty, tz
                b0, b1, b2 = 1, 2, 4
                if c1 < c0:
                    c0, c1, b0, b1 = c1, c0, b1, b0
                if c2 < c1:
                    c1, c2, b1, b2 = c2, c1, b2, b1
                    if c1 < c0:
                        c0, c1, b0, b1 = c1, c0, b1, b0
                for _ in range(3):  # drop crossings at or before t0: the entry octant accounts for them
                    if c0 <= t0:
                        c0, c1, c2, b0, b1, b2 = c1, c2, np.inf, b1, b2, 0
                first_child = node_link[node, 0]
                # octants along the ray and where each begins; pushed farthest first
                o1 = octant ^ b0
                o2 = o1 ^ b1
                o3 = o2 ^ b2
                pieces = 1 + (c0 < t1) + (c1 < t1) + (c2 < t1)
                node = -1
                for piece in range(pieces - 1, -1, -1):
                    if piece == 0:
                        child, start, stop = octant, t0, min(c0, t1) if pieces > 1 else t1
                    elif piece == 1:
                        child, start, stop = o1, c0, min(c1, t1) if pieces > 2 else t1
                    elif piece == 2:
                        child, start, stop = o2, c1, min(c2, t1) if pieces > 3 else t1
                    else:
                        child, start, stop = o3, c2, t1
                    child = first_child + child
                    if node_link[child, 1] == 0:
                        continue
                    stack_node[tid, sp] = child
                    stack_t[tid, sp, 0] = start
                    stack_t[tid, sp, 1] = stop
                    sp += 1
            else:
                n_leaves += 1
                first = node_link[node, 0]
                best_t, best_prim, best_u, best_v, n_tests, _ = intersect_references(
                    mode, action, row, first, first + count, leaf_prims, mailbox, tid, ray_id_base + i, kind,
                    geom, False, ray, ray_t_min, best_t, best_prim, best_u, best_v, n_tests, 0, any_hit)
                if (any_hit and best_prim >= 0) or settled_before(best_prim, best_t, t1):
                    break
                node = -1
            while node < 0 and sp > 0:
                sp -= 1
                if best_prim < 0 or not settled_before(best_prim, best_t, stack_t[tid, sp, 0]):
                    node = stack_node[tid, sp]
                    t0 = stack_t[tid, sp, 0]
                    t1 = stack_t[tid, sp, 1]
        finish_ray_in_mode(mode, action, row, best_t, best_prim, best_u, best_v)
        if count_work:
            work[row, 0] = n_nodes
            work[row, 1] = n_tests
            work[row, 3] = n_leaves


@chunk_kernel
def octree_closest_kernel(ray_first, ray_end, tid, lo, hi, node_center, node_link, leaf_prims, kind, geom, origins,
                          directions, t_min, t_max, hit_slot, any_hit, mailbox, ray_id_base, stack_node, stack_t,
                          action, work):
    """The closest-hit and any-hit walk (an action of mode ``NEAREST``), the other modes' code
    pruned before it is compiled (:func:`..actions.visit_prim_in_mode`)."""
    _walk(ray_first, ray_end, tid, lo, hi, node_center, node_link, leaf_prims, kind, geom, origins, directions, t_min,
          t_max, hit_slot, any_hit, mailbox, ray_id_base, stack_node, stack_t, NEAREST, action, work)


@chunk_kernel
def octree_crossings_kernel(ray_first, ray_end, tid, lo, hi, node_center, node_link, leaf_prims, kind, geom, origins,
                            directions, t_min, t_max, hit_slot, any_hit, mailbox, ray_id_base, stack_node, stack_t,
                            action, work):
    """The walk for the other actions (counting, listing, winding), compiled at their first use."""
    _walk(ray_first, ray_end, tid, lo, hi, node_center, node_link, leaf_prims, kind, geom, origins, directions, t_min,
          t_max, hit_slot, any_hit, mailbox, ray_id_base, stack_node, stack_t, action.mode, action, work)
