"""The eight-wide BVH walk with several rays in flight per thread, for incoherent rays
through a tree larger than the caches.

An incoherent ray through a large tree spends most of its time waiting for
nodes from memory: each node's address comes from the node before it, so one
ray has one load in flight at a time however early its children are
prefetched (:mod:`.traverse_wide`). This walk keeps ``slots`` rays per thread
and takes one step of each in turn, a step being one stack entry (a node's
eight child boxes, or a leaf's primitives) up to the choice of the ray's next
entry, whose memory is prefetched when it is chosen, taken or pushed
(:func:`.traverse_wide.descend`); by the time the ray's
turn comes again, the other rays' steps have given the load time to arrive.
This is asynchronous memory access chaining (Kocberber, Falsafi & Grot,
"Asynchronous Memory Access Chaining", PVLDB 9(4), 2015), applied to the
stack traversal. Each ray's state (its constants of
:func:`rayaccel.geometry.primitive.ray_setup`, best hit, stack top, counters)
waits in a row of per-thread scratch between its steps, its stack in a stack
row of its own. The node test, the choice of the next entry and the leaf visits
are those of :mod:`.traverse_wide`, so every ray gets the same answer.

Measured against :mod:`.traverse_wide` (``interleave=False``), medians of seven
interleaved rounds, 2**20 incoherent rays, ``bvh-binned``, same answers; closest
hit / any hit / ``count``, one core (CPU time) and two (wall time), both walks
choosing their next entry by :func:`.traverse_wide.descend` (2026-11-28, Zen 3):

* full dragon (61 MB of records and triangles): 1.19 / 1.34 / 1.43 and 1.14 /
  1.25 / 1.29;
* dragon-203k (15 MB): 1.22 / 1.25 / 1.28 and 1.13 / 1.14 / 1.29.

Before ``descend`` (each entered child pushed and popped, earlier sessions): full
dragon 1.34 / 1.39 / 1.57 and 1.35 / 1.40 / 1.42, dragon-203k 1.08 / 1.19 / 1.20
and 1.05 / 1.19 / 1.19; armadillo (5 MB), one core: 0.96 / 1.02;
forest-small-chair (3 MB): 0.84 / 0.82. These two trees stayed in that host's
2 MiB second-level caches and the last level, where saving and restoring each ray's
state and the rays' taking turns only cost; shadow rays through them ran at
0.78-0.83.

Twelve slots: on two cores, closest hit on the full dragon took 200, 200,
225, 194 and 210 ms with 4, 6, 8, 12 and 16 slots (8 was the slowest in
each of three queries and two runs); one core gained little beyond six.
Shadow rays from a camera's hits, whose neighbours start close together and
share their nodes, are not interleaved: on the full dragon they ran at
1.02-1.03 of the single walk on one core and 0.96-0.97 on two, on dragon-203k
at 0.94-0.95 (eight slots).
Hence :func:`rayaccel.ray_order.interleaving_pays`.
"""

from __future__ import annotations

import numpy as np

from ..._jit import chunk_kernel, inline_kernel, unsigned
from ..._validate import unusable_rays
from ...geometry.primitive import RAY_FLOATS, RAY_INTS, load_ray, ray_setup, store_ray
from ...rays import ray_at, ray_limit, result_row
from ..actions import COUNT, NEAREST, finish_misses_in_mode, finish_walked_ray
from .traverse_wide import descend, visit_leaf
from .wide_slab import SLAB_FLOATS, box_reach, enter_children, slab_limits, slab_ray

__all__ = ["SLOTS", "SLOT_INTS", "SLOT_FLOATS", "interleaved_nearest_kernel", "interleaved_count_kernel",
           "interleaved_crossings_kernel"]

SLOTS = 12
"""Rays in flight per thread."""

_RAY, _LINK, _COUNT, _SP, _PRIM, _NEAR_X, _NEAR_Y, _NEAR_Z, _NODES, _TESTS, _LEAVES = range(RAY_INTS, RAY_INTS + 11)
SLOT_INTS = RAY_INTS + 11
"""Integers of a ray's state: the ray's shear axes, its index (-1: the slot is free), its next
stack entry (link and primitive count: 0 for a node), stack size, best primitive, near faces
and work counters."""
_SLAB = RAY_FLOATS
_BEST_T, _BEST_U, _BEST_V, _ENTER_FROM, _EXIT_BY = range(_SLAB + SLAB_FLOATS, _SLAB + SLAB_FLOATS + 5)
SLOT_FLOATS = _EXIT_BY + 1
"""Floats of a ray's state: its constants of ``ray_setup`` and of the slab test, its best hit
and the slab test's bounds on its interval (float32 numbers kept as float64)."""


