"""The median of a small sample by selection, for the checks a query makes before its walk.

Hoare's selection (C. A. R. Hoare, "Algorithm 65: FIND", Communications of the ACM 4(7),
1961), in the form Wirth gives it ("Algorithms + Data Structures = Programs", 1976): the range
that holds the ``k``-th smallest value is partitioned around its middle value and narrowed to
the part that holds ``k``, in expected linear time. The checks of a ray batch that choose a
walk (:func:`rayaccel.ray_order.sample_neighbours`, :func:`rayaccel.ray_tiles.image_row_length`)
take medians of a thousand values inside their kernels, so that a query calls no NumPy function
before its walk; compiled there, ``np.median`` took 1.21 s of CPU on an empty cache and this 0.35 s
(2026-12-07, each in a process that had compiled one trivial function before).
"""

from __future__ import annotations

from ._jit import kernel

__all__ = ["median_in_place"]


@kernel
def _select_in_place(values, k):
    """``values`` reordered so that ``values[k]`` is their ``k``-th smallest, none before it
    larger and none after it smaller; returns ``values[k]``. A NaN stops both scans as any value
    would, so the partition stays inside the range, but the order it leaves is then arbitrary."""
    low, high = 0, values.shape[0] - 1
    while low < high:
        pivot = values[(low + high) // 2]
        i, j = low, high
        while i <= j:
            while values[i] < pivot:
                i += 1
            while values[j] > pivot:
                j -= 1
            if i <= j:
                values[i], values[j] = values[j], values[i]
                i += 1
                j -= 1
        if k <= j:
            high = j
        elif k >= i:
            low = i
        else:
            break
    return values[k]


@kernel
def median_in_place(values):
    """The median of the non-empty float64 array ``values`` (as ``np.median``, the mean of the two
    middle values for an even count), reordering ``values``."""
    n = values.shape[0]
    upper = _select_in_place(values, n // 2)
    if n % 2:
        return upper
    lower = values[0]
    for i in range(1, n // 2):
        lower = max(lower, values[i])
    return 0.5 * (lower + upper)
