"""Insertion-based optimisation of a built BVH: subtrees moved to where they cost least.

Bittner, Hapala & Havran, "Fast Insertion-Based Optimization of Bounding Volume
Hierarchies", Computer Graphics Forum 32(1), 2013. A top-down builder decides each
split once, from the top, and never revisits it; this pass takes the nodes that
look worst placed, removes each with its parent (the sibling takes the parent's
place), and inserts it again beside the node where it adds the least surface
area, which may be where it was. Moving a subtree changes no leaf, so the SAH
cost changes only by the inner nodes' areas: the cost of inserting node ``N`` as
sibling of node ``X`` is the area of the new parent's box (``X``'s and ``N``'s
together) plus what every ancestor of ``X`` grows by. The best ``X`` is found by
branch and bound over the tree, nodes taken in order of the growth their
ancestors already add (their "induced" cost), which never falls going down, a
subtree being cut off once that plus ``N``'s own area can no longer win. The old
position is among the candidates, so a move never raises the cost.

Which nodes to move: in each round the largest ``1 %`` by a measure after the
paper's combined one, the node's area times its area over its smaller child's and
over its children's sum (a node much larger than its children bounds them
loosely); leaves count by their area alone. Rounds go on while one lowers the
inner nodes' total area by more than :data:`MIN_ROUND_GAIN` of it, up to
``rounds``; a tree that all rounds together improve by less is kept as built. The
moved node becomes the first child of its new parent, where an any-hit walk,
which takes children in the tree's order, looks first: made the second, the
forest's any-hit rays ran at 0.72-0.92 of the tree as built. The tree is then
laid out again depth-first, leaves taking their primitives in that order.

Measured with ``bvh-binned`` (32 bins), whose top splits cannot isolate a small
dense object in a large scene: forest-small-chair (a chair half a unit tall among
the trees of a 100-unit forest, two thirds of the triangles) SAH cost 49.86 ->
43.46, nodes visited per incoherent ray 6.69 -> 6.20 (any hit 4.51 -> 4.22), per
shadow ray 6.50 -> 6.00, leaves and triangle tests the same; forest-large-chair
35.51 -> 33.84. (Since the choice of nodes breaks ties by node index, the forest's
many equal measures give 43.67, at the same speed.) On the scanned meshes (bunny,
armadillo, Buddha, the dragons) a round saves under 1 % and the tree stays as
built, after one round: 18 ms of the full dragon's build (45 ms with the measures
in NumPy and all of them partitioned). The measures and the moves run in a kernel
each, the moves' helpers inlined, and the choice of nodes in NumPy: written with
Numba's sort and partition as well, the first build on an empty cache compiled 52
kernels more (bunny, CPU: 23.8 s against 9.5-10.0 s without reinsertion; 12.2-14.1
s with the moves alone in a kernel).
"""

from __future__ import annotations

import numpy as np

from ..._jit import inline_kernel, kernel, unsigned
from .nodes import box_area6, box_surface_areas, compact

__all__ = ["reinsert_subtrees", "MIN_ROUND_GAIN"]

MIN_ROUND_GAIN = 0.01
"""A round that lowers the inner nodes' total area by less than this fraction of it is the last."""
_MOVED_FRACTION = 0.01
_SAMPLE_STRIDE = 16
_SAMPLE_MARGIN = 64


def _links(first, count):
    """``(left, right, parent)`` of the binary layout's nodes, -1 where there is none."""
    n = len(first)
    inner = np.flatnonzero(count == 0)
    left = np.full(n, -1, dtype=np.int64)
    left[inner] = first[inner]
    right = np.where(left >= 0, left + 1, -1)
    parent = np.full(n, -1, dtype=np.int64)
    parent[first[inner]] = inner
    parent[first[inner] + 1] = inner
    return left, right, parent


@kernel
def _node_measures(box, left, right, root):
    """``(measure, inner_area)``: each node's measure of how badly it is placed, its area times
    its area over its smaller child's and over its children's sum (a leaf: its area; the root
    and its children, which cannot move: -1; one that overflows, on huge boxes: infinite),
    and the inner nodes' total area. In NumPy, full dragon: 23 ms; here 4 ms."""
    n = box.shape[0]
    area = box_surface_areas(box)
    measure = np.empty(n)
    inner_area = 0.0
    for node in range(n):
        if left[node] < 0:
            measure[node] = area[node]
            continue
        inner_area += area[node]
        child_a = area[left[node]]
        child_b = area[right[node]]
        measure[node] = area[node] ** 3 / max(min(child_a, child_b) * (child_a + child_b), 1e-300)
    measure[root] = -1.0
    if left[root] >= 0:
        measure[left[root]] = -1.0
        measure[right[root]] = -1.0
    return measure, inner_area


