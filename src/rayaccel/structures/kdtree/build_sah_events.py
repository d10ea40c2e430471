"""SAH kd-tree construction in O(N log N) with sorted event lists.

Wald & Havran, "On building fast kd-Trees for Ray Tracing, and on doing that
in O(N log N)", IEEE Symposium on Interactive Ray Tracing 2006.

Every primitive contributes, on each axis, a *start* and an *end* event at the
two faces of its box, or one *planar* event where the box is flat. The events
are sorted once, by position and then type (end < planar < start), and stay
sorted: a node sweeps them to find its best plane, then hands them to its
children by filtering, so no node ever sorts more than the few events of the
primitives that the plane cuts. Events live in one arena used like a stack (see
:func:`build_subtrees`), so no node allocates event arrays of its own, and
one call builds the subtrees of many cells.

* **Sweep** (per axis): crossing the events in order keeps the counts left of,
  on, and right of the candidate plane, which gives the cost of every plane in
  one pass. Cost (the lecture's, MacDonald & Booth 1990) of splitting a cell of
  area ``S`` at a plane with ``N_L``/``N_R`` primitives on the two sides of
  areas ``S_L``/``S_R``::

      lambda * (C_t + C_i * (S_L N_L + S_R N_R) / S)

  with ``lambda = 1 - empty_bonus`` when one side is empty, else 1
  (:mod:`.split_cost`). Primitives lying in the plane are tried on each side in
  turn.
* **Termination**: a leaf when ``C_i N`` (not splitting) is no dearer than the
  best split, when ``N <= leaf_size``, or at ``max_depth``.
* **Perfect splits**: a primitive straddling the plane is clipped to each
  child's cell (:mod:`rayaccel.geometry.clip`) and its new, tighter events are
  sorted and merged into the child's lists; a primitive whose clipped part is
  empty on one side (its box straddles the plane, the primitive does not)
  leaves that side altogether.

Builders see geometry here, unlike the BVH's, because clipping needs it.
"""

from __future__ import annotations

import numpy as np
from numba.typed import List

from ..._jit import inline_kernel, kernel, unsigned
from ...geometry.clip import CLIP_VERTICES, split_clipped_bounds
from ..build_arrays import reserve_rows
from .events import END, PLANAR, START, event_before, put_events, sort_events, write_node_events
from .layout import LEAF, add_children, copy_cell, split_cell
from .split_cost import split_cost

__all__ = ["build_subtrees"]

_BOTH = 0
_LEFT = 1
_RIGHT = 2


@kernel
def _best_plane(pos, code, first, last, axis, cell, n, traversal_cost, intersection_cost, empty_bonus):
    """Sweep one axis's events; return (cost, position, planar primitives go left) of its best plane.

    The events are taken a position at a time. Before position ``p``, ``n_left``
    counts the boxes that start before ``p``; after its events, ``n_right``
    counts the boxes that end after it. The primitives lying in the plane
    (``planars``) are tried on the left side, then on the right.
    """
    lo = cell[axis]
    hi = cell[axis + 3]
    e1 = cell[(axis + 1) % 3 + 3] - cell[(axis + 1) % 3]
    e2 = cell[(axis + 2) % 3 + 3] - cell[(axis + 2) % 3]
    area = 2.0 * (e1 * e2 + (hi - lo) * (e1 + e2))
    best_cost = np.inf
    best_pos = 0.0
    best_planar_left = True
    if area <= 0.0:
        return best_cost, best_pos, best_planar_left
    scale = 2.0 * intersection_cost / area
    cap = e1 * e2
    ring = e1 + e2
    n_left = 0
    n_right = n
    k = first
    while k < last:
        p = pos[unsigned(k)]
        ends = 0
        planars = 0
        starts = 0
        while k < last and pos[unsigned(k)] == p:
            kind = code[unsigned(k)] & 3
            ends += kind == END
            planars += kind == PLANAR
            starts += kind == START
            k += 1
        n_right -= ends + planars
        if lo < p < hi:
            area_left = cap + (p - lo) * ring
            area_right = cap + (hi - p) * ring
            cost = split_cost(traversal_cost, scale, area_left, n_left + planars, area_right, n_right, empty_bonus)
            if cost < best_cost:
                best_cost, best_pos, best_planar_left = cost, p, True
            if planars > 0:
                cost = split_cost(traversal_cost, scale, area_left, n_left, area_right, n_right + planars,
                                  empty_bonus)
                if cost < best_cost:
                    best_cost, best_pos, best_planar_left = cost, p, False
        n_left += starts + planars
    return best_cost, best_pos, best_planar_left


