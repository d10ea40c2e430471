"""Front-to-back stack traversal of the kd-tree, closest hit and any hit.

The classic recursive ray traversal (Jansen 1986; Havran's thesis, 2000, calls
it TA_B^rec; pbrt's ``KdTreeAggregate::Intersect`` is one), made iterative:
the ray carries its parametric interval ``[t0, t1]`` inside the current cell.
At an inner node the plane distance ``t_plane`` cuts that interval; the child
the ray meets first is the one on the side its direction comes from. Only the
near child is visited when the plane lies beyond ``t1``, only the far one when
it lies before ``t0``, and otherwise the near one with ``[t0, t_plane]`` while
the far one waits on the stack with ``[t_plane, t1]``.

A hit found in a leaf may lie beyond the leaf's cell (the primitive reaches
into later cells); it is kept as the best candidate, and a cell taken from the
stack is skipped once the candidate lies before its entry
(:func:`settled_before`). A ray lying in a split plane (direction component
0, origin on the plane) visits both children over the same interval, since
primitives in the plane sit on one side only; so the walk does not simply stop
at the first leaf whose exit lies beyond the best hit, it lets the stack run
out, which costs one comparison per pending cell.
Stacks are preallocated per thread, as deep as the tree; a step writes the far
child to the stack whether it is pushed or not and moves the stack pointer by
0 or 1. A node is one 8-byte record (:mod:`.layout`), a sibling pair 16 bytes,
and a leaf's primitives are read from a copy of the geometry in reference order
(``geom`` row ``k`` is primitive ``leaf_prims[k]``), next to each other.

An inner step reads both children's records (plane and word) as soon as it has its own word, before
its plane crossing, and takes the next node's from the two by the crossing's choice: the next step
starts from numbers already loaded, not from a load that waited for the choice. Against reading the
chosen child's record after the choice (forest-small-chair, one thread, 2^19 incoherent rays, medians
of 7, processes alternating, five pairs, 2026-12-06, Zen 4): closest hit 1.03-1.05, any hit
1.03-1.06; camera rays and their shadow rays 0.98-1.02. Reading the ray's origin, reciprocal and
steps on both children's axes too, so that no load waits on the choice at all, ran at 0.96-0.97 of
this walk's closest hit and 0.97-1.01 of its any hit; computing both children's crossings before
the choice, 1.00-1.03 and 1.01-1.03 (README, "Tried and dropped"): not kept.

A child that is an empty leaf is neither entered nor pushed: a node's word says which of its two
children are empty leaves (:func:`.layout.empty_flags`), so that the walk goes on with the other
child or pops at once without reading the empty one's record (:func:`is_empty_child`;
``skip_empty`` None, without the option of that name, enters them and leaves the test out of the
compiled walk). A forest-small-chair incoherent ray met 2.04 empty leaves of its 3.61:
skipping them ran the forest's incoherent rays 1.03-1.04 times as fast, camera rays 0.98-1.01,
shadow rays 1.01-1.07, the full dragon's shadow rays 1.08-1.11 (one thread, medians of 7, processes
alternating with the code before, 2026-12-04). The rays-in-flight walk enters them (see
:mod:`.traverse_interleaved`).

The references from ``apart_first`` to the end of ``leaf_prims`` are the primitives the tree was
built without (the scene's few large ones, see the ``large_apart`` option of
:class:`.accelerator.KdTree`): a leaf that every ray visits before the root, whose hit bounds the
ray's interval in the tree, or settles an any-hit ray before it enters (:func:`visit_apart`); a
ray that misses their box, ``apart_box`` (2, 3: lo, hi), skips them. Without such primitives
``apart_box`` is ``None``, which leaves their code out of the compiled walk (full dragon, one thread,
3 runs of processes alternating with the code before: 0.96-1.08 of its speed; with the code kept in
behind a test of an empty range, 0.96-1.01).
"""

from __future__ import annotations

import numpy as np

