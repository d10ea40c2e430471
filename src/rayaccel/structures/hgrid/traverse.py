"""Nested 3D-DDA through a hierarchical grid, with mailboxing.

The walk of :mod:`..grid.traverse` (Amanatides & Woo 1987), made recursive
without recursion: on entering a cell that holds a nested grid, the DDA state
of the outer grid (cell, steps, next crossings, and the end of its stretch of
the ray) is saved in a per-thread array, one row per level, and a DDA starts
in the nested grid at the distance where the ray entered the cell, limited to
where it leaves it. When the inner walk runs out, the saved state comes back
and the outer walk steps on. Hits are kept as candidates and the walk ends
once the best lies before the exit of the cell being visited, at whatever
level; one mailbox stamp per ray serves all levels.
"""

from __future__ import annotations

import numpy as np

from ..._jit import chunk_kernel, inline_kernel
from ...geometry.box import clip_to_box
from ...geometry.primitive import ray_setup
from ...rays import ray_at, ray_limit, result_row
from ..actions import NEAREST, finish_ray_in_mode, intersect_references
from ..grid.traverse import axis_start, dda_step

__all__ = ["hgrid_closest_kernel", "hgrid_crossings_kernel"]


@inline_kernel
def _walk(ray_first, ray_end, tid, lo, hi, grid_lo, grid_res, grid_cell_size, grid_cell_base, cell_child, cell_first,
          cell_prims, kind, geom, origins, directions, t_min, t_max, hit_slot, any_hit, mailbox, ray_id_base, saved_int,
          saved_float, mode, action, work):
    """Trace rays ``ray_first`` to ``ray_end - 1`` (one chunk of :func:`rayaccel._jit.on_threads`), their
    stacks in row ``tid``; ``saved_int`` (threads, levels, 7) int64 and ``saved_float``
    (threads, levels, 7) hold the outer walks' DDA states; ``mailbox`` as in the uniform grid; the
    action in ``mode``, as in the uniform grid's walk."""
    count_work = work is not None
    for i in range(ray_first, ray_end):
        row = result_row(hit_slot, i)
        ray_t_min, ray_t_max = ray_limit(t_min, i), ray_limit(t_max, i)
        ox, oy, oz, dx, dy, dz = ray_at(origins, directions, i)
        t_enter, stretch_end = clip_to_box(lo, hi, ox, oy, oz, dx, dy, dz, ray_t_min, ray_t_max)
        if t_enter > stretch_end:
            finish_ray_in_mode(mode, action, row, np.inf, -1, 0.0, 0.0)
            continue
        ray = ray_setup(ox, oy, oz, dx, dy, dz)
        stamp = ray_id_base + i
        best_t = ray_t_max
        best_prim = -1
        best_u = 0.0
        best_v = 0.0
        n_cells = 0
        n_leaves = 0
        n_tests = 0
        n_skips = 0
        level = 0
        g = 0
        t_cell = t_enter
        cx, step_x, next_x, delta_x = axis_start(ox, dx, t_cell, grid_lo[g, 0], grid_cell_size[g, 0], grid_res[g, 0])
        cy, step_y, next_y, delta_y = axis_start(oy, dy, t_cell, grid_lo[g, 1], grid_cell_size[g, 1], grid_res[g, 1])
        cz, step_z, next_z, delta_z = axis_start(oz, dz, t_cell, grid_lo[g, 2], grid_cell_size[g, 2], grid_res[g, 2])
        while True:
            n_cells += 1
            cell = grid_cell_base[g] + cx + grid_res[g, 0] * (cy + grid_res[g, 1] * cz)
            cell_exit = min(next_x, next_y, next_z)
            child = cell_child[cell]
            n_leaves += child < 0
            if child >= 0:
                saved_int[tid, level, 0] = g
                saved_int[tid, level, 1] = cx
                saved_int[tid, level, 2] = cy
                saved_int[tid, level, 3] = cz
                saved_int[tid, level, 4] = step_x
                saved_int[tid, level, 5] = step_y
                saved_int[tid, level, 6] = step_z
                saved_float[tid, level, 0] = next_x
                saved_float[tid, level, 1] = next_y
                saved_float[tid, level, 2] = next_z
                saved_float[tid, level, 3] = delta_x
                saved_float[tid, level, 4] = delta_y
                saved_float[tid, level, 5] = delta_z
                saved_float[tid, level, 6] = stretch_end
                level += 1
                g = child
                stretch_end = min(stretch_end, cell_exit)
                cx, step_x, next_x, delta_x = axis_start(ox, dx, t_cell, grid_lo[g, 0], grid_cell_size[g, 0],
                                                         grid_res[g, 0])
                cy, step_y, next_y, delta_y = axis_start(oy, dy, t_cell, grid_lo[g, 1], grid_cell_size[g, 1],
                                                         grid_res[g, 1])
                cz, step_z, next_z, delta_z = axis_start(oz, dz, t_cell, grid_lo[g, 2], grid_cell_size[g, 2],
                                                         grid_res[g, 2])
                continue
            best_t, best_prim, best_u, best_v, n_tests, n_skips = intersect_references(
                mode, action, row, cell_first[cell], cell_first[cell + 1], cell_prims, mailbox, tid, stamp, kind,
                geom, False, ray, ray_t_min, best_t, best_prim, best_u, best_v, n_tests, n_skips, any_hit)
            if (any_hit and best_prim >= 0) or (best_prim >= 0 and best_t <= cell_exit):
                break
            done = False
            while True:  # step on; where a walk runs out, resume the walk it was nested in
                cell_exit = min(next_x, next_y, next_z)
                moved = cell_exit <= stretch_end
                if moved:
                    cx, cy, cz, next_x, next_y, next_z, moved = dda_step(cx, cy, cz, next_x, next_y, next_z, step_x,
                                                                         step_y, step_z, delta_x, delta_y, delta_z,
                                                                         grid_res[g])
                if moved:
                    t_cell = cell_exit
                    break
                if level == 0:
                    done = True
                    break
                level -= 1
                g = saved_int[tid, level, 0]
                cx = saved_int[tid, level, 1]
                cy = saved_int[tid, level, 2]
                cz = saved_int[tid, level, 3]
                step_x = saved_int[tid, level, 4]
                step_y = saved_int[tid, level, 5]
                step_z = saved_int[tid, level, 6]
                next_x = saved_float[tid, level, 0]
                next_y = saved_float[tid, level, 1]
                next_z = saved_float[tid, level, 2]
                delta_x = saved_float[tid, level, 3]
                delta_y = saved_float[tid, level, 4]
                delta_z = saved_float[tid, level, 5]
                stretch_end = saved_float[tid, level, 6]
            if done:
                break
        finish_ray_in_mode(mode, action, row, best_t, best_prim, best_u, best_v)
        if count_work:
            work[row, 0] = n_cells
            work[row, 1] = n_tests
            work[row, 2] = n_skips
            work[row, 3] = n_leaves


