"""The shared steps of a counting sort run in parallel over chunks of its items.

A counting sort (Seward 1954; Knuth, TAOCP vol. 3, 5.2) places items with
small integer keys in two passes: count the items of each key, then write each
item at its key's next free place. Split over ``n_chunks`` consecutive chunks,
each chunk counts into a row of its own, one scan turns the rows into each
chunk's first place per key (all of key 0 first, and within a key the chunks in
order), and the placing pass runs chunk by chunk again. The result is the
stable sort, whatever the number of chunks. The callers fuse their own work
into the passes (the grid builder writes each primitive's cell range, the ray
sorter copies each ray), so only these two steps are shared.
"""

from __future__ import annotations

from ._jit import inline_kernel, kernel

__all__ = ["chunk_range", "counts_to_starts"]


@inline_kernel
def chunk_range(n, n_chunks, c):
    """``(first, end)`` of chunk ``c`` when ``n`` items are split into ``n_chunks``."""
    return c * n // n_chunks, (c + 1) * n // n_chunks


@kernel
def counts_to_starts(counts):
    """Turn ``counts[chunk, key]`` in place into the first place of each chunk's items of
    each key in the sorted order; returns the number of items."""
    total = 0
    for key in range(counts.shape[1]):
        for c in range(counts.shape[0]):
            count = counts[c, key]
            counts[c, key] = total
            total += count
    return total
