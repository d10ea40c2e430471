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

__all__ = ["BvhArrays"]


class BvhArrays(NamedTuple):
    """The arrays a BVH traversal kernel reads (see the module docstring)."""

    node_box: np.ndarray
    node_first: np.ndarray
    node_count: np.ndarray
    prim_order: np.ndarray

    @property
    def n_nodes(self) -> int:
        return len(self.node_first)

    @property
    def nbytes(self) -> int:
        return int(sum(a.nbytes for a in self))
