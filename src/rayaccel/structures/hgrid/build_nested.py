"""Hierarchical grid construction: grids nested in dense cells, level by level.

Jevans & Wyvill, "Adaptive Voxel Subdivision for Ray Tracing", Graphics
Interface 1989; Klimaszewski & Sederberg, "Faster Ray Tracing Using Adaptive
Grids", IEEE CG&A 1997. The top grid is a uniform grid of ``density * n``
cells (:mod:`..grid.build_uniform`). Every cell holding more than
``threshold`` references then gets a grid of its own over the cell's box, with
``density * m`` cells for its ``m`` primitives, and the primitives move down
into it -- unless that grid would not separate them (its cells would hold
more than half of them on average) or would store more than
``REFERENCE_BUDGET`` references per primitive. The same happens to the new
grids' dense cells, down to ``max_levels`` levels. All nested grids of a level
are filled at once, in parallel over the grids, with the counting-sort
insertion of the uniform grid.
"""

from __future__ import annotations

import numpy as np
from numba import prange

from ..._jit import parallel_kernel
from ..grid.build_uniform import MAX_CELLS, REFERENCE_BUDGET, build_density_grid, insert_prim, prim_cells
from .layout import HierarchicalGridArrays

__all__ = ["build_hierarchical_grid"]


@parallel_kernel
def _insert_nested(prim_lo, prim_hi, kind, geom, exact, parent_first, parent_prims, grid_lo, cell_size, res,
                   cell_base, row_end, cell_prims, fill):
    """Insert the primitives of every nested grid ``d``, ``parent_prims[parent_first[d]:parent_first[d + 1]]``,
    into its cells with :func:`insert_prim` (``fill`` selects the pass), grids in parallel."""
    for d in prange(grid_lo.shape[0]):
        lo, size, r = grid_lo[d], cell_size[d], res[d]
        for k in range(parent_first[d], parent_first[d + 1]):
            prim = parent_prims[k]
            x0, x1, y0, y1, z0, z1 = prim_cells(prim_lo, prim_hi, prim, lo, size, r)
            test = exact and (x1 > x0 or y1 > y0 or z1 > z0)
            insert_prim(prim, kind, geom, test, lo, size, r, x0, x1, y0, y1, z0, z1, cell_base[d], row_end, cell_prims,
                        fill)


@parallel_kernel
def _count_nested(prim_lo, prim_hi, parent_first, parent_prims, grid_lo, cell_size, res, counts):
    """References each nested grid ``d`` would store with bounding-box insertion."""
    for d in prange(grid_lo.shape[0]):
        lo, size, r = grid_lo[d], cell_size[d], res[d]
        total = 0
        for k in range(parent_first[d], parent_first[d + 1]):
            x0, x1, y0, y1, z0, z1 = prim_cells(prim_lo, prim_hi, parent_prims[k], lo, size, r)
            total += (x1 - x0 + 1) * (y1 - y0 + 1) * (z1 - z0 + 1)
        counts[d] = total


def _rows(first: np.ndarray, prims: np.ndarray, cells: np.ndarray):
    """The references of ``cells`` in turn, and their row offsets."""
    counts = first[cells + 1] - first[cells]
    offsets = np.zeros(len(cells) + 1, dtype=np.int64)
    np.cumsum(counts, out=offsets[1:])
    take = np.repeat(first[cells] - offsets[:-1], counts) + np.arange(offsets[-1])
    return prims[take], offsets


