"""The public face every acceleration structure shares: validation, queries, statistics."""

from __future__ import annotations

import functools
import time

import numpy as np

from .._jit import helper_wake_seconds, inline_kernel, share_among_threads, thread_count, thread_rows
from .._validate import as_positive_int, check_ray_arrays
from ..geometry.sphere import sphere_hit_coords
from ..ray_order import coherent_batch, sorting_pays
from ..rays import WORK_COLUMNS, AllHits, Camera, Hits, RayBatch, RayCounters, prepare_rays
from ..scene import SPHERE, PrimitiveBounds, Spheres, TriangleMesh
from .actions import (
    NEAREST,
    hit_count,
    hit_flags,
    hit_list,
    hit_slots,
    intersect_references,
    is_closer,
    nearest_hit,
    store_hit,
)
from .grid.mailbox import MailboxPool
from .hit_slots import hit_arrays, kept_hits
from .large_primitives import LargePrimitives, large_primitives, unsettled_rays
from .point_queries import PointQueries, any_dask

__all__ = ["Accelerator", "is_closer", "intersect_references", "store_hit", "settled_before", "walk_rays",
           "interval_stacks", "EXIT_MARGIN", "RAY_CHUNK", "CHUNKS_PER_THREAD", "ALONE_FIRST_BELOW", "FIRST_CHUNK",
           "HELPERS_FROM_WAKES", "CHUNK_WAKES", "TAIL_CHUNK_WAKES"]

# Relative margin by which a hit must lie before a cell's exit for the walk to stop there.
EXIT_MARGIN = 1e-9

RAY_CHUNK = 1024
"""Fewest rays in a chunk of a ray walk (fewer rays run on one thread)."""

CHUNKS_PER_THREAD = 16
"""Chunks per thread a batch of rays is cut into, so that the threads finish together."""

ALONE_FIRST_BELOW = 1 << 17
"""Rays below which a batch begins on the calling thread alone (:func:`_walk_while_alone_pays`);
larger batches are shared among the threads at once."""

FIRST_CHUNK = 256
"""Rays of the first chunk of a batch that :func:`_walk_while_alone_pays` times."""

HELPERS_FROM_WAKES = 6.0
"""How many start latencies of a helper (:func:`rayaccel._jit.helper_wake_seconds`) the rays left
of a batch must take the calling thread alone for the helpers to share them
(:func:`_walk_while_alone_pays`)."""

CHUNK_WAKES = 2.0
"""How many start latencies of a helper a chunk of the rays then shared takes at least, at the
last chunk's time a ray: cheap rays go in fewer, longer chunks, with fewer hand-overs of the GIL."""

TAIL_CHUNK_WAKES = 8.0
"""How many start latencies of a helper the last chunks of a batch, which shrink so that the
threads end together (:func:`rayaccel._jit.share_among_threads`), take at least at the pace of
the chunk before: only chunks several times longer are cut (the incoherent rays' chunks of
milliseconds, not the camera rays' tenths of one)."""

LIST_SLOTS = (8, 64)
"""Hits per ray that the listing walks of :meth:`Accelerator.intersect_all` have room for: all
rays first, then those that filled the first size (see :meth:`Accelerator._nearest_hits`).
Measured on the full dragon (2**18 rays, bvh-binned, interleaved medians, load about 3.8):
incoherent rays 1.48 s with a counting and a listing walk, 1.07 s with (4, 32), 0.90 s with
(8, 64); camera rays 0.42, 0.29 and 0.25 s."""

LIST_BATCH = 1 << 17
"""Rays listed at a time by :meth:`Accelerator.intersect_all`, whose first slots, reused from
one batch to the next, take ``32 * LIST_SLOTS[0] * LIST_BATCH`` bytes (32 MiB). Fresh slots for
2**20 rays at once (256 MiB, which numpy asks the kernel to back with huge pages) made the first
touch of their pages the slowest part of many calls. Full dragon, 2**20 rays, medians of 6 calls
(camera / incoherent rays): batches of 2**15 rays 177 / 534 ms, 2**16 151 / 507, 2**17 134 / 479,
2**18 131 / 480, 2**20 299 / 739 ms (single calls 87-332 ms on camera rays)."""


