"""Stack traversal of the eight-wide BVH (:mod:`.wide`), closest hit and any hit.

At a wide node the ray tests the eight child boxes at once
(:func:`.wide_slab.enter_children`, vector instructions), which gives the mask of
the children it enters before its best hit. The walk goes on with one of them
without a stack entry and pushes the others (:func:`descend`), as Embree's BVH8
traversal does: the only one; of two, in a closest-hit walk, the nearer; of three
or more, a closest-hit walk inserts each where it keeps the stack's top part
ordered by entry distance (an insertion sort of the few children entered, nearest
on top, as Embree sorts its hits), then pops the nearest. An any-hit walk,
which ends at whatever hit it finds first, takes them in the tree's order unsorted,
as Embree's any-hit traversal does, and so do the walks that count or list hits,
which prune nothing (or, keeping the nearest ``max_hits``, little; counting the
dragon's camera rays: -25 % CPU time). Measured as CPU time of one thread on the
four-wide layout against always sorting: skipping the sort for a single child gave
+5-13 % on the full dragon and +15-30 % on camera rays of the forest; the unsorted
any-hit walk +18 % (incoherent) to +96 % (camera rays) on the forest and -4 to -7 %
on the dragon. A leaf child is taken or pushed like an inner one and its primitives
tested when the walk reaches it, so a closest-hit walk meets primitives in
front-to-back order. Against pushing every entered child and popping the nearest
(2026-11-28, forest-small-chair, 2**17 incoherent rays, one thread, instructions
counted by cachegrind): 1,278-1,292 instructions a ray against 1,428-1,503 for
closest hit, 830 against 958 for any hit, 69 branches against 84 with 10.6
mispredicted against 9.4 (cachegrind's model of a predictor); the same hits. On
that shared host the clocks could not tell them apart (in-process A/B, closest
hit, 0.92-1.11).
Whatever is pushed is prefetched, so its memory arrives while the ray works on
nearer children (measured on the dragon's incoherent rays: +20-25 % against the
binary walk, where a four-wide layout alone gave +5-14 %). An entry popped beyond
the best hit found since it was pushed is skipped. A ray that enters none of the
root's children stops there, before the watertight triangle test's set-up
(:func:`rayaccel.geometry.primitive.ray_setup`); the root's own test is the only
test of the whole tree's box. The child boxes' test runs in float32 lanes and is
conservative (:mod:`.wide_slab`): it enters every child the exact test enters, at
an entry distance no greater, so that the walk's answers are the exact primitive
tests'.
"""

from __future__ import annotations

import numpy as np

from ..._jit import chunk_kernel, inline_kernel, unsigned
from ..._validate import unusable_ray
from ...geometry.gather import LANE_BITS, LANES, is_lanes, prefetch_prim
from ...geometry.primitive import ray_setup
from ...rays import ray_at, ray_limit, result_row
from ..actions import COUNT, NEAREST, finish_ray_in_mode, finish_walked_ray, intersect_references, visit_prim_in_mode
from .triangle_lanes import edges_admit
from .wide import child_count, child_link, prefetch_record
from .wide_slab import box_reach, enter_children, highest_bit, lowest_bit, slab_limits, slab_ray

__all__ = ["wide_nearest_kernel", "wide_count_kernel", "wide_crossings_kernel", "prefetch_entry", "push_child",
           "descend", "visit_leaf", "walk_tree"]


@inline_kernel
def prefetch_entry(records, geom, link, count):
    """Start loading what a walk reads first at the stack entry ``(link, count)``: the four
    cache lines of an inner child's record (``count`` 0), or a leaf's first primitive."""
    if count == 0:
        prefetch_record(records, link)
    else:
        prefetch_prim(geom, link)


