"""Helpers every builder shares: node boxes, SAH of a split, depth-first compaction and closing gaps."""

from __future__ import annotations

import numpy as np

from ..._jit import kernel

__all__ = ["ROUNDING_MARGIN", "rounding_margin", "grow_by_rounding_margin", "box_area6", "longest_axis",
           "range_bounds", "swap_prims", "permute_prims", "compact", "close_gaps", "node_depths", "box_surface_areas",
           "sah_cost"]

ROUNDING_MARGIN = 1e-11
"""Node volumes are grown by this fraction of the scene's size (coordinates included): the slab
test's rounding, about 1e-16 of the coordinates, can then never cull a node that a ray only
touches, such as one at a vertex it aims at."""


def rounding_margin(lo, hi) -> float:
    """The margin node volumes are grown by in a scene whose box is ``lo``, ``hi``."""
    lo, hi = np.asarray(lo), np.asarray(hi)
    return ROUNDING_MARGIN * float(max(np.abs(lo).max(), np.abs(hi).max()) + (hi - lo).max())


def grow_by_rounding_margin(node_box) -> float:
    """Grow the boxes ``node_box`` (rows lo, hi) in place by the rounding margin of a tree whose root
    box is ``node_box[0]``; returns the margin."""
    pad = rounding_margin(node_box[0, :3], node_box[0, 3:])
    node_box[:, :3] -= pad
    node_box[:, 3:] += pad
    return pad


@kernel
def box_area6(box):
    """Surface area of a box given as ``(lo_x, lo_y, lo_z, hi_x, hi_y, hi_z)``; 0 when empty."""
    ex = max(box[3] - box[0], 0.0)
    ey = max(box[4] - box[1], 0.0)
    ez = max(box[5] - box[2], 0.0)
    return 2.0 * (ex * ey + ey * ez + ex * ez)


@kernel
def longest_axis(box):
    """``(axis, extent)`` of the longest side of a box ``(lo_x, lo_y, lo_z, hi_x, hi_y, hi_z)``."""
    axis = 0
    extent = box[3] - box[0]
    for k in (1, 2):
        if box[k + 3] - box[k] > extent:
            axis = k
            extent = box[k + 3] - box[k]
    return axis, extent


# The top-down builders keep each primitive's box and centroid in rows that
# move together with its index in ``order``: row i of ``lo``, ``hi`` and
# ``centroid`` belongs to primitive ``order[i]``. Splits then read their range
# front to back instead of gathering through ``order`` at random.


@kernel
def swap_prims(lo, hi, centroid, order, i, j):
    """Exchange rows i and j of the primitive records."""
    for k in range(3):
        lo[i, k], lo[j, k] = lo[j, k], lo[i, k]
        hi[i, k], hi[j, k] = hi[j, k], hi[i, k]
        centroid[i, k], centroid[j, k] = centroid[j, k], centroid[i, k]
    order[i], order[j] = order[j], order[i]


@kernel
def permute_prims(lo, hi, centroid, order, start, ranked):
    """Reorder rows ``start .. start + len(ranked)`` so that new row ``start + i`` is old row ``start + ranked[i]``."""
    n = ranked.shape[0]
    rows = start + ranked
    new_lo = lo[rows]
    new_hi = hi[rows]
    new_centroid = centroid[rows]
    new_order = order[rows]
    lo[start:start + n] = new_lo
    hi[start:start + n] = new_hi
    centroid[start:start + n] = new_centroid
    order[start:start + n] = new_order


@kernel
def range_bounds(lo, hi, centroid, start, end, box, centroid_box):
    """Box of the primitive rows ``start:end`` and box of their centroids, written in place."""
    for k in range(3):
        box[k] = np.inf
        box[k + 3] = -np.inf
        centroid_box[k] = np.inf
        centroid_box[k + 3] = -np.inf
    for i in range(start, end):
        for k in range(3):
            box[k] = min(box[k], lo[i, k])
            box[k + 3] = max(box[k + 3], hi[i, k])
            centroid_box[k] = min(centroid_box[k], centroid[i, k])
            centroid_box[k + 3] = max(centroid_box[k + 3], centroid[i, k])


