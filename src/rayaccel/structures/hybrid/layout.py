"""Flat layout of the grid-BVH hybrid.

A uniform grid exactly as in :mod:`..grid.layout` (``lo``, ``hi``, ``res``,
``cell_size``, rows ``cell_first``/``cell_prims``), plus one BVH per dense
cell, all in one forest of nodes laid out as in :mod:`..bvh.layout` (children
side by side; ``node_first`` is the left child of an inner node, or a leaf's
offset into ``cell_prims``; ``node_count`` is 0 for inner nodes):

* ``cell_root`` (n_cells,) int32: -1 for a cell whose references are tested
  one by one, else the root of the cell's BVH, whose leaves index the cell's
  own row of ``cell_prims`` (reordered into leaf order);
* ``node_box`` (n_nodes, 6) float32, rounded outwards, ``node_first``,
  ``node_count`` (n_nodes,) int32: the forest, each tree in one run of
  slots, a node's children side by side.

These are what is built and saved. The ray walk reads the forest collapsed
eight-wide (:func:`..bvh.wide.wide_tree` over all the cells' roots), derived
after a build or a load: 3D-DDA through the grid; in a cell with a BVH, a
stack traversal of that cell's wide tree replaces the loop over its row.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = ["GridBvhArrays"]


class GridBvhArrays(NamedTuple):
    """The arrays the grid-BVH traversal kernel reads."""

    lo: np.ndarray          # (3,) float64
    hi: np.ndarray          # (3,) float64
    res: np.ndarray         # (3,) int64
    cell_size: np.ndarray   # (3,) float64
    cell_first: np.ndarray  # (n_cells + 1,) int32
    cell_prims: np.ndarray  # (n_references,) int32
    cell_root: np.ndarray   # (n_cells,) int32
    node_box: np.ndarray    # (n_nodes, 6) float32
    node_first: np.ndarray  # (n_nodes,) int32
    node_count: np.ndarray  # (n_nodes,) int32

    @property
    def nbytes(self) -> int:
        return int(sum(a.nbytes for a in self))
