"""The top-down BVH builder that the median, SAH and Morton splits plug into.

A stack of (node, start, end) tasks over a permutation of the primitives:
each task computes its node's box, asks the split strategy for a cut, and
either makes a leaf or pushes its two children, allocated side by side as the
layout in :mod:`.layout` wants. The builder sees only primitive boxes and
centroids (and Morton codes for the linear BVH), never geometry.

Leaves: a node with at most ``max_leaf_size`` primitives becomes a leaf when
the strategy is a median or Morton split; with the SAH it becomes a leaf only
when that is cheaper than the best split (``C_i n <= split cost``). A node
with more primitives is always split, with the object median as the fallback
when the strategy cannot separate them (all centroids equal), so every leaf
holds at most ``max_leaf_size`` primitives.
"""

from __future__ import annotations

import numpy as np
from numba import prange

from ..._jit import kernel, parallel_kernel
from .nodes import box_area6, compact, range_bounds
from .split_median_object import split_object_median
from .split_median_space import split_spatial_median
from .split_morton import split_morton
from .split_sah_binned import split_sah_binned
from .split_sah_sweep import split_sah_sweep

__all__ = ["SPATIAL_MEDIAN", "OBJECT_MEDIAN", "SAH_SWEEP", "SAH_BINNED", "MORTON", "build_subtree", "build_top_down"]

SPATIAL_MEDIAN = 0
OBJECT_MEDIAN = 1
SAH_SWEEP = 2
SAH_BINNED = 3
MORTON = 4


@kernel
def build_subtree(lo, hi, centroid, order, sorted_codes, strategy, max_leaf_size, bins, traversal_cost,
                   intersection_cost, node_box, node_first, node_count, root, start, end, next_free,
                   defer_below, deferred):
    """Build the subtree of ``order[start:end]`` with its root in slot ``root`` and its other
    nodes from slot ``next_free`` on. Tasks with fewer than ``defer_below`` primitives are
    not built but appended to ``deferred`` as (node, start, end) rows, counted in its row 0.
    Returns the next free slot."""
    n = end - start
    task_node = np.empty(n + 1, dtype=np.int64)
    task_start = np.empty(n + 1, dtype=np.int64)
    task_end = np.empty(n + 1, dtype=np.int64)
    box = np.empty(6)
    centroid_box = np.empty(6)
    scratch_box = np.empty((3 * max(bins, 1), 6))
    scratch_count = np.empty(3 * max(bins, 1), dtype=np.int64)
    scratch_area = np.empty(max(bins, 1))
    scratch_acc = np.empty(6)
    sp = 1
    task_node[0] = root
    task_start[0] = start
    task_end[0] = end
    while sp > 0:
        sp -= 1
        node = task_node[sp]
        start = task_start[sp]
        end = task_end[sp]
        count = end - start
        if count < defer_below:
            row = deferred[0, 0] + 1
            deferred[0, 0] = row
            deferred[row, 0] = node
            deferred[row, 1] = start
            deferred[row, 2] = end
            continue
        range_bounds(lo, hi, centroid, start, end, box, centroid_box)
        node_box[node, :] = box
        mid = -1
        if count > 1:
            if strategy == SAH_BINNED or strategy == SAH_SWEEP:
                area = box_area6(box)
                if strategy == SAH_BINNED:
                    mid, cost = split_sah_binned(lo, hi, centroid, order, start, end, centroid_box, area, bins,
                                                 traversal_cost, intersection_cost, scratch_box, scratch_count,
                                                 scratch_area, scratch_acc)
                else:
                    mid, cost = split_sah_sweep(lo, hi, centroid, order, start, end, area,
                                                traversal_cost, intersection_cost)
                if count <= max_leaf_size and (mid < 0 or cost >= intersection_cost * count):
                    mid = -1
                elif mid < 0:
                    mid = split_object_median(lo, hi, centroid, order, start, end, centroid_box)
            elif count > max_leaf_size:
                if strategy == SPATIAL_MEDIAN:
                    mid = split_spatial_median(lo, hi, centroid, order, start, end, centroid_box)
                elif strategy == MORTON:
                    mid = split_morton(sorted_codes, start, end)
                if mid < 0:
                    mid = split_object_median(lo, hi, centroid, order, start, end, centroid_box)
        if mid < 0:
            node_first[node] = start
            node_count[node] = count
        else:
            left = next_free
            next_free += 2
            node_first[node] = left
            node_count[node] = 0
            task_node[sp] = left + 1
            task_start[sp] = mid
            task_end[sp] = end
            task_node[sp + 1] = left
            task_start[sp + 1] = start
            task_end[sp + 1] = mid
            sp += 2
    return next_free


@parallel_kernel
def build_top_down(lo, hi, centroid, order, sorted_codes, strategy, max_leaf_size, bins,
                   traversal_cost, intersection_cost, threads):
    """Build over the primitives in ``order`` (permuted in place into leaf order);
    the boxes and centroids are copied, then permuted along with ``order``.

    The top of the tree is built on one thread until the tasks left are
    smaller than ``n / (8 * threads)`` (at least 4096 primitives); those subtrees are then built in
    parallel, each into its own block of node slots (a subtree of m primitives
    needs at most 2m - 1), and the result is compacted into the canonical
    layout. Returns ``(node_box, node_first, node_count)``.
    """
    n = order.shape[0]
    lo = lo[order]
    hi = hi[order]
    centroid = centroid[order]
    workers = 2 * threads
    defer_below = max(n // (4 * workers), 4096) if threads > 1 else n + 1
    capacity = 4 * n + 1
    node_box = np.empty((capacity, 6))
    node_first = np.empty(capacity, dtype=np.int32)
    node_count = np.empty(capacity, dtype=np.int32)
    deferred = np.zeros((n + 1, 3), dtype=np.int64)
    top_end = build_subtree(lo, hi, centroid, order, sorted_codes, strategy, max_leaf_size, bins, traversal_cost,
                             intersection_cost, node_box, node_first, node_count, 0, 0, n, 1, defer_below, deferred)
    n_tasks = deferred[0, 0]
    tasks = deferred[1:n_tasks + 1]
    by_size = np.argsort(tasks[:, 1] - tasks[:, 2])  # largest first
    block = np.empty(n_tasks + 1, dtype=np.int64)
    block[0] = top_end
    for k in range(n_tasks):
        size = tasks[by_size[k], 2] - tasks[by_size[k], 1]
        block[k + 1] = block[k] + 2 * size - 1
    unused = np.zeros((1, 3), dtype=np.int64)
    for worker in prange(workers):
        for k in range(worker, n_tasks, workers):
            task = by_size[k]
            build_subtree(lo, hi, centroid, order, sorted_codes, strategy, max_leaf_size, bins, traversal_cost,
                           intersection_cost, node_box, node_first, node_count, tasks[task, 0], tasks[task, 1],
                           tasks[task, 2], block[k], 0, unused)
    used = block[n_tasks]
    if n_tasks == 0:
        return node_box[:used].copy(), node_first[:used].copy(), node_count[:used].copy()
    left = np.full(used, -1, dtype=np.int64)
    right = np.full(used, -1, dtype=np.int64)
    leaf_first = np.zeros(used, dtype=np.int64)
    leaf_count = np.zeros(used, dtype=np.int64)
    for node in range(used):
        if node_count[node] == 0:
            left[node] = node_first[node]
            right[node] = node_first[node] + 1
        else:
            leaf_first[node] = node_first[node]
            leaf_count[node] = node_count[node]
    return compact(node_box[:used], left, right, leaf_first, leaf_count, 0)
