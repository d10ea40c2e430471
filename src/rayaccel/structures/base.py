"""The public face every acceleration structure shares: validation, queries, statistics."""

from __future__ import annotations

import functools

import numpy as np

from .._jit import inline_kernel
from ..geometry.primitive import intersect_prim
from ..geometry.sphere import sphere_hit_coords
from ..ray_order import MIN_RAYS, coherent_batch
from ..rays import Camera, Hits, RayCounters, prepare_rays
from ..scene import SPHERE, PrimitiveBounds, Spheres, TriangleMesh
from .point_queries import PointQueries

__all__ = ["Accelerator", "is_closer", "intersect_references", "store_hit", "settled_before", "EXIT_MARGIN"]

# Relative margin by which a hit must lie before a cell's exit for the walk to stop there.
EXIT_MARGIN = 1e-9


@inline_kernel
def is_closer(t, prim, best_t, best_prim):
    """Whether a hit ``(t, prim)`` replaces the best so far. Equal distances go to
    the lower primitive index, so every structure reports the same primitive as
    brute force even where a ray meets a shared edge or vertex."""
    if t == np.inf:
        return False
    return best_prim < 0 or t < best_t or (t == best_t and prim < best_prim)


@inline_kernel
def intersect_references(first, end, refs, mailbox, tid, stamp, kind, geom, ray, t_min, best_t, best_prim, best_u,
                         best_v, n_tests, n_skips, any_hit):
    """Test the primitives ``refs[first:end]`` (a cell's or a leaf's references) against the ray,
    skipping those already stamped in the mailbox, when there is one (an empty array
    otherwise), and stamping the others; returns the best hit ``(t, prim, u, v)`` and the
    counters ``(tests, skips)``, updated."""
    for k in range(first, end):
        prim = refs[k]
        if mailbox.shape[0] > 0:
            if mailbox[tid, prim] == stamp:
                n_skips += 1
                continue
            mailbox[tid, prim] = stamp
        n_tests += 1
        t, u, v = intersect_prim(kind, geom, prim, ray, t_min, best_t)
        if is_closer(t, prim, best_t, best_prim):
            best_t, best_prim, best_u, best_v = t, prim, u, v
            if any_hit:
                break
    return best_t, best_prim, best_u, best_v, n_tests, n_skips


@inline_kernel
def settled_before(best_prim, best_t, t_exit):
    """Whether the best hit so far lies before a cell's exit distance, so no later cell can
    hold a closer one. The margin covers the rounding of plane distances: a hit on the
    plane itself (a shared edge lying in a split plane) lets the walk enter the next
    cell too, where a primitive hit at the same ``t`` with a lower index may wait."""
    return best_prim >= 0 and best_t < t_exit - EXIT_MARGIN * abs(t_exit)


@inline_kernel
def store_hit(i, t, prim, u, v, out_t, out_prim, out_u, out_v):
    """Write ray ``i``'s best hit into the output arrays (left as a miss when ``prim < 0``)."""
    if prim >= 0:
        out_t[i] = t
        out_prim[i] = prim
        out_u[i] = u
        out_v[i] = v


def _any_dask(*values) -> bool:
    """Whether any value is a Dask collection, decided without importing Dask."""
    return any(type(value).__module__.split(".")[0] == "dask" for value in values)