@inline_kernel
def _take_ray(slot, i, ints, floats, reach, origins, directions, t_min, t_max):
    """Put ray ``i`` into free ``slot``, at the root: its first step is the root's child test,
    which is where a ray that misses the whole tree ends (as in :mod:`.traverse_wide`, with no
    test of the tree's box before it)."""
    ox, oy, oz, dx, dy, dz = ray_at(origins, directions, i)
    ix, iy, iz = 1.0 / dx, 1.0 / dy, 1.0 / dz
    ray_t_max = ray_limit(t_max, i)
    store_ray(ray_setup(ox, oy, oz, dx, dy, dz), floats, ints, slot)
    ints[slot, _RAY] = i
    ints[slot, _LINK] = 0
    ints[slot, _COUNT] = 0
    ints[slot, _SP] = 0
    ints[slot, _PRIM] = -1
    ints[slot, _NEAR_X] = 0 if ix >= 0.0 else 3
    ints[slot, _NEAR_Y] = 1 if iy >= 0.0 else 4
    ints[slot, _NEAR_Z] = 2 if iz >= 0.0 else 5
    ints[slot, _NODES] = 0
    ints[slot, _TESTS] = 0
    ints[slot, _LEAVES] = 0
    slab = slab_ray(ox, oy, oz, dx, dy, dz, ix, iy, iz, reach[0], reach[1], reach[2])
    _keep_slab(slab, floats, slot)
    floats[slot, _BEST_T] = ray_t_max
    _keep_limits(floats, slot, slab, ray_limit(t_min, i), ray_t_max)
    floats[slot, _BEST_U] = 0.0
    floats[slot, _BEST_V] = 0.0


@inline_kernel
def _keep_slab(slab, floats, slot):
    """Keep the ray's :func:`.wide_slab.slab_ray` in row ``slot`` (:func:`_load_slab`)."""
    floats[slot, _SLAB], floats[slot, _SLAB + 1], floats[slot, _SLAB + 2] = slab[0], slab[1], slab[2]
    floats[slot, _SLAB + 3], floats[slot, _SLAB + 4], floats[slot, _SLAB + 5] = slab[3], slab[4], slab[5]
    floats[slot, _SLAB + 6], floats[slot, _SLAB + 7], floats[slot, _SLAB + 8] = slab[6], slab[7], slab[8]
    floats[slot, _SLAB + 9], floats[slot, _SLAB + 10] = slab[9], slab[10]


@inline_kernel
def _keep_limits(floats, slot, slab, t_min, t_max):
    """Keep the :func:`.wide_slab.slab_limits` of ``[t_min, t_max]`` for the ray of ``slab`` in
    row ``slot``, for the steps up to the ray's next leaf."""
    floats[slot, _ENTER_FROM], floats[slot, _EXIT_BY] = slab_limits(slab, t_min, t_max)


@inline_kernel
def _load_slab(floats, slot):
    """The :func:`.wide_slab.slab_ray` that :func:`_take_ray` kept in row ``slot``."""
    return (np.float32(floats[slot, _SLAB]), np.float32(floats[slot, _SLAB + 1]),
            np.float32(floats[slot, _SLAB + 2]), np.float32(floats[slot, _SLAB + 3]),
            np.float32(floats[slot, _SLAB + 4]), np.float32(floats[slot, _SLAB + 5]),
            np.float32(floats[slot, _SLAB + 6]), np.float32(floats[slot, _SLAB + 7]),
            np.float32(floats[slot, _SLAB + 8]), floats[slot, _SLAB + 9], floats[slot, _SLAB + 10])


