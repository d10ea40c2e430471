"""Bottom-up BVH by agglomerative clustering: PLOC.

Meister & Bittner, "Parallel Locally-Ordered Clustering for Bounding Volume
Hierarchy Construction", IEEE TVCG 24(3), 2018, after Walter, Bala,
Kulkarni & Pingali, "Fast Agglomerative Clustering for Rendering", IRT 2008.
Clusters start as single primitives in Morton order. In each round every
cluster finds, among the ``radius`` clusters before and after it in that
order, the one whose merged box has the smallest surface area; clusters that
are each other's nearest neighbours merge. Rounds repeat until one cluster is
left. Finally subtrees of at most ``max_leaf_size`` primitives collapse into
one leaf where the SAH says a leaf is cheaper.
"""

from __future__ import annotations

import numpy as np

from ..._jit import kernel
from .nodes import box_area6, compact

__all__ = ["build_ploc"]


@kernel
def _merged_area(node_box, a, b):
    ex = max(node_box[a, 3], node_box[b, 3]) - min(node_box[a, 0], node_box[b, 0])
    ey = max(node_box[a, 4], node_box[b, 4]) - min(node_box[a, 1], node_box[b, 1])
    ez = max(node_box[a, 5], node_box[b, 5]) - min(node_box[a, 2], node_box[b, 2])
    return 2.0 * (ex * ey + ey * ez + ex * ez)


@kernel
def _merge(node_box, left, right, clusters, i, j, node):
    """Make ``node`` the parent of clusters i and j; it takes i's place, j's place is freed."""
    a = clusters[i]
    b = clusters[j]
    left[node] = a
    right[node] = b
    for k in range(3):
        node_box[node, k] = min(node_box[a, k], node_box[b, k])
        node_box[node, k + 3] = max(node_box[a, k + 3], node_box[b, k + 3])
    clusters[i] = node
    clusters[j] = -1


@kernel
def _cluster(lo, hi, morton_order, radius):
    """Merge clusters until one is left; returns the binary tree (leaves 0..n-1 are primitives)."""
    n = lo.shape[0]
    capacity = 2 * n - 1
    node_box = np.empty((capacity, 6))
    left = np.full(capacity, -1, dtype=np.int64)
    right = np.full(capacity, -1, dtype=np.int64)
    for p in range(n):
        node_box[p, 0:3] = lo[p]
        node_box[p, 3:6] = hi[p]
    clusters = morton_order.copy()
    nearest = np.empty(n, dtype=np.int64)
    n_nodes = n
    n_clusters = n
    while n_clusters > 1:
        for i in range(n_clusters):
            # closest candidates first, and on equal areas the nearer one in the
            # order; even clusters look right first, odd ones left, so that equal
            # clusters pair up as (0, 1), (2, 3), ... and halve every round
            best = np.inf
            best_j = -1
            direction = 1 if i % 2 == 0 else -1
            for distance in range(1, radius + 1):
                for j in (i + direction * distance, i - direction * distance):
                    if 0 <= j < n_clusters:
                        area = _merged_area(node_box, clusters[i], clusters[j])
                        if area < best:
                            best = area
                            best_j = j
            nearest[i] = best_j
        merged_any = False
        for i in range(n_clusters):
            j = nearest[i]
            if j > i and nearest[j] == i:
                _merge(node_box, left, right, clusters, i, j, n_nodes)
                n_nodes += 1
                merged_any = True
        if not merged_any:  # cannot happen with a symmetric distance; kept as a guard against loops
            _merge(node_box, left, right, clusters, 0, 1, n_nodes)
            n_nodes += 1
        kept = 0
        for i in range(n_clusters):
            if clusters[i] >= 0:
                clusters[kept] = clusters[i]
                kept += 1
        n_clusters = kept
    return node_box[:n_nodes], left[:n_nodes], right[:n_nodes], clusters[0]


@kernel
def _collapse(node_box, left, right, root, n_prims, max_leaf_size, traversal_cost, intersection_cost):
    """Turn subtrees into leaves where the SAH prefers it; lay their primitives out contiguously."""
    n_nodes = left.shape[0]
    prims_below = np.zeros(n_nodes, dtype=np.int64)
    cost = np.zeros(n_nodes)
    as_leaf = np.zeros(n_nodes, dtype=np.bool_)
    for node in range(n_nodes):  # children are created before their parents
        if left[node] < 0:
            prims_below[node] = 1
            cost[node] = intersection_cost
            as_leaf[node] = True
        else:
            a, b = left[node], right[node]
            prims_below[node] = prims_below[a] + prims_below[b]
            area = max(box_area6(node_box[node]), 1e-300)
            split = traversal_cost + (box_area6(node_box[a]) * cost[a] + box_area6(node_box[b]) * cost[b]) / area
            leaf = intersection_cost * prims_below[node]
            if prims_below[node] <= max_leaf_size and leaf <= split:
                cost[node] = leaf
                as_leaf[node] = True
            else:
                cost[node] = split
    prim_order = np.empty(n_prims, dtype=np.int64)
    leaf_first = np.zeros(n_nodes, dtype=np.int64)
    leaf_count = np.zeros(n_nodes, dtype=np.int64)
    out_left = left.copy()
    out_right = right.copy()
    stack = np.empty(n_nodes + 1, dtype=np.int64)
    inner = np.empty(n_nodes + 1, dtype=np.int64)
    filled = 0
    sp = 1
    stack[0] = root
    while sp > 0:
        sp -= 1
        node = stack[sp]
        if as_leaf[node]:
            out_left[node] = -1
            out_right[node] = -1
            leaf_first[node] = filled
            leaf_count[node] = prims_below[node]
            inner_sp = 1
            inner[0] = node
            while inner_sp > 0:
                inner_sp -= 1
                sub = inner[inner_sp]
                if left[sub] < 0:
                    prim_order[filled] = sub
                    filled += 1
                else:
                    inner[inner_sp] = right[sub]
                    inner[inner_sp + 1] = left[sub]
                    inner_sp += 2
        else:
            stack[sp] = right[node]
            stack[sp + 1] = left[node]
            sp += 2
    return out_left, out_right, leaf_first, leaf_count, prim_order


def build_ploc(lo, hi, morton_order, radius, max_leaf_size, traversal_cost, intersection_cost):
    """PLOC over primitive boxes; returns ``(node_box, node_first, node_count, prim_order)``."""
    n = lo.shape[0]
    if n == 1:
        return (np.concatenate([lo[0], hi[0]])[None, :], np.zeros(1, np.int32), np.ones(1, np.int32),
                np.zeros(1, np.int64))
    node_box, left, right, root = _cluster(lo, hi, morton_order, radius)
    left, right, leaf_first, leaf_count, prim_order = _collapse(node_box, left, right, root, n, max_leaf_size,
                                                                traversal_cost, intersection_cost)
    box, first, count = compact(node_box, left, right, leaf_first, leaf_count, root)
    return box, first, count, prim_order