@inline_kernel
def settled_before(best_prim, best_t, t_exit):
    """Whether the best hit so far lies before a cell's exit distance, so no later cell can
    hold a closer one. The margin covers the rounding of plane distances: a hit on the
    plane itself (a shared edge lying in a split plane) lets the walk enter the next
    cell too, where a primitive hit at the same ``t`` with a lower index may wait."""
    return best_prim >= 0 and best_t < t_exit - EXIT_MARGIN * abs(t_exit)


def walk_rays(walk, n_rays: int, *args, align: int = 1) -> int:
    """Run a structure's ray walk, a :func:`rayaccel._jit.chunk_kernel` taking ``(ray_first,
    ray_end, tid, *args)``, over ``n_rays`` rays on threads: chunks of :data:`RAY_CHUNK` rays
    or more, a multiple of ``align``, about :data:`CHUNKS_PER_THREAD` per thread, each thread
    taking them from a part of the rays of its own first, the last ones shorter but no shorter
    than :data:`TAIL_CHUNK_WAKES` helper wakes (:func:`rayaccel._jit.share_among_threads`); ``tid``
    picks the chunk's rows of per-thread stacks and mailboxes. Returns the total of what the walk
    returns for its chunks: the unusable rays it met, for a walk that tests its rays itself (see
    :attr:`Accelerator._walk_checks_rays`), and 0 for one that returns nothing. A batch of one
    chunk or less runs on the calling thread at once, and one of fewer than
    :data:`ALONE_FIRST_BELOW` rays begins there alone (:func:`_walk_while_alone_pays`)."""
    if n_rays <= RAY_CHUNK:
        return walk(0, n_rays, 0, *args) or 0
    threads = thread_count()
    wake = helper_wake_seconds() if threads > 1 else 0.0
    first, found = 0, 0
    if n_rays < ALONE_FIRST_BELOW and threads > 1:
        first, found, seconds_a_ray = _walk_while_alone_pays(walk, n_rays, args, align, wake)
        if first == n_rays:
            return found
        chunk = _shared_chunk(n_rays - first, seconds_a_ray, wake, threads, align)
    else:
        chunk = -(-_even_chunk(n_rays, threads) // align) * align
    counts = []
    share_among_threads(lambda a, b, tid: counts.append(walk(first + a, first + b, tid, *args)), n_rays - first,
                        chunk, align, TAIL_CHUNK_WAKES * wake)
    return found + sum(count for count in counts if count is not None)


def _even_chunk(rays: int, threads: int) -> int:
    """Rays a chunk of ``rays`` shared among ``threads`` takes: about :data:`CHUNKS_PER_THREAD` a
    thread, :data:`RAY_CHUNK` at least."""
    return max(RAY_CHUNK, -(-rays // (CHUNKS_PER_THREAD * threads)))


def _shared_chunk(rays: int, seconds_a_ray: float, wake: float, threads: int, align: int) -> int:
    """The chunk length for the ``rays`` left of a batch that :func:`_walk_while_alone_pays` hands to
    the helpers: as a large batch's, but at least :data:`CHUNK_WAKES` helper wakes (``wake`` seconds
    each) long at ``seconds_a_ray``, and at most a thread's share, so that every thread gets a chunk;
    a multiple of ``align``."""
    chunk = max(_even_chunk(rays, threads), int(CHUNK_WAKES * wake / seconds_a_ray))
    return max(align, min(chunk, rays // threads) // align * align)


def _walk_while_alone_pays(walk, n_rays: int, args: tuple, align: int, wake: float) -> tuple[int, int, float]:
    """Walk the first rays of a batch on the calling thread, in chunks of :data:`FIRST_CHUNK` rays,
    then of three times the rays walked so far (multiples of ``align``), until the rays left would
    keep it busy alone for more than :data:`HELPERS_FROM_WAKES` start latencies of a helper
    (``wake`` seconds each, :func:`rayaccel._jit.helper_wake_seconds`), as the last chunk's time a
    ray foretells them, or none is left. Returns the rays walked, the total of what the walk
    returned and the last chunk's seconds a ray.

    A threaded pass pays about two wakes of a sleeping thread (the helper's at its start, the
    caller's when a helper ends last) and the GIL's hand-overs between chunks; the pool's median
    wake measured 55-70 us on the two-vCPU virtual machine this was written on, where the forest's
    4,096 middle camera rays took 301 us a call for an any hit on two threads and 137 us on one
    (2026-12-07). Rays that grow dearer along a batch (rows of sky above a model) call the helpers
    once a chunk shows it.
    Against every batch of more than :data:`RAY_CHUNK` rays threaded at once (time over time before;
    two threads, loops of distinct batches, medians of 9 rounds alternating in one process, batches
    of 2,048 / 4,096 / 8,192 rays, 2026-12-07): forest camera rays any hit 0.45 / 0.51 / 0.70,
    closest 0.83 / 1.04 / 1.01, incoherent 1.09 / 0.95 / 0.99 and 1.02 / 1.04 / 1.07; full dragon
    camera rays 0.79 / 0.95 / 1.06 and 0.83 / 1.02 / 1.09, incoherent 1.10 / 1.05 / 1.04 and
    1.14 / 1.01 / 1.02: the first chunk delays the helpers of a batch of dear rays, which a batch of
    2,048 pays most."""
    first, found = 0, 0
    end = -(-FIRST_CHUNK // align) * align
    while True:
        end = min(end, n_rays)
        start = time.perf_counter()
        found += walk(first, end, 0, *args) or 0
        seconds_a_ray = (time.perf_counter() - start) / (end - first)
        first = end
        if first == n_rays or seconds_a_ray * (n_rays - first) > HELPERS_FROM_WAKES * wake:
            return first, found, seconds_a_ray
        end = -(-4 * first // align) * align


def interval_stacks(rows: int, size: int) -> tuple[np.ndarray, np.ndarray]:
    """``rows`` per-thread stacks of ``size`` entries for the walks over cells that keep each pending
    node with its interval along the ray (the kd-tree's binary walks, the octree's): the nodes, and
    their ``(t_enter, t_exit)``."""
    return thread_rows((rows, size), np.int32), thread_rows((rows, size, 2))


class Accelerator(PointQueries):
    """A built acceleration structure over a scene.

    Subclasses set :attr:`method`, fill :attr:`build_seconds`, and implement
    :meth:`_trace` (one call of the structure's walk with a leaf action of
    :mod:`.actions`, ray ``i`` of the batch writing into row ``batch.hit_slot[i]``
    of the action's arrays; it returns the unusable rays met when :attr:`_walk_checks_rays`)
    and :meth:`_structure_stats`.
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
            order when the structure is larger than half the last-level cache
            and its walk gains from it (:mod:`rayaccel.ray_order`; not the
            eight-wide BVH's); the results are in the given order either
            way. ``False`` traces the rays in the given order.

        Any input a ``dask.array`` makes every field of the result a lazy Dask array
        chunked as the rays (:func:`rayaccel.distributed.intersect`).
        """
        if any_dask(origins, directions, t_min, t_max):
            from ..distributed import intersect

            return intersect(self, origins, directions, t_min, t_max, any_hit=any_hit, counters=counters,
                             reorder=reorder)
        return self._intersect(origins, directions, t_min, t_max, bool(any_hit), counters, reorder)

    def _intersect(self, origins, directions, t_min, t_max, any_hit, counters, reorder) -> Hits:
        """:meth:`intersect` on array inputs (scenes of instances override it)."""
        rays, t, prim, u, v, geom, work = self._cast(origins, directions, t_min, t_max, any_hit, counters, reorder)
        if self.scene.kind == SPHERE:
            sphere_hit_coords(self.scene.geometry, rays.with_origin_per_ray().origins, rays.directions, t, prim, u, v)
        ray_counters = RayCounters(*(work[:, k].copy() for k in range(WORK_COLUMNS))) if counters else None
        return Hits(t, prim, u, v, ray_counters, geom)

    def occluded(self, origins, directions, t_min=0.0, t_max=np.inf, *, reorder=True) -> np.ndarray:
        """(n,) bool: whether anything lies on each ray within ``[t_min, t_max]``; a lazy Dask
        array when any input is one (:func:`rayaccel.distributed.occluded`)."""
        if any_dask(origins, directions, t_min, t_max):
            from ..distributed import occluded

            return occluded(self, origins, directions, t_min, t_max, reorder=reorder)
        return self._occluded(origins, directions, t_min, t_max, reorder)

    def _occluded(self, origins, directions, t_min, t_max, reorder) -> np.ndarray:
        """:meth:`occluded` on array inputs (scenes of instances override it): the walk writes
        each ray's answer itself (:func:`.actions.hit_flags`)."""
        rays = self._prepare_rays(origins, directions, t_min, t_max)
        hit = np.empty(rays.size, dtype=np.bool_)
        self._walk_prepared(rays, reorder, True, hit_flags(hit), None)
        return hit

    def count(self, origins, directions, t_min=0.0, t_max=np.inf, *, reorder=True) -> np.ndarray:
        """(n,) int64: how many times each ray crosses the scene within ``[t_min, t_max]``.

        Every primitive counts once per ray however many cells or leaves reference it;
        a ray through an edge or vertex shared by triangles crosses one of them
        (:func:`rayaccel.geometry.triangle.cross_triangle`), so that on a closed mesh
        the count is odd from inside and even from outside; a sphere counts its
        entry and its exit (a tangent ray twice). Inputs as for :meth:`intersect`;
        a lazy Dask array when any input is one (:func:`rayaccel.distributed.count`).
        """
        if any_dask(origins, directions, t_min, t_max):
            from ..distributed import count

            return count(self, origins, directions, t_min, t_max, reorder=reorder)
        rays = prepare_rays(origins, directions, t_min, t_max)
        return self._count(rays, self._ordered(rays, reorder))

    def intersect_all(self, origins, directions, t_min=0.0, t_max=np.inf, *, max_hits=None,
                      reorder=True) -> AllHits:
        """Every hit of each ray within ``[t_min, t_max]``, the hits :meth:`count` counts.

        Returns an :class:`~rayaccel.rays.AllHits`: ray ``i``'s hits are
        ``hits.t[hits.offsets[i]:hits.offsets[i + 1]]`` (and so for ``prim``, ``u``,
        ``v``, ``geom``), sorted by ``t``, equal distances by ``prim``. ``max_hits``
        (a positive int, or None for all) keeps each ray's nearest ``max_hits``.
        Inputs as for :meth:`intersect`; Dask arrays in give Dask arrays out
        (:func:`rayaccel.distributed.intersect_all`).
        """
        if max_hits is not None:
            max_hits = as_positive_int("max_hits", max_hits)
        if any_dask(origins, directions, t_min, t_max):
            from ..distributed import intersect_all

            return intersect_all(self, origins, directions, t_min, t_max, max_hits=max_hits, reorder=reorder)
        return self._intersect_all(prepare_rays(origins, directions, t_min, t_max), max_hits, reorder)

    def _intersect_all(self, rays, max_hits, reorder) -> AllHits:
        """:meth:`intersect_all` on validated rays (scenes of instances override it): the hits of
        :meth:`_nearest_hits` with the slot sizes :data:`LIST_SLOTS`, over pieces of at most
        :data:`LIST_BATCH` rays, which bounds the memory the slots take."""
        pieces = []
        slots = hit_arrays(min(len(rays.origins), LIST_BATCH) * LIST_SLOTS[0]) if LIST_SLOTS else None
        for start in range(0, max(len(rays.origins), 1), LIST_BATCH):
            piece = RayBatch(*(array[start:start + LIST_BATCH] for array in rays[:4]),
                             np.arange(min(LIST_BATCH, len(rays.origins) - start), dtype=np.int64))
            pieces.append(self._nearest_hits(piece, max_hits, reorder, LIST_SLOTS, slots))
        counts, t, prim, u, v = pieces[0] if len(pieces) == 1 else (np.concatenate(field) for field in zip(*pieces))
        offsets = np.zeros(len(counts) + 1, dtype=np.int64)
        np.cumsum(counts, out=offsets[1:])
        m = int(offsets[-1])
        if self.scene.kind == SPHERE and m:
            ray = np.repeat(np.arange(len(counts)), counts)
            sphere_hit_coords(self.scene.geometry, rays.origins[ray], rays.directions[ray], t, prim, u, v)
        return AllHits(offsets, t, prim, u, v, np.zeros(m, dtype=np.int64))

    def _nearest_hits(self, rays, max_hits, reorder, slots, scratch=None):
        """``(counts, t, prim, u, v)``: each ray's nearest hits (all of them, or ``max_hits``), flat
        and in ray order.

        A listing walk with ``slots[0]`` slots per ray (``max_hits`` when fewer) keeps each
        ray's nearest hits and, once a ray's slots are full, prunes beyond the farthest
        kept, as a closest-hit walk prunes beyond its best. Only the rays that filled their
        slots, and so may have more hits, are walked again, with the next size of ``slots``;
        after the last, by a counting walk that sizes their slots exactly and a listing walk
        that fills them. Most rays of most scenes have few hits and are walked once instead
        of twice (a count, then a list); the slots take 32 bytes each while the query runs,
        slot-major (:func:`.actions.hit_slots`), in ``scratch`` (four arrays from
        :func:`.hit_slots.hit_arrays`) when it is large enough."""
        n = len(rays.origins)
        batch = self._ordered(rays, reorder)
        if not slots:
            counts = self._count(rays, batch)
            if max_hits is not None:
                np.minimum(counts, max_hits, out=counts)
            offsets = np.zeros(n + 1, dtype=np.int64)
            np.cumsum(counts, out=offsets[1:])
            return counts, *self._listed(batch, offsets)[1:]
        size = slots[0] if max_hits is None else min(max_hits, slots[0])
        counts = np.zeros(n, dtype=np.int64)
        if scratch is None or len(scratch[0]) < n * size:
            scratch = hit_arrays(n * size)
        t, prim, u, v = (array[:n * size] for array in scratch)
        self._trace(batch, False, hit_slots(size, counts, t, prim, u, v), None)
        full = counts == size if max_hits is None or max_hits > size else np.zeros(n, dtype=bool)
        t, prim, u, v = kept_hits(np.where(full, 0, counts), t, prim, u, v)
        if not full.any():
            return counts, t, prim, u, v
        rows = np.flatnonzero(full)
        subset = RayBatch(*(array[rows] for array in rays[:4]), np.arange(len(rows), dtype=np.int64))
        more, *again = self._nearest_hits(subset, max_hits, reorder, slots[1:])
        counts[rows] = more
        from_full = np.repeat(full, counts)
        merged = []
        for first, second in zip((t, prim, u, v), again):
            out = np.empty(len(from_full), dtype=first.dtype)
            out[~from_full] = first
            out[from_full] = second
            merged.append(out)
        return counts, *merged

    def _listed(self, batch, offsets):
        """``(fill, t, prim, u, v)``: a listing walk of ``batch`` into the slots ``offsets`` (n + 1,)
        of its rows, each row's ``fill`` nearest hits first in its slots, sorted by ``(t, prim)``."""
        m = int(offsets[-1])
        fill = np.zeros(len(offsets) - 1, dtype=np.int64)
        t, prim, u, v = hit_arrays(m)
        if m:
            self._trace(batch, False, hit_list(offsets, fill, t, prim, u, v), None)
        return fill, t, prim, u, v

    def _count(self, rays, batch) -> np.ndarray:
        counts = np.zeros(len(rays.origins), dtype=np.int64)
        if len(counts):
            self._trace(batch, False, hit_count(counts), None)
        return counts

    def _ordered(self, rays, reorder):
        """The batch to trace: ``rays`` in a coherent order when asked for and worth it
        (:func:`rayaccel.ray_order.sorting_pays`)."""
        if reorder and self._walk_gains_from_sorting and sorting_pays(rays.size, self.nbytes):
            return coherent_batch(rays, *self.scene_box)
        return rays

    @property
    def _walk_gains_from_sorting(self) -> bool:
        """Whether the structure's walk traces a large incoherent batch faster sorted (see
        :mod:`rayaccel.ray_order`): true unless a structure says otherwise."""
        return True

    def _mailboxes_for(self, action) -> MailboxPool:
        """The mailboxes of a walk with ``action``: the structure's own for the closest hit (none
        when it has none or they are off: a primitive met again is still the candidate), and
        always some for counting and collecting, which must see each primitive once per ray."""
        own = getattr(self, "mailboxes", None)
        if action.mode == NEAREST:
            return own if own is not None else MailboxPool(0, enabled=False)
        if own is not None and own.enabled:
            return own
        pool = self.__dict__.get("_unique_mailboxes")
        if pool is None:
            pool = self.__dict__.setdefault("_unique_mailboxes", MailboxPool(len(self.scene)))
        return pool

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

    def _cast(self, origins, directions, t_min, t_max, any_hit, counters, reorder):
        """Validate the rays and trace them: ``(rays, t, prim, u, v, geom, work)``, each in the order
        given. The kernels write every ray's row of ``t``, ``prim``, ``u``, ``v`` and ``geom``
        (:func:`.actions.finish_ray`), so these start empty."""
        rays = self._prepare_rays(origins, directions, t_min, t_max)
        n = rays.size
        t, u, v = (np.empty(n) for _ in range(3))
        prim, geom = np.empty(n, dtype=np.int64), np.empty(n, dtype=np.int64)
        work = np.zeros((n, WORK_COLUMNS), dtype=np.int64) if counters else None
        self._walk_prepared(rays, reorder, any_hit, nearest_hit(t, prim, u, v, geom), work)
        return rays, t, prim, u, v, geom, work

    def _prepare_rays(self, origins, directions, t_min, t_max) -> RayBatch:
        """The rays of a closest-hit or any-hit query, checked here unless the walk checks them,
        float32 rays kept so and one origin kept one where the walk takes them."""
        return prepare_rays(origins, directions, t_min, t_max, compact=True, check=not self._walk_checks_rays,
                            keep_float32=self._walk_takes_float32, shared_origin=self._walk_takes_shared_origin)

    def _walk_prepared(self, rays, reorder, any_hit, action, work) -> None:
        """Trace :meth:`_prepare_rays`'s rays with ``action``; when the walk met rays it could not
        use, the check it skipped runs to raise the error. An any-hit query without counters first
        lets the scene's large primitives answer the rays they can (:mod:`.large_primitives`)."""
        if not rays.size:
            return
        walked = rays
        if any_hit and work is None and self._large_primitives_first:
            walked = unsettled_rays(self._large_primitives, self.scene.kind, rays, action)
        if walked is not None and self._trace(self._ordered(walked, reorder), any_hit, action, work):
            check_ray_arrays(rays.origins, rays.directions)

    _large_primitives_first = True
    """Whether any-hit queries test the scene's large primitives before the walk: true for the
    spatial subdivisions, which reference such a primitive from every cell it crosses and reach it
    only after the cells before it on the ray (forest-small-chair, 2**19 incoherent rays, one
    thread, any hit, speed with over without: kdtree 1.21, grid 1.44, hgrid 1.35, octree 2.03,
    grid-bvh 1.14; camera and shadow rays 0.99-1.04)."""

    @functools.cached_property
    def _large_primitives(self) -> LargePrimitives:
        """The primitives any-hit queries test before the walk (:func:`.large_primitives.large_primitives`)."""
        return large_primitives(self.scene, *self.scene_box)

    @property
    def _walk_checks_rays(self) -> bool:
        """Whether the closest-hit and any-hit walk tests every ray as it reads it, leaves those
        :func:`rayaccel._validate.unusable_ray` refuses unwalked, and has :meth:`_trace` return how
        many it met, so that :meth:`intersect` and :meth:`occluded` need not read the rays once
        more beforehand to check them: false unless a structure says otherwise."""
        return False

    @property
    def _walk_takes_float32(self) -> bool:
        """Whether the closest-hit and any-hit walk reads float32 rays as they are
        (:func:`rayaccel.rays.ray_at`), so that :meth:`intersect` and :meth:`occluded` need not
        copy them into float64: false unless a structure says otherwise."""
        return False

    _walk_takes_shared_origin = False
    """Whether the closest-hit and any-hit walk takes a batch whose rays share one origin as
    that one origin (:attr:`rayaccel.rays.RayBatch.shares_origin`), so that :meth:`intersect`
    and :meth:`occluded` need not copy it to every ray: true for a walk that reads its rays
    through :func:`rayaccel.rays.ray_at`, which takes one origin for all as it takes one per ray."""

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

    def _trace(self, batch, any_hit, action, work) -> int | None:
        raise NotImplementedError

    @property
    def nbytes(self) -> int:
        """Bytes of the arrays that queries read (``stats()["bytes"]``); each structure says which."""
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
