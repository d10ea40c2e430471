"""3D-DDA traversal of a uniform grid with mailboxing.

Amanatides & Woo, "A Fast Voxel Traversal Algorithm for Ray Tracing",
Eurographics 1987: from the cell of the entry point, step each time into the
neighbour across the nearest of the three next cell boundaries, with
``t_next`` and ``t_delta`` per axis.

A hit found in a cell may lie beyond that cell (the object reaches into later
cells). Every hit found is kept as a candidate, but the walk stops only once
the best candidate lies before the current cell's exit: nothing in a later cell
can be closer. Keeping the candidate is also what makes mailboxing exact: an
object already tested for this ray (Amanatides & Woo's "mailbox", here one
stamp array per thread, so parallel rays never share one) is skipped in later
cells, and its hit is not lost because it is still the candidate.
"""

from __future__ import annotations

import math

import numpy as np

from ..._jit import chunk_kernel, inline_kernel, kernel
from ...geometry.box import clip_to_box
from ...geometry.primitive import ray_setup
from ...rays import ray_at, ray_limit, result_row
from ..actions import NEAREST, finish_ray_in_mode, intersect_references

__all__ = ["axis_start", "dda_step", "grid_closest_kernel", "grid_crossings_kernel"]


@kernel
def axis_start(o, d, t_enter, lo, size, n):
    """Cell of the entry point on one axis, step direction, first boundary crossing, crossing interval."""
    c = int(math.floor((o + t_enter * d - lo) / size))
    c = min(max(c, 0), n - 1)
    if d > 0.0:
        return c, 1, (lo + (c + 1) * size - o) / d, size / d
    if d < 0.0:
        return c, -1, (lo + c * size - o) / d, -size / d
    return c, 0, np.inf, np.inf


@inline_kernel
def dda_step(cx, cy, cz, next_x, next_y, next_z, step_x, step_y, step_z, delta_x, delta_y, delta_z, res):
    """Step into the neighbouring cell across the nearest cell boundary; returns the new cell,
    the next boundary crossings and whether the new cell is still inside the grid."""
    cell_exit = min(next_x, next_y, next_z)
    if next_x == cell_exit:
        cx += step_x
        next_x += delta_x
        inside = 0 <= cx < res[0]
    elif next_y == cell_exit:
        cy += step_y
        next_y += delta_y
        inside = 0 <= cy < res[1]
    else:
        cz += step_z
        next_z += delta_z
        inside = 0 <= cz < res[2]
    return cx, cy, cz, next_x, next_y, next_z, inside


@inline_kernel
def _walk(ray_first, ray_end, tid, grid_lo, grid_hi, res, cell_size, cell_first, cell_prims, kind, geom, origins,
          directions, t_min, t_max, hit_slot, any_hit, mailbox, ray_id_base, mode, action, work):
    """Trace rays ``ray_first`` to ``ray_end - 1``, giving the action, in ``mode``, to every
    primitive of the cells a ray crosses.

    ``mailbox`` is (threads, n_prims), or empty to disable mailboxing; ray ``i``
    stamps it with ``ray_id_base + i``, so a mailbox can be reused by later
    calls without clearing as long as each call gets a fresh range of ids.
    """
    nx, ny = res[0], res[1]
    count_work = work is not None
    for i in range(ray_first, ray_end):
        row = result_row(hit_slot, i)
        ray_t_min, ray_t_max = ray_limit(t_min, i), ray_limit(t_max, i)
        ox, oy, oz, dx, dy, dz = ray_at(origins, directions, i)
        t_enter, t_exit = clip_to_box(grid_lo, grid_hi, ox, oy, oz, dx, dy, dz, ray_t_min, ray_t_max)
        if t_enter > t_exit:
            finish_ray_in_mode(mode, action, row, np.inf, -1, 0.0, 0.0)
            continue
        ray = ray_setup(ox, oy, oz, dx, dy, dz)
        cx, step_x, next_x, delta_x = axis_start(ox, dx, t_enter, grid_lo[0], cell_size[0], res[0])
        cy, step_y, next_y, delta_y = axis_start(oy, dy, t_enter, grid_lo[1], cell_size[1], res[1])
        cz, step_z, next_z, delta_z = axis_start(oz, dz, t_enter, grid_lo[2], cell_size[2], res[2])
        stamp = ray_id_base + i
        best_t = ray_t_max
        best_prim = -1
        best_u = 0.0
        best_v = 0.0
        n_cells = 0
        n_tests = 0
        n_skips = 0
        while True:
            n_cells += 1
            flat = cx + nx * (cy + ny * cz)
            best_t, best_prim, best_u, best_v, n_tests, n_skips = intersect_references(
                mode, action, row, cell_first[flat], cell_first[flat + 1], cell_prims, mailbox, tid, stamp, kind,
                geom, False, ray, ray_t_min, best_t, best_prim, best_u, best_v, n_tests, n_skips, any_hit)
            if any_hit and best_prim >= 0:
                break
            cell_exit = min(next_x, next_y, next_z)
            if (best_prim >= 0 and best_t <= cell_exit) or cell_exit > t_exit:
                break
            cx, cy, cz, next_x, next_y, next_z, inside = dda_step(cx, cy, cz, next_x, next_y, next_z, step_x, step_y,
                                                                  step_z, delta_x, delta_y, delta_z, res)
            if not inside:
                break
        finish_ray_in_mode(mode, action, row, best_t, best_prim, best_u, best_v)
        if count_work:
            work[row, 0] = n_cells
            work[row, 1] = n_tests
            work[row, 2] = n_skips
            work[row, 3] = n_cells


@chunk_kernel
def grid_closest_kernel(ray_first, ray_end, tid, grid_lo, grid_hi, res, cell_size, cell_first, cell_prims, kind, geom,
                        origins, directions, t_min, t_max, hit_slot, any_hit, mailbox, ray_id_base, action, work):
    """The closest-hit and any-hit walk (an action of mode ``NEAREST``), the other modes' code
    pruned before it is compiled (:func:`..actions.visit_prim_in_mode`)."""
    _walk(ray_first, ray_end, tid, grid_lo, grid_hi, res, cell_size, cell_first, cell_prims, kind, geom, origins,
          directions, t_min, t_max, hit_slot, any_hit, mailbox, ray_id_base, NEAREST, action, work)


@chunk_kernel
def grid_crossings_kernel(ray_first, ray_end, tid, grid_lo, grid_hi, res, cell_size, cell_first, cell_prims, kind, geom,
                          origins, directions, t_min, t_max, hit_slot, any_hit, mailbox, ray_id_base, action, work):
    """The walk for the other actions (counting, listing, winding), compiled at their first use."""
    _walk(ray_first, ray_end, tid, grid_lo, grid_hi, res, cell_size, cell_first, cell_prims, kind, geom, origins,
          directions, t_min, t_max, hit_slot, any_hit, mailbox, ray_id_base, action.mode, action, work)
