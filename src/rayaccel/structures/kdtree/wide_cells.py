"""The kd-tree's cells collapsed eight to a node, for the eight-wide walks of the BVH.

A kd-tree's cells are boxes that tile its root box, so the tree is also a
hierarchy of boxes: a cell's children split it at a plane. Collapsed as a
binary BVH is into a wide one (Dammertz, Hanika & Keller 2008; Ernst &
Greiner 2008; :mod:`rayaccel.structures.bvh.wide`), a node holds up to eight
cells from the three or so levels of planes below it, and a ray tests the
eight at once in vector lanes (:mod:`rayaccel.structures.bvh.wide_slab`) and
takes those it enters front to back by their entry distance. The ray visits
the cells the binary walk visits, in the same order (the cells do not
overlap), but it takes three levels per step instead of one, and its next step
no longer waits for each plane's choice. Empty leaves get no slot (an inner
cell with one empty child is its other child), so no ray enters one, as with
``skip_empty``.

The cells are those the binary walks use (:func:`.layout.node_cells`: each
child reaches across its plane's float32 bracket), grown by the BVH's rounding
margin and rounded outwards to float32 by the wide records. The margin matters
where a plane passes through a vertex, as the perfect splits' planes do: a ray
aimed at the vertex meets the triangles on either side at the same point, but
their computed distances differ in the last bits, and the cell beyond the plane
must not be skipped as starting past the hit found in the cell before it (a
case the tests met). A ray so enters every cell the binary walk enters, and
those within the margin of it.

The primitives kept apart (``large_apart``) are a leaf beside the root's cell
under a root around both: the first child an any-hit walk takes, at the cost
of one more box in the root's test.

Measured against the binary walks of the same tree (2026-12-06, Zen 4, medians
of 7 interleaved rounds in one process, same answers): forest-small-chair, one
thread, 2**18 incoherent rays, closest / any hit 1.54 / 1.50 times as fast,
512² camera rays 2.08 / 3.02, their shadow rays 1.44 / 1.51; the full dragon,
two threads, 2**20 incoherent rays 1.54 / 1.74, 1024² camera rays 1.59 / 1.81,
shadow rays 1.49 / 1.46. The records cost 11.6 bytes a triangle on the forest
and 12.4 on the full dragon (72.2 in all, within Embree's 91.9), and 36 ms of
the dragon's build.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..._jit import kernel
from ..bvh.layout import pack_nodes
from ..bvh.nodes import grow_by_rounding_margin, node_depths
from ..bvh.wide import wide_records, wide_tree
from .layout import LEAF, leaf_first, node_cells, node_child, node_word

__all__ = ["CellHierarchy", "cell_hierarchy"]


@kernel
def _parents_first(words):
    """The nodes reachable from the root, each after its parent."""
    n = words.shape[0] // 2
    order = np.empty(n, dtype=np.int64)
    order[0] = 0
    size = 1
    for k in range(n):
        if k >= size:
            break
        word = node_word(words, order[k])
        if word & 3 != LEAF:
            order[size] = node_child(word)
            order[size + 1] = node_child(word) + 1
            size += 2
    return order[:size]


@kernel
def _empty_subtrees(words, order):
    """(n_nodes,) whether each node's subtree holds no reference."""
    empty = np.zeros(words.shape[0] // 2, dtype=np.bool_)
    for k in range(order.shape[0] - 1, -1, -1):
        node = order[k]
        word = node_word(words, node)
        if word & 3 == LEAF:
            empty[node] = (word >> 2) == 0
        else:
            empty[node] = empty[node_child(word)] and empty[node_child(word) + 1]
    return empty


@kernel
def _past_single_children(words, empty, node):
    """The first node at or below ``node`` that is a leaf or has two children holding references,
    following the only child that holds some."""
    while True:
        word = node_word(words, node)
        if word & 3 == LEAF:
            return node
        below = node_child(word)
        if empty[below]:
            node = below + 1
        elif empty[below + 1]:
            node = below
        else:
            return node


@kernel
def _binary_cells(lo, hi, planes, words, apart_first, apart_count, apart_box):
    """The binary hierarchy of boxes (box, first, count: see :mod:`rayaccel.structures.bvh.layout`) of
    the tree's cells holding references, rooted at 0, the two children of an inner node side by side,
    with the primitives kept apart (``apart_count`` rows from ``apart_first``, in ``apart_box``) as a
    leaf beside the root's cell. The tree must hold a reference or keep some apart."""
    cells, _ = node_cells(lo, hi, planes, words)
    empty = _empty_subtrees(words, _parents_first(words))
    n = words.shape[0] // 2
    box = np.empty((n + 2, 6))
    first = np.zeros(n + 2, dtype=np.int64)
    count = np.zeros(n + 2, dtype=np.int64)
    pending_new = np.empty(n + 2, dtype=np.int64)
    pending_node = np.empty(n + 2, dtype=np.int64)
    n_pending = 0
    size = 1
    root = _past_single_children(words, empty, 0)
    tree_row = 0
    if apart_count > 0:
        apart_row = 0
        if not empty[root]:
            first[0] = 1
            apart_row, tree_row, size = 1, 2, 3
        box[apart_row, :3] = apart_box[0]
        box[apart_row, 3:] = apart_box[1]
        first[apart_row] = apart_first
        count[apart_row] = apart_count
    if not empty[root]:
        box[tree_row] = cells[root]
        pending_new[0], pending_node[0] = tree_row, root
        n_pending = 1
    if size == 3:
        box[0, :3] = np.minimum(box[1, :3], box[2, :3])
        box[0, 3:] = np.maximum(box[1, 3:], box[2, 3:])
    while n_pending > 0:
        n_pending -= 1
        new = pending_new[n_pending]
        node = pending_node[n_pending]
        word = node_word(words, node)
        if word & 3 == LEAF:
            first[new] = leaf_first(words, node)
            count[new] = word >> 2
            continue
        first[new] = size
        for side in range(2):
            child = _past_single_children(words, empty, node_child(word) + side)
            box[size] = cells[child]
            pending_new[n_pending] = size
            pending_node[n_pending] = child
            n_pending += 1
            size += 1
    return box[:size], first[:size], count[:size]


class CellHierarchy(NamedTuple):
    """The tree's cells as eight-wide records (:mod:`rayaccel.structures.bvh.wide`):
    ``records``, ``root_record`` (the whole hierarchy's box, as the walks take it) and the
    depth of the binary hierarchy, which sizes the walks' stacks."""

    records: np.ndarray
    root_record: np.ndarray
    depth: int

    @property
    def nbytes(self) -> int:
        return int(self.records.nbytes + self.root_record.nbytes)


def cell_hierarchy(kd, apart_first: int, apart_count: int, apart_box: np.ndarray) -> CellHierarchy | None:
    """The :class:`CellHierarchy` of the kd-tree ``kd`` (:class:`.layout.KdTreeArrays`) whose
    primitives kept apart are ``apart_count`` rows from ``apart_first`` in the box ``apart_box``
    ((2, 3) lo and hi); ``None`` for a tree that holds no reference and keeps none apart."""
    if apart_count == 0 and not kd.count.any():
        return None
    box, first, count = _binary_cells(kd.lo, kd.hi, *kd.walk_records, apart_first, apart_count,
                                      np.ascontiguousarray(apart_box, dtype=np.float64))
    grow_by_rounding_margin(box)
    records = wide_records(box, first, count, wide_tree(box, first, count))
    return CellHierarchy(records, pack_nodes(box[:1], first[:1], count[:1]), int(node_depths(first, count).max()))
