"""The kd-tree walk with several rays in flight per thread.

A ray's step through a kd-tree is short (one plane distance and a choice of
child), but the next step needs the child's record, whose address comes from
the step before: one ray keeps one load in flight at a time and waits for it.
This walk keeps ``slots`` rays per thread and takes one step of each in turn,
as :mod:`rayaccel.structures.bvh.traverse_interleaved` does for the BVH
(asynchronous memory access chaining; Kocberber, Falsafi & Grot, PVLDB 9(4),
2015): a step prefetches the record of the node it chooses, so by the ray's
next turn the other rays' steps have given the load time to arrive. The plane
crossings, the stack and the leaf visits are those of :mod:`.traverse`, so
every ray gets the same answer and the same counters.

Measured against :mod:`.traverse` (``interleave=False``), incoherent rays,
medians of 5-15 interleaved rounds, closest / any hit:

* full dragon (52 MB of records and float32 rows), 2**18 rays sorted: one core
  (CPU time) 1.44 / 1.26, 1.18 / 1.19 and 1.05 / 1.13 in three runs, two
  (wall time) 1.09 / 1.11 and 1.06 / 1.04; 2**20 rays as given, two cores,
  1.33 / 1.28 (which is how this walk takes them: see
  :attr:`.accelerator.KdTree._walk_gains_from_sorting`);
* dragon-203k (11 MB) 1.22 / 1.28, the armadillo (5.7 MB) 1.22 / 1.17, one core;
* where the tree stays in the caches it gains nothing: the bunny (4.0 MB) 0.96
  / 1.00, forest-small-chair (2.4 MB) 0.87-0.99 in two runs. Hence the rule of
  the BVH's walk, :func:`rayaccel.ray_order.interleaving_pays`.

Twelve slots: on the full dragon's closest hit 4, 8 and 12 gave 1.22, 1.41 and
1.44 in one run, 16 gave 1.00 where 12 gave 1.05 in another. A variant that
prefetched a leaf's first primitive and tested the leaf at the ray's next turn
measured the same as testing it at once, within the noise (0.83-1.10 of it
over three runs). A leaf's triangles are tested one by one
(:func:`rayaccel.structures.actions.intersect_references`), not four edge tests at once as the
other walks do (:func:`.traverse.visit_references`): a leaf of the full dragon holds about four
references, which mostly straddle two groups of the lanes, so the lanes read twice the bytes,
and this walk waits on memory: with them, the dragon's incoherent rays ran at 0.95-1.00 of the
speed (one thread, 2**19 rays, 9 rounds alternating with the code before in one process, both
orders, 2026-12-02). A ray goes on within its turn for no more than one node:
stepping on while the next record lay in the same 64-byte line (68 % of the
children below a plane and 47 % above it, full dragon) traced 2.51 / 2.68
Mrays/s against 3.31 / 3.52 (two threads, 2**20 rays as given), level with one
ray at a time (2.49 / 2.74). The work counters are kept in the slots only when
a query asks for them: kept always, two threads ran at 0.92-0.94 / 0.92-0.99
of the speed in two runs, one thread at 1.01 / 1.03.

This walk enters empty leaves, which the other walks skip (see :mod:`.traverse`), and leaves them
out of the counters, so that the counters match theirs (``skip_empty`` None, the option of that name
off, counts them as those walks then do). Skipping them here, a turn that chooses one popping at
once, ran the full dragon's incoherent rays at 0.85-0.90 of the speed with the flags in the node's
word, and at 0.76-0.97 with them in a byte array of their own, prefetched with the record or not
(one thread, 2^19 rays, 2026-12-04): fewer turns a ray leave less time for the prefetches of the
other rays in flight to arrive, which is the likely reason, not measured.
"""

from __future__ import annotations

import numpy as np

from ..._jit import chunk_kernel, inline_kernel, prefetch, unsigned
from ...geometry.box import clip_to_box
from ...geometry.primitive import RAY_FLOATS, RAY_INTS, load_ray, ray_setup, store_ray
from ...rays import ray_limit, result_row
from ..actions import NEAREST, finish_walked_ray, intersect_references
from .layout import LEAF, leaf_first, node_plane, node_word
from .traverse import cross_split, plane_steps, pop_unsettled, visit_apart

