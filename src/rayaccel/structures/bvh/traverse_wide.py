"""Stack traversal of the four-wide BVH (:mod:`.wide`), closest hit and any hit.

At a wide node the ray tests the four child boxes at once
(:func:`.wide_slab.enter_children`, vector instructions) and counts the ones it
enters before its best hit. A single one is descended into directly. Of two or
more, a closest-hit walk orders them by entry distance (a five-comparator sorting
network on registers), pushes all but the nearest, farthest first, and descends into
the nearest; an any-hit walk, which ends at whatever hit it finds first, takes them
in the tree's order unsorted, as Embree's any-hit traversal does, and so do the walks
that count or list hits, which prune nothing (or, keeping the nearest ``max_hits``,
little; counting the dragon's camera rays: -25 % CPU time). Measured as CPU
time of one thread against always sorting: skipping the sort for a single child
gave +5-13 % on the full dragon and +15-30 % on camera rays of the forest; the
unsorted any-hit walk +18 % (incoherent) to +96 % (camera rays) on the forest and
-4 to -7 % on the dragon. Leaf children are pushed like inner ones (the nearest too)
and their primitives tested when popped, so a closest-hit walk meets primitives in
front-to-back order. Whatever is pushed is prefetched, so its memory arrives while
the ray works on nearer children (measured on the dragon's incoherent rays: +20-25 %
against the binary walk, where the wide layout alone gave +5-14 %). An entry popped
beyond the best hit found since it was pushed is skipped. A ray that misses the whole
tree's box stops there, before testing four boxes. The slab test computes exactly
what :func:`.traverse.enter_box` computes, with the same NaN-safe comparisons.
"""

from __future__ import annotations

import numpy as np

from ..._jit import chunk_kernel, inline_kernel, prefetch
from ...geometry.primitive import ray_setup
from ..actions import NEAREST, finish_ray, visit_prim
from .traverse import enter_box
from .wide_slab import enter_children

__all__ = ["wide_trace_kernel"]


@inline_kernel
def _in_order(ta, la, ca, tb, lb, cb):
    if tb < ta:
        return tb, lb, cb, ta, la, ca
    return ta, la, ca, tb, lb, cb


@inline_kernel
def _push(records, geom, stack_link, stack_count, stack_t, tid, sp, t, link, count):
    """Push a child the ray enters at ``t`` (none when ``t`` is inf) and prefetch what popping
    it will read: its record's two cache lines, or its first primitive."""
    if t == np.inf:
        return sp
    if count == 0:
        prefetch(records, link, 0)
        prefetch(records, link, 16)
    else:
        prefetch(geom, link, 0)
    stack_link[tid, sp] = link
    stack_count[tid, sp] = count
    stack_t[tid, sp] = t
    return sp + 1


