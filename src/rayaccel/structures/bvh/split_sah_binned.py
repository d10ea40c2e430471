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

from ..._jit import kernel

__all__ = ["split_sah_binned"]


@kernel
def _grow(bin_box, b, lo, hi, p):
    for k in range(3):
        if lo[p, k] < bin_box[b, k]:
            bin_box[b, k] = lo[p, k]
        if hi[p, k] > bin_box[b, k + 3]:
            bin_box[b, k + 3] = hi[p, k]


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
                     traversal_cost, intersection_cost, scratch_box, scratch_count, scratch_area):
    """Best binned SAH cut of ``order[start:end]``, partitioned in place.

    ``scratch_*`` are work arrays of at least ``bins`` rows, reused across nodes.
    Returns ``(mid, cost)``, or ``(-1, inf)`` when all centroids coincide.
    """
    best_cost = np.inf
    best_axis = -1
    best_bin = -1
    acc = np.empty(6)
    for axis in range(3):
        c_lo = centroid_box[axis]
        extent = centroid_box[axis + 3] - c_lo
        if extent <= 0.0:
            continue
        scale = bins / extent
        for b in range(bins):
            scratch_count[b] = 0
            for k in range(3):
                scratch_box[b, k] = np.inf
                scratch_box[b, k + 3] = -np.inf
        for i in range(start, end):
            p = order[i]
            b = min(int((centroid[p, axis] - c_lo) * scale), bins - 1)
            scratch_count[b] += 1
            _grow(scratch_box, b, lo, hi, p)
        for k in range(3):
            acc[k] = np.inf
            acc[k + 3] = -np.inf
        right_count = 0
        for b in range(bins - 1, 0, -1):
            right_count += scratch_count[b]
            scratch_area[b] = _merged_area(acc, scratch_box, b) * right_count if right_count > 0 else 0.0
        for k in range(3):
            acc[k] = np.inf
            acc[k + 3] = -np.inf
        left_count = 0
        for b in range(bins - 1):
            left_count += scratch_count[b]
            if left_count == 0:
                continue
            left_area = _merged_area(acc, scratch_box, b)
            if left_count == end - start:
                break
            cost = left_area * left_count + scratch_area[b + 1]
            if cost < best_cost:
                best_cost = cost
                best_axis = axis
                best_bin = b
    if best_axis < 0:
        return -1, np.inf
    c_lo = centroid_box[best_axis]
    scale = bins / (centroid_box[best_axis + 3] - c_lo)
    left = start
    right = end - 1
    while left <= right:
        if min(int((centroid[order[left], best_axis] - c_lo) * scale), bins - 1) <= best_bin:
            left += 1
        else:
            order[left], order[right] = order[right], order[left]
            right -= 1
    return left, traversal_cost + intersection_cost * best_cost / max(parent_area, 1e-300)
