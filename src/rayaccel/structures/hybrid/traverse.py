"""Traversal of the grid-BVH hybrid: 3D-DDA between cells, a BVH stack walk inside dense ones.

Between cells the walk is the uniform grid's (:mod:`..grid.traverse`:
candidates kept, stop once the best lies before the current cell's exit,
mailboxing across cells). In a cell with a BVH the cell's references are
reached through that BVH's front-to-back stack traversal
(:mod:`..bvh.traverse`) instead of one by one, its node tests limited to the
ray's stretch through the cell; the mailbox still skips primitives that an
earlier cell already tested. Stacks are per thread.
"""

from __future__ import annotations

import numpy as np

from ..._jit import chunk_kernel
from ...geometry.box import clip_to_box
from ...geometry.primitive import ray_setup
from ...rays import ray_limit, result_row
from ..actions import finish_ray, intersect_references
from ..base import EXIT_MARGIN
from ..bvh.traverse import enter_box
from ..grid.traverse import axis_start, dda_step

__all__ = ["grid_bvh_trace_kernel"]


@chunk_kernel
def grid_bvh_trace_kernel(ray_first, ray_end, tid, lo, hi, res, cell_size, cell_first, cell_prims, cell_root, node_box,
                          node_first, node_count, kind, geom, origins, directions, t_min, t_max, hit_slot, any_hit,
                          mailbox, ray_id_base, stack_node, stack_t, action, work):
    """Trace rays ``ray_first`` to ``ray_end - 1`` (one chunk of :func:`rayaccel._jit.on_threads`), their
    stacks in row ``tid``; ``mailbox`` as in the uniform grid, stacks (threads, depth + 2)."""
    nx, ny, nz = res[0], res[1], res[2]
    count_work = work.shape[0] > 0
    for i in range(ray_first, ray_end):
        row = result_row(hit_slot, i)
        ray_t_min, ray_t_max = ray_limit(t_min, i), ray_limit(t_max, i)
        ox, oy, oz = origins[i, 0], origins[i, 1], origins[i, 2]
        dx, dy, dz = directions[i, 0], directions[i, 1], directions[i, 2]
        t_enter, t_exit = clip_to_box(lo, hi, ox, oy, oz, dx, dy, dz, ray_t_min, ray_t_max)
        if t_enter > t_exit:
            finish_ray(action, row, np.inf, -1, 0.0, 0.0)
            continue
        ray = ray_setup(ox, oy, oz, dx, dy, dz)
        ix, iy, iz = 1.0 / dx, 1.0 / dy, 1.0 / dz
        near_x, near_y, near_z = 0 if ix >= 0.0 else 3, 1 if iy >= 0.0 else 4, 2 if iz >= 0.0 else 5
        cx, step_x, next_x, delta_x = axis_start(ox, dx, t_enter, lo[0], cell_size[0], nx)
        cy, step_y, next_y, delta_y = axis_start(oy, dy, t_enter, lo[1], cell_size[1], ny)
        cz, step_z, next_z, delta_z = axis_start(oz, dz, t_enter, lo[2], cell_size[2], nz)
        stamp = ray_id_base + i
        best_t, best_prim, best_u, best_v = ray_t_max, -1, 0.0, 0.0
        n_tests = 0
        n_skips = 0
        n_steps = 0
        n_leaves = 0
        t_cell = t_enter
        while True:
            n_steps += 1
            cell = cx + nx * (cy + ny * cz)
            cell_exit = min(next_x, next_y, next_z)
            # nodes are tested only on the ray's stretch through this cell (with a margin for
            # rounding): a primitive hit beyond it is referenced by, and found in, a later cell
            span_lo = max(ray_t_min, t_cell - EXIT_MARGIN * abs(t_cell))
            span_hi = cell_exit + EXIT_MARGIN * abs(cell_exit)
            root = cell_root[cell]
            if root < 0:
                n_leaves += 1
                best_t, best_prim, best_u, best_v, n_tests, n_skips = intersect_references(
                    action.mode, action, row, cell_first[cell], cell_first[cell + 1], cell_prims, mailbox, tid, stamp,
                    kind, geom, True, ray, ray_t_min, best_t, best_prim, best_u, best_v, n_tests, n_skips, any_hit)
            else:
                node = root
                sp = 0
                if enter_box(node_box, root, ox, oy, oz, ix, iy, iz, near_x, near_y, near_z,
                             span_lo, min(best_t, span_hi)) == np.inf:
                    node = -1
                while node >= 0:
                    n_steps += 1
                    count = node_count[node]
                    if count > 0:
                        n_leaves += 1
                        first = node_first[node]
                        best_t, best_prim, best_u, best_v, n_tests, n_skips = intersect_references(
                            action.mode, action, row, first, first + count, cell_prims, mailbox, tid, stamp, kind,
                            geom, True, ray, ray_t_min, best_t, best_prim, best_u, best_v, n_tests, n_skips, any_hit)
                        if any_hit and best_prim >= 0:
                            break
                        node = -1
                    else:
                        left = node_first[node]
                        t_left = enter_box(node_box, left, ox, oy, oz, ix, iy, iz, near_x, near_y, near_z,
                                           span_lo, min(best_t, span_hi))
                        t_right = enter_box(node_box, left + 1, ox, oy, oz, ix, iy, iz, near_x, near_y,
                                            near_z, span_lo, min(best_t, span_hi))
                        near_child, far_child, t_far = left, left + 1, t_right
                        if t_right < t_left:
                            near_child, far_child, t_far = left + 1, left, t_left
                        node = near_child if min(t_left, t_right) != np.inf else -1
                        if node >= 0 and t_far != np.inf:
                            stack_node[tid, sp] = far_child
                            stack_t[tid, sp] = t_far
                            sp += 1
                    while node < 0 and sp > 0:
                        sp -= 1
                        if stack_t[tid, sp] <= best_t:
                            node = stack_node[tid, sp]
            if best_prim >= 0 and (any_hit or best_t <= cell_exit):
                break
            if cell_exit > t_exit:
                break
            cx, cy, cz, next_x, next_y, next_z, inside = dda_step(cx, cy, cz, next_x, next_y, next_z, step_x, step_y,
                                                                  step_z, delta_x, delta_y, delta_z, res)
            if not inside:
                break
            t_cell = cell_exit
        finish_ray(action, row, best_t, best_prim, best_u, best_v)
        if count_work:
            work[row, 0] = n_steps
            work[row, 1] = n_tests
            work[row, 2] = n_skips
            work[row, 3] = n_leaves
