"""Flat layout of a kd-tree.

Nodes are numbered from the root, 0; the two children of an inner node sit
side by side (below the plane, then above it), so a node stores one index for
both. Each node is one 8-byte record, ``node_records`` (n_nodes, 2) int32, as
pbrt's ``KdTreeNode`` is (Pharr, Jakob & Humphreys, *Physically Based
Rendering*, 3rd ed., section 4.4.1):

* column 0 is, for an inner node, its split plane rounded down to a float32
  number (the records seen as float32), and for a leaf the offset of its first
  reference in ``leaf_prims``;
* column 1 is ``child << 4 | empty << 2 | axis`` for an inner node, ``child``
  the index of its child below the plane (the child above is ``child + 1``),
  ``empty`` bit 0 set when the child below is an empty leaf and bit 1 when the
  child above is (:func:`empty_flags`), and ``axis`` 0, 1 or 2; and
  ``count << 2 | 3`` for a leaf holding ``count`` references (possibly none:
  empty leaves are what makes kd-trees skip empty space, and the flags let the
  walks skip them without reading their records).

The builders place planes in float64, at the primitives' (clipped) bounds:
rounding a plane there would cut the primitives that end or start on it (on
the full dragon, rounding the chosen planes to float32 during the build raised
the expected cost from 90.2 to 98.6 and the tests per incoherent ray from 3.0
to 5.0). So the record keeps a float32 ``q`` at or below the plane, and the
plane lies in ``[q, q + (|q| + 2^-126) 2^-23]`` (:func:`plane_bracket`, one
float32 step): the walks treat the cell below as reaching the top of that
bracket and the cell above as starting at its bottom, so each child is walked
over at least its cell, and a ray crossing the bracket visits both.

Against the 16-byte records of float64 planes this layout replaced (same
trees): 55.3 instead of 70.6 bytes a triangle on the full dragon, 71.2 instead
of 85.2 on the forest (the tree and the primitives in reference order), and,
with the branch-free step of :mod:`.traverse`, incoherent rays 1.04 / 1.08
times as fast on the dragon (closest / any hit) and 1.08-1.11 on the forest,
camera and shadow rays 0.98-1.02 and 0.91-0.97 (one thread, medians of 5-7
interleaved rounds).

``leaf_prims`` (n_references,) int32 holds the primitive indices of every leaf
in turn; a primitive that straddles planes is referenced by every leaf whose
cell it overlaps. The node cells are not stored: the root cell is the box
``lo``..``hi`` and every split halves a cell at the node's plane.

To walk it: clip the ray to the root box, then at an inner node compute the
distance to the plane and visit the near child, the far one, or both
(the far one pushed with its part of the ray's interval) -- see :mod:`.traverse`.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..._jit import inline_kernel, kernel, unsigned
from ...geometry.rounding import float32_below
from ..build_arrays import reserve_rows

__all__ = ["LEAF", "MAX_NODES", "CHILD_SHIFT", "PLANE_STEP", "PLANE_FLOOR", "KdTreeArrays", "node_word", "node_plane",
           "node_record", "node_child", "empty_flags", "leaf_first",
           "plane_bracket", "node_cells", "add_children", "copy_cell", "split_cell"]

LEAF = 3
MAX_NODES = 1 << 27
"""Node indices are stored shifted left by :data:`CHILD_SHIFT` bits in an int32 (leaf counts by two)."""
CHILD_SHIFT = 4
"""Bits below an inner node's child index in its word: the axis and the flags of empty children."""
PLANE_STEP = 2.0 ** -23
"""A float32 number's next one up lies at most ``|q| PLANE_STEP`` above it, when ``|q|`` is at least
:data:`PLANE_FLOOR`, and ``PLANE_FLOOR * PLANE_STEP`` (the smallest float32 step) above it otherwise."""
PLANE_FLOOR = 2.0 ** -126