@inline_kernel
def push_child(records, geom, stack_link, stack_count, stack_t, tid, base, sp, t, link, count, word, nearest_first):
    """Push a child entered at ``t`` on the stack, whose entries from ``base`` on are this node's
    children, below those nearer than it when ``nearest_first``; ``word`` goes into ``stack_count``
    (the child's primitive count, which a packet walk extends by its lanes); prefetch what
    popping it will read (:func:`prefetch_entry`)."""
    prefetch_entry(records, geom, link, count)
    row = unsigned(tid)
    slot = sp
    if nearest_first:
        while slot > base and stack_t[row, unsigned(slot - 1)] < t:
            above, below = unsigned(slot), unsigned(slot - 1)
            stack_link[row, above] = stack_link[row, below]
            stack_count[row, above] = stack_count[row, below]
            stack_t[row, above] = stack_t[row, below]
            slot -= 1
    stack_link[row, unsigned(slot)] = link
    stack_count[row, unsigned(slot)] = word
    stack_t[row, unsigned(slot)] = t
    return sp + 1


@inline_kernel
def _ray_distance(child_entry, c, entry_scale):
    """Child ``c``'s entry distance along the ray, from the float32 one of ``child_entry``."""
    return np.float64(child_entry[unsigned(c)]) * entry_scale


@inline_kernel
def descend(records, links, geom, node, entered, child_entry, entry_scale, stack_link, stack_count, stack_t, tid, sp,
            nearest_first, prefetch_next):
    """Choose the entry a walk goes on with among the children of wide ``node`` it enters (the
    bits of ``entered``, not 0; their float32 entry distances in ``child_entry``, which
    ``entry_scale`` turns into the ray's, :func:`.wide_slab.enter_children`) and push the others
    (:func:`push_child`), as Embree's BVH8 traversal does: the only child is taken with no
    stack entry; of two, a closest-hit walk (``nearest_first``) takes the nearer and pushes the
    other; of three or more it pushes all, sorted, and pops the nearest. A walk that does not
    sort pushes all but the child of lowest index and takes that one, in the order popping
    them all would have given. ``prefetch_next`` prefetches the entry taken
    (:func:`prefetch_entry`) for a walk that reads it a step later. Returns the entry
    ``(link, count)`` and the stack size.

    Scaling the float32 distances of the pushed children alone, instead of widening and
    scaling all eight at every node (same answers; one thread, 2**19 rays, 7-9 rounds
    alternating with the code before in one process, both orders, closest / any hit,
    2026-12-03): forest-small-chair incoherent 1.11-1.13 / 1.05-1.11 (1,219 -> 1,174
    instructions a ray counted, closest hit, 2**14 rays), camera 1.02-1.04 / 1.08-1.10,
    shadow 1.05 / 0.99-1.06; the full dragon's incoherent rays (interleaved walk) 1.03-1.04 /
    1.02-1.04, camera and shadow rays 0.98-1.06; the
    grid-BVH's cells on the forest: incoherent 1.07-1.15 / 0.94-1.14, camera 1.09 / 1.14-1.15,
    shadow 1.18 / 1.18-1.21."""
    c = highest_bit(entered)
    others = entered ^ (1 << c)
    if others != 0 and nearest_first:
        d = highest_bit(others)
        if others != 1 << d:
            base = sp
            while entered != 0:
                c = highest_bit(entered)
                entered ^= 1 << c
                count = child_count(links, node, c)
                sp = push_child(records, geom, stack_link, stack_count, stack_t, tid, base, sp,
                                _ray_distance(child_entry, c, entry_scale), child_link(links, node, c), count,
                                count, True)
            sp -= 1
            return stack_link[unsigned(tid), unsigned(sp)], stack_count[unsigned(tid), unsigned(sp)], sp
        near, far = (d, c) if child_entry[unsigned(d)] <= child_entry[unsigned(c)] else (c, d)
        c, others = far, 1 << near
    while others != 0:
        count = child_count(links, node, c)
        sp = push_child(records, geom, stack_link, stack_count, stack_t, tid, sp, sp,
                        _ray_distance(child_entry, c, entry_scale), child_link(links, node, c), count, count, False)
        c = highest_bit(others)
        others ^= 1 << c
    link = child_link(links, node, c)
    count = child_count(links, node, c)
    if prefetch_next:
        prefetch_entry(records, geom, link, count)
    return link, count, sp