from ..._jit import chunk_kernel, inline_kernel, unsigned
from ...geometry.box import clip_to_box
from ...geometry.primitive import ray_setup
from ...rays import ray_limit, result_row
from ..actions import NEAREST, finish_walked_ray, intersect_references
from ..base import EXIT_MARGIN, settled_before
from ..bvh.traverse_wide import visit_leaf
from .layout import LEAF, PLANE_FLOOR, PLANE_STEP, empty_flags, leaf_first, node_child, node_record

__all__ = ["RAY_ROW", "kdtree_closest_kernel", "kdtree_crossings_kernel", "walk_singly", "plane_steps", "cross_split",
           "empty_children_of", "is_empty_child", "skips_empty", "pop_unsettled", "visit_references", "visit_apart"]

RAY_ROW = 9
"""Width of a walk's per-thread ``inv_dir`` row: the ray's reciprocal direction, then its exit and
entry steps (:func:`plane_steps`)."""


@inline_kernel
def _margin(t):
    return EXIT_MARGIN * abs(t)


@inline_kernel
def plane_steps(inv_a):
    """``(exit_step, entry_step)`` of a ray whose reciprocal direction on an axis is ``inv_a``, as
    :func:`cross_split` reads them: ``PLANE_STEP |inv_a|`` for the face of a plane's bracket where
    the ray leaves it (the top when ``inv_a`` is positive), 0 for the other face, so that the
    step adds the bracket's width to the one face without choosing by the direction's sign."""
    step = PLANE_STEP * inv_a
    return max(step, 0.0), max(-step, 0.0)


@inline_kernel
def cross_split(plane, word, oa, inv_a, exit_step_a, entry_step_a, t0, t1):
    """One step at an inner node (its float32 ``plane`` and its record's second word ``word``) of
    a ray with origin ``oa``, reciprocal direction ``inv_a`` and steps :func:`plane_steps` on the
    node's axis, inside ``[t0, t1]``: ``(next, t1, pushed, push_t0, push_t1)``, the child to visit
    next with the end of its interval (its start stays ``t0``), and the child to push with its
    interval, ``pushed = -1`` when none.

    The plane is known to lie in a bracket a float32 step wide (:func:`.layout.plane_bracket`),
    which the ray crosses from ``t_plane``, where it meets the bracket's bottom, over
    ``(|plane| + PLANE_FLOOR) PLANE_STEP |inv_a|``: the ray leaves the near child where it leaves
    the bracket and enters the far one where it enters it. The near child is the one on the side
    the direction comes from. A ray parallel to the plane whose crossing comes out not a number
    (``0 * inf`` or ``inf - inf``) visits both children over its whole interval. Which of near,
    far or both a ray meets is a coin toss to the branch predictor, so the choice is made with
    selects: against the same step written with branches, forest incoherent rays 1.22 / 1.24
    times as fast (closest / any hit), the dragon's 1.04 / 1.07, camera and shadow rays 0.97-0.99
    (one thread, medians of 5-7 interleaved rounds). Not every select stayed one: a float chosen
    by the direction's sign (``t_plane`` or ``t_plane + width``), and one chosen on a condition
    of two comparisons (the near child's end on ``both``), LLVM compiled to branches on AVX2,
    which Valgrind's simulated predictor missed 6.2 and 3.8 times in the 18.9 steps a forest
    incoherent ray takes. So the bracket's width goes to its faces by the ray's steps
    (:func:`plane_steps`), and the near child's end is chosen on ``visit_near`` alone, which gives
    the same number, since a ray that reaches the near child but not the far one leaves the
    bracket after ``t1``: mispredicted branches 25.5 -> 15.0 a ray (AVX2 code, simulated), and
    forest incoherent rays 1.04-1.07 times as fast on AVX2 and on AVX-512 code, the full dragon's
    (interleaved walk) 1.00-1.07, camera and shadow rays (packets) 0.95-1.01 (one thread, 2**19
    rays, 9-11 rounds alternating with the code before in one process, both orders)."""
    plane = np.float64(plane)
    below = node_child(word)
    t_plane = (plane - oa) * inv_a
    bracket = abs(plane) + PLANE_FLOOR
    t_exit = t_plane + bracket * exit_step_a
    t_entry = t_plane - bracket * entry_step_a
    near = below + np.int64(not inv_a > 0.0)
    far = 2 * below + 1 - near
    if t_exit != t_exit or t_entry != t_entry:
        return near, t1, far, t0, t1
    visit_near = not (t_exit < t0 - _margin(t0))
    both = visit_near & (not (t_entry > t1 + _margin(t1)))
    exit_clamped = min(max(t_exit, t0), t1)
    entry_clamped = min(max(t_entry, t0), t1)
    return (far + (near - far) * np.int64(visit_near), exit_clamped if visit_near else t1,
            far if both else -1, entry_clamped, t1)


