"""Point queries every accelerator answers: closest point, distance, winding number, inside test,
signed distance (:class:`PointQueries`, a base of :class:`rayaccel.structures.base.Accelerator`).

Each structure supplies one walk by distance, :meth:`PointQueries._nearest`
(its ``nearest.py``). The winding number of a triangle mesh comes from one
ray per point (:mod:`.ray_winding`): the signed crossings counted by the
structure's own ray walk, plus, where the mesh has holes, the crossings and
the fast winding number (:mod:`rayaccel.structures.bvh.fast_winding`) of the
small caps that close them. The fast winding number reads a BVH that
partitions the primitives: a BVH method's own tree, or, for the structures
that reference a primitive from several cells (grids, kd-tree, octree,
hybrid), a binned-SAH BVH built on first use and cached on the accelerator
(``_winding_cache``; not saved with it); it alone answers for spheres and for
triangle soups whose caps would be large. Brute force (``none``) sums the
exact solid angles.

Sign convention: the winding number is +1 inside a closed mesh whose
triangles are counter-clockwise seen from outside, -1 inside an inverted one.
:meth:`PointQueries.contains` thresholds ``|w| > 0.5``, so a consistently
inverted mesh still has an inside; mixed orientations cancel as the winding
number says.
"""

from __future__ import annotations

import numba
import numpy as np

from .._jit import lent_rows, thread_rows
from ..geometry.kinds import TRIANGLE
from ..points import ClosestPoints, check_accuracy, check_max_distance, prepare_points
from .point_actions import empty_closest, finish_closest
from .ray_winding import ray_winding_number

__all__ = ["PointQueries", "any_dask", "nearest_walk_scratch"]