@inline_kernel
def visit_leaf(mode, action, row, kind, geom, prim_order, first, count, ray, t_min, best_t, best_prim, best_u, best_v,
               any_hit):
    """Visit the ``count`` primitives of a leaf from row ``first`` of ``geom`` on with the action
    (:func:`..actions.visit_prim_in_mode`), stopping at the first hit of an any-hit walk:
    ``(best_t, best_prim, best_u, best_v, tests)``, the walk's best hit and the primitives tested.

    In the lanes layout of :mod:`rayaccel.geometry.gather` the leaf's triangles are taken a
    group at a time: the edge functions of the group's lanes in the leaf first
    (:func:`.triangle_lanes.edges_admit`), then the action on those admitted, in the leaf's
    order; the others every test of a triangle would reject. Both ways share one call of the
    action, so that the walk compiles one copy of the primitive tests (choosing between two
    copies by the layout's type, an overload, took the first compile from 15 to 29 s of CPU).
    Counted against float32 rows tested one by one (``benchmarks/profile_walk.py --count``, 2**14
    incoherent rays, one thread, closest hit): forest-small-chair rounded to float32 1,336 ->
    1,247 instructions a ray, dragon-203k 1,235 -> 1,154; the forest's closest and any hits the same
    on 2**18 incoherent rays."""
    by_groups = is_lanes(geom)
    _, _, _, _, _, _, kx, ky, kz, sx, sy, _, okx, oky, okz = ray
    end = first + count
    group = (first >> LANE_BITS) - 1
    admitted = 0
    k = first - 1
    tests = count
    while True:
        if by_groups:
            while admitted == 0 and LANES * (group + 1) < end:
                group += 1
                admitted = edges_admit(geom, group, kx, ky, kz, okx, oky, okz, sx, sy)
                admitted &= _lanes_within(first, end, group)
            if admitted == 0:
                break
            k = LANES * group + lowest_bit(admitted)
            admitted &= admitted - 1
        else:
            k += 1
            if k >= end:
                break
        best_t, best_prim, best_u, best_v, stop = visit_prim_in_mode(mode, action, row, kind, geom, k, prim_order,
                                                                     unsigned(k), ray, t_min, best_t, best_prim,
                                                                     best_u, best_v, any_hit)
        if stop:
            tests = k + 1 - first
            break
    return best_t, best_prim, best_u, best_v, tests


@inline_kernel
def _lanes_within(first, end, group):
    """The mask of the lanes of group ``group`` that hold rows ``first`` to ``end - 1``."""
    low = max(first - LANES * group, 0)
    high = min(end - LANES * group, LANES)
    return ((1 << high) - 1) & ~((1 << low) - 1)