@chunk_kernel
def hgrid_closest_kernel(ray_first, ray_end, tid, lo, hi, grid_lo, grid_res, grid_cell_size, grid_cell_base, cell_child,
                         cell_first, cell_prims, kind, geom, origins, directions, t_min, t_max, hit_slot, any_hit,
                         mailbox, ray_id_base, saved_int, saved_float, action, work):
    """The closest-hit and any-hit walk (an action of mode ``NEAREST``), the other modes' code
    pruned before it is compiled (:func:`..actions.visit_prim_in_mode`)."""
    _walk(ray_first, ray_end, tid, lo, hi, grid_lo, grid_res, grid_cell_size, grid_cell_base, cell_child, cell_first,
          cell_prims, kind, geom, origins, directions, t_min, t_max, hit_slot, any_hit, mailbox, ray_id_base, saved_int,
          saved_float, NEAREST, action, work)


@chunk_kernel
def hgrid_crossings_kernel(ray_first, ray_end, tid, lo, hi, grid_lo, grid_res, grid_cell_size, grid_cell_base,
                           cell_child, cell_first, cell_prims, kind, geom, origins, directions, t_min, t_max, hit_slot,
                           any_hit, mailbox, ray_id_base, saved_int, saved_float, action, work):
    """The walk for the other actions (counting, listing, winding), compiled at their first use."""
    _walk(ray_first, ray_end, tid, lo, hi, grid_lo, grid_res, grid_cell_size, grid_cell_base, cell_child, cell_first,
          cell_prims, kind, geom, origins, directions, t_min, t_max, hit_slot, any_hit, mailbox, ray_id_base, saved_int,
          saved_float, action.mode, action, work)