@inline_kernel
def empty_children_of(skip_empty, word):
    """The flags of empty children in an inner node's ``word`` (:func:`.layout.empty_flags`), 0 when
    the walk enters empty leaves (``skip_empty`` None, which leaves the test out of the code)."""
    if skip_empty is None:
        return 0
    return empty_flags(word)


@inline_kernel
def is_empty_child(empty, below, child):
    """Whether ``child`` (``below`` or ``below + 1``) of a node whose flags of empty children are
    ``empty`` (:func:`empty_children_of`) is an empty leaf. The shift is masked to the pair, so that
    ``child`` -1 (no child pushed) reads one of the two flags rather than shifting by a negative
    count; :func:`skips_empty` tests for it first."""
    return (empty >> ((child - below) & 1)) & 1 != 0


@inline_kernel
def skips_empty(empty, below, pushed):
    """1 when ``pushed`` is a child to keep on the stack, 0 when it is none (-1) or an empty leaf."""
    return np.int64(pushed >= 0) * np.int64(not is_empty_child(empty, below, pushed))


@inline_kernel
def pop_unsettled(stack_node, stack_t, row, sp, best_prim, best_t, t0, t1):
    """The next cell to visit from the stack of ``row`` (``sp`` entries), skipping those that start
    after the best hit: ``(node, t0, t1, sp)``, ``node = -1`` when none is left. Once the best hit
    lies before a leaf's exit, every cell pushed by a plane crossing starts after it; only a cell
    pushed for a ray lying in a split plane (same interval as its sibling) can still be entered."""
    while sp > 0:
        sp -= 1
        if best_prim < 0 or not settled_before(best_prim, best_t, stack_t[row, sp, 0]):
            return stack_node[row, sp], stack_t[row, sp, 0], stack_t[row, sp, 1], sp
    return -1, t0, t1, sp


@inline_kernel
def visit_references(mode, action, row, first, end, leaf_prims, mailbox, tid, stamp, kind, geom, ray, t_min, best_t,
                     best_prim, best_u, best_v, any_hit):
    """Visit a leaf's references ``first`` to ``end - 1`` with the action: ``(best_t, best_prim,
    best_u, best_v, tests)``. With a mailbox, through :func:`..actions.intersect_references`,
    which skips the primitives the ray met in an earlier leaf; with ``None`` (the closest and
    any hit, which need none), through the BVH's :func:`..bvh.traverse_wide.visit_leaf`, which
    tests the edges of four triangles of the float32 lanes at once before any triangle in full.
    The mailbox's type chooses before Numba types the walk, so that only one is compiled.
    Against testing every reference in full (one thread, 2**19 rays, 9 rounds alternating with
    the code before in one process, both orders, closest / any hit, 2026-12-02):
    forest-small-chair incoherent rays (this walk) 1.12-1.13 / 1.10-1.13, camera rays (packets)
    1.20 / 1.16, shadow rays 1.21 / 1.21-1.24; the full dragon's camera rays 1.21-1.23 /
    1.17, shadow rays 1.24-1.27 / 1.24-1.30; the same answers."""
    if mailbox is None:
        return visit_leaf(mode, action, row, kind, geom, leaf_prims, first, end - first, ray, t_min, best_t,
                          best_prim, best_u, best_v, any_hit)
    best_t, best_prim, best_u, best_v, tests, _ = intersect_references(
        mode, action, row, first, end, leaf_prims, mailbox, tid, stamp, kind, geom, True, ray, t_min, best_t,
        best_prim, best_u, best_v, 0, 0, any_hit)
    return best_t, best_prim, best_u, best_v, tests


