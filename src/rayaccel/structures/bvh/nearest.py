"""The BVH's walk by distance: closest primitive to each query point.

Best-first descent with a stack (the branch-and-bound nearest-neighbour
search of Roussopoulos, Kelley & Vincent, "Nearest Neighbor Queries",
SIGMOD 1995, on a BVH): at an inner node the squared distances from the
point to both children's boxes are computed, the nearer child is visited
next and the farther one pushed with its distance; a node, pushed or
visited, whose box lies farther than the best primitive found so far is
skipped. Leaves call the shared action
:func:`rayaccel.structures.point_actions.nearest_in_refs`. The walk reads the
binary layout of :mod:`.layout` in float64 (``node_box``), also for BVHs whose
rays walk the eight-wide records, and the grid-BVH hybrid walks the BVHs of
its dense cells with the same function.
"""

from __future__ import annotations

import numpy as np
from numba import prange

from ..._jit import inline_kernel, kernel, parallel_kernel, thread_id, thread_rows
from ..point_actions import box_distance2, nearest_in_refs

__all__ = ["bvh_nearest", "bvh_nearest_kernel", "binary_walk_stacks"]


def binary_walk_stacks(rows: int, depth: int) -> tuple[np.ndarray, np.ndarray]:
    """The per-thread stacks of the walks over a binary tree ``depth`` deep (this one, the rays' walk
    of :mod:`.traverse`, and the grids' walks of the BVHs in their cells): the pending nodes and their
    entry distances (squared distances for the nearest)."""
    return thread_rows((rows, depth + 2), np.int32), thread_rows((rows, depth + 2))


@inline_kernel
def _node_distance2(node_box, node, px, py, pz):
    return box_distance2(node_box[node, 0], node_box[node, 1], node_box[node, 2], node_box[node, 3],
                         node_box[node, 4], node_box[node, 5], px, py, pz)


@kernel
def bvh_nearest(node_box, node_first, node_count, refs, in_leaf_order, root, kind, geom, px, py, pz, best_d2,
                best_prim, stack_node, stack_d2, tid):
    """Closest primitive ``(d2, prim)`` under ``root`` within the running best ``(best_d2, best_prim)``;
    ``stack_node[tid]``, ``stack_d2[tid]`` are this thread's stack rows (as deep as the tree + 2)."""
    node = root
    if _node_distance2(node_box, node, px, py, pz) > best_d2:
        node = -1
    sp = 0
    while node >= 0:
        count = node_count[node]
        if count > 0:
            first = node_first[node]
            best_d2, best_prim = nearest_in_refs(kind, geom, refs, first, first + count, in_leaf_order, px, py,
                                                 pz, best_d2, best_prim)
            node = -1
        else:
            near = node_first[node]
            far = near + 1
            d_near = _node_distance2(node_box, near, px, py, pz)
            d_far = _node_distance2(node_box, far, px, py, pz)
            if d_far < d_near:
                near, far = far, near
                d_near, d_far = d_far, d_near
            node = near if d_near <= best_d2 else -1
            if d_far <= best_d2:
                stack_node[tid, sp] = far
                stack_d2[tid, sp] = d_far
                sp += 1
        while node < 0 and sp > 0:
            sp -= 1
            if stack_d2[tid, sp] <= best_d2:
                node = stack_node[tid, sp]
    return best_d2, best_prim


@parallel_kernel
def bvh_nearest_kernel(node_box, node_first, node_count, prim_order, kind, geom, points, limit_d2, stack_node,
                       stack_d2, out_d2, out_prim):
    """For each point, the closest primitive within ``sqrt(limit_d2[i])``: ``out_d2``, ``out_prim``
    (-1 when none); ``geom`` is in leaf order (``geom[prim_order]``)."""
    for i in prange(points.shape[0]):
        tid = thread_id()
        d2, prim = bvh_nearest(node_box, node_first, node_count, prim_order, True, 0, kind, geom, points[i, 0],
                               points[i, 1], points[i, 2], limit_d2[i], -1, stack_node, stack_d2, tid)
        out_d2[i] = d2
        out_prim[i] = prim
