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

from ..._jit import kernel
from .nodes import box_area6, range_bounds
from .split_median_object import split_object_median
from .split_median_space import split_spatial_median
from .split_morton import split_morton
from .split_sah_binned import split_sah_binned
from .split_sah_sweep import split_sah_sweep

__all__ = ["SPATIAL_MEDIAN", "OBJECT_MEDIAN", "SAH_SWEEP", "SAH_BINNED", "MORTON", "build_top_down"]

SPATIAL_MEDIAN = 0
OBJECT_MEDIAN = 1
SAH_SWEEP = 2
SAH_BINNED = 3
MORTON = 4


@kernel
def build_top_down(lo, hi, centroid, order, sorted_codes, strategy, max_leaf_size, bins,
                   traversal_cost, intersection_cost):
    """Build over the primitives in ``order`` (permuted in place into leaf order).

    Returns ``(node_box, node_first, node_count)`` in the canonical layout.
    """
    n = order.shape[0]
    capacity = 2 * n - 1
    node_box = np.empty((capacity, 6))
    node_first = np.empty(capacity, dtype=np.int32)
    node_count = np.empty(capacity, dtype=np.int32)
    task_node = np.empty(n + 1, dtype=np.int64)
    task_start = np.empty(n + 1, dtype=np.int64)
    task_end = np.empty(n + 1, dtype=np.int64)
    box = np.empty(6)
    centroid_box = np.empty(6)
    scratch_box = np.empty((max(bins, 1), 6))
    scratch_count = np.empty(max(bins, 1), dtype=np.int64)
    scratch_area = np.empty(max(bins, 1))
    n_nodes = 1
    sp = 1
    task_node[0] = 0
    task_start[0] = 0
    task_end[0] = n
    while sp > 0:
        sp -= 1
        node = task_node[sp]
        start = task_start[sp]
        end = task_end[sp]
        range_bounds(lo, hi, centroid, order, start, end, box, centroid_box)
        node_box[node, :] = box
        count = end - start
        mid = -1
        if count > 1:
            if strategy == SAH_BINNED or strategy == SAH_SWEEP:
                area = box_area6(box)
                if strategy == SAH_BINNED:
                    mid, cost = split_sah_binned(lo, hi, centroid, order, start, end, centroid_box, area, bins,
                                                 traversal_cost, intersection_cost, scratch_box, scratch_count,
                                                 scratch_area)
                else:
                    mid, cost = split_sah_sweep(lo, hi, centroid, order, start, end, area,
                                                traversal_cost, intersection_cost)
                if count <= max_leaf_size and (mid < 0 or cost >= intersection_cost * count):
                    mid = -1
                elif mid < 0:
                    mid = split_object_median(centroid, order, start, end, centroid_box)
            elif count > max_leaf_size:
                if strategy == SPATIAL_MEDIAN:
                    mid = split_spatial_median(centroid, order, start, end, centroid_box)
                elif strategy == MORTON:
                    mid = split_morton(sorted_codes, start, end)
                if mid < 0:
                    mid = split_object_median(centroid, order, start, end, centroid_box)
        if mid < 0:
            node_first[node] = start
            node_count[node] = count
        else:
            left = n_nodes
            n_nodes += 2
            node_first[node] = left
            node_count[node] = 0
            task_node[sp] = left + 1
            task_start[sp] = mid
            task_end[sp] = end
            task_node[sp + 1] = left
            task_start[sp + 1] = start
            task_end[sp + 1] = mid
            sp += 2
    return node_box[:n_nodes].copy(), node_first[:n_nodes].copy(), node_count[:n_nodes].copy()
