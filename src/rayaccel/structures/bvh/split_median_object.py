"""Top-down split at the object median: half of the primitives on each side.

Sorts the range by centroid along the centroid box's longest axis and cuts it
in the middle, which gives a balanced tree of depth log2(n) whatever the
scene. It is also the fallback of every other builder when their split
cannot separate the primitives (all centroids equal).
"""

from __future__ import annotations

import numpy as np

from ..._jit import kernel
from .nodes import longest_axis, permute_prims

__all__ = ["split_object_median"]


@kernel
def split_object_median(lo, hi, centroid, order, start, end, centroid_box):
    """Sort the primitive rows ``start:end`` along the longest centroid axis; return the middle index."""
    axis, extent = longest_axis(centroid_box)
    if extent > 0.0:
        keys = np.empty(end - start)
        for i in range(start, end):
            keys[i - start] = centroid[i, axis]
        permute_prims(lo, hi, centroid, order, start, np.argsort(keys, kind="mergesort"))
    return (start + end) // 2
