"""Coherent ray order: an incoherent batch is traced sorted by a Morton key, so that
rays which follow each other through a kernel also fetch the same nodes.

Pharr, Kolb, Gershbein & Hanrahan, "Rendering Complex Scenes with
Memory-Coherent Ray Tracing", SIGGRAPH 1997, and Moon, Byun, Kim, Yoon & Yoon,
"Cache-Oblivious Ray Reordering", ACM TOG 2010: on a scene larger than the
caches, an incoherent ray spends its time waiting for nodes and primitives
from memory, and rays with nearby origins and like directions wait for the
same ones. Each ray's key is its direction octant (3 bits, most significant)
above the Morton code of its origin's cell in a 4 x 4 x 4 grid over the
batch's origins; one counting sort, whose placing pass copies the rays, puts
them in key order. The copy carries each ray's ``hit_slot``, so the kernels
write every hit in its ray's place and the caller sees its own order.

A batch whose consecutive rays already start close together (camera rays,
shadow rays from their hits) is traced as given: sorting camera rays by
direction cells measured slower than their scanline order. Measured on the
full dragon (2**20 incoherent rays, bvh-binned, 2 threads, interleaved
medians): closest hit 1.32 -> 1.46 Mrays/s and any hit 1.43 -> 1.59 Mrays/s,
the sort included (about 55 ms). Finer keys (up to 32 cells per axis) sorted
no better and cost up to 145 ms; gathering rays through a permutation inside
the kernel, instead of copying them, cost the whole gain (a cache miss per ray).

A structure that fits in half of the last-level cache is traced with its rays as
given: its nodes stay in the cache whatever the order, and the sort only costs. One
run, 2**20 incoherent rays, bvh-binned, 2 threads, 32 MiB L3, time as given over
time sorted (closest / any hit): forest-small-chair (5.7 MiB) 0.81 / 0.72, armadillo
(9.7 MiB) 0.79 / 0.70, buddha (9.5 MiB) 0.81 / 0.93; dragon-203k (19.4 MiB) 1.05 /
1.09 and, in a second run, 1.04 / 0.93; the full dragon (83.6 MiB) 0.98 / 0.99 and
1.10 / 0.98. Nine interleaved rounds on the full dragon, closest hit: time sorted over
time as given 0.965 for bvh-binned, 0.80 for the kd-tree.

Since the BVH is walked eight-wide it loses to the sort wherever measured, so its
accelerators trace their rays as given (``_walk_gains_from_sorting``). Nine
interleaved rounds, 2 threads, 2**20 incoherent rays, time sorted over time as given
(closest / any hit): full dragon, bvh-binned (88 MiB) 1.05 / 1.08 and kd-tree (91 MiB) 0.85 / 0.82;
the full dragon subdivided once (3.5 million triangles, 353 MiB, seven rounds),
bvh-binned 1.09 / 1.08. The kd-tree, once it kept rays in flight per thread on such
batches (:mod:`.structures.kdtree.traverse_interleaved`), traced them faster as given
too (full dragon, 52 MB, 2 threads, seven rounds: time sorted over time as given 1.10 /
1.12); without ``interleave`` it sorts them (0.98 / 0.97 then).
"""

from __future__ import annotations

import functools
import math
from pathlib import Path
from typing import NamedTuple

import numpy as np
from numba import prange

from ._jit import kernel, parallel_kernel, thread_count
from .counting_sort import chunk_range, counts_to_starts
from .rays import RayBatch, ray_at, result_row
from .selection import median_in_place

__all__ = ["MIN_RAYS", "MIN_PACKET_RAYS", "coherent_batch", "last_level_cache_bytes", "second_level_cache_bytes",
           "sorting_pays", "Neighbours", "sample_neighbours", "packets_pay", "lane_packets_pay",
           "interleaving_pays"]

MIN_RAYS = 1 << 15
"""Batches smaller than this are traced as given: the sort would cost more than it saves."""

MIN_PACKET_RAYS = 1024
"""Batches smaller than this are traced ray by ray (the coherence test itself would be most of the work)."""
_PACKET_ANGLE = 0.02
_ALIKE_ANGLE = 0.1

