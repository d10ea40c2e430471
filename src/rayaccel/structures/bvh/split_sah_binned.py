"""Top-down split by the binned surface area heuristic.

Wald, "On fast Construction of SAH-based Bounding Volume Hierarchies",
IEEE Symposium on Interactive Ray Tracing 2007: centroids are dropped into
``bins`` equal intervals of the centroid box on each axis, the boxes and counts
of the bins are swept from both ends, and only the ``bins - 1`` bin boundaries
are evaluated with the SAH. Linear per node, and close to the full sweep in
quality with 16 to 32 bins.
"""

from __future__ import annotations

import numpy as np

from ..._jit import kernel, unsigned
from .nodes import swap_prims

__all__ = ["split_sah_binned"]


@kernel
def _grow(bin_box, b, lo, hi, p):
    """Grow bin ``b``'s box over primitive ``p``'s, with ``min``/``max`` rather than a compare
    and a conditional store each: no branches to mispredict (whole build of the full dragon,
    one thread: 0.90 -> 0.67 s, the same tree)."""
    row, prim = unsigned(b), unsigned(p)
    for k in range(3):
        bin_box[row, k] = min(bin_box[row, k], lo[prim, k])
        bin_box[row, k + 3] = max(bin_box[row, k + 3], hi[prim, k])


@kernel
def _grow_centroids(child_bounds, side, centroid, p):
    """Grow the centroid box of part ``side`` over primitive ``p``'s centroid."""
    for k in range(3):
        child_bounds[side, k + 6] = min(child_bounds[side, k + 6], centroid[p, k])
        child_bounds[side, k + 9] = max(child_bounds[side, k + 9], centroid[p, k])


@kernel
def _merged_area(acc, bin_box, b):
    for k in range(3):
        acc[k] = min(acc[k], bin_box[b, k])
        acc[k + 3] = max(acc[k + 3], bin_box[b, k + 3])
    ex = acc[3] - acc[0]
    ey = acc[4] - acc[1]
    ez = acc[5] - acc[2]
    return 2.0 * (ex * ey + ey * ez + ex * ez)


@kernel
def split_sah_binned(lo, hi, centroid, order, start, end, centroid_box, parent_area, bins,
                     traversal_cost, intersection_cost, scratch_box, scratch_count, scratch_area, acc, child_bounds):
    """Best binned SAH cut of the primitive rows ``start:end``, partitioned in place.

    ``scratch_box`` (3 * bins, 6), ``scratch_count`` (3 * bins), ``scratch_area``
    (bins) and ``acc`` (6) are work arrays reused across nodes. All three axes
    are binned in one pass over the primitives. A node of n primitives uses at most n / 2
    bins, so that a small node sweeps half as many bins as it has primitives (the sweeps took
    21 % of the subtree kernel in a profile, README "Tried and dropped"), and the trees lose
    little (against one bin per primitive,
    up to ``bins``: full dragon, CPU time of the whole build on one thread 0.885, on two 0.874,
    wall time 0.469 -> 0.407 s, medians of 7 interleaved rounds; SAH cost dragon 91.04 -> 91.17,
    forest-small-chair 43.67 -> 43.69, bunny 58.71 -> 58.82, armadillo 53.19 -> 53.30; at most
    n / 4 bins: 0.843 of the CPU time, SAH cost up 1.0 % on the dragon and 1.1 % on the bunny).
    Returns ``(mid, cost)``, or ``(-1, inf)`` when all centroids coincide. After a cut,
    row 0 of ``child_bounds`` (2, 12) holds the left part's box and centroid box and row 1
    the right part's: the boxes are the unions of their bins', the centroid boxes grow
    as the partition places each primitive, so the builder need not read the parts again
    to bound them (:func:`.build_top_down.build_subtrees`).
    """
    n = end - start
    bins = min(bins, max(n // 2, 2))
    scale = np.zeros(3)
    for axis in range(3):
        extent = centroid_box[axis + 3] - centroid_box[axis]
        if extent > 0.0:
            scale[axis] = bins / extent
    for b in range(3 * bins):
        scratch_count[b] = 0
        for k in range(3):
            scratch_box[b, k] = np.inf
            scratch_box[b, k + 3] = -np.inf
    for i in range(start, end):
        for axis in range(3):
            b = axis * bins + min(int((centroid[i, axis] - centroid_box[axis]) * scale[axis]), bins - 1)
            scratch_count[unsigned(b)] += 1
            _grow(scratch_box, b, lo, hi, i)
    best_cost = np.inf
    best_axis = -1
    best_bin = -1
    for axis in range(3):
        if scale[axis] == 0.0:
            continue
        first = axis * bins
        for k in range(3):
            acc[k] = np.inf
            acc[k + 3] = -np.inf
        right_count = 0
        for b in range(bins - 1, 0, -1):
            right_count += scratch_count[first + b]
            scratch_area[b] = _merged_area(acc, scratch_box, first + b) * right_count if right_count > 0 else 0.0
        for k in range(3):
            acc[k] = np.inf
            acc[k + 3] = -np.inf
        left_count = 0
        for b in range(bins - 1):
            left_count += scratch_count[first + b]
            if left_count == 0:
                continue
            if left_count == n:
                break
            cost = _merged_area(acc, scratch_box, first + b) * left_count + scratch_area[b + 1]
            if cost < best_cost:
                best_cost = cost
                best_axis = axis
                best_bin = b
    if best_axis < 0:
        return -1, np.inf
    for side in range(2):
        for k in range(3):
            child_bounds[side, k] = np.inf
            child_bounds[side, k + 3] = -np.inf
            child_bounds[side, k + 6] = np.inf
            child_bounds[side, k + 9] = -np.inf
    first = best_axis * bins
    for b in range(bins):
        side = 0 if b <= best_bin else 1
        for k in range(3):
            child_bounds[side, k] = min(child_bounds[side, k], scratch_box[first + b, k])
            child_bounds[side, k + 3] = max(child_bounds[side, k + 3], scratch_box[first + b, k + 3])
    c_lo = centroid_box[best_axis]
    s = scale[best_axis]
    left = start
    right = end - 1
    while left <= right:
        if min(int((centroid[left, best_axis] - c_lo) * s), bins - 1) <= best_bin:
            _grow_centroids(child_bounds, 0, centroid, left)
            left += 1
        else:
            swap_prims(lo, hi, centroid, order, left, right)
            _grow_centroids(child_bounds, 1, centroid, right)
            right -= 1
    return left, traversal_cost + intersection_cost * best_cost / max(parent_area, 1e-300)
