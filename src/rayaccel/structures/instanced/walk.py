"""The top level of a two-level scene: which instances each ray meets, rays into object frames, merging.

The top level is a binary BVH over the instances' world boxes, one instance
per leaf, in the layout of :mod:`..bvh.layout` (float64 boxes, no packed
records). Rather than descending into an object's structure from inside the
walk (one kernel for every pair of methods), a ray batch is traced in three
steps: :func:`instance_candidates` walks the top level and lists, per ray, the
instances whose box it enters, sorted by entry distance; the caller hands the
(ray, instance) pairs, grouped by object, to that object's structure through
:func:`object_rays`, which moves the rays into the object's frame; and
:func:`merge_hits` keeps each ray's closest hit.

In the object's frame the ray is ``A^-1 (o - b) + t A^-1 d`` for the instance
transform ``x -> A x + b``: the same parameter ``t`` names the same point in
both frames, so distances stay in world units of the given direction without
renormalising (pbrt-v4's ``Transform::ApplyInverse(Ray)``; Embree's instance
intersector does the same).
"""

from __future__ import annotations

import numba
import numpy as np
from numba import prange

from ..._jit import inline_kernel, kernel, lent_rows, parallel_kernel, thread_id, thread_rows

__all__ = ["instance_candidates", "object_rays", "merge_hits"]


@inline_kernel
def _clip_axis(lo, hi, o, d, t_enter, t_exit):
    """:func:`rayaccel.geometry.box.clip_to_box` on one axis: exact for a zero component,
    where the ray runs inside the slab for all ``t`` or for none."""
    if d == 0.0:
        if o < lo or o > hi:
            return 1.0, 0.0
        return t_enter, t_exit
    t0 = (lo - o) / d
    t1 = (hi - o) / d
    if t0 > t1:
        t0, t1 = t1, t0
    return max(t_enter, t0), min(t_exit, t1)


@inline_kernel
def _clip_to_node(box, node, ox, oy, oz, dx, dy, dz, t_enter, t_exit):
    """``(enter, exit)`` of the ray's interval inside row ``node`` of ``box`` (lo, hi); enter > exit on a miss."""
    t_enter, t_exit = _clip_axis(box[node, 0], box[node, 3], ox, dx, t_enter, t_exit)
    t_enter, t_exit = _clip_axis(box[node, 1], box[node, 4], oy, dy, t_enter, t_exit)
    return _clip_axis(box[node, 2], box[node, 5], oz, dz, t_enter, t_exit)


@parallel_kernel
def _walk(node_box, node_first, node_count, prim_order, origins, directions, t_min, t_max, stack, offsets, fill,
          out_instance, out_entry, nodes_visited):
    """Count (``fill`` False) or list (``fill`` True, at ``offsets[i]``) the instances whose
    box ray ``i`` enters within its interval, with their entry distances."""
    for i in prange(origins.shape[0]):
        ox, oy, oz = origins[i, 0], origins[i, 1], origins[i, 2]
        dx, dy, dz = directions[i, 0], directions[i, 1], directions[i, 2]
        tid = thread_id()
        found = 0
        visited = 0
        sp = 0
        stack[tid, sp] = 0
        sp += 1
        while sp > 0:
            sp -= 1
            node = stack[tid, sp]
            visited += 1
            enter, exit_ = _clip_to_node(node_box, node, ox, oy, oz, dx, dy, dz, t_min[i], t_max[i])
            if enter > exit_:
                continue
            if node_count[node] == 0:
                stack[tid, sp] = node_first[node]
                stack[tid, sp + 1] = node_first[node] + 1
                sp += 2
                continue
            for k in range(node_first[node], node_first[node] + node_count[node]):
                if fill:
                    slot = offsets[i] + found
                    out_instance[slot] = prim_order[k]
                    out_entry[slot] = enter
                found += 1
        if fill:
            _sort_by_entry(out_instance, out_entry, offsets[i], offsets[i] + found)
        else:
            offsets[i + 1] = found
            nodes_visited[i] = visited