_DEFAULT_CACHE_BYTES = 32 << 20
_DEFAULT_L2_BYTES = 1 << 20
_BITS_PER_AXIS = 2
_NEARBY = 1.0 / 64.0
_SAMPLE = 1024
"""Most pairs of neighbouring rays :func:`sample_neighbours` reads. It runs before the walk
starts, while the threads wait: for 2**20 forest camera rays (``occluded`` on two threads, a
call of 12-15 ms), 4096 pairs took 0.66 ms and the first chunk began 1.23 ms into the call;
1024 pairs 0.29 ms, the first chunk at 0.73-0.76 ms (medians of 15 calls)."""
_SAMPLE_RUNS = 32
"""Runs of consecutive rays, evenly spaced over a batch, that :func:`sample_neighbours` takes its
:data:`_SAMPLE` pairs from, so that it reads a few stretches of the rays rather than a cache line
and a page each pair: 1024 pairs spread one by one over 2**20 forest camera rays took 229 us after
a walk had filled the caches with other data (91 us when the sampled rays were in cache), in 32
runs 122 us (21 us), medians of 30 and 200 calls."""


@kernel
def _spread_bits(x, bits):
    """The low ``bits`` bits of ``x`` moved to every third position, for a 3-D Morton code."""
    spread = 0
    for bit in range(bits):
        spread |= ((x >> bit) & 1) << (3 * bit)
    return spread


@kernel
def _cell(value, lo, scale, cells):
    return min(max(int((value - lo) * scale), 0), cells - 1)


@parallel_kernel
def _sort_rays(origins, directions, t_min, t_max, hit_slot, lo, scale, bits_per_axis, n_chunks,
               out_origins, out_directions, out_t_min, out_t_max, out_hit_slot):
    """Copy the rays into the ``out_*`` arrays, stably sorted by key (octant, Morton code of
    the origin's cell in ``lo + [0, 2**bits_per_axis) / scale``): a counting sort over
    ``n_chunks`` chunks of rays (:mod:`rayaccel.counting_sort`). The placing pass
    reads the rays in order and writes each where it belongs; reading each from its
    place in the sorted order instead waits on a cache and TLB miss per ray."""
    n = origins.shape[0]
    cells = 1 << bits_per_axis
    keys = np.empty(n, dtype=np.int32)
    starts = np.zeros((n_chunks, 8 << (3 * bits_per_axis)), dtype=np.int64)
    for c in prange(n_chunks):
        first, end = chunk_range(n, n_chunks, c)
        for i in range(first, end):
            morton = (_spread_bits(_cell(origins[i, 0], lo[0], scale[0], cells), bits_per_axis)
                      | (_spread_bits(_cell(origins[i, 1], lo[1], scale[1], cells), bits_per_axis) << 1)
                      | (_spread_bits(_cell(origins[i, 2], lo[2], scale[2], cells), bits_per_axis) << 2))
            octant = ((directions[i, 0] < 0.0) << 2) | ((directions[i, 1] < 0.0) << 1) | (directions[i, 2] < 0.0)
            key = (octant << (3 * bits_per_axis)) | morton
            keys[i] = key
            starts[c, key] += 1
    counts_to_starts(starts)
    for c in prange(n_chunks):
        first, end = chunk_range(n, n_chunks, c)
        for i in range(first, end):
            place = starts[c, keys[i]]
            starts[c, keys[i]] += 1
            for axis in range(3):
                out_origins[place, axis] = origins[i, axis]
                out_directions[place, axis] = directions[i, axis]
            if t_min.shape[0] > 1:
                out_t_min[place] = t_min[i]
            if t_max.shape[0] > 1:
                out_t_max[place] = t_max[i]
            out_hit_slot[place] = result_row(hit_slot, i)


class Neighbours(NamedTuple):
    """What consecutive rays of an evenly spaced sample of a batch say about its coherence
    (:func:`sample_neighbours`): the batch's size, the median over the sampled neighbours of
    the largest coordinate difference of their origins, the scene's size (its box's longest
    side) and the median cosine of the angle between the neighbours' directions."""

    rays: int
    origin_step: float
    scene_size: float
    cosine: float

    def start_together(self, fraction: float) -> bool:
        """Whether half of the sampled neighbours or more start within ``fraction`` of the
        scene's size of each other."""
        return self.origin_step <= fraction * self.scene_size

    def head_alike(self, angle: float) -> bool:
        """Whether half of the sampled neighbours or more head within ``angle`` radians."""
        return self.cosine >= math.cos(angle)