class KdTreeArrays(NamedTuple):
    """The arrays a kd-tree traversal kernel reads."""

    lo: np.ndarray            # (3,) float64, root cell
    hi: np.ndarray            # (3,) float64
    node_records: np.ndarray  # (n_nodes, 2) int32: float32 plane or first reference, then the word
    leaf_prims: np.ndarray    # (n_references,) int32

    @classmethod
    def pack(cls, lo, hi, node_split, node_link, leaf_prims) -> KdTreeArrays:
        """The arrays of a tree given as its planes (n_nodes,) float64 and its links (n_nodes, 2)
        int32: an inner node's child below the plane and its axis, a leaf's first reference and
        ``count << 2 | LEAF``."""
        node_link = np.asarray(node_link, dtype=np.int32)
        if len(node_link) >= MAX_NODES:
            raise ValueError(f"a kd-tree holds fewer than {MAX_NODES:,} nodes, got {len(node_link):,}")
        leaf = (node_link[:, 1] & 3) == LEAF
        rounded = float32_below(np.asarray(node_split, dtype=np.float64)[~leaf])
        if not np.isfinite(rounded).all():
            raise ValueError("a kd-tree split plane lies beyond the float32 range")
        planes = np.zeros(len(node_link), dtype=np.float32)
        planes[~leaf] = rounded
        node_records = np.empty((len(node_link), 2), dtype=np.int32)
        node_records[:, 0] = np.where(leaf, node_link[:, 0], planes.view(np.int32))
        inner = np.flatnonzero(~leaf)
        below = node_link[inner, 0]
        empty_leaf = (node_link[:, 1] == LEAF).astype(np.int32)
        node_records[:, 1] = node_link[:, 1]
        node_records[inner, 1] = (below << CHILD_SHIFT | (empty_leaf[below] | empty_leaf[below + 1] << 1) << 2
                                  | node_link[inner, 1])
        return cls(lo, hi, node_records, leaf_prims)

    @property
    def walk_records(self) -> tuple[np.ndarray, np.ndarray]:
        """The records as the walks read them, ``(planes, words)``: one flat array seen as float32
        and as int32, node ``k``'s first column at ``2k`` and its second at ``2k + 1`` (read with
        :func:`node_word`, :func:`node_plane` and :func:`leaf_first`). Numba indexes a 2-D array
        by multiplying the row by its length, read at run time, which put a multiplication on the
        path from one node to the next: flat, forest incoherent rays 1.04-1.09 times as fast (closest
        and any hit, both orders of the comparison), the full dragon's 0.99 / 1.03, camera and shadow
        rays level (one thread, medians of 5-9 interleaved rounds)."""
        words = self.node_records.reshape(-1)
        return words.view(np.float32), words

    @property
    def node_planes(self) -> np.ndarray:
        """(n_nodes, 2) float32 view of the records: column 0 is an inner node's plane."""
        return self.node_records.view(np.float32)

    @property
    def leaf(self) -> np.ndarray:
        return (self.node_records[:, 1] & 3) == LEAF

    @property
    def node_split(self) -> np.ndarray:
        """(n_nodes,) float64: each inner node's plane rounded down to float32, 0 for a leaf."""
        return np.where(self.leaf, 0.0, self.node_planes[:, 0].astype(np.float64))

    @property
    def node_link(self) -> np.ndarray:
        """(n_nodes, 2) int32: each inner node's child below the plane and its axis, each leaf's
        first reference and ``count << 2 | LEAF`` (the form :meth:`pack` takes)."""
        leaf = self.leaf
        word = self.node_records[:, 1]
        return np.stack((np.where(leaf, self.node_records[:, 0], word >> CHILD_SHIFT), np.where(leaf, word, word & 3)),
                        axis=1)

    @property
    def n_nodes(self) -> int:
        return len(self.node_records)

    @property
    def axis(self) -> np.ndarray:
        return self.node_records[:, 1] & 3

    @property
    def count(self) -> np.ndarray:
        return np.where(self.leaf, self.node_records[:, 1] >> 2, 0)

    @property
    def nbytes(self) -> int:
        return int(sum(a.nbytes for a in self))

    def empty_children(self) -> np.ndarray:
        """(n_nodes,) each inner node's flags of empty children (:func:`empty_flags`), 0 for a leaf."""
        words = self.node_records[:, 1]
        return np.where(words & 3 == LEAF, 0, empty_flags.py_func(words))