@inline_kernel
def walk_tree(mode, action, row, records, links, prim_order, kind, geom, mailbox, tid, stamp, root, root_entered, slab,
              near_x, near_y, near_z, ray, t_min, span_lo, span_hi, best_t, best_prim, best_u, best_v, any_hit,
              stack_link, stack_count, stack_t, child_entry):
    """Walk one ray (from ``t_min`` on) through the wide tree rooted at ``root``, its stack in row
    ``tid``, entering boxes within ``[span_lo, min(best_t, span_hi)]`` and giving each primitive of
    a leaf it reaches the action: through :func:`..actions.intersect_references`, which skips
    those already stamped ``stamp`` in ``mailbox`` (when it is not empty), or, when ``mailbox`` is
    ``None``, through :func:`visit_leaf`, which has no mailbox test (taking the mailbox path
    without a mailbox cost the BVH's walk 0.82-0.98 of its speed). The mailbox's type chooses,
    before Numba types the walk, so that only one of the two is compiled: the BVH's own walks
    pass ``None`` (the first ``intersect`` on an empty cache took 8.5 s of CPU instead of 10.5,
    bunny, 2026-11-27), the grid-BVH's walks ``None`` or a mailbox (see :mod:`..hybrid.traverse`).
    ``slab`` and ``near_*`` as for :func:`.wide_slab.enter_children`, ``ray`` the
    primitive test's set-up, ``child_entry`` this thread's float32 row of children's entry
    distances.
    ``root_entered`` is 0, or the mask of the root's children the caller has already found the
    ray to enter (:func:`.wide_slab.enter_children`, their entry distances in ``child_entry``),
    with which the walk goes on at once. Returns the walk's ``(best_t, best_prim, best_u, best_v)``
    and its counters ``(nodes, leaves, tests, skips)``; a leaf counts as a node too."""
    nearest_first = not any_hit and mode == NEAREST
    stack_row = unsigned(tid)
    n_nodes = 0
    n_leaves = 0
    n_tests = 0
    n_skips = 0
    link = root
    count = 0
    sp = 0
    enter_from, exit_by = slab_limits(slab, span_lo, min(best_t, span_hi))
    entered = root_entered
    while True:
        n_nodes += 1
        if count == 0:
            if entered == 0:
                entered = enter_children(records, link, near_x, near_y, near_z, slab, enter_from, exit_by,
                                         child_entry)
            if entered != 0:
                link, count, sp = descend(records, links, geom, link, entered, child_entry, slab[9], stack_link,
                                          stack_count, stack_t, tid, sp, nearest_first, False)
                entered = 0
                continue
        else:
            n_leaves += 1
            if mailbox is None:
                best_t, best_prim, best_u, best_v, tests = visit_leaf(mode, action, row, kind, geom, prim_order, link,
                                                                      count, ray, t_min, best_t, best_prim, best_u,
                                                                      best_v, any_hit)
                n_tests += tests
            else:
                best_t, best_prim, best_u, best_v, n_tests, n_skips = intersect_references(
                    mode, action, row, link, link + count, prim_order, mailbox, tid, stamp, kind, geom, True, ray,
                    t_min, best_t, best_prim, best_u, best_v, n_tests, n_skips, any_hit)
            if any_hit and best_prim >= 0:
                break
            enter_from, exit_by = slab_limits(slab, span_lo, min(best_t, span_hi))
        while sp > 0 and stack_t[stack_row, unsigned(sp - 1)] > best_t:
            sp -= 1
        if sp == 0:
            break
        sp -= 1
        link = stack_link[stack_row, unsigned(sp)]
        count = stack_count[stack_row, unsigned(sp)]
    return best_t, best_prim, best_u, best_v, n_nodes, n_leaves, n_tests, n_skips