@inline_kernel
def meets_apart(apart_box, ox, oy, oz, dx, dy, dz, t_min, t_max):
    """Whether the ray meets the box of the primitives kept apart from the tree within ``[t_min,
    t_max]`` (false when there are none, ``apart_box`` None)."""
    if apart_box is None:
        return False
    t0, t1 = clip_to_box(apart_box[0], apart_box[1], ox, oy, oz, dx, dy, dz, t_min, t_max)
    return t0 <= t1


@inline_kernel
def visit_apart(mode, action, row, apart_first, apart_box, leaf_prims, mailbox, tid, stamp, kind, geom, ox, oy, oz,
                dx, dy, dz, t_min, t_max, any_hit):
    """Visit the primitives kept apart from the tree, ``leaf_prims[apart_first:]``, as the first leaf
    of the ray from ``(ox, oy, oz)`` along ``(dx, dy, dz)`` when it meets their box: ``(best_t,
    best_prim, best_u, best_v, tests)`` to start its walk with (see :func:`visit_references`)."""
    if not meets_apart(apart_box, ox, oy, oz, dx, dy, dz, t_min, t_max):
        return t_max, -1, 0.0, 0.0, 0
    return visit_references(mode, action, row, apart_first, leaf_prims.shape[0], leaf_prims, mailbox, tid, stamp,
                            kind, geom, ray_setup(ox, oy, oz, dx, dy, dz), t_min, t_max, -1, 0.0, 0.0, any_hit)