@kernel
def _classify(pos, code, first, last, p, planar_left, flags, straddling):
    """Mark each primitive of the node left only, right only, or both (straddling the plane);
    list the straddling ones in ``straddling``. Returns the numbers of primitives left only,
    right only, and straddling.

    One pass over the split axis's events suffices: a box's start comes before its end,
    so a start below the plane marks the primitive as straddling until an end at or
    below the plane moves it to the left."""
    n_left = 0
    n_right = 0
    n_straddling = 0
    for i in range(first, last):
        c = code[unsigned(i)]
        kind = c & 3
        prim = unsigned(c >> 2)
        x = pos[unsigned(i)]
        if kind == START:
            flags[prim] = _RIGHT if x >= p else _BOTH
        elif kind == END:
            if x <= p:
                flags[prim] = _LEFT
                n_left += 1
            elif flags[prim] == _BOTH:
                straddling[unsigned(n_straddling)] = prim
                n_straddling += 1
            else:
                n_right += 1
        elif x < p or (x == p and planar_left):
            flags[prim] = _LEFT
            n_left += 1
        else:
            flags[prim] = _RIGHT
            n_right += 1
    return n_left, n_right, n_straddling


@kernel
def _clip_straddling(straddling, n_straddling, ids, cell, axis, p, kind, geom, slack, poly, boxes, new_pos, new_code,
                     fill):
    """Events of the straddling primitives ``straddling[:n_straddling]`` (scene primitives
    ``ids[straddling]``) clipped to the two halves of ``cell`` split at ``p`` on
    ``axis``: rows ``new_pos[side, b, :fill[side, b]]`` (and ``new_code``) per side and
    axis ``b``, each sorted; ``fill`` arrives zeroed. Returns how many primitives each
    side keeps."""
    kept_left = 0
    kept_right = 0
    for k in range(n_straddling):
        prim = straddling[k]
        sides = split_clipped_bounds(kind, geom, ids[prim], cell, axis, p, slack, poly, boxes)
        kept_left += sides & 1
        kept_right += sides >> 1
        for side in range(2):
            if not sides & (1 << side):
                continue
            for b in range(3):
                fill[side, b] = put_events(new_pos[side, b], new_code[side, b], fill[side, b], prim,
                                           boxes[side, b], boxes[side, b + 3])
    for side in range(2):
        for b in range(3):
            sort_events(new_pos[side, b], new_code[side, b], fill[side, b])
    return kept_left, kept_right


@inline_kernel
def _merge_clipped(pos, code, first, end, new_pos, new_code, n_new):
    """Merge the sorted clipped events ``new_pos[:n_new]`` into a child's slot, whose
    sorted parent events are ``pos[first + n_new:end]``, writing from ``first`` on.
    The write cursor never passes the read cursor, so no copy of the parent events
    is needed."""
    i = first + n_new
    o = first
    j = 0
    while j < n_new:
        x = new_pos[unsigned(j)]
        c = new_code[unsigned(j)]
        if i < end and event_before(pos[unsigned(i)], code[unsigned(i)], x, c):
            x = pos[unsigned(i)]
            c = code[unsigned(i)]
            i += 1
        else:
            j += 1
        pos[unsigned(o)] = x
        code[unsigned(o)] = c
        o += 1


@inline_kernel
def _distribute_axis(pos, code, span, flags, new_pos, new_code, fill, child_span, b):
    """Axis ``b`` of :func:`_distribute`. The parent events of each child go after room for
    its clipped events, which are then merged in from the front. Every event is written
    to both children's next free places and only the cursor of its side moves on, so the
    loop does not branch on the side (the branching loop measured 3-17 % slower on whole
    subtree builds); the slots have room for every parent event of the axis, so a write
    that is not kept never passes a slot's end."""
    o0 = child_span[0, b, 0] + fill[0, b]
    o1 = child_span[1, b, 0] + fill[1, b]
    for i in range(span[b, 0], span[b, 1]):
        c = code[unsigned(i)]
        x = pos[unsigned(i)]
        side = flags[unsigned(c >> 2)]
        pos[unsigned(o0)] = x
        code[unsigned(o0)] = c
        o0 += side == _LEFT
        pos[unsigned(o1)] = x
        code[unsigned(o1)] = c
        o1 += side == _RIGHT
    for side, o in ((0, o0), (1, o1)):
        child_span[side, b, 1] = o
        if fill[side, b] > 0:
            _merge_clipped(pos, code, child_span[side, b, 0], o, new_pos[side, b], new_code[side, b], fill[side, b])


