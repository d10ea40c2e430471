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
when the strategy cannot separate them, so every leaf holds at most
``max_leaf_size`` primitives.

Compiling only what a method needs: the loop :func:`build_subtrees` is
compiled into its callers at Numba's IR level (``inline="always"``), and each
strategy has its own small entry kernel that calls it with the strategy as a
module constant. Numba's dead-branch pruning, which runs after inlining, then
drops the other strategies' branches before type inference, so a build
compiles its own split kernel only (measured on the bunny with an empty
cache: ``bvh-binned`` no longer compiles the sweep, the medians, the Morton
split or the merge sort). Passing the split as a first-class function or
making the entry kernels in a factory would do the same but defeats Numba's
on-disk cache, which keys a kernel by its module and name. The threads of the
parallel phase are Python threads running the GIL-free entry kernel, as the
kd-tree builder's are: a ``prange`` kernel would add a parallel compile of
the whole loop (8 s on the bunny's first build).
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np

from ..._jit import inline_kernel, kernel
from .nodes import box_area6, close_gaps, range_bounds
from .split_median_object import split_object_median
from .split_median_space import split_spatial_median
from .split_morton import split_morton
from .split_sah_binned import split_sah_binned
from .split_sah_sweep import split_sah_sweep

__all__ = ["SPATIAL_MEDIAN", "OBJECT_MEDIAN", "SAH_SWEEP", "SAH_BINNED", "MORTON", "SUBTREE_KERNELS",
           "build_subtrees", "build_blocks", "build_top_down"]

SPATIAL_MEDIAN = 0
OBJECT_MEDIAN = 1
SAH_SWEEP = 2
SAH_BINNED = 3
MORTON = 4


@inline_kernel
def build_subtrees(strategy, lo, hi, centroid, order, sorted_codes, max_leaf_size, bins, traversal_cost,
                   intersection_cost, node_box, node_first, node_count, tasks, slots, ends, defer_below, deferred):
    """Build the subtree of every row ``(node, start, end)`` of ``tasks``: over
    ``order[start:end]``, its root in slot ``node`` and its other nodes from slot
    ``slots[k]`` on, up to the slot before ``ends[k]``, which it writes. Tasks with fewer
    than ``defer_below`` primitives met on the way are not built but appended to
    ``deferred`` as (node, start, end) rows, counted in its row 0. Returns the next free
    slot after the last task's subtree."""
    box = np.empty(6)
    centroid_box = np.empty(6)
    scratch_box = np.empty((3 * max(bins, 1), 6))
    scratch_count = np.empty(3 * max(bins, 1), dtype=np.int64)
    scratch_area = np.empty(max(bins, 1))
    scratch_acc = np.empty(6)
    child_bounds = np.empty((2, 12))
    next_free = 0
    for k in range(tasks.shape[0]):
        next_free = slots[k]
        n = tasks[k, 2] - tasks[k, 1]
        task_node = np.empty(n + 1, dtype=np.int64)
        task_start = np.empty(n + 1, dtype=np.int64)
        task_end = np.empty(n + 1, dtype=np.int64)
        task_bounds = np.empty((n + 1, 12))
        task_bounded = np.empty(n + 1, dtype=np.bool_)
        task_node[0] = tasks[k, 0]
        task_bounded[0] = False
        task_start[0] = tasks[k, 1]
        task_end[0] = tasks[k, 2]
        sp = 1
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
            if task_bounded[sp]:
                for axis in range(6):
                    box[axis] = task_bounds[sp, axis]
                    centroid_box[axis] = task_bounds[sp, axis + 6]
            else:
                range_bounds(lo, hi, centroid, start, end, box, centroid_box)
            for axis in range(6):
                node_box[node, axis] = box[axis]
            mid = -1
            bounded = False
            if count > 1:
                if strategy == SAH_BINNED or strategy == SAH_SWEEP:
                    area = box_area6(box)
                    if strategy == SAH_BINNED:
                        mid, cost = split_sah_binned(lo, hi, centroid, order, start, end, centroid_box, area, bins,
                                                     traversal_cost, intersection_cost, scratch_box, scratch_count,
                                                     scratch_area, scratch_acc, child_bounds)
                        bounded = mid >= 0
                    else:
                        mid, cost = split_sah_sweep(lo, hi, centroid, order, start, end, area,
                                                    traversal_cost, intersection_cost)
                    if count <= max_leaf_size and (mid < 0 or cost >= intersection_cost * count):
                        mid = -1
                    elif mid < 0:
                        # the SAH splits give up only when all centroids coincide: the object median is
                        # then the middle, with nothing to sort
                        mid = (start + end) // 2
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
                task_bounded[sp] = bounded
                task_bounded[sp + 1] = bounded
                if bounded:
                    for axis in range(12):
                        task_bounds[sp, axis] = child_bounds[1, axis]
                        task_bounds[sp + 1, axis] = child_bounds[0, axis]
                sp += 2
        ends[k] = next_free
    return next_free


@kernel
def _spatial_median_subtrees(lo, hi, centroid, order, sorted_codes, max_leaf_size, bins, traversal_cost,
                             intersection_cost, node_box, node_first, node_count, tasks, slots, ends, defer_below,
                            deferred):
    """:func:`build_subtrees` split at the spatial median."""
    return build_subtrees(SPATIAL_MEDIAN, lo, hi, centroid, order, sorted_codes, max_leaf_size, bins,
                          traversal_cost, intersection_cost, node_box, node_first, node_count, tasks, slots,
                          ends, defer_below, deferred)


@kernel
def _object_median_subtrees(lo, hi, centroid, order, sorted_codes, max_leaf_size, bins, traversal_cost,
                            intersection_cost, node_box, node_first, node_count, tasks, slots, ends, defer_below,
                            deferred):
    """:func:`build_subtrees` split at the object median."""
    return build_subtrees(OBJECT_MEDIAN, lo, hi, centroid, order, sorted_codes, max_leaf_size, bins,
                          traversal_cost, intersection_cost, node_box, node_first, node_count, tasks, slots,
                          ends, defer_below, deferred)


@kernel
def _sah_sweep_subtrees(lo, hi, centroid, order, sorted_codes, max_leaf_size, bins, traversal_cost,
                        intersection_cost, node_box, node_first, node_count, tasks, slots, ends, defer_below, deferred):
    """:func:`build_subtrees` split by the full-sweep SAH."""
    return build_subtrees(SAH_SWEEP, lo, hi, centroid, order, sorted_codes, max_leaf_size, bins,
                          traversal_cost, intersection_cost, node_box, node_first, node_count, tasks, slots,
                          ends, defer_below, deferred)


@kernel
def _sah_binned_subtrees(lo, hi, centroid, order, sorted_codes, max_leaf_size, bins, traversal_cost,
                         intersection_cost, node_box, node_first, node_count, tasks, slots, ends, defer_below,
                         deferred):
    """:func:`build_subtrees` split by the binned SAH."""
    return build_subtrees(SAH_BINNED, lo, hi, centroid, order, sorted_codes, max_leaf_size, bins,
                          traversal_cost, intersection_cost, node_box, node_first, node_count, tasks, slots,
                          ends, defer_below, deferred)


@kernel
def _morton_subtrees(lo, hi, centroid, order, sorted_codes, max_leaf_size, bins, traversal_cost,
                     intersection_cost, node_box, node_first, node_count, tasks, slots, ends, defer_below, deferred):
    """:func:`build_subtrees` split where the Morton codes' top differing bit changes."""
    return build_subtrees(MORTON, lo, hi, centroid, order, sorted_codes, max_leaf_size, bins,
                          traversal_cost, intersection_cost, node_box, node_first, node_count, tasks, slots,
                          ends, defer_below, deferred)


SUBTREE_KERNELS = {SPATIAL_MEDIAN: _spatial_median_subtrees, OBJECT_MEDIAN: _object_median_subtrees,
                   SAH_SWEEP: _sah_sweep_subtrees, SAH_BINNED: _sah_binned_subtrees, MORTON: _morton_subtrees}
"""The entry kernel of each strategy, all with the arguments of :func:`build_subtrees` after ``strategy``."""


def build_blocks(build, common, tasks, slots, threads):
    """Build the subtree of each task (rows ``(root slot, first, end)`` over ``order``, largest
    first) into its own block of node slots from ``slots[k]`` with the entry kernel ``build``
    and its leading arguments ``common``, the tasks dealt out to two shares per thread, each
    share on a thread of its own (the kernels release the GIL); returns the slot after each
    task's subtree."""
    ends = np.empty(len(tasks), dtype=np.int64)
    unused = np.zeros((1, 3), dtype=np.int64)
    workers = 2 * threads
    shares = [np.arange(worker, len(tasks), workers) for worker in range(min(workers, len(tasks)))]

    def build_share(share):
        share_ends = np.empty(len(share), dtype=np.int64)
        build(*common, tasks[share], slots[share], share_ends, 0, unused)
        ends[share] = share_ends

    with ThreadPoolExecutor(threads) as pool:
        list(pool.map(build_share, shares))
    return ends


def build_top_down(lo, hi, centroid, order, sorted_codes, strategy, max_leaf_size, bins,
                   traversal_cost, intersection_cost, threads, identity_order=False):
    """Build over the primitives in ``order`` (permuted in place into leaf order; ``identity_order``
    says it is ``arange(n)``, which saves gathering the boxes through it); the boxes and centroids
    are copied, then permuted along with ``order``.

    With more than one thread, the top of the tree is built on one thread until the tasks
    left are smaller than ``n / (8 * threads)`` (at least 4096 primitives); those subtrees are
    then built on ``threads`` threads, largest first, each into its own block of node slots
    (a subtree of m primitives needs at most 2m - 1), and the blocks are moved down to close
    the gaps between them (:func:`.nodes.close_gaps`: full dragon, 7-11 ms against 46-123 ms
    for renumbering the whole tree depth-first). Either way a node's children lie side by side,
    after it. Returns ``(node_box, node_first, node_count)``.
    """
    build = SUBTREE_KERNELS[strategy]
    n = order.shape[0]
    if identity_order:
        lo, hi, centroid = (np.array(values, dtype=np.float64) for values in (lo, hi, centroid))
    else:
        lo, hi, centroid = (np.ascontiguousarray(values[order], dtype=np.float64) for values in (lo, hi, centroid))
    workers = 2 * threads
    defer_below = max(n // (4 * workers), 4096) if threads > 1 else 0
    capacity = 4 * n + 1
    node_box = np.empty((capacity, 6))
    node_first = np.empty(capacity, dtype=np.int32)
    node_count = np.empty(capacity, dtype=np.int32)
    deferred = np.zeros((n + 1 if threads > 1 else 1, 3), dtype=np.int64)
    common = (lo, hi, centroid, order, np.ascontiguousarray(sorted_codes, dtype=np.int64), int(max_leaf_size),
              int(bins), float(traversal_cost), float(intersection_cost), node_box, node_first, node_count)
    root = np.array([[0, 0, n]], dtype=np.int64)
    end = build(*common, root, np.ones(1, dtype=np.int64), np.empty(1, dtype=np.int64), defer_below, deferred)
    tasks = deferred[1:deferred[0, 0] + 1]
    if len(tasks):
        tasks = tasks[np.argsort(tasks[:, 1] - tasks[:, 2], kind="stable")]  # largest first
        sizes = 2 * (tasks[:, 2] - tasks[:, 1]) - 1
        slots = end + np.cumsum(sizes) - sizes
        ends = build_blocks(build, common, tasks, slots, threads)
        end = close_gaps(node_box, node_first, node_count, end, tasks[:, 0], slots, ends)
    return _shrunk(node_box, end), _shrunk(node_first, end), _shrunk(node_count, end)


def _shrunk(array, rows):
    """``array`` cut to its first ``rows`` rows in place: its memory reallocated, which gives
    the unused rows back without copying the used ones (full dragon: a copy of the three arrays
    took 28 ms of each build). No view of ``array`` may exist, since its memory may move."""
    array.resize((rows,) + array.shape[1:], refcheck=False)
    return array
