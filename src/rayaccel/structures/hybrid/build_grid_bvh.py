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
The blocks, sized for leaves of one reference, are then compacted into one array
of the nodes the trees use, each tree depth first with siblings side by side, and
the boxes rounded outwards to float32 (:func:`_compact_forest`).
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np

from ..._jit import kernel, thread_count
from ..bvh.build_top_down import SAH_BINNED, SUBTREE_KERNELS
from ..bvh.layout import float32_boxes
from ..bvh.nodes import node_depths
from ..grid.build_uniform import build_density_grid
from .layout import GridBvhArrays

__all__ = ["build_grid_bvh"]


def _build_cell_bvhs(lo, hi, centroid, order, row_first, row_end, cell_root, max_leaf_size, bins, traversal_cost,
                     intersection_cost, node_box, node_first, node_count):
    """Build the BVH of every dense cell ``d`` over ``order[row_first[d]:row_end[d]]``, rooted in
    slot ``cell_root[d]`` with its other nodes in the slots after it: the cells, largest first,
    dealt out to two shares per thread, each share built by the binned top-down builder's
    GIL-free entry kernel on a thread of its own."""
    tasks = np.stack((cell_root, row_first, row_end), axis=1).astype(np.int64)
    tasks = tasks[np.argsort(row_first - row_end, kind="stable")]
    slots = tasks[:, 0] + 1
    threads = thread_count()
    workers = 2 * threads
    build = SUBTREE_KERNELS[SAH_BINNED]
    common = (lo, hi, centroid, order, np.zeros(0, dtype=np.int64), int(max_leaf_size), int(bins),
              float(traversal_cost), float(intersection_cost), node_box, node_first, node_count)
    unused = np.zeros((1, 3), dtype=np.int64)
    shares = [np.arange(worker, len(tasks), workers) for worker in range(min(workers, len(tasks)))]
    with ThreadPoolExecutor(threads) as pool:
        list(pool.map(lambda share: build(*common, tasks[share], slots[share], np.empty(len(share), dtype=np.int64), 0,
                                           unused), shares))


@kernel
def _depth_first_slots(cell_root, node_first, node_count):
    """The slots the cells' trees use, in their new order: each tree depth first from its root,
    a node's two children side by side; returns ``(new_slot, old_slot)``, the new slot of every
    old one (-1 for unused) and the old slot at every new one."""
    new_slot = np.full(len(node_first), -1, dtype=np.int64)
    old_slot = np.empty(len(node_first), dtype=np.int64)
    stack = np.empty(len(node_first) + 1, dtype=np.int64)
    n = 0
    for cell in range(len(cell_root)):
        root = cell_root[cell]
        if root < 0:
            continue
        new_slot[root] = n
        old_slot[n] = root
        n += 1
        stack[0] = root
        sp = 1
        while sp > 0:
            sp -= 1
            node = stack[sp]
            if node_count[node] == 0:
                left = node_first[node]
                for k in range(2):
                    new_slot[left + k] = n
                    old_slot[n] = left + k
                    n += 1
                stack[sp] = left + 1
                stack[sp + 1] = left
                sp += 2
    return new_slot, old_slot[:n]


def _compact_forest(cell_root, node_box, node_first, node_count):
    """The forest without the slots its trees leave unused, boxes in float32 rounded outwards:
    ``(cell_root, node_box, node_first, node_count)`` renumbered by :func:`_depth_first_slots`.
    Leaves keep their offsets into ``cell_prims``."""
    new_slot, old_slot = _depth_first_slots(cell_root, node_first, node_count)
    count = node_count[old_slot]
    first = node_first[old_slot]
    inner = count == 0
    first = np.where(inner, new_slot[np.where(inner, first, 0)], first).astype(np.int32)
    root = np.full_like(cell_root, -1)
    with_tree = cell_root >= 0
    root[with_tree] = new_slot[cell_root[with_tree]]
    return root, float32_boxes(node_box[old_slot]), first, count


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
    node_count = np.ones(n_nodes, dtype=np.int32)  # unused slots read as empty leaves
    depth = 0
    if len(dense):
        _build_cell_bvhs(bounds.lo[order], bounds.hi[order], bounds.centroid[order], order,
                         grid.cell_first[dense].astype(np.int64), grid.cell_first[dense + 1].astype(np.int64),
                         blocks[:-1], max_leaf_size, bins, traversal_cost, intersection_cost, node_box, node_first,
                         node_count)
        node_box[:, :3] -= pad
        node_box[:, 3:] += pad
    cell_root, node_box, node_first, node_count = _compact_forest(cell_root, node_box, node_first, node_count)
    if len(dense):
        depth = int(node_depths(node_first, node_count).max())
    arrays = GridBvhArrays(grid.lo, grid.hi, grid.res, grid.cell_size, grid.cell_first, order.astype(np.int32),
                           cell_root, node_box, node_first, node_count)
    return arrays, depth