@kernel
def close_gaps(node_box, node_first, node_count, top_end, block_root, block_first, block_end):
    """Move the blocks of node slots ``[block_first[k], block_end[k])``, in increasing order and
    each holding the subtree under node ``block_root[k]`` (a node before ``top_end``, or -1 for a
    block that holds its own root), down to follow each other from slot ``top_end``, shifting
    the child links that point into them; returns the number of nodes. Slots only move down, so
    each is read before it is overwritten."""
    end = top_end
    for k in range(block_first.shape[0]):
        shift = block_first[k] - end
        if block_root[k] >= 0 and node_count[block_root[k]] == 0:
            node_first[block_root[k]] -= shift
        for old in range(block_first[k], block_end[k]):
            new = old - shift
            for axis in range(6):
                node_box[new, axis] = node_box[old, axis]
            node_count[new] = node_count[old]
            node_first[new] = node_first[old] - shift if node_count[old] == 0 else node_first[old]
        end += block_end[k] - block_first[k]
    return end


@kernel
def compact(node_box, left, right, leaf_first, leaf_count, root):
    """Renumber a binary tree given by ``left``/``right`` child indices (-1 at leaves)
    into the canonical layout: root 0, children side by side, depth-first order."""
    n = 0
    stack = np.empty(left.shape[0] + 1, dtype=np.int64)
    # count nodes reachable from the root
    sp = 0
    stack[sp] = root
    sp += 1
    while sp > 0:
        sp -= 1
        node = stack[sp]
        n += 1
        if left[node] >= 0:
            stack[sp] = left[node]
            stack[sp + 1] = right[node]
            sp += 2
    out_box = np.empty((n, 6))
    out_first = np.empty(n, dtype=np.int32)
    out_count = np.empty(n, dtype=np.int32)
    target = np.empty(left.shape[0] + 1, dtype=np.int64)
    sp = 0
    stack[sp] = root
    target[sp] = 0
    sp += 1
    n_out = 1
    while sp > 0:
        sp -= 1
        node = stack[sp]
        slot = target[sp]
        for k in range(6):
            out_box[slot, k] = node_box[node, k]
        if left[node] >= 0:
            out_first[slot] = n_out
            out_count[slot] = 0
            stack[sp] = right[node]
            target[sp] = n_out + 1
            stack[sp + 1] = left[node]
            target[sp + 1] = n_out
            sp += 2
            n_out += 2
        else:
            out_first[slot] = leaf_first[node]
            out_count[slot] = leaf_count[node]
    return out_box, out_first, out_count


@kernel
def node_depths(node_first, node_count):
    """Depth of every node (root 0)."""
    depth = np.zeros(node_first.shape[0], dtype=np.int64)
    for node in range(node_first.shape[0]):
        if node_count[node] == 0:
            depth[node_first[node]] = depth[node] + 1
            depth[node_first[node] + 1] = depth[node] + 1
    return depth


@kernel
def box_surface_areas(node_box):
    """Surface area of every box row ``lo, hi`` of ``node_box`` (n, 6)."""
    areas = np.empty(node_box.shape[0])
    for node in range(node_box.shape[0]):
        areas[node] = box_area6(node_box[node])
    return areas


@kernel
def sah_cost(areas, node_count, traversal_cost, intersection_cost):
    """The tree's SAH cost (MacDonald & Booth 1990): ``traversal_cost`` per inner node and
    ``intersection_cost`` per primitive of each leaf, weighted by the node's surface area
    relative to the root's, the probability that a random line through the root meets it."""
    steps = 0.0
    tests = 0.0
    for node in range(areas.shape[0]):
        if node_count[node] == 0:
            steps += areas[node]
        else:
            tests += areas[node] * node_count[node]
    return (traversal_cost * steps + intersection_cost * tests) / areas[0]
