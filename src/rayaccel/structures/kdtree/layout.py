"""Flat layout of a kd-tree.

Nodes are numbered from the root, 0; the two children of an inner node sit
side by side (below the plane, then above it), so a node stores one index for
both. Each node is one 16-byte record, so that a step of the walk reads one
cache line: ``node_records`` (n_nodes, 2) float64, whose

* column 0 is the split plane's coordinate on the node's axis (unused for a
  leaf);
* column 1 holds two int32 (:attr:`KdTreeArrays.node_link`, the records seen
  as int32, columns 2 and 3): the first is, for an inner node, the index of
  its child below the plane (the child above is that + 1) and, for a leaf,
  the offset of its first reference in ``leaf_prims``; the second is
  ``count << 2 | axis`` with ``axis`` 0, 1, 2 for an inner node (``count`` 0)
  and 3 for a leaf holding ``count`` references (possibly none: empty leaves
  are what makes kd-trees skip empty space).

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

from ..._jit import inline_kernel, kernel
from ..build_arrays import reserve_rows

__all__ = ["LEAF", "KdTreeArrays", "node_cells", "add_children", "copy_cell", "split_cell"]

LEAF = 3


class KdTreeArrays(NamedTuple):
    """The arrays a kd-tree traversal kernel reads."""

    lo: np.ndarray            # (3,) float64, root cell
    hi: np.ndarray            # (3,) float64
    node_records: np.ndarray  # (n_nodes, 2) float64: split, then (link, count << 2 | axis) as two int32
    leaf_prims: np.ndarray    # (n_references,) int32

    @classmethod
    def pack(cls, lo, hi, node_split, node_link, leaf_prims) -> KdTreeArrays:
        """The arrays of a tree given as its planes (n_nodes,) and links (n_nodes, 2) int32."""
        node_records = np.empty((len(node_split), 2))
        node_records[:, 0] = node_split
        node_records.view(np.int32)[:, 2:] = node_link
        return cls(lo, hi, node_records, leaf_prims)

    @property
    def node_split(self) -> np.ndarray:
        """(n_nodes,) float64 view: each node's plane."""
        return self.node_records[:, 0]

    @property
    def node_link(self) -> np.ndarray:
        """(n_nodes, 2) int32 view: each node's child or first reference, and its count and axis."""
        return self.node_records.view(np.int32)[:, 2:]

    @property
    def n_nodes(self) -> int:
        return len(self.node_records)

    @property
    def axis(self) -> np.ndarray:
        return self.node_link[:, 1] & 3

    @property
    def count(self) -> np.ndarray:
        return self.node_link[:, 1] >> 2

    @property
    def nbytes(self) -> int:
        return int(sum(a.nbytes for a in self))


@kernel
def node_cells(lo, hi, node_records):
    """(n_nodes, 6) cell of every node (lo, hi), from the root box and the split planes."""
    n = node_records.shape[0]
    links = node_records.view(np.int32)
    cells = np.empty((n, 6))
    cells[0, :3] = lo
    cells[0, 3:] = hi
    depth = np.zeros(n, dtype=np.int64)
    for node in range(n):
        axis = links[node, 3] & 3
        if axis == LEAF:
            continue
        below = links[node, 2]
        cells[below] = cells[node]
        cells[below + 1] = cells[node]
        cells[below, axis + 3] = node_records[node, 0]
        cells[below + 1, axis] = node_records[node, 0]
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
