"""Float64 values rounded to float32 numbers on a chosen side, for bounds kept in float32.

A bound rounded to the nearest float32 number may move inwards and lose what it
bounded; rounded down (a lower bound) or up (an upper bound) it keeps it. The
BVH's float32 node boxes are rounded outwards this way, and the kd-tree's
float32 planes are rounded down (the walks then widen each plane by one float32
step, :func:`rayaccel.structures.kdtree.layout.plane_bracket`).
"""

from __future__ import annotations

import numpy as np

__all__ = ["float32_below", "float32_above"]


def float32_below(values: np.ndarray) -> np.ndarray:
    """The largest float32 numbers at or below ``values`` (float64), as float32."""
    rounded = np.asarray(values, dtype=np.float64).astype(np.float32)
    return np.where(rounded > values, np.nextafter(rounded, np.float32(-np.inf)), rounded)


def float32_above(values: np.ndarray) -> np.ndarray:
    """The smallest float32 numbers at or above ``values`` (float64), as float32."""
    rounded = np.asarray(values, dtype=np.float64).astype(np.float32)
    return np.where(rounded < values, np.nextafter(rounded, np.float32(np.inf)), rounded)
