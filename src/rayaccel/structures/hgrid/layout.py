"""Flat layout of a hierarchical grid.

Grids are numbered from the top grid, 0; grid ``g`` covers the box
``grid_lo[g]``..``grid_lo[g] + grid_res[g] * grid_cell_size[g]`` with
``grid_res[g]`` cells per axis, and its cells are numbered, globally, from
``grid_cell_base[g]`` on, cell ``(x, y, z)`` being ``grid_cell_base[g] + x +
nx * (y + ny * z)`` as in the uniform grid.

Per cell, over all grids:

* ``cell_child`` (n_cells,) int32: -1, or the grid nested in this cell (it
  covers exactly the cell's box, and the cell itself then holds nothing);
* ``cell_first`` (n_cells + 1,) int64 and ``cell_prims`` (n_references,) int32:
  compressed rows of primitive references, as in :mod:`..grid.layout`.

To walk it: 3D-DDA through the top grid; on entering a cell with a nested
grid, start a DDA in that grid over the part of the ray inside the cell, and
resume the outer walk where the inner one leaves (:mod:`.traverse`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = ["HierarchicalGridArrays"]


class HierarchicalGridArrays(NamedTuple):
    """The arrays a hierarchical grid traversal kernel reads."""

    lo: np.ndarray              # (3,) float64, the top grid's box
    hi: np.ndarray              # (3,) float64
    grid_lo: np.ndarray         # (n_grids, 3) float64
    grid_res: np.ndarray        # (n_grids, 3) int64
    grid_cell_size: np.ndarray  # (n_grids, 3) float64
    grid_cell_base: np.ndarray  # (n_grids,) int64
    grid_level: np.ndarray      # (n_grids,) int64, 0 for the top grid
    cell_child: np.ndarray      # (n_cells,) int32
    cell_first: np.ndarray      # (n_cells + 1,) int64
    cell_prims: np.ndarray      # (n_references,) int32

    @property
    def n_grids(self) -> int:
        return len(self.grid_lo)

    @property
    def n_cells(self) -> int:
        return len(self.cell_child)

    @property
    def nbytes(self) -> int:
        return int(sum(a.nbytes for a in self))
