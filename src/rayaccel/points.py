"""Point queries' inputs and results: validated query points and :class:`ClosestPoints`."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ._validate import as_points

__all__ = ["ClosestPoints", "prepare_points", "check_max_distance", "check_accuracy"]


class ClosestPoints(NamedTuple):
    """The closest surface point to each query point.

    ``point`` (n, 3) float64: the closest point (NaN where nothing lies within
    ``max_distance``); ``distance`` (n,) float64: its Euclidean distance (inf there);
    ``prim`` (n,) int64: the primitive it lies on, -1 there; at equal distance the
    lowest primitive index (a point on a shared edge or vertex reports the lowest
    of the triangles there); ``u``, ``v`` (n,) float64: as in :class:`rayaccel.Hits`
    -- a triangle's barycentrics (``point = (1-u-v) v0 + u v1 + v v2``), a sphere's
    texture coordinates -- NaN there; ``geom`` (n,) int64: the instance of a
    :class:`rayaccel.Scene` (0 for a plain mesh or sphere set, -1 where nothing was found).
    """

    point: np.ndarray
    distance: np.ndarray
    prim: np.ndarray
    u: np.ndarray
    v: np.ndarray
    geom: np.ndarray


def prepare_points(points) -> np.ndarray:
    """``points`` as a float64 C-contiguous (n, 3) array of finite coordinates (``n = 0``
    allowed); ``ValueError`` for NaN, inf or a wrong shape, ``TypeError`` for a non-numeric dtype."""
    try:
        return as_points("points", points, allow_empty=True)
    except TypeError as exc:
        raise ValueError(str(exc)) from None


def check_max_distance(max_distance) -> float:
    """``max_distance`` as a float >= 0 (inf allowed): the search radius of :meth:`closest_point`."""
    if isinstance(max_distance, bool) or not isinstance(max_distance, (int, float, np.integer, np.floating)):
        raise ValueError(f"max_distance must be a number, got {type(max_distance).__name__}")
    value = float(max_distance)
    if not value >= 0.0:
        raise ValueError(f"max_distance must be >= 0 (inf for no limit), got {max_distance!r}")
    return value


def check_accuracy(accuracy) -> float:
    """``accuracy`` (the fast winding number's ``beta``) as a float > 0, inf for the exact sum."""
    if isinstance(accuracy, bool) or not isinstance(accuracy, (int, float, np.integer, np.floating)):
        raise ValueError(f"accuracy must be a number, got {type(accuracy).__name__}")
    value = float(accuracy)
    if not value > 0.0:
        raise ValueError(f"accuracy must be > 0 (inf for the exact winding number), got {accuracy!r}")
    return value