def _worst_nodes(box, left, right, root, batch):
    """The ``batch`` nodes that look worst placed (:func:`_node_measures`), worst first, and the
    inner nodes' total area."""
    measure, inner_area = _node_measures(box, left, right, root)
    return _largest(measure, batch), inner_area


def _largest(measure, batch):
    """The indices of the ``batch`` largest non-negative entries of ``measure``, largest first,
    equal ones by index. A threshold from every :data:`_SAMPLE_STRIDE`-th entry keeps a few
    more candidates than ``batch``, which are then sorted; when it keeps too few, the threshold
    is the ``batch``-th largest entry of all. Full dragon (1.17 million nodes, a batch of
    11,680): 3 ms, where NumPy's ``argpartition`` of all the entries took 25-33 ms."""
    batch = min(batch, len(measure))
    candidates = np.zeros(0, dtype=np.int64)
    rank = batch // _SAMPLE_STRIDE + _SAMPLE_MARGIN
    sample = measure[::_SAMPLE_STRIDE]
    if rank < len(sample):
        candidates = np.flatnonzero(measure >= _at_least_zero(np.partition(sample, len(sample) - rank)[-rank]))
    if len(candidates) < batch:
        candidates = np.flatnonzero(measure >= _at_least_zero(np.partition(measure, len(measure) - batch)[-batch]))
    return candidates[np.argsort(-measure[candidates], kind="stable")[:batch]]


def _at_least_zero(threshold):
    """``threshold``, or 0 where it is negative or NaN: only non-negative measures are moved."""
    return threshold if threshold >= 0.0 else 0.0


@inline_kernel
def _union_area(box, a, other):
    """Area of the box around row ``a`` of ``box`` and the box ``other`` (6,)."""
    ex = max(box[a, 3], other[3]) - min(box[a, 0], other[0])
    ey = max(box[a, 4], other[4]) - min(box[a, 1], other[1])
    ez = max(box[a, 5], other[5]) - min(box[a, 2], other[2])
    return 2.0 * (ex * ey + ey * ez + ex * ez)


@inline_kernel
def _refit_upwards(box, left, right, parent, node):
    """Make the boxes from ``node`` up to the root the unions of their children's, stopping at
    the first that stays as it was (those above it then stay too)."""
    while node >= 0:
        a, b = left[node], right[node]
        changed = False
        for k in range(3):
            lo = min(box[a, k], box[b, k])
            hi = max(box[a, k + 3], box[b, k + 3])
            changed |= lo != box[node, k] or hi != box[node, k + 3]
            box[node, k] = lo
            box[node, k + 3] = hi
        if not changed:
            return
        node = parent[node]


@inline_kernel
def _heap_push(costs, nodes, size, cost, node):
    """Add ``node`` with ``cost`` to the binary min-heap held in the first ``size`` entries."""
    slot = size
    while slot > 0:
        up = (slot - 1) >> 1
        if costs[up] <= cost:
            break
        costs[slot] = costs[up]
        nodes[slot] = nodes[up]
        slot = up
    costs[slot] = cost
    nodes[slot] = node
    return size + 1


@inline_kernel
def _heap_pop(costs, nodes, size):
    """Remove the heap's cheapest entry: ``(cost, node, new size)``."""
    cost, node = costs[0], nodes[0]
    size -= 1
    last_cost, last_node = costs[size], nodes[size]
    slot = 0
    while True:
        child = 2 * slot + 1
        if child >= size:
            break
        if child + 1 < size and costs[child + 1] < costs[child]:
            child += 1
        if costs[child] >= last_cost:
            break
        costs[slot] = costs[child]
        nodes[slot] = nodes[child]
        slot = child
    costs[slot] = last_cost
    nodes[slot] = last_node
    return cost, node, size


@inline_kernel
def _best_sibling(box, left, right, root, node, heap_costs, heap_nodes):
    """The node beside which node ``node``'s box adds the least area to the tree under ``root``,
    and that area: branch and bound on the induced cost (see the module docstring)."""
    moved = box[node]
    moved_area = box_area6(moved)
    best_cost = np.inf
    best = root
    size = _heap_push(heap_costs, heap_nodes, 0, 0.0, root)
    while size > 0:
        induced, candidate, size = _heap_pop(heap_costs, heap_nodes, size)
        if induced + moved_area >= best_cost:
            break
        direct = _union_area(box, candidate, moved)
        if induced + direct < best_cost:
            best_cost = induced + direct
            best = candidate
        if left[candidate] >= 0:
            below = induced + direct - box_area6(box[candidate])
            if below + moved_area < best_cost:
                size = _heap_push(heap_costs, heap_nodes, size, below, left[candidate])
                size = _heap_push(heap_costs, heap_nodes, size, below, right[candidate])
    return best, best_cost


