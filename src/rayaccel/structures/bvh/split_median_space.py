"""Top-down split at the spatial median: the middle of the centroid box's longest axis.

The classic "median cut" of Kay & Kajiya (1986): cheap, blind to where the
primitives are, and fine for evenly spread scenes.
"""

from __future__ import annotations

from ..._jit import kernel
from .nodes import longest_axis, swap_prims

__all__ = ["split_spatial_median"]


@kernel
def split_spatial_median(lo, hi, centroid, order, start, end, centroid_box):
    """Partition the primitive rows ``start:end`` in place at the middle of the longest centroid axis.

    Returns the index of the first primitive on the right, or -1 when one side
    would be empty (all centroids on one side of the middle, or all equal).
    """
    axis, extent = longest_axis(centroid_box)
    if extent <= 0.0:
        return -1
    middle = 0.5 * (centroid_box[axis] + centroid_box[axis + 3])
    left = start
    right = end - 1
    while left <= right:
        if centroid[left, axis] < middle:
            left += 1
        else:
            swap_prims(lo, hi, centroid, order, left, right)
            right -= 1
    if left == start or left == end:
        return -1
    return left