class Accelerator(PointQueries):
    """A built acceleration structure over a scene.

    Subclasses set :attr:`method`, fill :attr:`build_seconds`, and implement
    :meth:`_trace` (one kernel call filling the output arrays, ray ``i`` of the
    batch into row ``batch.hit_slot[i]``) and
    :meth:`_structure_stats`.
    """

    method = "?"
    build_bytes_per_primitive = 400
    """Upper bound on the memory a build takes per primitive, checked before it starts."""

    def __init__(self, scene: TriangleMesh | Spheres, options: dict):
        self.scene = scene
        self.options = options
        self.build_seconds = 0.0

    def __repr__(self) -> str:
        opts = ", ".join(f"{k}={v!r}" for k, v in self.options.items())
        return f"<{self.method} over {self.scene!r}{', ' + opts if opts else ''}>"

    def intersect(self, origins, directions, t_min=0.0, t_max=np.inf, *, any_hit=False, counters=False,
                  reorder=True) -> Hits:
        """Closest hit of each ray in ``[t_min, t_max]``.

        Parameters
        ----------
        origins, directions : (n, 3) array_like
            Rays ``origin + t * direction``; directions need not be unit length but
            must not be zero. A single origin is broadcast to all directions.
        t_min, t_max : float or (n,) array_like
            The interval searched, inclusive.
        any_hit : bool
            Stop at the first hit found rather than the closest (shadow rays).
        counters : bool
            Also return per-ray work counters in ``hits.counters``.
        reorder : bool
            Trace a batch of ``ray_order.MIN_RAYS`` rays or more in a coherent
            order (:mod:`rayaccel.ray_order`); the results are in the given order
            either way. ``False`` traces the rays in the given order.

        Any input a ``dask.array`` makes every field of the result a lazy Dask array
        chunked as the rays (:func:`rayaccel.distributed.intersect`).
        """
        if _any_dask(origins, directions, t_min, t_max):
            from ..distributed import intersect

            return intersect(self, origins, directions, t_min, t_max, any_hit=any_hit, counters=counters,
                             reorder=reorder)
        return self._intersect(origins, directions, t_min, t_max, bool(any_hit), counters, reorder)

    def _intersect(self, origins, directions, t_min, t_max, any_hit, counters, reorder) -> Hits:
        """:meth:`intersect` on array inputs (scenes of instances override it)."""
        rays, t, prim, u, v, work = self._cast(origins, directions, t_min, t_max, any_hit, counters, reorder,
                                               coordinates=True)
        if self.scene.kind == SPHERE:
            sphere_hit_coords(self.scene.geometry, rays.origins, rays.directions, t, prim, u, v)
        ray_counters = RayCounters(work[:, 0].copy(), work[:, 1].copy(), work[:, 2].copy()) if counters else None
        return Hits(t, prim, u, v, ray_counters, np.minimum(prim, 0))

    def occluded(self, origins, directions, t_min=0.0, t_max=np.inf, *, reorder=True) -> np.ndarray:
        """(n,) bool: whether anything lies on each ray within ``[t_min, t_max]``; a lazy Dask
        array when any input is one (:func:`rayaccel.distributed.occluded`)."""
        if _any_dask(origins, directions, t_min, t_max):
            from ..distributed import occluded

            return occluded(self, origins, directions, t_min, t_max, reorder=reorder)
        return self._occluded(origins, directions, t_min, t_max, reorder)

    def _occluded(self, origins, directions, t_min, t_max, reorder) -> np.ndarray:
        """:meth:`occluded` on array inputs (scenes of instances override it)."""
        return self._cast(origins, directions, t_min, t_max, True, False, reorder)[2] >= 0

    def save(self, path) -> None:
        """Write the built structure, its scene and options to one file (:mod:`rayaccel.persist`);
        ``rayaccel.load_accelerator(path)`` reads it back without rebuilding."""
        from ..persist import save

        save(self, path)

    def __reduce__(self):
        from ..persist import reduce_accelerator

        return reduce_accelerator(self)

    def refit(self, vertices=None) -> None:
        """Move the primitives and update the structure without rebuilding it: the BVH
        methods only (``bvh-*``); the others raise ``NotImplementedError``."""
        raise NotImplementedError(
            f"{self.method!r} cannot be refitted (only the bvh-* methods can); build it again over the moved "
            f"scene with ra.build(scene, {self.method!r})"
        )

    def _cast(self, origins, directions, t_min, t_max, any_hit, counters, reorder, coordinates=False):
        """Validate the rays and trace them: ``(rays, t, prim, u, v, work)``, each in the order given.
        The kernels write hits only, so ``t`` and ``prim`` start as misses, and so do ``u`` and
        ``v`` (NaN) when the caller reads them (``coordinates``); otherwise they are scratch."""
        rays = prepare_rays(origins, directions, t_min, t_max)
        n = len(rays.origins)
        t = np.full(n, np.inf)
        prim = np.full(n, -1, dtype=np.int64)
        u = np.full(n, np.nan) if coordinates else np.empty(n)
        v = np.full(n, np.nan) if coordinates else np.empty(n)
        work = np.zeros((n if counters else 0, 3), dtype=np.int64)
        batch = coherent_batch(rays, *self.scene_box) if reorder and n >= MIN_RAYS else rays
        if n:
            self._trace(batch, any_hit, t, prim, u, v, work)
        return rays, t, prim, u, v, work

    @functools.cached_property
    def scene_box(self) -> tuple[np.ndarray, np.ndarray]:
        """``(lo, hi)``: the box around the whole scene, as the build saw it (computed on first
        use for structures whose build needs no primitive boxes)."""
        bounds = self.scene.bounds()
        return bounds.scene_lo, bounds.scene_hi

    def _primitive_bounds(self) -> PrimitiveBounds:
        """The scene's primitive boxes, for a build; keeps the scene box for the queries and
        the renderer, which would otherwise compute all the boxes again."""
        bounds = self.scene.bounds()
        self.scene_box = bounds.scene_lo, bounds.scene_hi
        return bounds

    def _trace(self, batch, any_hit, t, prim, u, v, work) -> None:
        raise NotImplementedError

    def _structure_stats(self) -> dict:
        raise NotImplementedError

    def stats(self, origins=None, directions=None) -> dict:
        """The statistics of :mod:`rayaccel.stats`, whose docstring defines each.

        Structural figures come from the built arrays; ``avg_nodes_per_ray`` and
        ``avg_intersections_per_ray`` are measured over the given rays, or over
        128 x 128 primary rays of the default camera when none are given.
        """
        from ..stats import measured_stats

        result = {"method": self.method, "primitives": len(self.scene), "build_seconds": self.build_seconds}
        result.update(self._structure_stats())
        if origins is None:
            origins, directions = Camera.framing(*self.scene_box).rays(128, 128)
        result.update(measured_stats(self, origins, directions))
        return result
