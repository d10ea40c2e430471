"""Two-level acceleration of a :class:`rayaccel.Scene`: a BVH over instances, any method below.

Each distinct object gets its own structure, built once with the method and
options asked for; a binned-SAH BVH over the instances' world boxes sits on
top (Wald, Benthin & Slusallek, "A Simple and Practical Method for
Interactive Ray Tracing of Dynamic Scenes", 2003; Embree's and pbrt-v4's
instancing). A ray batch is traced front to back in *waves*: the pairs (ray,
instance) from the top level (:func:`.walk.instance_candidates`), ranked by
entry distance per ray, are taken in waves of rank 0, 1, 2-3, 4-7, ...; a
pair is traced only if its entry lies before the ray's best hit so far, and
within a wave all pairs of one object go to that object's structure in one
batch query with ``t_max`` the ray's best so far. So Python calls grow with
objects times waves (logarithmic in the instances a ray crosses), not with
instances.
"""

from __future__ import annotations

import time

import numpy as np

from ..._jit import thread_count
from ...rays import WORK_COLUMNS, AllHits, Hits, RayCounters, prepare_rays
from ...stats import box_area, surface_area_stats
from ..base import Accelerator
from ..bvh.build_top_down import SAH_BINNED, build_top_down
from ..bvh.nodes import node_depths
from ..bvh.refit import refit_boxes
from .points import scene_closest_point, scene_nearest, scene_winding_number
from .walk import instance_candidates, merge_hits, object_rays

__all__ = ["InstancedScene"]

# Instance world boxes are grown by this fraction of their size and position, so that the
# rounding of the transforms never culls an instance a ray hits in its own frame.
_BOX_PAD = 1e-9
_TOP_TRAVERSAL_COST = 1.0
# Once this few pairs are left after the first wave, they go in one last wave: a query
# costs a fixed few milliseconds (more when other processes hold the cores), more than
# the tests the later waves would save on so few pairs.
_FOLD_PAIRS = 16384


