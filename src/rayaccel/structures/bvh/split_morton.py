"""Linear BVH: primitives sorted along a Morton curve, split where the code's top bit changes.

Lauterbach, Garland, Sengupta, Luebke & Manocha, "Fast BVH Construction on
GPUs", Eurographics 2009, and Karras, "Maximizing Parallelism in the
Construction of BVHs, Octrees, and k-d Trees", HPG 2012: centroids are
quantised to 21 bits per axis and interleaved into 63-bit Morton codes; after
one sort, a node over a run of codes splits where the highest bit in which its
first and last code differ turns from 0 to 1, which is a spatial median split
on a 2^21 grid found by binary search. Very fast, lower quality than the SAH.
"""

from __future__ import annotations

import numpy as np

from ..._jit import kernel

__all__ = ["morton_codes", "split_morton"]


@kernel
def _spread_bits(v):
    """Put the 21 low bits of ``v`` at every third bit position."""
    v &= 0x1FFFFF
    v = (v | (v << 32)) & 0x1F00000000FFFF
    v = (v | (v << 16)) & 0x1F0000FF0000FF
    v = (v | (v << 8)) & 0x100F00F00F00F00F
    v = (v | (v << 4)) & 0x10C30C30C30C30C3
    v = (v | (v << 2)) & 0x1249249249249249
    return v


@kernel
def morton_codes(centroid):
    """63-bit Morton codes of the centroids within their bounding box."""
    n = centroid.shape[0]
    c_lo = np.empty(3)
    scale = np.empty(3)
    for k in range(3):
        c_lo[k] = centroid[:, k].min()
        extent = centroid[:, k].max() - c_lo[k]
        scale[k] = (2.0**21 - 1.0) / extent if extent > 0.0 else 0.0
    codes = np.empty(n, dtype=np.int64)
    for i in range(n):
        code = 0
        for k in range(3):
            q = np.int64((centroid[i, k] - c_lo[k]) * scale[k])
            code |= _spread_bits(q) << (2 - k)
        codes[i] = code
    return codes


@kernel
def split_morton(sorted_codes, start, end):
    """Index of the first code in ``sorted_codes[start:end]`` with the highest differing bit set;
    the middle when all codes are equal."""
    first = sorted_codes[start]
    last = sorted_codes[end - 1]
    if first == last:
        return (start + end) // 2
    diff = first ^ last
    bit = np.int64(1)
    while (diff >> np.int64(1)) >= bit:
        bit <<= np.int64(1)
    low = start
    high = end - 1
    while low < high:
        mid = (low + high) // 2
        if sorted_codes[mid] & bit:
            high = mid
        else:
            low = mid + 1
    return low
