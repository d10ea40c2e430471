"""Binned SAH splits for the upper levels of the kd-tree.

The exact event sweep (:mod:`.build_sah_events`) handles about six events per
primitive at every level, at about 12 ns each (sweep, classification and
distribution, measured on the bunny); binning handles a primitive's reference
at a level in about 35 ns (measured on the dragon's root), and on the large
nodes near the root an approximate plane costs little tree quality (expected
cost on the full dragon 90.2 against 89.7). There the builder counts the
primitives' box faces into ``bins`` equal bins per axis (the
min-max binning of Popov, Guenther, Seidel & Slusallek, "Experiences with
Streaming Construction of SAH KD-Trees", IEEE Symposium on Interactive Ray
Tracing 2006, and of Shevtsov, Soupikov & Kapustin, "Highly Parallel Fast
KD-tree Construction for Interactive Ray Tracing of Dynamic Scenes",
Eurographics 2007) and tries the planes between bins: prefix sums of the
*start* counts give ``N_L``, suffix sums of the *end* counts ``N_R``, and
the cost is the same as the sweep's, empty bonus included. No events and no
sorting are needed.

A node is split this way while it holds at least ``task_below`` primitives;
smaller nodes are returned as tasks: for the exact sweep, which starts from
their (clipped) boxes, or for binning on other threads. Straddling primitives
are clipped to each child's cell as in the sweep, so splits stay perfect.
"""

from __future__ import annotations

import numpy as np
from numba.typed import List

from ..._jit import inline_kernel, kernel
from ...geometry.clip import CLIP_VERTICES, split_clipped_bounds
from ..build_arrays import reserve_rows
from .layout import LEAF, add_children, split_cell
from .split_cost import split_cost

__all__ = ["build_binned_top"]


@kernel
def _bin_faces(boxes, cell, bins, starts, ends):
    """Count on each axis the boxes whose low face (``starts``) and high face (``ends``)
    fall into each of ``bins`` equal bins across the cell."""
    starts[:] = 0
    ends[:] = 0
    scale = np.empty(3)
    for axis in range(3):
        scale[axis] = bins / max(cell[axis + 3] - cell[axis], 1e-300)
    top = bins - 1
    for i in range(boxes.shape[0]):
        for axis in range(3):
            b0 = int((boxes[i, axis] - cell[axis]) * scale[axis])
            b1 = int((boxes[i, axis + 3] - cell[axis]) * scale[axis])
            starts[axis, min(max(b0, 0), top)] += 1
            ends[axis, min(max(b1, 0), top)] += 1


@kernel
def _best_binned_plane(starts, ends, n, cell, bins, traversal_cost, intersection_cost, empty_bonus):
    """The cheapest plane between bins on any axis: ``(cost, axis, position)``; cost is inf
    when the cell has no area or no plane lies inside it."""
    best_cost = np.inf
    best_axis = -1
    best_pos = 0.0
    for axis in range(3):
        lo = cell[axis]
        hi = cell[axis + 3]
        e1 = cell[(axis + 1) % 3 + 3] - cell[(axis + 1) % 3]
        e2 = cell[(axis + 2) % 3 + 3] - cell[(axis + 2) % 3]
        area = 2.0 * (e1 * e2 + (hi - lo) * (e1 + e2))
        if area <= 0.0 or hi <= lo:
            continue
        scale = 2.0 * intersection_cost / area
        n_left = 0
        n_right = n
        for b in range(1, bins):
            n_left += starts[axis, b - 1]
            n_right -= ends[axis, b - 1]
            p = lo + (hi - lo) * b / bins
            if not lo < p < hi:
                continue
            area_left = e1 * e2 + (p - lo) * (e1 + e2)
            area_right = e1 * e2 + (hi - p) * (e1 + e2)
            cost = split_cost(traversal_cost, scale, area_left, n_left, area_right, n_right, empty_bonus)
            if cost < best_cost:
                best_cost, best_axis, best_pos = cost, axis, p
    return best_cost, best_axis, best_pos


@inline_kernel
def _copy_ref(prim, box, ids, boxes, k):
    ids[k] = prim
    for c in range(6):
        boxes[k, c] = box[c]