def nearest_walk_scratch(rows: int, depth: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The per-thread stacks, ``depth`` deep, of a closest-point walk over cells (the kd-tree's, the
    octree's): the pending nodes, their distances, and their boxes."""
    return thread_rows((rows, depth), np.int32), thread_rows((rows, depth)), thread_rows((rows, depth, 6))


def _winding_stack(rows: int, depth: int) -> tuple[np.ndarray]:
    """The per-thread stack of the fast winding number's walk over a tree ``depth`` deep."""
    return (thread_rows((rows, 2 * depth + 4), np.int64),)


_NOT_DASK = frozenset((np.ndarray, float, int))


def any_dask(*values) -> bool:
    """Whether any value is a Dask collection, decided without importing Dask (NumPy arrays and
    Python numbers at a glance: 0.4 against 0.8 us for a query's four inputs, in a loop)."""
    return any(type(value) not in _NOT_DASK and type(value).__module__.partition(".")[0] == "dask"
               for value in values)


class PointQueries:
    """The point queries of the public API; subclasses provide :meth:`_nearest`."""

    def closest_point(self, points, max_distance=np.inf) -> ClosestPoints:
        """The closest surface point to each query point within ``max_distance``.

        Parameters
        ----------
        points : (n, 3) array_like
            Finite query points (``ValueError`` for NaN, inf, a wrong shape or dtype).
        max_distance : float
            Search radius, >= 0; a point with nothing within it gets ``prim = -1``.

        Returns
        -------
        ClosestPoints
            ``point``, ``distance``, ``prim``, ``u``, ``v``, ``geom``; ties at equal
            distance go to the lowest primitive index (see :class:`rayaccel.points.ClosestPoints`).
            Lazy Dask arrays when ``points`` is one (:func:`rayaccel.distributed.closest_point`).
        """
        if any_dask(points):
            from ..distributed import closest_point

            return closest_point(self, points, max_distance)
        return self._closest_point(prepare_points(points), check_max_distance(max_distance))

    def distance(self, points) -> np.ndarray:
        """(n,) unsigned distance from each point to the nearest primitive's surface (for spheres:
        to the nearest sphere's surface, also from inside it)."""
        if any_dask(points):
            from ..distributed import distance

            return distance(self, points)
        points = prepare_points(points)
        d2, _ = self._nearest_d2(points, np.inf)
        return np.sqrt(d2)

    def winding_number(self, points, *, accuracy=2.0) -> np.ndarray:
        """(n,) generalized winding number at each point (Jacobson et al. 2013).

        Triangles: the sum of the signed solid angles over 4 pi. Off the surface of a closed
        mesh it is an integer, counted exactly from one ray per point; a mesh with holes adds
        the winding number of caps over them, evaluated with the fast winding number's dipole
        expansion (Barill et al. 2018) where a BVH node is farther than ``accuracy`` times its
        radius (``accuracy = inf``: the exact sum; brute force always sums exactly); see
        :mod:`rayaccel.structures.ray_winding`. On the surface itself the winding number jumps;
        the value there is that of one side, or 1/2 for a point exactly on a triangle.
        Spheres: how many spheres contain the point.
        """
        if any_dask(points):
            from ..distributed import winding_number

            return winding_number(self, points, accuracy=accuracy)
        return self._winding_number(prepare_points(points), check_accuracy(accuracy))

    def contains(self, points, *, accuracy=2.0) -> np.ndarray:
        """(n,) bool: ``|winding_number| > 0.5`` -- inside the mesh (robust to holes, duplicated
        and flipped triangles), or inside any sphere."""
        if any_dask(points):
            from ..distributed import contains

            return contains(self, points, accuracy=accuracy)
        return np.abs(self._winding_number(prepare_points(points), check_accuracy(accuracy))) > 0.5

    def signed_distance(self, points, *, accuracy=2.0) -> np.ndarray:
        """(n,) :meth:`distance`, negative where :meth:`contains` holds."""
        if any_dask(points):
            from ..distributed import signed_distance

            return signed_distance(self, points, accuracy=accuracy)
        points = prepare_points(points)
        accuracy = check_accuracy(accuracy)
        distance = np.sqrt(self._nearest_d2(points, np.inf)[0])
        inside = np.abs(self._winding_number(points, accuracy)) > 0.5
        return np.where(inside, -distance, distance)

    def _closest_point(self, points, max_distance) -> ClosestPoints:
        """:meth:`closest_point` on validated points (scenes of instances override it)."""
        point, distance, prim, u, v = empty_closest(len(points))
        if len(points):
            _, prim = self._nearest_d2(points, max_distance)
            finish_closest(self.scene.kind, self.scene.prim_layout, points, prim, point, distance, u, v)
        return ClosestPoints(point, distance, prim, u, v, np.minimum(prim, 0))

    def _nearest_d2(self, points, max_distance):
        """``(d2, prim)``: squared distance and index of each point's closest primitive within
        ``max_distance`` (inf, -1 where none)."""
        n = len(points)
        d2 = np.full(n, np.inf)
        prim = np.full(n, -1, dtype=np.int64)
        if n:
            self._nearest(points, np.full(n, max_distance * max_distance), d2, prim)
        return d2, prim

    def _nearest(self, points, limit_d2, out_d2, out_prim) -> None:
        """The structure's walk by distance: fill ``out_d2``, ``out_prim`` for each point's closest
        primitive with squared distance <= ``limit_d2[i]``."""
        raise NotImplementedError(f"{self.method!r} has no walk by distance")

    def _winding_number(self, points, accuracy) -> np.ndarray:
        """:meth:`winding_number` on validated points (brute force and scenes override it): one ray
        per point on triangles (:mod:`.ray_winding`), the fast winding number on spheres."""
        if self.scene.kind == TRIANGLE:
            return ray_winding_number(self, points, accuracy)
        return self._fast_winding(points, accuracy)

    def _fast_winding(self, points, accuracy) -> np.ndarray:
        """The fast winding number (Barill et al. 2018) of the primitives at validated points."""
        from .bvh.fast_winding import fast_winding_kernel

        out = np.zeros(len(points))
        if len(points):
            box, first, count, geometry, moments, depth = self._winding_tree()
            with lent_rows(_winding_stack, numba.config.NUMBA_NUM_THREADS, depth) as (stack,):
                fast_winding_kernel(self.scene.kind, geometry, box, first, count, moments, points, accuracy, stack,
                                    out)
        return out

    def _winding_tree(self):
        """``(node_box, node_first, node_count, geometry in leaf order, moments, depth)`` of a BVH
        partitioning the primitives: built here with binned SAH on first use and cached; the BVH
        methods return their own tree."""
        cache = getattr(self, "_winding_cache", None)
        if cache is None:
            from .bvh.accelerator import _top_down
            from .bvh.build_top_down import SAH_BINNED
            from .bvh.fast_winding import winding_moments
            from .bvh.nodes import grow_by_rounding_margin, node_depths

            box, first, count, order = _top_down(self.scene.bounds(), SAH_BINNED, 8, 3.0, 1.0, bins=16)
            grow_by_rounding_margin(box)
            geometry = self.scene.gather(order)
            moments = winding_moments(self.scene.kind, geometry, box, first, count)
            cache = (box, first, count, geometry, moments, int(node_depths(first, count).max()))
            self._winding_cache = cache
        return cache