__all__ = ["SLOTS", "SLOT_INTS", "SLOT_FLOATS", "interleaved_closest_kernel"]

SLOTS = 12
"""Rays in flight per thread."""

_RAY, _NODE, _SP, _PRIM, _NODES, _TESTS, _LEAVES = range(RAY_INTS, RAY_INTS + 7)
SLOT_INTS = RAY_INTS + 7
"""Integers of a ray's state: the ray's shear axes, its index (-1: the slot is free), its node,
stack size, best primitive and work counters."""
_INV, _EXIT_STEP, _ENTRY_STEP = RAY_FLOATS, RAY_FLOATS + 3, RAY_FLOATS + 6
_T0, _T1, _BEST_T, _BEST_U, _BEST_V = range(RAY_FLOATS + 9, RAY_FLOATS + 14)
SLOT_FLOATS = RAY_FLOATS + 14
"""Floats of a ray's state: its constants of ``ray_setup`` (the origin first), reciprocal
direction and plane steps (as :data:`.traverse.RAY_ROW`), the interval of its node's cell and its
best hit."""


@inline_kernel
def _take_ray(slot, next_ray, ray_end, ints, floats, tid, lo, hi, leaf_prims, apart_first, apart_box, kind, geom,
              origins, directions, t_min, t_max, hit_slot, any_hit, mailbox, ray_id_base, action, work):
    """Put the next ray of the chunk that the primitives kept apart leave unsettled and that meets
    the root cell into free ``slot``, at the root (:func:`.traverse.visit_apart`), finishing the
    rays before it; returns the index after it. The slot stays free (ray -1) when the chunk has no
    ray left."""
    while next_ray < ray_end:
        i = next_ray
        next_ray += 1
        ox, oy, oz = origins[i, 0], origins[i, 1], origins[i, 2]
        dx, dy, dz = directions[i, 0], directions[i, 1], directions[i, 2]
        row = result_row(hit_slot, i)
        ray_t_min = ray_limit(t_min, i)
        best_t, best_prim, best_u, best_v, tests = visit_apart(
            NEAREST, action, row, apart_first, apart_box, leaf_prims, mailbox, tid, ray_id_base + i, kind, geom, ox, oy,
            oz, dx, dy, dz, ray_t_min, ray_limit(t_max, i), any_hit)
        t0, t1 = clip_to_box(lo, hi, ox, oy, oz, dx, dy, dz, ray_t_min, best_t)
        if t0 > t1 or (any_hit and best_prim >= 0):
            finish_walked_ray(NEAREST, action, work, row, best_t, best_prim, best_u, best_v, 0, tests, 0)
            continue
        store_ray(ray_setup(ox, oy, oz, dx, dy, dz), floats, ints, slot)
        for axis in range(3):
            inv_a = 1.0 / directions[i, axis]
            floats[slot, _INV + axis] = inv_a
            floats[slot, _EXIT_STEP + axis], floats[slot, _ENTRY_STEP + axis] = plane_steps(inv_a)
        floats[slot, _T0] = t0
        floats[slot, _T1] = t1
        floats[slot, _BEST_T] = best_t
        floats[slot, _BEST_U] = best_u
        floats[slot, _BEST_V] = best_v
        ints[slot, _RAY] = i
        ints[slot, _NODE] = 0
        ints[slot, _SP] = 0
        ints[slot, _PRIM] = best_prim
        ints[slot, _NODES] = 0
        ints[slot, _TESTS] = tests
        ints[slot, _LEAVES] = 0
        break
    return next_ray