@kernel
def _neighbour_medians(origins, directions, scene_lo, scene_hi, run, gap, pairs):
    """``(origin step, scene size, cosine)`` of :class:`Neighbours` from ``pairs`` rays ``(k // run) *
    gap + k % run`` (runs of ``run`` consecutive rays, ``gap`` apart) and their successors: the
    medians of the largest coordinate difference of their origins and of the cosine of the angle
    between their directions, and the longest side of the box ``scene_lo``..``scene_hi``."""
    steps = np.empty(pairs)
    cosines = np.empty(pairs)
    for k in range(pairs):
        i = (k // run) * gap + k % run
        step = 0.0
        dot = 0.0
        square_0 = 0.0
        square_1 = 0.0
        ray = ray_at(origins, directions, i)
        following = ray_at(origins, directions, i + 1)
        for axis in range(3):
            step = max(step, abs(following[axis] - ray[axis]))
            dot += ray[axis + 3] * following[axis + 3]
            square_0 += ray[axis + 3] ** 2
            square_1 += following[axis + 3] ** 2
        steps[k] = step
        cosines[k] = dot / np.sqrt(square_0 * square_1)
    scene_size = max(scene_hi[0] - scene_lo[0], scene_hi[1] - scene_lo[1], scene_hi[2] - scene_lo[2])
    return median_in_place(steps), scene_size, median_in_place(cosines)


def _sample_stride(n: int) -> int:
    """The step between the sampled rays of a batch of ``n``: at most :data:`_SAMPLE` of them."""
    return max(1, n // _SAMPLE)


def sample_neighbours(batch: RayBatch, scene_lo, scene_hi) -> Neighbours:
    """The :class:`Neighbours` of ``batch`` in a scene whose box is ``scene_lo``..``scene_hi``,
    from at most :data:`_SAMPLE` pairs of consecutive rays, in :data:`_SAMPLE_RUNS` runs; a batch of fewer than two rays
    counts as coherent. A walk's choices (:func:`packets_pay`, :func:`lane_packets_pay`,
    :func:`interleaving_pays`) share one sample. One kernel takes it (:func:`_neighbour_medians`):
    for 1024^2 forest camera rays, 23 us in a loop and 56 us in a query, after its walk; the
    scene's size, the sample's arrays and its medians taken in NumPy beside the kernel made it
    189 us in a query (medians of 15, 2026-12-07), each NumPy call slow with the caches cold."""
    n = batch.size
    if n < 2:
        return Neighbours(n, 0.0, float(np.max(scene_hi - scene_lo)), 1.0)
    pairs = min(n - 1, _SAMPLE)
    run = pairs if pairs < _SAMPLE else _SAMPLE // _SAMPLE_RUNS
    gap = run if pairs < _SAMPLE else (n - 1 - run) // (_SAMPLE_RUNS - 1)
    return Neighbours(n, *_neighbour_medians(batch.origins, batch.directions, scene_lo, scene_hi, run, gap, pairs))


def packets_pay(batch: RayBatch, scene_lo, scene_hi, sampled: Neighbours | None = None) -> bool:
    """Whether a batch is coherent enough to trace in packets of consecutive rays: at least
    :data:`MIN_PACKET_RAYS` rays, half of the sampled neighbours or more starting at the same
    point (to within ``1e-9`` of the scene's size) and heading within :data:`_PACKET_ANGLE`
    radians of each other, as a pinhole camera's rays through neighbouring pixels do.
    Shadow rays from neighbouring hits to one light start apart, on the surface, where the
    bounds of eight of them (:mod:`.structures.bvh.packet_slab`) cull little: the full dragon's
    ran at 0.3 of their single-ray speed in such packets; :func:`lane_packets_pay` takes them.
    ``sampled``: the batch's :func:`sample_neighbours`, when known."""
    sampled = sampled or sample_neighbours(batch, scene_lo, scene_hi)
    return sampled.rays >= MIN_PACKET_RAYS and sampled.start_together(1e-9) and sampled.head_alike(_PACKET_ANGLE)


def lane_packets_pay(batch: RayBatch, scene_lo, scene_hi, sampled: Neighbours | None = None) -> bool:
    """Whether a batch is coherent enough to trace in packets of consecutive rays tested lane by
    lane: at least :data:`MIN_PACKET_RAYS` rays, half of the sampled neighbours or more starting
    within ``1/64`` of the scene's size of each other and heading within :data:`_ALIKE_ANGLE`
    radians, as shadow rays from neighbouring hits to one light do."""
    sampled = sampled or sample_neighbours(batch, scene_lo, scene_hi)
    return sampled.rays >= MIN_PACKET_RAYS and sampled.start_together(_NEARBY) and sampled.head_alike(_ALIKE_ANGLE)


def interleaving_pays(batch: RayBatch, scene_lo, scene_hi, structure_bytes: int,
                      sampled: Neighbours | None = None, *, caches: int = 4) -> bool:
    """Whether a walk should keep several rays in flight per thread (the eight-wide BVH's,
    :mod:`.structures.bvh.traverse_interleaved`, and the kd-tree's,
    :mod:`.structures.kdtree.traverse_interleaved`): a structure of more than ``caches`` times
    a core's second-level cache, and a batch whose neighbouring rays start apart (more than
    ``1/64`` of the scene's size, for half of them or more) or head apart (by more than
    :data:`_ALIKE_ANGLE` radians), so that they do not share the nodes they wait for. Camera
    rays and shadow rays from their hits to one light keep the walk of one ray at a time."""
    if structure_bytes <= caches * second_level_cache_bytes() or batch.size < 2:
        return False
    sampled = sampled or sample_neighbours(batch, scene_lo, scene_hi)
    return not (sampled.start_together(_NEARBY) and sampled.head_alike(_ALIKE_ANGLE))


def coherent_batch(batch: RayBatch, scene_lo: np.ndarray, scene_hi: np.ndarray) -> RayBatch:
    """``batch`` sorted into coherent order (see the module docstring), each ray's
    ``hit_slot`` going with it; ``batch`` itself when it is coherent already, that is when
    consecutive rays of an evenly spaced sample start within ``1/64`` of the scene's size
    of each other (half of them or more), as camera rays and the shadow rays from
    their hits do."""
    n = batch.size
    if sample_neighbours(batch, scene_lo, scene_hi).start_together(_NEARBY):
        return batch
    origins = batch.origins[:n - 1:_sample_stride(n)]
    lo, extent = origins.min(axis=0), np.ptp(origins, axis=0)
    scale = (1 << _BITS_PER_AXIS) / np.where(extent > 0.0, extent, 1.0)
    sorted_batch = RayBatch(np.empty_like(batch.origins), np.empty_like(batch.directions),
                            batch.t_min.copy() if len(batch.t_min) == 1 else np.empty_like(batch.t_min),
                            batch.t_max.copy() if len(batch.t_max) == 1 else np.empty_like(batch.t_max),
                            np.empty(n, dtype=np.int64))
    _sort_rays(*batch, lo, scale, _BITS_PER_AXIS, thread_count(), *sorted_batch)
    return sorted_batch


@functools.cache
def _cache_sizes() -> dict[int, int]:
    """The size in bytes of each level of CPU cache that holds data, read from Linux's ``/sys``
    (empty where it cannot be read)."""
    sizes = {}
    for index in Path("/sys/devices/system/cpu/cpu0/cache").glob("index*"):
        try:
            level = int((index / "level").read_text())
            kind = (index / "type").read_text().strip()
            text = (index / "size").read_text().strip().upper()
        except (OSError, ValueError):
            continue
        unit = {"K": 1 << 10, "M": 1 << 20, "G": 1 << 30}.get(text[-1:], 1)
        digits = text.rstrip("KMG")
        if kind != "Instruction" and digits.isdigit():
            sizes[level] = max(sizes.get(level, 0), int(digits) * unit)
    return sizes


def last_level_cache_bytes() -> int:
    """Size of the largest CPU cache; 32 MiB where it cannot be read."""
    return max(_cache_sizes().values(), default=_DEFAULT_CACHE_BYTES)


def second_level_cache_bytes() -> int:
    """Size of one core's second-level cache; 1 MiB where it cannot be read."""
    return _cache_sizes().get(2, _DEFAULT_L2_BYTES)


def sorting_pays(n_rays: int, structure_bytes: int) -> bool:
    """Whether a batch of ``n_rays`` is worth sorting for a structure of ``structure_bytes``:
    at least :data:`MIN_RAYS` rays and a structure larger than half the last-level cache
    (see the module docstring)."""
    return n_rays >= MIN_RAYS and structure_bytes > last_level_cache_bytes() // 2