@inline_kernel
def _walk(ray_first, ray_end, tid, root_box, records, links, prim_order, kind, geom, origins, directions, t_min,
          t_max, hit_slot, any_hit, stack_link, stack_count, stack_t, entry, mode, action, work):
    """Trace rays ``ray_first`` to ``ray_end - 1`` through the wide BVH, keeping their stacks and the
    entry distances of a node's children in row ``tid`` (one chunk of
    :func:`rayaccel._jit.share_among_threads`); ``geom`` is in leaf order (``geom[prim_order]``),
    ``links`` is ``records`` seen as int32, and row 0 of ``root_box`` (a binary node record)
    the whole tree's box, which bounds the boxes' coordinates (:func:`.wide_slab.box_reach`).
    A ray that enters none of the root's children is answered as a miss before its triangle
    test's set-up; no test of the whole tree's box in float64 comes first (together with the
    select-based :func:`rayaccel.geometry.triangle.shear_setup`: forest-small-chair, 2**14
    incoherent rays, closest hit, one thread, 1,284 -> 1,249 instructions a ray counted on AVX2
    code). Each primitive of a leaf gets the leaf action (:mod:`..actions`). Counters:
    wide nodes and leaves visited (a leaf counts as a node too), primitive tests. A ray that
    :func:`rayaccel._validate.unusable_ray` refuses is left unwalked, answered as a miss;
    returns how many there were."""
    child_entry = entry[tid]
    reach_x, reach_y, reach_z = box_reach(root_box[0, :3], root_box[0, 3:6])
    unusable = 0
    for i in range(ray_first, ray_end):
        row = result_row(hit_slot, i)
        ray_t_min, ray_t_max = ray_limit(t_min, i), ray_limit(t_max, i)
        ox, oy, oz, dx, dy, dz = ray_at(origins, directions, i)
        if unusable_ray(ox, oy, oz, dx, dy, dz):
            unusable += 1
            finish_ray_in_mode(mode, action, row, ray_t_max, -1, 0.0, 0.0)
            continue
        ix, iy, iz = 1.0 / dx, 1.0 / dy, 1.0 / dz
        near_x = 0 if ix >= 0.0 else 3
        near_y = 1 if iy >= 0.0 else 4
        near_z = 2 if iz >= 0.0 else 5
        slab = slab_ray(ox, oy, oz, dx, dy, dz, ix, iy, iz, reach_x, reach_y, reach_z)
        enter_from, exit_by = slab_limits(slab, ray_t_min, ray_t_max)
        entered = enter_children(records, 0, near_x, near_y, near_z, slab, enter_from, exit_by, child_entry)
        if entered == 0:
            finish_walked_ray(mode, action, work, row, ray_t_max, -1, 0.0, 0.0, 1, 0, 0)
            continue
        ray = ray_setup(ox, oy, oz, dx, dy, dz)
        best_t, best_prim, best_u, best_v, n_nodes, n_leaves, n_tests, _ = walk_tree(
            mode, action, row, records, links, prim_order, kind, geom, None, tid, 0, 0, entered, slab, near_x,
            near_y, near_z, ray, ray_t_min, ray_t_min, np.inf, ray_t_max, -1, 0.0, 0.0, any_hit, stack_link,
            stack_count, stack_t, child_entry)
        finish_walked_ray(mode, action, work, row, best_t, best_prim, best_u, best_v, n_nodes, n_tests, n_leaves)
    return unusable


@chunk_kernel
def wide_nearest_kernel(ray_first, ray_end, tid, root_box, records, links, prim_order, kind, geom, origins,
                        directions, t_min, t_max, hit_slot, any_hit, stack_link, stack_count, stack_t, entry, action,
                        work):
    """The closest-hit and any-hit walk (an action of mode ``NEAREST``): the other modes' code is
    pruned away before it is compiled (:func:`..actions.visit_prim_in_mode`), so that a first
    ``intersect`` compiles none of it, nor the mailbox path (:func:`walk_tree`). Compile time
    on an empty cache, CPU: 5.4 s for this kernel, 9.8 s for :func:`wide_crossings_kernel`, the
    walk of every mode (older Numba, quieter host)."""
    return _walk(ray_first, ray_end, tid, root_box, records, links, prim_order, kind, geom, origins, directions,
                 t_min, t_max, hit_slot, any_hit, stack_link, stack_count, stack_t, entry, NEAREST, action, work)


@chunk_kernel
def wide_count_kernel(ray_first, ray_end, tid, root_box, records, links, prim_order, kind, geom, origins, directions,
                      t_min, t_max, hit_slot, any_hit, stack_link, stack_count, stack_t, entry, action, work):
    """The counting walk (an action of mode ``COUNT``), the other modes' code pruned (see
    :func:`.traverse_interleaved.interleaved_count_kernel` for what that gained)."""
    return _walk(ray_first, ray_end, tid, root_box, records, links, prim_order, kind, geom, origins, directions,
                 t_min, t_max, hit_slot, any_hit, stack_link, stack_count, stack_t, entry, COUNT, action, work)


@chunk_kernel
def wide_crossings_kernel(ray_first, ray_end, tid, root_box, records, links, prim_order, kind, geom, origins,
                          directions, t_min, t_max, hit_slot, any_hit, stack_link, stack_count, stack_t, entry, action,
                          work):
    """The walk for the other actions (listing, winding), compiled at their first use."""
    return _walk(ray_first, ray_end, tid, root_box, records, links, prim_order, kind, geom, origins, directions,
                 t_min, t_max, hit_slot, any_hit, stack_link, stack_count, stack_t, entry, action.mode, action, work)
