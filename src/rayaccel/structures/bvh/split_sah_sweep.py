"""Top-down split by the surface area heuristic with a full sweep.

Goldsmith & Salmon (1987) and MacDonald & Booth (1990): a split into L and R
costs ``C_t + C_i (SA(L) n_L + SA(R) n_R) / SA(parent)``. Here every position
between the centroid-sorted primitives on each of the three axes is a
candidate: for each axis the range is sorted, the boxes of all suffixes are
accumulated right to left, and a left-to-right sweep evaluates each cut.
Cuts between equal centroids are skipped, as no plane can make them.
O(n log n) per node; the best tree the SAH can give for object partitions,
and the reference the binned builder approximates.
"""

from __future__ import annotations

import numpy as np

from ..._jit import kernel
from .nodes import permute_prims

__all__ = ["split_sah_sweep"]


@kernel
def _sorted_along(centroid, start, end, axis):
    """Rows ``start:end`` sorted by centroid along ``axis`` (as row indices)."""
    keys = np.empty(end - start)
    for i in range(start, end):
        keys[i - start] = centroid[i, axis]
    return start + np.argsort(keys, kind="mergesort")


_EMPTY_BOX = (np.inf, np.inf, np.inf, -np.inf, -np.inf, -np.inf)


@kernel
def _grown(box, lo, hi, p):
    """The box (a 6-tuple) grown by primitive row ``p``."""
    return (min(box[0], lo[p, 0]), min(box[1], lo[p, 1]), min(box[2], lo[p, 2]),
            max(box[3], hi[p, 0]), max(box[4], hi[p, 1]), max(box[5], hi[p, 2]))


@kernel
def _area(box):
    ex = box[3] - box[0]
    ey = box[4] - box[1]
    ez = box[5] - box[2]
    return 2.0 * (ex * ey + ey * ez + ex * ez)


@kernel
def split_sah_sweep(lo, hi, centroid, order, start, end, parent_area, traversal_cost, intersection_cost):
    """Best SAH cut of the primitive rows ``start:end`` over all sorted positions on all axes.

    Reorders the range along the winning axis and returns ``(mid, cost)``;
    ``(-1, inf)`` when there is nothing to split.
    """
    n = end - start
    best_cost = np.inf
    best_axis = -1
    best_index = -1
    suffix_area = np.empty(n)
    for axis in range(3):
        sorted_prims = _sorted_along(centroid, start, end, axis)
        box = _EMPTY_BOX
        for i in range(n - 1, 0, -1):
            box = _grown(box, lo, hi, sorted_prims[i])
            suffix_area[i] = _area(box)
        box = _EMPTY_BOX
        for i in range(1, n):
            p = sorted_prims[i - 1]
            box = _grown(box, lo, hi, p)
            if centroid[p, axis] == centroid[sorted_prims[i], axis]:
                continue  # no plane separates equal centroids
            cost = _area(box) * i + suffix_area[i] * (n - i)
            if cost < best_cost:
                best_cost = cost
                best_axis = axis
                best_index = i
    if best_axis < 0:
        return -1, np.inf
    permute_prims(lo, hi, centroid, order, start, _sorted_along(centroid, start, end, best_axis) - start)
    return start + best_index, traversal_cost + intersection_cost * best_cost / max(parent_area, 1e-300)