@kernel
def _distribute(pos, code, span, flags, new_pos, new_code, fill, child_span):
    """One pass over the parent's events: each goes to the left child, the right child or
    (straddling) neither; then each child's clipped events are merged in.

    ``child_span[side, axis]`` arrives holding where that child's events of that axis
    start (room for every parent event of the axis plus the clipped ones) and leaves
    holding their (first, end). The helpers are inlined, so that this is one function
    without calls: in a function that calls others, Numba keeps the reference counting
    of every array it handles, which measured 260 ns a node here.
    """
    for b in range(3):
        _distribute_axis(pos, code, span, flags, new_pos, new_code, fill, child_span, b)


@kernel
def _deferred_task(pos, code, span, ids, local):
    """The primitives of one node, as scene primitives and their (clipped) bounds rebuilt from
    the node's events: ``(ids, boxes)``. ``local`` is -1 for every primitive of the
    builder and is left so."""
    task_ids = np.empty(span[0, 1] - span[0, 0], dtype=np.int64)
    n = 0
    for i in range(span[0, 0], span[0, 1]):
        prim = code[i] >> 2
        if local[prim] < 0:
            local[prim] = n
            task_ids[n] = ids[prim]
            n += 1
    boxes = np.empty((n, 6))
    for axis in range(3):
        for i in range(span[axis, 0], span[axis, 1]):
            row = local[code[i] >> 2]
            kind = code[i] & 3
            if kind != END:
                boxes[row, axis] = pos[i]
            if kind != START:
                boxes[row, axis + 3] = pos[i]
    for i in range(span[0, 0], span[0, 1]):
        local[code[i] >> 2] = -1
    return task_ids[:n].copy(), boxes


@inline_kernel
def _copy_span(dst, src):
    for axis in range(3):
        dst[axis, 0] = src[axis, 0]
        dst[axis, 1] = src[axis, 1]