def _cell_boxes(cells, base, lo, res, size):
    """Boxes (lo, hi) of level-local cells, given the level's grids."""
    grid = np.searchsorted(base, cells, side="right") - 1
    local = cells - base[grid]
    r = res[grid]
    xyz = np.stack((local % r[:, 0], (local // r[:, 0]) % r[:, 1], local // (r[:, 0] * r[:, 1])), axis=1)
    cell_lo = lo[grid] + xyz * size[grid]
    return cell_lo, cell_lo + size[grid]


class _Level:
    """The grids of one level: boxes, resolutions, level-local cell numbering and rows."""

    def __init__(self, lo, res, size, prim_first, prims):
        self.lo, self.res, self.size = lo, res, size
        self.base = np.zeros(len(lo) + 1, dtype=np.int64)
        np.cumsum(res.prod(axis=1), out=self.base[1:])
        self.first, self.prims = prim_first, prims
        self.dense = np.zeros(0, dtype=np.int64)


def _nested_level(level, bounds, kind, geom, density, threshold, exact):
    """The grids nested in ``level``'s cells with more than ``threshold`` references, and
    those cells; None where no cell gets one."""
    dense = np.flatnonzero(np.diff(level.first) > threshold)
    if len(dense) == 0:
        return None
    cell_lo, cell_hi = _cell_boxes(dense, level.base, level.lo, level.res, level.size)
    parent_prims, parent_first = _rows(level.first, level.prims, dense)
    extent = cell_hi - cell_lo
    m = np.diff(parent_first)
    side = (np.prod(extent, axis=1) / (density * m)) ** (1.0 / 3.0)
    res = np.clip(np.round(extent / side[:, None]), 1, 256).astype(np.int64)
    size = extent / res
    # nest only where it pays: the nested cells must separate the primitives (hold half of
    # them or fewer on average) without the references growing past the budget
    references = np.empty(len(dense), dtype=np.int64)
    _count_nested(bounds.lo, bounds.hi, parent_first, parent_prims, cell_lo, size, res, references)
    useful = (references <= REFERENCE_BUDGET * m) & (references < 0.5 * m * res.prod(axis=1))
    if not useful.all():
        dense, cell_lo, res, size = dense[useful], cell_lo[useful], res[useful], size[useful]
        if len(dense) == 0:
            return None
        parent_prims, parent_first = _rows(level.first, level.prims, dense)
    if res.prod(axis=1).sum() > MAX_CELLS:
        return None
    nested = _Level(cell_lo, res, size, None, None)
    row_end = np.zeros(nested.base[-1] + 1, dtype=np.int64)
    args = (bounds.lo, bounds.hi, kind, geom, exact, parent_first, parent_prims, cell_lo, size, res, nested.base[:-1])
    _insert_nested(*args, row_end[1:], np.zeros(0, dtype=np.int32), False)
    np.cumsum(row_end, out=row_end)
    prims = np.empty(row_end[-1], dtype=np.int32)
    _insert_nested(*args, row_end[1:], prims, True)
    row_end[:-1] = row_end[1:].copy()
    row_end[-1] = len(prims)
    nested.first, nested.prims = row_end, prims
    return nested, dense


def build_hierarchical_grid(bounds, kind, geom, density, threshold, max_levels, exact) -> HierarchicalGridArrays:
    """Build the hierarchical grid over a scene's primitive ``bounds``; see the module docstring."""
    top = build_density_grid(bounds, kind, geom, density, exact)
    lo, hi = top.lo, top.hi
    levels = [_Level(lo[None], top.res[None], top.cell_size[None], top.cell_first.astype(np.int64), top.cell_prims)]
    while len(levels) < max_levels:
        found = _nested_level(levels[-1], bounds, kind, geom, density, threshold, exact)
        if found is None:
            break
        nested, levels[-1].dense = found
        levels.append(nested)
    cell_offset = 0
    grid_offset = 0
    grid_cell_base, grid_level, cell_child, counts, kept = [], [], [], [], []
    for depth, level in enumerate(levels):
        n_grids = len(level.lo)
        n_cells = int(level.base[-1])
        grid_cell_base.append(cell_offset + level.base[:-1])
        grid_level.append(np.full(n_grids, depth, dtype=np.int64))
        child = np.full(n_cells, -1, dtype=np.int32)
        child[level.dense] = grid_offset + n_grids + np.arange(len(level.dense))
        row_counts = np.diff(level.first)
        moved_down = child >= 0
        row_counts[moved_down] = 0
        kept.append(level.prims[~np.repeat(moved_down, np.diff(level.first))])
        cell_child.append(child)
        counts.append(row_counts)
        cell_offset += n_cells
        grid_offset += n_grids
    cell_first = np.zeros(cell_offset + 1, dtype=np.int64)
    np.cumsum(np.concatenate(counts), out=cell_first[1:])
    return HierarchicalGridArrays(
        lo, hi,
        np.concatenate([level.lo for level in levels]),
        np.concatenate([level.res for level in levels]),
        np.concatenate([level.size for level in levels]),
        np.concatenate(grid_cell_base), np.concatenate(grid_level),
        np.concatenate(cell_child), cell_first, np.concatenate(kept),
    )