@inline_kernel
def node_word(words, node):
    """Node ``node``'s second column in the flat records (:attr:`KdTreeArrays.walk_records`)."""
    return words[unsigned(2 * node + 1)]


@inline_kernel
def node_plane(planes, node):
    """Inner node ``node``'s float32 plane in the flat records, as stored, not widened (a leaf's slot
    holds the bits of its first reference, which a walk may read with its sibling's but never uses as
    a number)."""
    return planes[unsigned(2 * node)]


@inline_kernel
def node_record(planes, words, node):
    """``(plane, word)``: node ``node``'s :func:`node_plane` and :func:`node_word`."""
    return node_plane(planes, node), node_word(words, node)


@inline_kernel
def node_child(word):
    """The child below the plane of the inner node whose word is ``word`` (the child above is the next)."""
    return word >> CHILD_SHIFT


@inline_kernel
def empty_flags(word):
    """The flags of an inner node's empty children in its word: bit 0 set when the child below the
    plane is an empty leaf, bit 1 when the child above is."""
    return (word >> 2) & 3


@inline_kernel
def leaf_first(words, node):
    """Leaf ``node``'s first reference in the flat records."""
    return words[unsigned(2 * node)]


@inline_kernel
def plane_bracket(plane):
    """``(below, above)``: float64 bounds of the plane a node's float32 ``plane`` was rounded down
    from, ``q`` and ``q + (|q| + PLANE_FLOOR) PLANE_STEP``, one float32 step or a little more
    (the sum is exact in float64 where the floor matters)."""
    below = np.float64(plane)
    return below, below + (abs(below) + PLANE_FLOOR) * PLANE_STEP


@kernel
def node_cells(lo, hi, planes, words):
    """(n_nodes, 6) cell of every node (lo, hi), from the root box and the split planes of the
    flat records (:attr:`KdTreeArrays.walk_records`), each child's reaching across its plane's
    bracket (:func:`plane_bracket`)."""
    n = words.shape[0] // 2
    cells = np.empty((n, 6))
    cells[0, :3] = lo
    cells[0, 3:] = hi
    depth = np.zeros(n, dtype=np.int64)
    for node in range(n):
        word = node_word(words, node)
        axis = word & 3
        if axis == LEAF:
            continue
        below = node_child(word)
        plane_below, plane_above = plane_bracket(node_plane(planes, node))
        cells[below] = cells[node]
        cells[below + 1] = cells[node]
        cells[below, axis + 3] = plane_above
        cells[below + 1, axis] = plane_below
        depth[below] = depth[node] + 1
        depth[below + 1] = depth[node] + 1
    return cells, depth


@inline_kernel
def add_children(node_split, node_link, n_nodes, node, position, axis):
    """Make ``node`` an inner node split at ``position`` on ``axis`` with two new children,
    appended to the growable node arrays. Returns the arrays, the left child's index and
    the new node count."""
    node_split = reserve_rows(node_split, n_nodes + 2)
    node_link = reserve_rows(node_link, n_nodes + 2)
    node_split[node] = position
    node_link[node, 0] = n_nodes
    node_link[node, 1] = axis
    return node_split, node_link, n_nodes, n_nodes + 2


@inline_kernel
def copy_cell(dst, src):
    """``dst[:] = src`` for a cell's six bounds, without the cost of a slice assignment."""
    for c in range(6):
        dst[c] = src[c]


@inline_kernel
def split_cell(cell, axis, position, child_cell):
    """``child_cell[0]`` and ``child_cell[1]``: ``cell`` below and above ``position`` on ``axis``."""
    copy_cell(child_cell[0], cell)
    copy_cell(child_cell[1], cell)
    child_cell[0, axis + 3] = position
    child_cell[1, axis] = position
