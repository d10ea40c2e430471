"""The grid's walk by distance: cells searched outward in shells, for the uniform grid, the
hierarchical grid and the grid-BVH hybrid alike.

The point's cell (clamped to the grid when the point lies outside) is shell 0;
shell ``k`` holds the cells whose index differs from it by exactly ``k`` on
some axis (Chebyshev distance in cells), as in the ring search of Cleary,
"Analysis of an Algorithm for Finding Nearest Neighbors in Euclidean Space",
ACM TOMS 5(2), 1979. Every cell of shell ``k`` lies beyond one of the planes
bounding shell ``k - 1``'s block of cells, so the nearest such plane (combined
with the point's distance to the grid's slabs on the other axes) bounds the
whole shell from below; the search stops at the first shell whose bound
exceeds the best primitive so far. Within a shell, a cell whose box is farther
than the best is skipped. A cell's content is visited by the shared action
:func:`rayaccel.structures.point_actions.nearest_in_refs`, or, in the hybrid,
by the BVH walk of :mod:`..bvh.nearest` over the cell's own BVH (``cell_root``),
or, in the hierarchical grid, by scanning the nested grid (``cell_child``)
cell by cell with the same pruning, nested grids within it pushed on a stack.
Structures without BVH cells or nested grids pass empty arrays for them.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numba import prange

from ..._jit import inline_kernel, kernel, lent_rows, parallel_kernel, thread_id, thread_rows
from ..bvh.nearest import binary_walk_stacks, bvh_nearest
from ..point_actions import box_distance2, nearest_in_refs

__all__ = ["grid_nearest_kernel", "grid_nearest"]


@inline_kernel
def _cell_distance2(glo, gsize, x, y, z, pad, px, py, pz):
    lx, ly, lz = glo[0] + x * gsize[0], glo[1] + y * gsize[1], glo[2] + z * gsize[2]
    return box_distance2(lx - pad, ly - pad, lz - pad, lx + gsize[0] + pad, ly + gsize[1] + pad, lz + gsize[2] + pad,
                         px, py, pz)


@kernel
def _nested_grids(first_grid, grid_lo, grid_res, grid_cell_size, grid_cell_base, cell_child, cell_first, cell_prims,
                  kind, geom, in_leaf_order, pad, px, py, pz, best_d2, best_prim, grid_stack, tid):
    """Scan the nested grid ``first_grid`` and the grids nested in it, skipping far cells."""
    grid_stack[tid, 0] = first_grid
    sp = 1
    while sp > 0:
        sp -= 1
        g = grid_stack[tid, sp]
        nx, ny, nz = grid_res[g, 0], grid_res[g, 1], grid_res[g, 2]
        for z in range(nz):
            for y in range(ny):
                for x in range(nx):
                    if _cell_distance2(grid_lo[g], grid_cell_size[g], x, y, z, pad, px, py, pz) > best_d2:
                        continue
                    cell = grid_cell_base[g] + x + nx * (y + ny * z)
                    if cell_child[cell] >= 0:
                        grid_stack[tid, sp] = cell_child[cell]
                        sp += 1
                    else:
                        best_d2, best_prim = nearest_in_refs(kind, geom, cell_prims, cell_first[cell],
                                                             cell_first[cell + 1], in_leaf_order, px, py, pz, best_d2,
                                                             best_prim)
    return best_d2, best_prim


@inline_kernel
def _shell_bound2(glo, gsize, res, c, k, px, py, pz):
    """Lower bound on the squared distance to any cell of shell ``k`` (inf if the shell is empty)."""
    p = (px, py, pz)
    out = (max(glo[0] - px, 0.0, px - (glo[0] + res[0] * gsize[0])) ** 2,
           max(glo[1] - py, 0.0, py - (glo[1] + res[1] * gsize[1])) ** 2,
           max(glo[2] - pz, 0.0, pz - (glo[2] + res[2] * gsize[2])) ** 2)
    bound = math.inf
    for a in range(3):
        others = out[0] + out[1] + out[2] - out[a]
        if c[a] - k >= 0:
            gap = max(p[a] - (glo[a] + (c[a] - k + 1) * gsize[a]), 0.0)
            bound = min(bound, gap * gap + others)
        if c[a] + k < res[a]:
            gap = max(glo[a] + (c[a] + k) * gsize[a] - p[a], 0.0)
            bound = min(bound, gap * gap + others)
    return bound


@kernel
def _grid_point(lo, res, cell_size, cell_first, cell_prims, cell_root, node_box, node_first, node_count, cell_child,
                grid_lo, grid_res, grid_cell_size, grid_cell_base, kind, geom, in_leaf_order, pad, px, py, pz, best_d2,
                stack_node, stack_d2, grid_stack, tid):
    """One point's shell search: its closest primitive ``(d2, prim)`` within ``sqrt(best_d2)``."""
    nx, ny, nz = res[0], res[1], res[2]
    best_prim = -1
    c = (min(max(int(math.floor((px - lo[0]) / cell_size[0])), 0), nx - 1),
         min(max(int(math.floor((py - lo[1]) / cell_size[1])), 0), ny - 1),
         min(max(int(math.floor((pz - lo[2]) / cell_size[2])), 0), nz - 1))
    k = 0
    while True:
        if k > 0 and _shell_bound2(lo, cell_size, res, c, k, px, py, pz) > best_d2:
            break
        for x in range(max(c[0] - k, 0), min(c[0] + k, nx - 1) + 1):
            gx = max(lo[0] + x * cell_size[0] - pad - px, 0.0, px - (lo[0] + (x + 1) * cell_size[0] + pad))
            if gx * gx > best_d2:
                continue
            for y in range(max(c[1] - k, 0), min(c[1] + k, ny - 1) + 1):
                gy = max(lo[1] + y * cell_size[1] - pad - py, 0.0, py - (lo[1] + (y + 1) * cell_size[1] + pad))
                if gx * gx + gy * gy > best_d2:
                    continue
                if abs(x - c[0]) == k or abs(y - c[1]) == k:
                    z_first, z_last, z_step = max(c[2] - k, 0), min(c[2] + k, nz - 1), 1
                else:
                    z_first, z_last, z_step = c[2] - k, c[2] + k, 2 * k
                for z in range(z_first, z_last + 1, z_step):
                    if z < 0 or z >= nz:
                        continue
                    if _cell_distance2(lo, cell_size, x, y, z, pad, px, py, pz) > best_d2:
                        continue
                    cell = x + nx * (y + ny * z)
                    if cell_root.shape[0] > 0 and cell_root[cell] >= 0:
                        best_d2, best_prim = bvh_nearest(node_box, node_first, node_count, cell_prims, in_leaf_order,
                                                         cell_root[cell], kind, geom, px, py, pz, best_d2,
                                                         best_prim, stack_node, stack_d2, tid)
                    elif cell_child.shape[0] > 0 and cell_child[cell] >= 0:
                        best_d2, best_prim = _nested_grids(cell_child[cell], grid_lo, grid_res, grid_cell_size,
                                                           grid_cell_base, cell_child, cell_first, cell_prims,
                                                           kind, geom, in_leaf_order, pad, px, py, pz, best_d2,
                                                           best_prim, grid_stack, tid)
                    else:
                        best_d2, best_prim = nearest_in_refs(kind, geom, cell_prims, cell_first[cell],
                                                             cell_first[cell + 1], in_leaf_order, px, py, pz, best_d2,
                                                             best_prim)
        k += 1
        if k > max(c[0], nx - 1 - c[0], c[1], ny - 1 - c[1], c[2], nz - 1 - c[2]):
            break
    return best_d2, best_prim


