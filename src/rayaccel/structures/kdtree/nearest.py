"""The kd-tree's walk by distance: near side of each plane first.

Friedman, Bentley & Finkel, "An Algorithm for Finding Best Matches in
Logarithmic Expected Time", ACM TOMS 3(3), 1977. At an inner node the child
on the point's side of the split plane is visited first; the other child's
cell is the parent's with one face moved to the plane (the layout stores no
cells: they are carried down the walk). The other child is pushed with its
cell and the squared distance from the point to it, and skipped, when popped, if it lies farther than the best
primitive so far. Leaves call the shared
:func:`rayaccel.structures.point_actions.nearest_in_refs`; a primitive that
straddles planes is met in several leaves, at the same distance, so the tie
rule is unaffected.
"""

from __future__ import annotations

from numba import prange

from ..._jit import inline_kernel, parallel_kernel, thread_id
from ..point_actions import box_distance2, nearest_in_refs
from .layout import LEAF, leaf_first, node_child, node_plane, node_word, plane_bracket

__all__ = ["kdtree_nearest_kernel"]


@inline_kernel
def _with(cell, j, value):
    """The 6-tuple ``cell`` (lo, hi) with entry ``j`` replaced by ``value``."""
    return (value if j == 0 else cell[0], value if j == 1 else cell[1], value if j == 2 else cell[2],
            value if j == 3 else cell[3], value if j == 4 else cell[4], value if j == 5 else cell[5])


@inline_kernel
def _cell_distance2(cell, p):
    return box_distance2(cell[0], cell[1], cell[2], cell[3], cell[4], cell[5], p[0], p[1], p[2])


@parallel_kernel
def kdtree_nearest_kernel(lo, hi, node_planes, node_links, leaf_prims, apart_first, kind, geom, pad, points, limit_d2,
                          stack_node, stack_d2, stack_cell, out_d2, out_prim):
    """For each point, the closest primitive within ``sqrt(limit_d2[i])`` (``out_d2``, ``out_prim``);
    ``node_planes`` and ``node_links`` the flat node records (:attr:`.layout.KdTreeArrays.walk_records`),
    ``geom`` in reference order; stacks as deep as the tree + 2, ``stack_cell`` (threads, depth, 6).
    The primitives kept apart from the tree, ``leaf_prims[apart_first:]``, are tested first, so that
    the nearest of them bounds the walk."""
    for i in prange(points.shape[0]):
        tid = thread_id()
        p = (points[i, 0], points[i, 1], points[i, 2])
        best_d2, best_prim = nearest_in_refs(kind, geom, leaf_prims, apart_first, leaf_prims.shape[0], True, p[0], p[1],
                                             p[2], limit_d2[i], -1)
        cell = (lo[0] - pad, lo[1] - pad, lo[2] - pad, hi[0] + pad, hi[1] + pad, hi[2] + pad)
        node = 0
        if _cell_distance2(cell, p) > best_d2:
            node = -1
        sp = 0
        while node >= 0:
            link = node_word(node_links, node)
            axis = link & 3
            if axis == LEAF:
                first = leaf_first(node_links, node)
                best_d2, best_prim = nearest_in_refs(kind, geom, leaf_prims, first, first + (link >> 2), True, p[0],
                                                     p[1], p[2], best_d2, best_prim)
                node = -1
            else:
                plane_below, plane_above = plane_bracket(node_plane(node_planes, node))
                below = node_child(link)
                if p[axis] < plane_below:
                    node, far = below, below + 1
                    far_cell = _with(cell, axis, plane_below - pad)
                    cell = _with(cell, axis + 3, plane_above + pad)
                else:
                    node, far = below + 1, below
                    far_cell = _with(cell, axis + 3, plane_above + pad)
                    cell = _with(cell, axis, plane_below - pad)
                d_far = _cell_distance2(far_cell, p)
                if d_far <= best_d2:
                    stack_node[tid, sp] = far
                    stack_d2[tid, sp] = d_far
                    for j in range(6):
                        stack_cell[tid, sp, j] = far_cell[j]
                    sp += 1
            while node < 0 and sp > 0:
                sp -= 1
                if stack_d2[tid, sp] <= best_d2:
                    node = stack_node[tid, sp]
                    cell = (stack_cell[tid, sp, 0], stack_cell[tid, sp, 1], stack_cell[tid, sp, 2],
                            stack_cell[tid, sp, 3], stack_cell[tid, sp, 4], stack_cell[tid, sp, 5])
        out_d2[i] = best_d2
        out_prim[i] = best_prim