@inline_kernel
def _replace_child(left, right, parent, old, new):
    """Put ``new`` where ``old`` hangs under its parent (nothing when ``old`` is the root)."""
    above = parent[old]
    if above >= 0:
        if left[above] == old:
            left[above] = new
        else:
            right[above] = new
    parent[new] = above


@inline_kernel
def _path_area(box, parent, node):
    """The summed area of ``node`` and its ancestors' boxes."""
    total = 0.0
    while node >= 0:
        total += box_area6(box[node])
        node = parent[node]
    return total


@kernel
def _move_nodes(box, left, right, parent, root, nodes, heap_costs, heap_nodes):
    """Remove each of ``nodes`` in turn with its parent and insert it again beside its best
    sibling, its old parent's record becoming the new parent, with the node as its first
    child; a node that has come to hang under the root or its children stays. Returns
    ``(root, area saved)``."""
    total_saved = 0.0
    for node in nodes:
        old_parent = parent[node]
        if old_parent < 0 or parent[old_parent] < 0:
            continue
        sibling = right[old_parent] if left[old_parent] == node else left[old_parent]
        grand = parent[old_parent]
        saved = box_area6(box[old_parent]) + _path_area(box, parent, grand)
        _replace_child(left, right, parent, old_parent, sibling)
        _refit_upwards(box, left, right, parent, grand)
        saved -= _path_area(box, parent, grand)
        target, added = _best_sibling(box, left, right, root, node, heap_costs, heap_nodes)
        if target == root:
            root = old_parent
        _replace_child(left, right, parent, target, old_parent)
        left[old_parent] = node
        right[old_parent] = target
        parent[target] = old_parent
        parent[node] = old_parent
        for k in range(3):
            box[old_parent, k] = min(box[target, k], box[node, k])
            box[old_parent, k + 3] = max(box[target, k + 3], box[node, k + 3])
        _refit_upwards(box, left, right, parent, parent[old_parent])
        total_saved += saved - added
    return root, total_saved


@kernel
def _leaves_in_order(first, count, order):
    """``order`` rewritten so that the leaves of the depth-first layout take their primitives
    one after the other, and ``first`` of each leaf pointing there."""
    new_order = np.empty_like(order)
    offset = 0
    stack = np.empty(first.shape[0] + 1, dtype=np.int64)
    stack[0] = 0
    sp = 1
    while sp > 0:
        sp -= 1
        node = stack[sp]
        if count[node] == 0:
            stack[sp] = first[node] + 1
            stack[sp + 1] = first[node]
            sp += 2
            continue
        for k in range(count[node]):
            new_order[offset + k] = order[unsigned(first[node] + k)]
        first[node] = offset
        offset += count[node]
    return new_order


def reinsert_subtrees(box, first, count, order, rounds: int = 64):
    """The tree of the binary layout ``(box, first, count, order)`` improved by moving subtrees
    (see the module docstring), laid out afresh in four arrays of the same kinds; the arrays
    given when the moves would save less than :data:`MIN_ROUND_GAIN` of the inner area."""
    n = len(first)
    if n < 5:
        return box, first, count, order
    moved_box = box.copy()
    left, right, parent = _links(first, count)
    root = 0
    heap_costs = np.empty(n + 1)
    heap_nodes = np.empty(n + 1, dtype=np.int64)
    batch = max(1, int(n * _MOVED_FRACTION))
    total_saved = 0.0
    for round_number in range(rounds):
        nodes, inner_area = _worst_nodes(moved_box, left, right, root, batch)
        if round_number == 0:
            area_as_built = inner_area
        root, saved = _move_nodes(moved_box, left, right, parent, root, nodes, heap_costs, heap_nodes)
        total_saved += saved
        if saved <= MIN_ROUND_GAIN * inner_area:
            break
    if total_saved <= MIN_ROUND_GAIN * area_as_built:
        return box, first, count, order
    leaf_count = np.where(left < 0, count, 0).astype(np.int32)
    new_box, new_first, new_count = compact(moved_box, left, right, first, leaf_count, root)
    return new_box, new_first, new_count, _leaves_in_order(new_first, new_count, order)
