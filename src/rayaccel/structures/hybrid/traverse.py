"""Traversal of the grid-BVH hybrid: 3D-DDA between cells, an eight-wide BVH walk inside dense ones.

Between cells the walk is the uniform grid's (:mod:`..grid.traverse`:
candidates kept, stop once the best lies before the current cell's exit,
mailboxing across cells when there are mailboxes). In a cell with a BVH the
cell's references are reached through the eight-wide stack walk of
``bvh-binned`` (:func:`..bvh.traverse_wide.walk_tree`) over the cell's tree,
its child boxes entered only on the ray's stretch through the cell; the
mailbox, if any, still skips primitives that an earlier cell already tested.
A walk without one is given ``None``, not an empty mailbox, so that each
kernel compiles two copies of the primitive visit (a cell's references and a
tree's leaf) instead of three (:func:`..bvh.traverse_wide.walk_tree`).
Stacks are per thread. As the eight-wide BVH's walk, it tests each ray as it
reads it and reads float32 rays as they are.
"""

from __future__ import annotations

import numpy as np

from ..._jit import chunk_kernel, inline_kernel
from ..._validate import unusable_ray
from ...geometry.box import clip_to_box
from ...geometry.primitive import ray_setup
from ...rays import ray_at, ray_limit, result_row
from ..actions import NEAREST, finish_ray_in_mode, intersect_references
from ..base import EXIT_MARGIN
from ..bvh.traverse_wide import walk_tree
from ..bvh.wide_slab import box_reach, slab_ray
from ..grid.traverse import axis_start, dda_step

__all__ = ["grid_bvh_nearest_kernel", "grid_bvh_crossings_kernel"]


@inline_kernel
def _walk(ray_first, ray_end, tid, lo, hi, res, cell_size, cell_first, cell_prims, cell_root, records, links, kind,
          geom, origins, directions, t_min, t_max, hit_slot, any_hit, mailbox, ray_id_base, stack_link, stack_count,
          stack_t, entry, mode, action, work):
    """Trace rays ``ray_first`` to ``ray_end - 1`` (one chunk of :func:`rayaccel._jit.on_threads`), their
    stacks in row ``tid``; ``cell_root`` is each cell's wide root (-1 without a BVH) in ``records``
    (:mod:`..bvh.wide`, ``links`` the same seen as int32), whose leaves index ``cell_prims``;
    ``mailbox`` as in the uniform grid, or ``None`` for none; stacks as the eight-wide BVH's. A ray that
    :func:`rayaccel._validate.unusable_ray` refuses is answered as a miss; returns how many
    there were."""
    nx, ny, nz = res[0], res[1], res[2]
    child_entry = entry[tid]
    reach_x, reach_y, reach_z = box_reach(lo, hi)
    unusable = 0
    count_work = work is not None
    for i in range(ray_first, ray_end):
        row = result_row(hit_slot, i)
        ray_t_min, ray_t_max = ray_limit(t_min, i), ray_limit(t_max, i)
        ox, oy, oz, dx, dy, dz = ray_at(origins, directions, i)
        if unusable_ray(ox, oy, oz, dx, dy, dz):
            unusable += 1
            finish_ray_in_mode(mode, action, row, ray_t_max, -1, 0.0, 0.0)
            continue
        t_enter, t_exit = clip_to_box(lo, hi, ox, oy, oz, dx, dy, dz, ray_t_min, ray_t_max)
        if t_enter > t_exit:
            finish_ray_in_mode(mode, action, row, np.inf, -1, 0.0, 0.0)
            continue
        ray = ray_setup(ox, oy, oz, dx, dy, dz)
        ix, iy, iz = 1.0 / dx, 1.0 / dy, 1.0 / dz
        near_x, near_y, near_z = 0 if ix >= 0.0 else 3, 1 if iy >= 0.0 else 4, 2 if iz >= 0.0 else 5
        slab = slab_ray(ox, oy, oz, dx, dy, dz, ix, iy, iz, reach_x, reach_y, reach_z)
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
                    mode, action, row, cell_first[cell], cell_first[cell + 1], cell_prims, mailbox, tid, stamp,
                    kind, geom, True, ray, ray_t_min, best_t, best_prim, best_u, best_v, n_tests, n_skips, any_hit)
            else:
                best_t, best_prim, best_u, best_v, nodes, leaves, n_tests_cell, n_skips_cell = walk_tree(
                    mode, action, row, records, links, cell_prims, kind, geom, mailbox, tid, stamp, root, 0, slab,
                    near_x, near_y, near_z, ray, ray_t_min, span_lo, span_hi, best_t, best_prim, best_u, best_v,
                    any_hit, stack_link, stack_count, stack_t, child_entry)
                n_steps += nodes
                n_leaves += leaves
                n_tests += n_tests_cell
                n_skips += n_skips_cell
            if best_prim >= 0 and (any_hit or best_t <= cell_exit):
                break
            if cell_exit > t_exit:
                break
            cx, cy, cz, next_x, next_y, next_z, inside = dda_step(cx, cy, cz, next_x, next_y, next_z, step_x, step_y,
                                                                  step_z, delta_x, delta_y, delta_z, res)
            if not inside:
                break
            t_cell = cell_exit
        finish_ray_in_mode(mode, action, row, best_t, best_prim, best_u, best_v)
        if count_work:
            work[row, 0] = n_steps
            work[row, 1] = n_tests
            work[row, 2] = n_skips
            work[row, 3] = n_leaves
    return unusable


@chunk_kernel
def grid_bvh_nearest_kernel(ray_first, ray_end, tid, lo, hi, res, cell_size, cell_first, cell_prims, cell_root, records,
                            links, kind, geom, origins, directions, t_min, t_max, hit_slot, any_hit, mailbox,
                            ray_id_base, stack_link, stack_count, stack_t, entry, action, work):
    """The closest-hit and any-hit walk (an action of mode ``NEAREST``), the other modes' code
    pruned before it is compiled (:func:`..actions.visit_prim_in_mode`)."""
    return _walk(ray_first, ray_end, tid, lo, hi, res, cell_size, cell_first, cell_prims, cell_root, records, links,
                 kind, geom, origins, directions, t_min, t_max, hit_slot, any_hit, mailbox, ray_id_base, stack_link,
                 stack_count, stack_t, entry, NEAREST, action, work)


@chunk_kernel
def grid_bvh_crossings_kernel(ray_first, ray_end, tid, lo, hi, res, cell_size, cell_first, cell_prims, cell_root,
                              records, links, kind, geom, origins, directions, t_min, t_max, hit_slot, any_hit,
                              mailbox, ray_id_base, stack_link, stack_count, stack_t, entry, action, work):
    """The walk for the other actions (counting, listing, winding), compiled at their first use."""
    return _walk(ray_first, ray_end, tid, lo, hi, res, cell_size, cell_first, cell_prims, cell_root, records, links,
                 kind, geom, origins, directions, t_min, t_max, hit_slot, any_hit, mailbox, ray_id_base, stack_link,
                 stack_count, stack_t, entry, action.mode, action, work)