@kernel
def _split_refs(ids, boxes, axis, p, cell, kind, geom, slack):
    """The references of the two children of a split at ``p`` on ``axis``: boxes wholly at or
    below ``p`` go left (those flat in the plane too), boxes at or above it right, and the
    primitives straddling it are clipped to each child's cell. Returns
    ``(left_ids, left_boxes, right_ids, right_boxes)``."""
    n = ids.shape[0]
    n_left = 0
    n_right = 0
    for i in range(n):
        n_left += boxes[i, axis] < p or boxes[i, axis + 3] <= p
        n_right += boxes[i, axis + 3] > p
    left_ids = np.empty(n_left, dtype=np.int64)
    left_boxes = np.empty((n_left, 6))
    right_ids = np.empty(n_right, dtype=np.int64)
    right_boxes = np.empty((n_right, 6))
    n_left = 0
    n_right = 0
    poly = np.empty((2, CLIP_VERTICES, 3))
    clipped = np.empty((2, 6))
    for i in range(n):
        left = boxes[i, axis + 3] <= p
        right = boxes[i, axis] >= p and not left
        if left:
            _copy_ref(ids[i], boxes[i], left_ids, left_boxes, n_left)
            n_left += 1
        elif right:
            _copy_ref(ids[i], boxes[i], right_ids, right_boxes, n_right)
            n_right += 1
        else:
            sides = split_clipped_bounds(kind, geom, ids[i], cell, axis, p, slack, poly, clipped)
            if sides & 1:
                _copy_ref(ids[i], clipped[0], left_ids, left_boxes, n_left)
                n_left += 1
            if sides & 2:
                _copy_ref(ids[i], clipped[1], right_ids, right_boxes, n_right)
                n_right += 1
    return left_ids[:n_left], left_boxes[:n_left], right_ids[:n_right], right_boxes[:n_right]


@kernel
def build_binned_top(ids, boxes, cell, depth, kind, geom, traversal_cost, intersection_cost, empty_bonus, leaf_size,
                     max_depth, slack, bins, task_below):
    """Build the kd-tree's nodes of at least ``task_below`` primitives with binned SAH splits.

    ``ids`` and ``boxes`` (n, 6: lo, hi) are the primitives of the root, a node at
    ``depth`` with ``cell``, and their bounds within it. Smaller nodes are left as
    placeholders and returned as tasks. Returns ``(node_split, node_link, leaf_prims,
    tasks)`` with ``tasks`` listing ``(node, ids, boxes, cell, depth)``.
    """
    node_split = np.zeros(64)
    node_link = np.zeros((64, 2), dtype=np.int32)
    leaf_prims = np.empty(16, dtype=np.int32)
    n_nodes = 1
    n_refs = 0
    starts = np.empty((3, bins), dtype=np.int64)
    ends = np.empty((3, bins), dtype=np.int64)
    child_cell = np.empty((2, 6))
    stack = List()
    stack.append((0, ids, boxes, cell.copy(), depth))
    tasks = List()
    while len(stack) > 0:
        node, ids, boxes, cell, depth = stack.pop()
        n = ids.shape[0]
        if n < task_below:
            tasks.append((node, ids, boxes, cell, depth))
            continue
        best_cost = np.inf
        axis = -1
        if n > leaf_size and depth < max_depth:
            _bin_faces(boxes, cell, bins, starts, ends)
            best_cost, axis, p = _best_binned_plane(starts, ends, n, cell, bins, traversal_cost, intersection_cost,
                                                    empty_bonus)
        if axis < 0 or best_cost >= intersection_cost * n:
            leaf_prims = reserve_rows(leaf_prims, n_refs + n)
            node_link[node, 0] = n_refs
            node_link[node, 1] = n << 2 | LEAF
            leaf_prims[n_refs:n_refs + n] = ids
            n_refs += n
            continue
        left_ids, left_boxes, right_ids, right_boxes = _split_refs(ids, boxes, axis, p, cell, kind, geom, slack)
        split_cell(cell, axis, p, child_cell)
        node_split, node_link, child, n_nodes = add_children(node_split, node_link, n_nodes, node, p, axis)
        stack.append((child + 1, right_ids, right_boxes, child_cell[1].copy(), depth + 1))
        stack.append((child, left_ids, left_boxes, child_cell[0].copy(), depth + 1))
    return node_split[:n_nodes].copy(), node_link[:n_nodes].copy(), leaf_prims[:n_refs].copy(), tasks
