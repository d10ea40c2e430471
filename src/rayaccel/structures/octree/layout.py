"""Flat layout of an adaptive octree.

Nodes are numbered breadth first from the root, 0; the eight children of an
inner node are consecutive, child ``c`` covering the octant whose bit
``c & 1`` is set when it lies above the centre on x, ``c & 2`` on y and
``c & 4`` on z. Arrays of ``n_nodes`` rows:

* ``node_center`` (n_nodes, 3) float64: the centre of the node's cell, where
  its three splitting planes cross;
* ``node_link`` (n_nodes, 2) int32: column 0 is, for an inner node, the index
  of its first child and, for a leaf, the offset of its first reference in
  ``leaf_prims``; column 1 is -1 for an inner node and the number of
  references (possibly 0) for a leaf.

``leaf_prims`` (n_references,) int32 holds every leaf's primitive indices in
turn; a primitive is referenced by every leaf whose cell it overlaps. The root
cell is the box ``lo``..``hi``; every level halves the cells on all three axes.

To walk it: clip the ray to the root box; at an inner node, the distances to
the three planes through its centre split the ray's interval into at most four
pieces, each inside one child, visited in order (:mod:`.traverse`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = ["OctreeArrays"]


class OctreeArrays(NamedTuple):
    """The arrays an octree traversal kernel reads."""

    lo: np.ndarray           # (3,) float64, root cell
    hi: np.ndarray           # (3,) float64
    node_center: np.ndarray  # (n_nodes, 3) float64
    node_link: np.ndarray    # (n_nodes, 2) int32
    leaf_prims: np.ndarray   # (n_references,) int32

    @property
    def n_nodes(self) -> int:
        return len(self.node_center)

    @property
    def leaf(self) -> np.ndarray:
        return self.node_link[:, 1] >= 0

    @property
    def nbytes(self) -> int:
        return int(sum(a.nbytes for a in self))
