"""Flat layout of a bounding volume hierarchy, shared by every builder.

Nodes are numbered from the root, 0, with the two children of an inner node
side by side, so a node stores one index for both:

* ``node_box`` (n_nodes, 6) float64: the node's axis-aligned box,
  ``lo_x, lo_y, lo_z, hi_x, hi_y, hi_z``;
* ``node_first`` (n_nodes,) int32: for an inner node the index of its left
  child (the right child is ``node_first + 1``); for a leaf the offset of its
  first primitive in ``prim_order``;
* ``node_count`` (n_nodes,) int32: 0 for an inner node, the number of
  primitives (at least 1) for a leaf;
* ``prim_order`` (n_prims,) int64: primitive indices in leaf order; a leaf
  holds ``prim_order[first : first + count]``. The traversal reads the
  primitives' geometry reordered the same way (``geom[prim_order]``), so that a
  leaf's primitives lie next to each other in memory.

For traversal the nodes are also packed into one record of 32 bytes each,
``node_records`` (n_nodes + 1, 8) float32: the box rounded outwards to float32
and ``first``, ``count`` stored bit for bit as int32 in the last two columns
(read them through ``node_records.view(np.int32)``). Record 1 is padding and
node k >= 1 is record k + 1 (child links shifted to match), so that the two
children of a node share one 64-byte cache line; see :func:`node_rows`, which
lays out the sphere and k-DOP volumes the same way. A BVH walked eight-wide
(:mod:`.wide`) keeps only the root's record here (rows 0 and 1): the box a ray
must enter before the walk starts.

Bounding volumes other than boxes (spheres, k-DOPs) are stored per node in an
extra array ``node_volume`` beside the boxes; see :mod:`.volumes`.

To walk it: test the root's volume; at an inner node test both children,
descend into the nearer hit and push the farther one (with its entry distance)
on a stack; at a leaf test its primitives; pop nodes whose entry distance is
still below the best hit.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..._memory import cache_line_aligned
from ...geometry.rounding import float32_above, float32_below

__all__ = ["BvhArrays", "node_rows", "float32_boxes", "pack_nodes"]


class BvhArrays(NamedTuple):
    """The arrays a BVH traversal kernel reads (see the module docstring)."""

    node_box: np.ndarray
    node_first: np.ndarray
    node_count: np.ndarray
    prim_order: np.ndarray
    node_records: np.ndarray

    @property
    def n_nodes(self) -> int:
        return len(self.node_first)

    @property
    def traversal_bytes(self) -> int:
        """Memory the traversal reads besides geometry: node records and primitive order."""
        return int(self.node_records.nbytes + self.prim_order.nbytes)


def node_rows(per_node: np.ndarray) -> np.ndarray:
    """``per_node`` (n_nodes, m) laid out the way the traversal indexes nodes: row 0 is the
    root, row 1 padding (zeros), node k >= 1 row k + 1; on a 64-byte boundary, so that
    with 32-byte rows every sibling pair shares one cache line."""
    n, m = per_node.shape
    rows = cache_line_aligned((n + 1, m), per_node.dtype)
    rows[0] = per_node[0]
    rows[2:] = per_node[1:]
    return rows


def float32_boxes(node_box: np.ndarray) -> np.ndarray:
    """``node_box`` (n, 6), lo then hi, rounded outwards to float32: each box contains the
    exact one, so that a slab test of the rounded box culls nothing the exact box holds."""
    return np.hstack((float32_below(node_box[:, :3]), float32_above(node_box[:, 3:])))


def pack_nodes(node_box: np.ndarray, node_first: np.ndarray, node_count: np.ndarray) -> np.ndarray:
    """The traversal's float32 records, (n_nodes + 1, 8) in :func:`node_rows` order: the box
    rounded outwards, then first and count, with child links shifted to the record numbering
    (leaf offsets into ``prim_order`` are not shifted)."""
    records = np.empty((len(node_first), 8), dtype=np.float32)
    records[:, :6] = float32_boxes(node_box)
    links = records.view(np.int32)
    links[:, 6] = np.where(node_count == 0, node_first + 1, node_first)
    links[:, 7] = node_count
    return node_rows(records)