@chunk_kernel
def wide_trace_kernel(ray_first, ray_end, tid, root_box, records, links, prim_order, kind, geom, origins, directions,
                      t_min, t_max, hit_slot, any_hit, stack_link, stack_count, stack_t, action, work):
    """Trace rays ``ray_first`` to ``ray_end - 1`` through the wide BVH, keeping their stacks in row
    ``tid`` (one chunk of :func:`rayaccel._jit.on_threads`); ``geom`` is in leaf order (``geom[prim_order]``),
    ``links`` is ``records`` seen as int32, and row 0 of ``root_box`` (a binary node record)
    the whole tree's box, which a ray must enter before the root's four children are
    tested. Each primitive of a leaf gets the leaf action (:mod:`..actions`). Counters:
    wide nodes and leaves visited (a leaf counts as a node too), primitive tests."""
    count_work = work.shape[0] > 0
    nearest_first = not any_hit and action.mode == NEAREST
    for i in range(ray_first, ray_end):
        ox, oy, oz = origins[i, 0], origins[i, 1], origins[i, 2]
        dx, dy, dz = directions[i, 0], directions[i, 1], directions[i, 2]
        ray = ray_setup(ox, oy, oz, dx, dy, dz)
        ix, iy, iz = 1.0 / dx, 1.0 / dy, 1.0 / dz
        origin = (ox, oy, oz)
        inv_dir = (ix, iy, iz)
        near_x = 0 if ix >= 0.0 else 3
        near_y = 1 if iy >= 0.0 else 4
        near_z = 2 if iz >= 0.0 else 5
        ray_t_min = t_min[i]
        best_t = t_max[i]
        best_prim = -1
        best_u = 0.0
        best_v = 0.0
        n_nodes = 0
        n_tests = 0
        n_leaves = 0
        node = 0
        sp = 0
        if enter_box(root_box, 0, ox, oy, oz, ix, iy, iz, near_x, near_y, near_z, ray_t_min, best_t) == np.inf:
            node = -1
        while node >= 0:
            n_nodes += 1
            t0, t1, t2, t3 = enter_children(records, node, near_x, near_y, near_z, origin, inv_dir, ray_t_min, best_t)
            l0, l1, l2, l3 = links[node, 24], links[node, 25], links[node, 26], links[node, 27]
            c0, c1, c2, c3 = links[node, 28], links[node, 29], links[node, 30], links[node, 31]
            entered = (t0 != np.inf) + (t1 != np.inf) + (t2 != np.inf) + (t3 != np.inf)
            if entered > 0 and t0 == np.inf:
                if t1 != np.inf:
                    t0, l0, c0, t1, l1, c1 = t1, l1, c1, t0, l0, c0
                elif t2 != np.inf:
                    t0, l0, c0, t2, l2, c2 = t2, l2, c2, t0, l0, c0
                else:
                    t0, l0, c0, t3, l3, c3 = t3, l3, c3, t0, l0, c0
            if entered > 1:
                if nearest_first:
                    t0, l0, c0, t1, l1, c1 = _in_order(t0, l0, c0, t1, l1, c1)
                    t2, l2, c2, t3, l3, c3 = _in_order(t2, l2, c2, t3, l3, c3)
                    t0, l0, c0, t2, l2, c2 = _in_order(t0, l0, c0, t2, l2, c2)
                    t1, l1, c1, t3, l3, c3 = _in_order(t1, l1, c1, t3, l3, c3)
                    t1, l1, c1, t2, l2, c2 = _in_order(t1, l1, c1, t2, l2, c2)
                sp = _push(records, geom, stack_link, stack_count, stack_t, tid, sp, t3, l3, c3)
                sp = _push(records, geom, stack_link, stack_count, stack_t, tid, sp, t2, l2, c2)
                sp = _push(records, geom, stack_link, stack_count, stack_t, tid, sp, t1, l1, c1)
            node = -1
            if entered > 0:
                if c0 == 0:
                    node = l0
                else:
                    sp = _push(records, geom, stack_link, stack_count, stack_t, tid, sp, t0, l0, c0)
            while node < 0 and sp > 0:
                sp -= 1
                if stack_t[tid, sp] > best_t:
                    continue
                count = stack_count[tid, sp]
                if count == 0:
                    node = stack_link[tid, sp]
                    break
                n_nodes += 1
                n_leaves += 1
                first = stack_link[tid, sp]
                for k in range(first, first + count):
                    n_tests += 1
                    best_t, best_prim, best_u, best_v, stop = visit_prim(action, hit_slot[i], kind, geom, k,
                                                                         prim_order[k], ray, ray_t_min, best_t,
                                                                         best_prim, best_u, best_v, any_hit)
                    if stop:
                        break
                if any_hit and best_prim >= 0:
                    sp = 0
        finish_ray(action, hit_slot[i], best_t, best_prim, best_u, best_v)
        if count_work:
            work[hit_slot[i], 0] = n_nodes
            work[hit_slot[i], 1] = n_tests
            work[hit_slot[i], 3] = n_leaves