@kernel
def _sort_by_entry(instance, entry, first, end):
    """Insertion sort of ``first:end`` by entry distance, ties by instance id (short runs)."""
    for a in range(first + 1, end):
        key_entry = entry[a]
        key_instance = instance[a]
        b = a - 1
        while b >= first and (entry[b] > key_entry or (entry[b] == key_entry and instance[b] > key_instance)):
            entry[b + 1] = entry[b]
            instance[b + 1] = instance[b]
            b -= 1
        entry[b + 1] = key_entry
        instance[b + 1] = key_instance


def _walk_stack(rows: int, max_depth: int) -> tuple[np.ndarray]:
    """The per-thread stack of :func:`_walk` over a top tree ``max_depth`` deep."""
    return (thread_rows((rows, max_depth + 2), np.int64),)


def instance_candidates(top, max_depth, origins, directions, t_min, t_max):
    """``(offsets, instance, entry, nodes_visited)``: ray ``i`` enters the boxes of the
    instances ``instance[offsets[i]:offsets[i + 1]]`` at ``entry[...]``, nearest first;
    ``top`` is ``(node_box, node_first, node_count, prim_order)``."""
    n = len(origins)
    offsets = np.zeros(n + 1, dtype=np.int64)
    nodes_visited = np.zeros(n, dtype=np.int64)
    empty_i, empty_f = np.zeros(0, np.int64), np.zeros(0)
    with lent_rows(_walk_stack, numba.config.NUMBA_NUM_THREADS, max_depth) as (stack,):
        _walk(*top, origins, directions, t_min, t_max, stack, offsets, False, empty_i, empty_f, nodes_visited)
        np.cumsum(offsets, out=offsets)
        instance = np.empty(offsets[-1], dtype=np.int64)
        entry = np.empty(offsets[-1])
        _walk(*top, origins, directions, t_min, t_max, stack, offsets, True, instance, entry, nodes_visited)
    return offsets, instance, entry, nodes_visited


@kernel
def object_rays(inverse, instance, ray, origins, directions):
    """Rays ``ray[k]`` moved into the frame of instance ``instance[k]`` by its inverse
    transform ``inverse[instance[k]]`` (4, 4): origins and directions (m, 3). Serial: it is
    memory-bound and cheap, and a parallel launch costs more than it when the cores are busy."""
    m = ray.shape[0]
    out_o = np.empty((m, 3))
    out_d = np.empty((m, 3))
    for k in range(m):
        g = instance[k]
        r = ray[k]
        for row in range(3):
            out_o[k, row] = (inverse[g, row, 0] * origins[r, 0] + inverse[g, row, 1] * origins[r, 1]
                             + inverse[g, row, 2] * origins[r, 2] + inverse[g, row, 3])
            out_d[k, row] = (inverse[g, row, 0] * directions[r, 0] + inverse[g, row, 1] * directions[r, 1]
                             + inverse[g, row, 2] * directions[r, 2])
    return out_o, out_d


@kernel
def merge_hits(ray, t, prim, u, v, instance, best_t, best_prim, best_u, best_v, best_geom, limit):
    """Fold the hits of (ray, instance) pairs into each ray's best: the closest, equal distances
    to the lower instance id, then the lower primitive. ``limit`` (the interval's end for
    later pairs) drops to each new best distance."""
    for k in range(ray.shape[0]):
        if prim[k] < 0:
            continue
        r = ray[k]
        g = instance[k]
        better = best_prim[r] < 0 or t[k] < best_t[r] or (
            t[k] == best_t[r] and (g < best_geom[r] or (g == best_geom[r] and prim[k] < best_prim[r])))
        if better:
            best_t[r] = t[k]
            best_prim[r] = prim[k]
            best_u[r] = u[k]
            best_v[r] = v[k]
            best_geom[r] = g
            limit[r] = t[k]