@chunk_kernel
def interleaved_closest_kernel(ray_first, ray_end, tid, lo, hi, node_planes, node_links, skip_empty, leaf_prims,
                               apart_first, apart_box, kind, geom, origins, directions, t_min, t_max, hit_slot, any_hit,
                               mailbox, ray_id_base, stack_node, stack_t, slots, slot_ints, slot_floats, action, work):
    """Trace rays ``ray_first`` to ``ray_end - 1`` for the closest or any hit (an action of mode
    ``NEAREST``), ``slots`` at a time, their states in row ``tid`` of ``slot_ints`` (threads,
    slots, :data:`SLOT_INTS`) and ``slot_floats`` (threads, slots, :data:`SLOT_FLOATS`) and their
    stacks in rows ``tid * slots`` to ``tid * slots + slots - 1`` of ``stack_node`` and
    ``stack_t``. The other arguments, and the counters, are those of
    :func:`.traverse.walk_singly`. Only these queries: the counting and collecting actions stamp
    each primitive a ray meets in the thread's mailbox row, which the rays in flight would share
    (``mailbox`` is ``None`` here)."""
    ints = slot_ints[tid]
    floats = slot_floats[tid]
    count_work = work is not None
    next_ray = ray_first
    for slot in range(slots):
        ints[slot, _RAY] = -1
    in_flight = True
    while in_flight:
        in_flight = False
        for slot in range(slots):
            i = ints[slot, _RAY]
            if i < 0:
                if next_ray == ray_end:
                    continue
                next_ray = _take_ray(slot, next_ray, ray_end, ints, floats, tid, lo, hi, leaf_prims, apart_first,
                                     apart_box, kind, geom, origins, directions, t_min, t_max, hit_slot, any_hit,
                                     mailbox, ray_id_base, action, work)
                i = ints[slot, _RAY]
                if i < 0:
                    continue
            in_flight = True
            stack = unsigned(tid * slots + slot)
            node = ints[slot, _NODE]
            sp = ints[slot, _SP]
            word = node_word(node_links, node)
            axis = word & 3
            if axis != LEAF:
                if count_work:
                    ints[slot, _NODES] += 1
                node, t1, pushed, push_t0, push_t1 = cross_split(
                    node_plane(node_planes, node), word, floats[slot, axis], floats[slot, _INV + axis],
                    floats[slot, _EXIT_STEP + axis], floats[slot, _ENTRY_STEP + axis], floats[slot, _T0],
                    floats[slot, _T1])
                prefetch(node_links, 2 * node, 0)
                top = unsigned(sp)
                stack_node[stack, top] = pushed
                stack_t[stack, top, 0] = push_t0
                stack_t[stack, top, 1] = push_t1
                ints[slot, _SP] = sp + np.int64(pushed >= 0)
                ints[slot, _NODE] = node
                floats[slot, _T1] = t1
                continue
            first = leaf_first(node_links, node)
            if count_work and (word >> 2 != 0 or skip_empty is None):
                ints[slot, _NODES] += 1
                ints[slot, _LEAVES] += 1
            best_t, best_prim, best_u, best_v, tests, _ = intersect_references(
                NEAREST, action, result_row(hit_slot, i), first, first + (word >> 2), leaf_prims, mailbox, tid,
                ray_id_base + i, kind, geom, True, load_ray(floats, ints, slot), ray_limit(t_min, i),
                floats[slot, _BEST_T], ints[slot, _PRIM], floats[slot, _BEST_U], floats[slot, _BEST_V], 0, 0,
                any_hit)
            if count_work:
                ints[slot, _TESTS] += tests
            floats[slot, _BEST_T] = best_t
            ints[slot, _PRIM] = best_prim
            floats[slot, _BEST_U] = best_u
            floats[slot, _BEST_V] = best_v
            node = -1
            if not (any_hit and best_prim >= 0):
                node, t0, t1, sp = pop_unsettled(stack_node, stack_t, stack, sp, best_prim, best_t, 0.0, 0.0)
            if node >= 0:
                prefetch(node_links, 2 * node, 0)
                ints[slot, _NODE] = node
                ints[slot, _SP] = sp
                floats[slot, _T0] = t0
                floats[slot, _T1] = t1
                continue
            finish_walked_ray(NEAREST, action, work, result_row(hit_slot, i), best_t, best_prim, best_u, best_v,
                              ints[slot, _NODES], ints[slot, _TESTS], ints[slot, _LEAVES])
            ints[slot, _RAY] = -1

