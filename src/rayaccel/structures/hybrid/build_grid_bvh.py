"""Grid-BVH hybrid construction: a uniform grid, then a binned-SAH BVH in every dense cell.

The hybrid the lecture sketches (grids and hierarchies combined, as in
Cazals, Drettakis & Puech's "Filtering, Clustering and Hierarchy Construction"
1995 and the two-level schemes since): a coarse uniform grid skips empty space
with cheap DDA steps, and cells crowded with primitives -- where a grid would
need many more cells -- are searched by a BVH instead. The grid is built as in
:mod:`..grid.build_uniform`; the cells with more than ``threshold`` references
then get a BVH over their references with the top-down binned SAH builder of
:mod:`..bvh.build_top_down`, all cells in parallel, each into its own block
of node slots; the hybrid shares that builder's compiled kernel with ``bvh-binned``.
The blocks, sized for leaves of one reference, are then moved together so that no
slot is left unused (:func:`..bvh.nodes.close_gaps`, as the top-down builder
closes the gaps between its subtrees), and the boxes rounded outwards to float32.
"""

from __future__ import annotations

import numpy as np

from ..._jit import thread_count
from ..bvh.build_top_down import SAH_BINNED, SUBTREE_KERNELS, build_blocks
from ..bvh.layout import float32_boxes
from ..bvh.nodes import close_gaps, node_depths
from ..grid.build_uniform import build_density_grid
from .layout import GridBvhArrays

__all__ = ["build_grid_bvh"]


def _build_cell_bvhs(lo, hi, centroid, order, row_first, row_end, cell_root, max_leaf_size, bins, traversal_cost,
                     intersection_cost, node_box, node_first, node_count):
    """Build the BVH of every dense cell ``d`` over ``order[row_first[d]:row_end[d]]``, rooted in
    slot ``cell_root[d]`` with its other nodes in the slots after it: the cells, largest first,
    dealt out to two shares per thread, each share built by the binned top-down builder's
    GIL-free entry kernel on a thread of its own (:func:`..bvh.build_top_down.build_blocks`).
    Returns the slot after each cell's tree."""
    tasks = np.stack((cell_root, row_first, row_end), axis=1).astype(np.int64)
    by_size = np.argsort(row_first - row_end, kind="stable")
    tasks = tasks[by_size]
    common = (lo, hi, centroid, order, np.zeros(0, dtype=np.int64), int(max_leaf_size), int(bins),
              float(traversal_cost), float(intersection_cost), node_box, node_first, node_count)
    ends = build_blocks(SUBTREE_KERNELS[SAH_BINNED], common, tasks, tasks[:, 0] + 1, thread_count())
    cell_ends = np.empty_like(ends)
    cell_ends[by_size] = ends
    return cell_ends


def build_grid_bvh(bounds, kind, geom, density, threshold, max_leaf_size, bins, traversal_cost, intersection_cost,
                   exact, pad) -> tuple[GridBvhArrays, int]:
    """Build the hybrid; returns the arrays and the deepest BVH's depth. Node boxes are grown by ``pad``."""
    grid = build_density_grid(bounds, kind, geom, density, exact)
    counts = np.diff(grid.cell_first)
    dense = np.flatnonzero(counts > threshold)
    sizes = counts[dense].astype(np.int64)
    cell_root = np.full(len(counts), -1, dtype=np.int32)
    blocks = np.zeros(len(dense) + 1, dtype=np.int64)
    np.cumsum(2 * sizes - 1, out=blocks[1:])
    cell_root[dense] = blocks[:-1]
    order = grid.cell_prims.astype(np.int64)
    n_nodes = int(blocks[-1])
    node_box = np.zeros((n_nodes, 6))
    node_first = np.zeros(n_nodes, dtype=np.int32)
    node_count = np.ones(n_nodes, dtype=np.int32)
    depth = 0
    if len(dense):
        ends = _build_cell_bvhs(bounds.lo[order], bounds.hi[order], bounds.centroid[order], order,
                                grid.cell_first[dense].astype(np.int64), grid.cell_first[dense + 1].astype(np.int64),
                                blocks[:-1], max_leaf_size, bins, traversal_cost, intersection_cost, node_box,
                                node_first, node_count)
        n_nodes = close_gaps(node_box, node_first, node_count, 0, np.full(len(dense), -1, dtype=np.int64),
                             blocks[:-1], ends)
        used = ends - blocks[:-1]
        cell_root[dense] = np.cumsum(used) - used
        node_box[:n_nodes, :3] -= pad
        node_box[:n_nodes, 3:] += pad
        depth = int(node_depths(node_first[:n_nodes], node_count[:n_nodes]).max())
    arrays = GridBvhArrays(grid.lo, grid.hi, grid.res, grid.cell_size, grid.cell_first, order.astype(np.int32),
                           cell_root, float32_boxes(node_box[:n_nodes]), node_first[:n_nodes].copy(),
                           node_count[:n_nodes].copy())
    return arrays, depth
