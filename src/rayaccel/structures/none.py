"""Brute force: every ray against every primitive. The reference all structures are checked against."""

from __future__ import annotations

import numpy as np
from numba import prange

from .._jit import chunk_kernel, parallel_kernel
from ..geometry.primitive import ray_setup
from ..geometry.winding import prim_winding
from ..rays import ray_limit, result_row
from .actions import finish_ray, visit_prim
from .base import Accelerator, walk_rays
from .point_actions import nearest_in_refs

__all__ = ["BruteForce", "brute_force_kernel", "brute_force_nearest_kernel", "brute_force_winding_kernel"]


@chunk_kernel
def brute_force_kernel(ray_first, ray_end, tid, kind, geom, all_prims, origins, directions, t_min, t_max, hit_slot,
                       any_hit, action, work):
    """Every ray against every primitive, the leaf action (:mod:`.actions`) applied to each;
    ``all_prims`` is ``arange(n)``, each primitive's index."""
    n_prims = geom.shape[0]
    for i in range(ray_first, ray_end):
        row = result_row(hit_slot, i)
        ray_t_min, ray_t_max = ray_limit(t_min, i), ray_limit(t_max, i)
        ray = ray_setup(origins[i, 0], origins[i, 1], origins[i, 2],
                        directions[i, 0], directions[i, 1], directions[i, 2])
        best_t = ray_t_max
        best_prim = -1
        best_u = 0.0
        best_v = 0.0
        tests = 0
        for prim in range(n_prims):
            tests += 1
            best_t, best_prim, best_u, best_v, stop = visit_prim(action, row, kind, geom, prim, all_prims, prim, ray,
                                                                 ray_t_min, best_t, best_prim, best_u, best_v, any_hit)
            if stop:
                break
        finish_ray(action, row, best_t, best_prim, best_u, best_v)
        if work is not None:
            work[row, 1] = tests


@parallel_kernel
def brute_force_nearest_kernel(kind, geom, all_prims, points, limit_d2, out_d2, out_prim):
    """Each point's closest primitive within ``sqrt(limit_d2[i])``, over every primitive."""
    for i in prange(points.shape[0]):
        out_d2[i], out_prim[i] = nearest_in_refs(kind, geom, all_prims, 0, all_prims.shape[0], False, points[i, 0],
                                                 points[i, 1], points[i, 2], limit_d2[i], -1)


@parallel_kernel
def brute_force_winding_kernel(kind, geom, points, out):
    """The exact winding number at each point: every primitive's share summed."""
    for i in prange(points.shape[0]):
        total = 0.0
        for prim in range(geom.shape[0]):
            total += prim_winding(kind, geom, prim, points[i, 0], points[i, 1], points[i, 2])
        out[i] = total


class BruteForce(Accelerator):
    """``none``: no acceleration structure; every ray tests every primitive (O(n) per ray).

    No options. The counters report 0 nodes and n primitive tests per ray
    (fewer for any-hit queries).
    """

    method = "none"
    build_bytes_per_primitive = 16
    _large_primitives_first = False

    def __init__(self, scene):
        super().__init__(scene, {})

    def _trace(self, batch, any_hit, action, work):
        walk_rays(brute_force_kernel, len(batch.origins), self.scene.kind, self.scene.geometry,
                  np.arange(len(self.scene)), *batch, any_hit, action, work)

    def _nearest(self, points, limit_d2, out_d2, out_prim):
        """Point queries test every primitive, too; the winding number is the exact sum."""
        brute_force_nearest_kernel(self.scene.kind, self.scene.geometry, np.arange(len(self.scene)), points, limit_d2,
                                   out_d2, out_prim)

    def _winding_number(self, points, accuracy):
        out = np.zeros(len(points))
        brute_force_winding_kernel(self.scene.kind, self.scene.geometry, points, out)
        return out

    @property
    def nbytes(self) -> int:
        """Bytes of the arrays that queries read: the primitives."""
        return int(self.scene.geometry.nbytes)

    def _structure_stats(self) -> dict:
        n = len(self.scene)
        return {
            "nodes": 1, "leaves": 1, "nonempty_leaves": 1, "max_depth": 0, "references": n,
            "avg_prims_per_nonempty_leaf": float(n), "bytes": self.nbytes,
            "expected_traversal_steps": 0.0, "expected_leaves_visited": 1.0,
            "expected_intersections": float(n), "expected_cost": float(n),
        }