@inline_kernel
def walk_singly(ray_first, ray_end, tid, lo, hi, node_planes, node_links, skip_empty, leaf_prims, apart_first,
                apart_box, kind, geom, origins, directions, t_min, t_max, hit_slot, any_hit, mailbox, ray_id_base,
                stack_node, stack_t, inv_dir, mode, action, work):
    """Trace rays ``ray_first`` to ``ray_end - 1`` (one chunk of :func:`rayaccel._jit.on_threads`), their
    stacks in row ``tid``; ``stack_node`` (threads, depth) int32 and ``stack_t`` (threads, depth, 2);
    ``node_planes`` and ``node_links`` are the flat node records (:attr:`.layout.KdTreeArrays.walk_records`),
    ``skip_empty`` True or None (see above);
    ``mailbox`` as in the uniform grid (empty for the closest hit, which needs none). A step
    reads the ray on the node's axis from memory (``inv_dir`` (threads, :data:`RAY_ROW`) holds
    the ray's reciprocal direction, then its exit and entry steps, see :func:`cross_split`):
    taken from a tuple by a varying index, the reciprocal was computed again, a division per
    step, which took 7 % of the walk's samples (full dragon, incoherent rays, one thread)."""
    row_of_thread = unsigned(tid)
    for i in range(ray_first, ray_end):
        row = result_row(hit_slot, i)
        ray_t_min, ray_t_max = ray_limit(t_min, i), ray_limit(t_max, i)
        o = (origins[i, 0], origins[i, 1], origins[i, 2])
        d = (directions[i, 0], directions[i, 1], directions[i, 2])
        best_t, best_prim, best_u, best_v, n_tests = visit_apart(
            mode, action, row, apart_first, apart_box, leaf_prims, mailbox, tid, ray_id_base + i, kind, geom, o[0],
            o[1], o[2], d[0], d[1], d[2], ray_t_min, ray_t_max, any_hit)
        t0, t1 = clip_to_box(lo, hi, o[0], o[1], o[2], d[0], d[1], d[2], ray_t_min, best_t)
        if t0 > t1 or (any_hit and best_prim >= 0):
            finish_walked_ray(mode, action, work, row, best_t, best_prim, best_u, best_v, 0, n_tests, 0)
            continue
        for axis in range(3):
            inv_a = 1.0 / directions[i, axis]
            inv_dir[row_of_thread, axis] = inv_a
            inv_dir[row_of_thread, 3 + axis], inv_dir[row_of_thread, 6 + axis] = plane_steps(inv_a)
        ray = ray_setup(o[0], o[1], o[2], d[0], d[1], d[2])
        n_nodes = 0
        n_leaves = 0
        node = 0
        plane, word = node_record(node_planes, node_links, 0)
        sp = 0
        while True:
            n_nodes += 1
            axis = word & 3
            if axis != LEAF:
                empty = empty_children_of(skip_empty, word)
                below = node_child(word)
                plane_below, word_below = node_record(node_planes, node_links, below)
                plane_above, word_above = node_record(node_planes, node_links, below + 1)
                node, t1, pushed, push_t0, push_t1 = cross_split(plane, word, origins[i, axis],
                                                                  inv_dir[row_of_thread, axis],
                                                                  inv_dir[row_of_thread, 3 + axis],
                                                                  inv_dir[row_of_thread, 6 + axis], t0, t1)
                above = node != below
                word = word_above if above else word_below
                plane = plane_above if above else plane_below
                slot = unsigned(sp)
                stack_node[row_of_thread, slot] = pushed
                stack_t[row_of_thread, slot, 0] = push_t0
                stack_t[row_of_thread, slot, 1] = push_t1
                sp += skips_empty(empty, below, pushed)
                if not is_empty_child(empty, below, node):
                    continue
            else:
                n_leaves += 1
                first = leaf_first(node_links, node)
                best_t, best_prim, best_u, best_v, tests = visit_references(
                    mode, action, row, first, first + (word >> 2), leaf_prims, mailbox, tid, ray_id_base + i, kind,
                    geom, ray, ray_t_min, best_t, best_prim, best_u, best_v, any_hit)
                n_tests += tests
                if any_hit and best_prim >= 0:
                    break
            node, t0, t1, sp = pop_unsettled(stack_node, stack_t, tid, sp, best_prim, best_t, t0, t1)
            if node < 0:
                break
            plane, word = node_record(node_planes, node_links, node)
        finish_walked_ray(mode, action, work, row, best_t, best_prim, best_u, best_v, n_nodes, n_tests, n_leaves)


@chunk_kernel
def kdtree_closest_kernel(ray_first, ray_end, tid, lo, hi, node_planes, node_links, skip_empty, leaf_prims,
                          apart_first, apart_box, kind, geom, origins, directions, t_min, t_max, hit_slot, any_hit,
                          mailbox, ray_id_base, stack_node, stack_t, inv_dir, action, work):
    """The closest-hit and any-hit walk (an action of mode ``NEAREST``), the other modes' code
    pruned before it is compiled (:func:`..actions.visit_prim_in_mode`)."""
    walk_singly(ray_first, ray_end, tid, lo, hi, node_planes, node_links, skip_empty, leaf_prims, apart_first,
                apart_box, kind, geom, origins, directions, t_min, t_max, hit_slot, any_hit, mailbox, ray_id_base,
                stack_node, stack_t, inv_dir, NEAREST, action, work)


@chunk_kernel
def kdtree_crossings_kernel(ray_first, ray_end, tid, lo, hi, node_planes, node_links, skip_empty, leaf_prims,
                            apart_first, apart_box, kind, geom, origins, directions, t_min, t_max, hit_slot, any_hit,
                            mailbox, ray_id_base, stack_node, stack_t, inv_dir, action, work):
    """The walk for the other actions (counting, listing, winding), compiled at their first use."""
    walk_singly(ray_first, ray_end, tid, lo, hi, node_planes, node_links, skip_empty, leaf_prims, apart_first,
                apart_box, kind, geom, origins, directions, t_min, t_max, hit_slot, any_hit, mailbox, ray_id_base,
                stack_node, stack_t, inv_dir, action.mode, action, work)
