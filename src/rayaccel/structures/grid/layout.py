"""Flat layout of a uniform grid.

A grid of ``res = (nx, ny, nz)`` cells covers the box ``lo``..``hi``; every
cell has the size ``cell_size = (hi - lo) / res``. Cell ``(x, y, z)`` has the
flat index ``x + nx * (y + ny * z)``.

Objects per cell are stored as compressed rows: the references of cell ``c``
are ``cell_prims[cell_first[c] : cell_first[c + 1]]``, in no particular
order. ``cell_first`` has ``n_cells + 1`` entries, the last being the number
of references; a primitive that overlaps k cells is referenced k times.

To walk it: clip the ray to ``lo``..``hi``, find the cell of the entry point,
then step cell to cell with 3D-DDA (:mod:`.traverse`), reading each cell's row.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = ["GridArrays"]


class GridArrays(NamedTuple):
    """The arrays a grid traversal kernel reads."""

    lo: np.ndarray          # (3,) float64, the grid's lower corner
    hi: np.ndarray          # (3,) float64, the grid's upper corner
    res: np.ndarray         # (3,) int64, cells per axis
    cell_size: np.ndarray   # (3,) float64
    cell_first: np.ndarray  # (n_cells + 1,) int32 row offsets
    cell_prims: np.ndarray  # (n_references,) int32 primitive indices

    @property
    def n_cells(self) -> int:
        return int(self.res.prod())

    @property
    def nbytes(self) -> int:
        return int(sum(a.nbytes for a in self))
