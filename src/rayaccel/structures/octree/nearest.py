"""The octree's walk by distance: children nearest first, by the distance to their cells.

Best-first branch and bound (Samet, "Foundations of Multidimensional and
Metric Data Structures", 2006, section 4.1, on an octree): at an inner node the
eight children's cells are cut at the node's centre and those no farther than
the best primitive so far are pushed, sorted so that the nearest is popped
first; a popped cell farther than the best by then is skipped. Leaves call
the shared :func:`rayaccel.structures.point_actions.nearest_in_refs` (a
primitive referenced by several leaves is met at the same distance each time).
"""

from __future__ import annotations

from numba import prange

from ..._jit import parallel_kernel, thread_id
from ..point_actions import box_distance2, nearest_in_refs

__all__ = ["octree_nearest_kernel"]


@parallel_kernel
def octree_nearest_kernel(lo, hi, node_center, node_link, leaf_prims, kind, geom, pad, points, limit_d2, stack_node,
                          stack_d2, stack_cell, out_d2, out_prim):
    """For each point, the closest primitive within ``sqrt(limit_d2[i])`` (``out_d2``, ``out_prim``);
    stacks of 7 * depth + 9 entries, ``stack_cell`` (threads, entries, 6)."""
    for i in prange(points.shape[0]):
        tid = thread_id()
        px, py, pz = points[i, 0], points[i, 1], points[i, 2]
        best_d2 = limit_d2[i]
        best_prim = -1
        stack_node[tid, 0] = 0
        stack_d2[tid, 0] = 0.0
        for j in range(3):
            stack_cell[tid, 0, j] = lo[j] - pad
            stack_cell[tid, 0, j + 3] = hi[j] + pad
        sp = 1
        while sp > 0:
            sp -= 1
            if stack_d2[tid, sp] > best_d2:
                continue
            node = stack_node[tid, sp]
            count = node_link[node, 1]
            if count >= 0:
                first = node_link[node, 0]
                best_d2, best_prim = nearest_in_refs(kind, geom, leaf_prims, first, first + count, False, px, py, pz,
                                                     best_d2, best_prim)
                continue
            cx, cy, cz = node_center[node, 0], node_center[node, 1], node_center[node, 2]
            l0, l1, l2 = stack_cell[tid, sp, 0], stack_cell[tid, sp, 1], stack_cell[tid, sp, 2]
            h0, h1, h2 = stack_cell[tid, sp, 3], stack_cell[tid, sp, 4], stack_cell[tid, sp, 5]
            top = sp
            for c in range(8):
                bx0, bx1 = (cx - pad, h0) if c & 1 else (l0, cx + pad)
                by0, by1 = (cy - pad, h1) if c & 2 else (l1, cy + pad)
                bz0, bz1 = (cz - pad, h2) if c & 4 else (l2, cz + pad)
                d2 = box_distance2(bx0, by0, bz0, bx1, by1, bz1, px, py, pz)
                if d2 > best_d2:
                    continue
                slot = top
                while slot > sp and stack_d2[tid, slot - 1] < d2:
                    stack_node[tid, slot] = stack_node[tid, slot - 1]
                    stack_d2[tid, slot] = stack_d2[tid, slot - 1]
                    for j in range(6):
                        stack_cell[tid, slot, j] = stack_cell[tid, slot - 1, j]
                    slot -= 1
                stack_node[tid, slot] = node_link[node, 0] + c
                stack_d2[tid, slot] = d2
                stack_cell[tid, slot, 0], stack_cell[tid, slot, 1], stack_cell[tid, slot, 2] = bx0, by0, bz0
                stack_cell[tid, slot, 3], stack_cell[tid, slot, 4], stack_cell[tid, slot, 5] = bx1, by1, bz1
                top += 1
            sp = top
        out_d2[i] = best_d2
        out_prim[i] = best_prim
