"""Growable output arrays for builders that cannot know their node count in advance."""

from __future__ import annotations

import numpy as np

from .._jit import kernel

__all__ = ["reserve_rows"]


@kernel
def reserve_rows(a, rows):
    """``a`` itself if it has at least ``rows`` rows, else a copy grown to at least twice its size
    (amortised O(1) per appended row)."""
    if rows <= a.shape[0]:
        return a
    grown = np.empty((max(rows, 2 * a.shape[0]),) + a.shape[1:], dtype=a.dtype)
    grown[:a.shape[0]] = a
    return grown