@kernel
def build_subtrees(ids, boxes, task_first, task_cell, task_depth, kind, geom, traversal_cost, intersection_cost,
                   empty_bonus, leaf_size, max_depth, slack, defer_below):
    """Build the kd-trees of many cells, depth first, one after the other.

    Task ``t`` is the cell ``task_cell[t]`` at ``task_depth[t]`` holding the scene
    primitives ``ids[task_first[t]:task_first[t + 1]]``, whose (clipped) bounds are the
    rows of ``boxes`` (lo, hi). The events number the primitives by their row, so the
    per-primitive scratch is as large as ``ids``, and all tasks share it and the event
    arena: one call builds the subtrees of many small cells without allocating.

    The events live in one arena used like a stack. First each task's sorted
    events are written at the bottom, one task after the other; the tasks are taken
    from the last. A split writes both children's events above everything in use,
    the right child's below the left's (each axis of each child in a slot sized for
    the worst case), and the walk continues into the left child; whenever a node
    is taken from the task stack, everything above its events -- the finished
    subtrees' -- is free again.

    Nodes holding fewer than ``defer_below`` primitives are not built but left as
    placeholders and returned as new tasks with their primitives' bounds in their
    cells (for building in parallel; pass 0 to build everything).

    Returns ``(node_split, node_link, leaf_prims, deferred)``: one node array for all
    the subtrees, task ``t``'s root at node ``t``, and ``deferred`` listing ``(node,
    ids, boxes, cell, depth)``.
    """
    n_tasks = task_cell.shape[0]
    n_prims = ids.shape[0]
    region = 6 * n_prims
    arena_pos = np.empty(4 * region + 64)
    arena_code = np.empty(4 * region + 64, dtype=np.int64)
    max_task = 0
    for t in range(n_tasks):
        max_task = max(max_task, task_first[t + 1] - task_first[t])
    keys = np.empty(2 * max_task, dtype=np.uint64)
    spare_keys = np.empty(2 * max_task, dtype=np.uint64)
    spare_code = np.empty(2 * max_task, dtype=np.int64)
    max_tasks = n_tasks + max_depth + 2
    task_node = np.empty(max_tasks, dtype=np.int64)
    task_span = np.empty((max_tasks, 3, 2), dtype=np.int64)
    task_n = np.empty(max_tasks, dtype=np.int64)
    task_cells = np.empty((max_tasks, 6))
    task_depths = np.empty(max_tasks, dtype=np.int64)
    top = 0
    for t in range(n_tasks):
        first, last = task_first[t], task_first[t + 1]
        write_node_events(first, boxes[first:last], arena_pos[top:], arena_code[top:], task_span[t], keys, spare_keys,
                          spare_code)
        task_span[t] += top
        top = task_span[t, 2, 1]
        task_node[t] = t
        task_n[t] = last - first
        copy_cell(task_cells[t], task_cell[t])
        task_depths[t] = task_depth[t]
    capacity = max(64, n_tasks + 4 * n_prims // max(leaf_size, 1))
    node_split = np.zeros(capacity)
    node_link = np.zeros((capacity, 2), dtype=np.int32)
    leaf_prims = np.empty(2 * n_prims + 16, dtype=np.int32)
    n_nodes = n_tasks
    n_refs = 0
    flags = np.empty(n_prims, dtype=np.uint8)
    local = np.full(n_prims if defer_below > 0 else 0, -1, dtype=np.int64)
    poly = np.empty((2, CLIP_VERTICES, 3))
    clipped = np.empty((2, 6))
    fill = np.empty((2, 3), dtype=np.int64)
    straddling = np.empty(64, dtype=np.int64)
    new_pos = np.empty((2, 3, 64))
    new_code = np.empty((2, 3, 64), dtype=np.int64)
    span = np.empty((3, 2), dtype=np.int64)
    cell = np.empty(6)
    child_span = np.empty((2, 3, 2), dtype=np.int64)
    child_cell = np.empty((2, 6))
    deferred = List()
    sp = n_tasks
    while sp > 0:
        sp -= 1
        node = task_node[sp]
        _copy_span(span, task_span[sp])
        n = task_n[sp]
        copy_cell(cell, task_cells[sp])
        depth = task_depths[sp]
        top = span[2, 1]
        if n < defer_below:
            deferred.append((node, *_deferred_task(arena_pos, arena_code, span, ids, local), cell.copy(), depth))
            continue
        best_axis = -1
        best_cost = np.inf
        best_pos = 0.0
        best_planar_left = True
        if n > leaf_size and depth < max_depth:
            for axis in range(3):
                cost, p, planar_left = _best_plane(arena_pos, arena_code, span[axis, 0], span[axis, 1], axis, cell, n,
                                                   traversal_cost, intersection_cost, empty_bonus)
                if cost < best_cost:
                    best_cost, best_axis, best_pos, best_planar_left = cost, axis, p, planar_left
        if best_axis < 0 or best_cost >= intersection_cost * n:
            leaf_prims = reserve_rows(leaf_prims, n_refs + n)
            node_link[node, 0] = n_refs
            node_link[node, 1] = n << 2 | LEAF
            for i in range(span[0, 0], span[0, 1]):
                if arena_code[i] & 3 != END:
                    leaf_prims[n_refs] = ids[arena_code[i] >> 2]
                    n_refs += 1
            continue
        axis = best_axis
        first, last = span[axis, 0], span[axis, 1]
        straddling = reserve_rows(straddling, last - first)
        n_left, n_right, n_straddling = _classify(arena_pos, arena_code, first, last, best_pos, best_planar_left,
                                                  flags, straddling)
        if new_pos.shape[2] < 2 * n_straddling:
            new_pos = np.empty((2, 3, 4 * n_straddling))
            new_code = np.empty((2, 3, 4 * n_straddling), dtype=np.int64)
        split_cell(cell, axis, best_pos, child_cell)
        kept_left = kept_right = 0
        fill[:] = 0
        if n_straddling > 0:
            kept_left, kept_right = _clip_straddling(straddling, n_straddling, ids, cell, axis, best_pos, kind, geom,
                                                     slack, poly, clipped, new_pos, new_code, fill)
        slot = top
        for side in (1, 0):
            for b in range(3):
                child_span[side, b, 0] = slot
                slot += span[b, 1] - span[b, 0] + fill[side, b]
        arena_pos = reserve_rows(arena_pos, slot)
        arena_code = reserve_rows(arena_code, slot)
        _distribute(arena_pos, arena_code, span, flags, new_pos, new_code, fill, child_span)
        node_split, node_link, child, n_nodes = add_children(node_split, node_link, n_nodes, node, best_pos, axis)
        for side, count in ((1, n_right + kept_right), (0, n_left + kept_left)):
            task_node[sp] = child + side
            _copy_span(task_span[sp], child_span[side])
            task_n[sp] = count
            copy_cell(task_cells[sp], child_cell[side])
            task_depths[sp] = depth + 1
            sp += 1
    return node_split[:n_nodes].copy(), node_link[:n_nodes].copy(), leaf_prims[:n_refs].copy(), deferred