@inline_kernel
def _walk(ray_first, ray_end, tid, root_box, records, links, prim_order, kind, geom, origins, directions, t_min,
          t_max, hit_slot, any_hit, stack_link, stack_count, stack_t, entry, slots, slot_ints, slot_floats, mode,
          action, work):
    """Trace rays ``ray_first`` to ``ray_end - 1``, ``slots`` at a time, in row ``tid`` of the
    per-thread scratch: ``entry`` (a node's child entry distances), ``slot_ints`` and
    ``slot_floats`` (each ray's state, ``slots`` rows) and rows ``tid * slots`` to
    ``tid * slots + slots - 1`` of the stacks. The other arguments are those of
    :mod:`.traverse_wide`'s walk, and so are the counters. A chunk holding a ray that
    :func:`rayaccel._validate.unusable_rays` counts is left unwalked, answered as misses;
    returns that count."""
    unusable = unusable_rays(origins, directions, ray_first, ray_end)
    if unusable:
        finish_misses_in_mode(mode, action, hit_slot, ray_first, ray_end)
        return unusable
    nearest_first = not any_hit and mode == NEAREST
    child_entry = entry[tid]
    ints = slot_ints[tid]
    floats = slot_floats[tid]
    reach = box_reach(root_box[0, :3], root_box[0, 3:6])
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
                _take_ray(slot, next_ray, ints, floats, reach, origins, directions, t_min, t_max)
                i = next_ray
                next_ray += 1
            in_flight = True
            stack = unsigned(tid * slots + slot)
            sp = ints[slot, _SP]
            link = ints[slot, _LINK]
            count = ints[slot, _COUNT]
            best_t = floats[slot, _BEST_T]
            ray_t_min = ray_limit(t_min, i)
            ray = load_ray(floats, ints, slot)
            ints[slot, _NODES] += 1
            next_count = -1
            if count == 0:
                entered = enter_children(records, link, ints[slot, _NEAR_X], ints[slot, _NEAR_Y],
                                         ints[slot, _NEAR_Z], _load_slab(floats, slot),
                                         np.float32(floats[slot, _ENTER_FROM]), np.float32(floats[slot, _EXIT_BY]),
                                         child_entry)
                if entered != 0:
                    link, next_count, sp = descend(records, links, geom, link, entered, child_entry,
                                                   floats[slot, _SLAB + 9], stack_link, stack_count, stack_t, stack,
                                                   sp, nearest_first, True)
            else:
                ints[slot, _LEAVES] += 1
                best_t, best_prim, best_u, best_v, tests = visit_leaf(mode, action, result_row(hit_slot, i), kind,
                                                                      geom, prim_order, link, count, ray, ray_t_min,
                                                                      best_t, ints[slot, _PRIM], floats[slot, _BEST_U],
                                                                      floats[slot, _BEST_V], any_hit)
                ints[slot, _TESTS] += tests
                floats[slot, _BEST_T] = best_t
                _keep_limits(floats, slot, _load_slab(floats, slot), ray_t_min, best_t)
                ints[slot, _PRIM] = best_prim
                floats[slot, _BEST_U] = best_u
                floats[slot, _BEST_V] = best_v
                if any_hit and best_prim >= 0:
                    sp = 0
            while next_count < 0 and sp > 0:
                sp -= 1
                top = unsigned(sp)
                if stack_t[stack, top] <= best_t:
                    link = stack_link[stack, top]
                    next_count = stack_count[stack, top]
            if next_count >= 0:
                ints[slot, _SP] = sp
                ints[slot, _LINK] = link
                ints[slot, _COUNT] = next_count
                continue
            finish_walked_ray(mode, action, work, result_row(hit_slot, i), best_t, ints[slot, _PRIM],
                              floats[slot, _BEST_U], floats[slot, _BEST_V], ints[slot, _NODES], ints[slot, _TESTS],
                              ints[slot, _LEAVES])
            ints[slot, _RAY] = -1
    return 0


@chunk_kernel
def interleaved_nearest_kernel(ray_first, ray_end, tid, root_box, records, links, prim_order, kind, geom, origins,
                               directions, t_min, t_max, hit_slot, any_hit, stack_link, stack_count, stack_t, entry,
                               slots, slot_ints, slot_floats, action, work):
    """The closest-hit and any-hit walk (an action of mode ``NEAREST``, the other modes' code
    pruned before it is compiled, as in :func:`.traverse_wide.wide_nearest_kernel`)."""
    return _walk(ray_first, ray_end, tid, root_box, records, links, prim_order, kind, geom, origins, directions,
                 t_min, t_max, hit_slot, any_hit, stack_link, stack_count, stack_t, entry, slots, slot_ints,
                 slot_floats, NEAREST, action, work)


@chunk_kernel
def interleaved_count_kernel(ray_first, ray_end, tid, root_box, records, links, prim_order, kind, geom, origins,
                             directions, t_min, t_max, hit_slot, any_hit, stack_link, stack_count, stack_t, entry,
                             slots, slot_ints, slot_floats, action, work):
    """The counting walk (an action of mode ``COUNT``), the other modes' code pruned: counting
    2**20 incoherent rays through the full dragon took 317 against 361 ms in
    :func:`interleaved_crossings_kernel` on two threads, 663 against 749 ms on one."""
    return _walk(ray_first, ray_end, tid, root_box, records, links, prim_order, kind, geom, origins, directions,
                 t_min, t_max, hit_slot, any_hit, stack_link, stack_count, stack_t, entry, slots, slot_ints,
                 slot_floats, COUNT, action, work)


@chunk_kernel
def interleaved_crossings_kernel(ray_first, ray_end, tid, root_box, records, links, prim_order, kind, geom, origins,
                                 directions, t_min, t_max, hit_slot, any_hit, stack_link, stack_count, stack_t, entry,
                                 slots, slot_ints, slot_floats, action, work):
    """The walk for the other actions (listing, winding), compiled at their first use."""
    return _walk(ray_first, ray_end, tid, root_box, records, links, prim_order, kind, geom, origins, directions,
                 t_min, t_max, hit_slot, any_hit, stack_link, stack_count, stack_t, entry, slots, slot_ints,
                 slot_floats, action.mode, action, work)