@parallel_kernel
def grid_nearest_kernel(lo, res, cell_size, cell_first, cell_prims, cell_root, node_box, node_first, node_count,
                        cell_child, grid_lo, grid_res, grid_cell_size, grid_cell_base, kind, geom, in_leaf_order, pad,
                        points, limit_d2, stack_node, stack_d2, grid_stack, out_d2, out_prim):
    """For each point, the closest primitive within ``sqrt(limit_d2[i])`` (``out_d2``, ``out_prim``);
    ``geom`` in the order of ``cell_prims`` when ``in_leaf_order``, else the scene's."""
    for i in prange(points.shape[0]):
        out_d2[i], out_prim[i] = _grid_point(lo, res, cell_size, cell_first, cell_prims, cell_root, node_box,
                                             node_first, node_count, cell_child, grid_lo, grid_res, grid_cell_size,
                                             grid_cell_base, kind, geom, in_leaf_order, pad, points[i, 0],
                                             points[i, 1], points[i, 2], limit_d2[i], stack_node, stack_d2, grid_stack,
                                             thread_id())


def _nearest_scratch(rows: int, bvh_depth: int, nested_grids: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The per-thread scratch of :func:`grid_nearest_kernel`: the stacks of the cells' BVHs
    (:func:`..bvh.nearest.binary_walk_stacks`), and a row over the nested grids."""
    return (*binary_walk_stacks(rows, bvh_depth), thread_rows((rows, nested_grids + 1), np.int64))


def grid_nearest(lo, hi, res, cell_size, cell_first, cell_prims, kind, geom, points, limit_d2, out_d2, out_prim, *,
                 cell_root=None, forest=None, bvh_depth=0, nested=None, in_leaf_order=False) -> None:
    """Run :func:`grid_nearest_kernel`; ``cell_root`` and ``forest`` (node_box, node_first, node_count)
    for the hybrid's cell BVHs, ``nested`` (cell_child, grid_lo, grid_res, grid_cell_size,
    grid_cell_base) for the hierarchical grid's nested grids, ``in_leaf_order`` when ``geom`` is
    in the order of ``cell_prims``."""
    rows = numba.config.NUMBA_NUM_THREADS
    if cell_root is None:
        cell_root = np.zeros(0, dtype=np.int32)
        forest = (np.zeros((0, 6)), np.zeros(0, dtype=np.int32), np.zeros(0, dtype=np.int32))
    if nested is None:
        nested = (np.zeros(0, dtype=np.int32), np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), np.zeros((0, 3)),
                  np.zeros(0, dtype=np.int64))
    pad = 1e-9 * float(np.abs(lo).max() + np.abs(hi).max() + (hi - lo).max())
    with lent_rows(_nearest_scratch, rows, bvh_depth, len(nested[1])) as scratch:
        grid_nearest_kernel(lo, res, cell_size, cell_first, cell_prims, cell_root, *forest, *nested, kind, geom,
                            in_leaf_order, pad, points, limit_d2, *scratch, out_d2, out_prim)