class InstancedScene(Accelerator):
    """The structure ``ra.build(scene, method, **options)`` returns for a :class:`rayaccel.Scene`.

    ``method`` and ``options`` apply to every object's own structure; the top
    level is always a binned-SAH BVH with one instance per leaf. ``hits.geom``
    is the id ``scene.add`` returned; ``t`` is in world units of the given
    direction, ``prim``, ``u`` and ``v`` as for the object hit. ``refit()``
    takes the transforms set since with ``scene.set_transform`` (top level only).
    """

    def __init__(self, scene, method, objects, options):
        super().__init__(scene, dict(options))
        self.method = method
        start = time.perf_counter()
        self.objects = objects
        self._place(scene.instance_object, scene.transforms)
        order = np.arange(len(self.instance_object), dtype=np.int64)
        box, first, count = build_top_down(self.world_lo, self.world_hi, 0.5 * (self.world_lo + self.world_hi), order,
                                           np.zeros(0, np.int64), SAH_BINNED, 1, 16, _TOP_TRAVERSAL_COST, 1.0,
                                           thread_count())
        self.top = (box, first, count, order)
        self.top_depth = int(node_depths(first, count).max())
        self.build_seconds = time.perf_counter() - start + sum(obj.build_seconds for obj in objects)

    def _place(self, instance_object, transforms):
        """Take the instances' placements: their inverses and padded world boxes."""
        self.instance_object = np.ascontiguousarray(instance_object, dtype=np.int64)
        self.transforms = np.ascontiguousarray(transforms, dtype=np.float64)
        self.inverse = np.ascontiguousarray(np.linalg.inv(self.transforms))
        self.inverse[:, 3] = (0.0, 0.0, 0.0, 1.0)
        lo, hi = self.scene.world_boxes(self.instance_object, self.transforms)
        pad = _BOX_PAD * (np.abs(lo).max(axis=1) + np.abs(hi).max(axis=1) + (hi - lo).max(axis=1))
        self.world_lo = lo - pad[:, None]
        self.world_hi = hi + pad[:, None]
        self.scene_box = self.world_lo.min(axis=0), self.world_hi.max(axis=0)

    def refit(self, vertices=None) -> None:
        """Take the instances' current transforms (``scene.set_transform``) and refit the top
        level's boxes bottom-up; the objects' structures are kept. ``stats()`` shows the top
        level's SAH cost before (``top_sah_cost_at_build``) and after."""
        if vertices is not None:
            raise TypeError("a scene's refit takes no vertices: move instances with scene.set_transform(gid, T), "
                            "or refit an object's own structure")
        if self.scene.n_instances != len(self.instance_object):
            raise ValueError(f"the scene has {self.scene.n_instances} instances, the structure "
                             f"{len(self.instance_object)}: instances added since need ra.build")
        start = time.perf_counter()
        if not hasattr(self, "top_sah_cost_at_build"):
            self.top_sah_cost_at_build = self._top_stats()["expected_cost"]
        self._place(self.instance_object, self.scene.transforms)
        box, first, count, order = self.top
        refit_boxes(first, count, self.world_lo[order], self.world_hi[order], box)
        self.refit_seconds = time.perf_counter() - start

    def _intersect(self, origins, directions, t_min, t_max, any_hit, counters, reorder) -> Hits:
        """The two-level walk behind :meth:`Accelerator.intersect`; ``hits.geom`` is the instance hit."""
        return self._trace_scene(origins, directions, t_min, t_max, any_hit, counters, reorder)

    def _occluded(self, origins, directions, t_min, t_max, reorder) -> np.ndarray:
        return self._trace_scene(origins, directions, t_min, t_max, True, False, reorder).prim >= 0

    def _trace_scene(self, origins, directions, t_min, t_max, any_hit, counters, reorder) -> Hits:
        rays = prepare_rays(origins, directions, t_min, t_max)
        n = len(rays.origins)
        best_t = np.full(n, np.inf)
        best_prim = np.full(n, -1, dtype=np.int64)
        best_u = np.full(n, np.nan)
        best_v = np.full(n, np.nan)
        best_geom = np.full(n, -1, dtype=np.int64)
        limit = rays.t_max.copy()
        work = np.zeros((n, WORK_COLUMNS), dtype=np.int64) if counters else None
        offsets, instance, entry, top_nodes = instance_candidates(self.top, self.top_depth, rays.origins,
                                                                  rays.directions, rays.t_min, rays.t_max)
        if counters:
            work[:, 0] = top_nodes
        ray_of_pair = np.repeat(np.arange(n), np.diff(offsets))
        rank = np.arange(len(instance)) - offsets[ray_of_pair]
        wave_first = 0
        last = rank.max() if len(rank) else -1
        while wave_first <= last:
            wave_end = max(1, 2 * wave_first)
            if wave_first and np.count_nonzero(rank >= wave_first) <= _FOLD_PAIRS:
                wave_end = last + 1
            pairs = np.flatnonzero((rank >= wave_first) & (rank < wave_end))
            pairs = pairs[entry[pairs] <= limit[ray_of_pair[pairs]]]
            if any_hit:
                pairs = pairs[best_prim[ray_of_pair[pairs]] < 0]
            self._trace_pairs(rays, ray_of_pair[pairs], instance[pairs], limit, any_hit, counters, reorder, work,
                              (best_t, best_prim, best_u, best_v, best_geom))
            wave_first = wave_end
        ray_counters = RayCounters(*(work[:, k].copy() for k in range(WORK_COLUMNS))) if counters else None
        return Hits(best_t, best_prim, best_u, best_v, ray_counters, best_geom)

    def _trace_pairs(self, rays, ray, instance, limit, any_hit, counters, reorder, work, best):
        """Trace the (ray, instance) pairs, one batch query per object, and merge their hits."""
        obj = self.instance_object[instance]
        by_object = np.argsort(obj, kind="stable")
        bounds = np.searchsorted(obj[by_object], np.arange(len(self.objects) + 1))
        for o in np.flatnonzero(np.diff(bounds)):
            chosen = by_object[bounds[o]:bounds[o + 1]]
            ray_k, instance_k = ray[chosen], instance[chosen]
            local_o, local_d = object_rays(self.inverse, instance_k, ray_k, rays.origins, rays.directions)
            hits = self.objects[o].intersect(local_o, local_d, rays.t_min[ray_k], limit[ray_k], any_hit=any_hit,
                                             counters=counters, reorder=reorder)
            merge_hits(ray_k, hits.t, hits.prim, hits.u, hits.v, instance_k, *best, limit)
            if counters:
                np.add.at(work, ray_k, np.column_stack(hits.counters))

    def _closest_point(self, points, max_distance):
        """Point queries ask every instance in its frame (:mod:`.points`)."""
        return scene_closest_point(self, points, max_distance)

    def _nearest_d2(self, points, max_distance):
        return scene_nearest(self, points, max_distance)[:2]

    def _winding_number(self, points, accuracy):
        return scene_winding_number(self, points, accuracy)

    def _ordered(self, rays, reorder):
        """The rays as given: each object's structure orders its own pairs."""
        return rays

    def _object_pairs(self, rays):
        """Per object, the pairs (ray, instance) whose instance box the ray enters, and those rays
        moved into the object's frame: ``(object, ray, instance, origins, directions)``."""
        offsets, instance, _, _ = instance_candidates(self.top, self.top_depth, rays.origins, rays.directions,
                                                      rays.t_min, rays.t_max)
        ray = np.repeat(np.arange(len(rays.origins)), np.diff(offsets))
        obj = self.instance_object[instance]
        by_object = np.argsort(obj, kind="stable")
        bounds = np.searchsorted(obj[by_object], np.arange(len(self.objects) + 1))
        for o in np.flatnonzero(np.diff(bounds)):
            chosen = by_object[bounds[o]:bounds[o + 1]]
            local_o, local_d = object_rays(self.inverse, instance[chosen], ray[chosen], rays.origins, rays.directions)
            yield self.objects[o], ray[chosen], instance[chosen], local_o, local_d

    def _count(self, rays, batch) -> np.ndarray:
        """:meth:`Accelerator.count`: each object counts the crossings of the rays that enter its
        instances' boxes, in its own frame."""
        counts = np.zeros(len(rays.origins), dtype=np.int64)
        for obj, ray, _, local_o, local_d in self._object_pairs(rays):
            np.add.at(counts, ray, obj.count(local_o, local_d, rays.t_min[ray], rays.t_max[ray]))
        return counts

    def _intersect_all(self, rays, max_hits, reorder) -> AllHits:
        """:meth:`Accelerator.intersect_all`: each object lists the hits of the rays that enter its
        instances' boxes (its nearest ``max_hits`` each), then each ray's are merged, sorted by
        ``(t, geom, prim)``, and cut to ``max_hits``."""
        n = len(rays.origins)
        parts = []
        for obj, ray, instance, local_o, local_d in self._object_pairs(rays):
            found = obj.intersect_all(local_o, local_d, rays.t_min[ray], rays.t_max[ray], max_hits=max_hits,
                                      reorder=reorder)
            pair = found.ray
            parts.append((ray[pair], instance[pair], found.t, found.prim, found.u, found.v))
        if parts:
            ray, geom, t, prim, u, v = (np.concatenate(column) for column in zip(*parts))
        else:
            ray, geom, prim = (np.zeros(0, dtype=np.int64) for _ in range(3))
            t, u, v = (np.zeros(0) for _ in range(3))
        order = np.lexsort((prim, geom, t, ray))
        ray, geom, t, prim, u, v = ray[order], geom[order], t[order], prim[order], u[order], v[order]
        counts = np.bincount(ray, minlength=n)
        if max_hits is not None:
            first = np.cumsum(counts) - counts
            keep = np.arange(len(ray)) - first[ray] < max_hits
            ray, geom, t, prim, u, v = ray[keep], geom[keep], t[keep], prim[keep], u[keep], v[keep]
            counts = np.minimum(counts, max_hits)
        offsets = np.zeros(n + 1, dtype=np.int64)
        np.cumsum(counts, out=offsets[1:])
        return AllHits(offsets, t, prim, u, v, geom)

    def _top_stats(self) -> dict:
        box, first, count, _ = self.top
        areas = box_area(box[:, :3], box[:, 3:])
        leaf = count > 0
        return surface_area_stats(areas[0], step_areas=areas[~leaf], leaf_areas=areas[leaf],
                                  leaf_counts=count[leaf], traversal_cost=_TOP_TRAVERSAL_COST)

    def _top_bytes(self) -> int:
        box, first, count, order = self.top
        return int(box.nbytes + first.nbytes + count.nbytes + order.nbytes + self.instance_object.nbytes
                   + self.transforms.nbytes + self.inverse.nbytes + self.world_lo.nbytes + self.world_hi.nbytes)

    @property
    def nbytes(self) -> int:
        """Bytes of the arrays that queries read: the top level and every object's structure."""
        return self._top_bytes() + sum(obj.nbytes for obj in self.objects)

    def _structure_stats(self) -> dict:
        _, first, count, _ = self.top
        objects = [obj._structure_stats() for obj in self.objects]
        top = self._top_stats()
        top_bytes = self._top_bytes()
        object_bytes = sum(s["bytes"] for s in objects)
        leaves = sum(s["nonempty_leaves"] for s in objects)
        references = sum(s["references"] for s in objects)
        result = {
            "objects": len(self.objects),
            "instances": len(self.instance_object),
            "object_primitives": sum(len(obj.scene) for obj in self.objects),
            "nodes": len(first) + sum(s["nodes"] for s in objects),
            "leaves": int((count > 0).sum()) + sum(s["leaves"] for s in objects),
            "nonempty_leaves": leaves,
            "max_depth": self.top_depth + 1 + max(s["max_depth"] for s in objects),
            "references": references,
            "avg_prims_per_nonempty_leaf": references / max(leaves, 1),
            "bytes": top_bytes + object_bytes,
            "top_nodes": len(first),
            "top_max_depth": self.top_depth,
            "top_bytes": top_bytes,
            "top_sah_cost": top["expected_cost"],
            "top_sah_cost_at_build": getattr(self, "top_sah_cost_at_build", top["expected_cost"]),
            "object_bytes": object_bytes,
            **{f"top_{key}": value for key, value in top.items() if key != "expected_cost"},
            "object_stats": objects,
        }
        return result
