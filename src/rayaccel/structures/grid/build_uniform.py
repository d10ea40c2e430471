"""Uniform grid construction: resolution choice and counting-sort insertion.

The number of cells follows either a density, ``cells = density * n`` (the
lecture uses 8), or the cost model of a grid traversal: a ray crosses about
``R^(1/3)`` of ``R`` cells and meets ``n / R^(2/3)`` objects, so the cost
``C_c R^(1/3) + C_i n / R^(2/3)`` is least at ``R = 2 n C_i / C_c`` cells,
with ``C_i`` one object test and ``C_c`` one cell-to-cell step as measured by
:mod:`.calibrate`. Cells are shaped like the scene's box, so they need not be
cubes.

Insertion (after Cleary & Wyvill 1988; the two-pass counting layout as in
Lagae & Dutre, "Compact, Fast and Robust Grids for Ray Tracing", 2008): one
pass counts the references per cell, a prefix sum turns the counts into row
offsets, a second pass writes the references. With ``exact=True`` a primitive
goes only into the cells it really overlaps (triangle-box SAT, sphere-box
distance); otherwise into every cell its bounding box overlaps. Both passes
run in parallel over slabs of cell layers along z, each slab with its own
bucket of the primitives that reach it, so writes never collide and stay
within a cache-sized part of the cell arrays. Offsets and references are
int32, which halves the memory a large grid touches.
"""

from __future__ import annotations

import math

import numpy as np

from numba import prange

from ..._jit import inline_kernel, kernel, parallel_kernel, thread_count
from ...geometry.overlap import prim_overlaps_box
from .layout import GridArrays

__all__ = ["MAX_CELLS", "CELL_PAD", "REFERENCE_BUDGET", "grid_box", "resolution_for", "cell_span", "prim_cells",
           "insert_prim", "count_references", "capped_resolution", "build_grid", "build_density_grid"]

MAX_CELLS = 1 << 27
REFERENCE_BUDGET = 64  # a resolution chosen for the user stores at most this many references per primitive
CELL_PAD = 1e-6  # cells are grown by this fraction of their size when inserting


def grid_box(scene_lo: np.ndarray, scene_hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The scene box, padded a little and given a minimum thickness on flat axes."""
    extent = scene_hi - scene_lo
    size = max(float(extent.max()), 1e-12)
    pad = np.maximum(1e-7 * size, 0.5 * np.maximum(1e-3 * size - extent, 0.0))
    return scene_lo - pad, scene_hi + pad


def resolution_for(extent: np.ndarray, n_cells: float) -> np.ndarray:
    """Cells per axis, about ``n_cells`` in all, shaped to the box ``extent``."""
    n_cells = min(max(float(n_cells), 1.0), float(MAX_CELLS))
    side = (float(np.prod(extent)) / n_cells) ** (1.0 / 3.0)
    res = np.maximum(1, np.round(extent / side)).astype(np.int64)
    while res.prod() > MAX_CELLS:
        res = np.maximum(1, res * 0.95).astype(np.int64)
    return res


@kernel
def cell_span(lo, hi, grid_lo, cell_size, res, axis):
    """First and last cell on ``axis`` that the interval ``lo..hi``, grown by ``CELL_PAD``
    of a cell, reaches; clamped to the grid."""
    pad = CELL_PAD * cell_size[axis]
    first = int(math.floor((lo - pad - grid_lo[axis]) / cell_size[axis]))
    last = int(math.floor((hi + pad - grid_lo[axis]) / cell_size[axis]))
    return max(first, 0), min(last, res[axis] - 1)


@kernel
def _z_slabs(prim_lo, prim_hi, grid_lo, cell_size, res, slab_depth, n_slabs):
    """Bucket the primitives by the slabs of ``slab_depth`` cell layers their boxes reach."""
    n_prims = prim_lo.shape[0]
    spans = np.empty((n_prims, 2), dtype=np.int64)
    slab_first = np.zeros(n_slabs + 1, dtype=np.int64)
    for prim in range(n_prims):
        z0, z1 = cell_span(prim_lo[prim, 2], prim_hi[prim, 2], grid_lo, cell_size, res, 2)
        spans[prim, 0] = z0 // slab_depth
        spans[prim, 1] = z1 // slab_depth
        for s in range(spans[prim, 0], spans[prim, 1] + 1):
            slab_first[s + 1] += 1
    for s in range(n_slabs):
        slab_first[s + 1] += slab_first[s]
    cursor = slab_first[:-1].copy()
    slab_prims = np.empty(slab_first[-1], dtype=np.int64)
    for prim in range(n_prims):
        for s in range(spans[prim, 0], spans[prim, 1] + 1):
            slab_prims[cursor[s]] = prim
            cursor[s] += 1
    return slab_first, slab_prims


@inline_kernel
def prim_cells(prim_lo, prim_hi, prim, grid_lo, cell_size, res):
    """The cell ranges ``x0, x1, y0, y1, z0, z1`` (inclusive) that primitive ``prim``'s box reaches."""
    x0, x1 = cell_span(prim_lo[prim, 0], prim_hi[prim, 0], grid_lo, cell_size, res, 0)
    y0, y1 = cell_span(prim_lo[prim, 1], prim_hi[prim, 1], grid_lo, cell_size, res, 1)
    z0, z1 = cell_span(prim_lo[prim, 2], prim_hi[prim, 2], grid_lo, cell_size, res, 2)
    return x0, x1, y0, y1, z0, z1


@inline_kernel
def insert_prim(prim, kind, geom, test, grid_lo, cell_size, res, x0, x1, y0, y1, z0, z1, cell_base, row_end,
                cell_prims, fill):
    """Visit the cells ``x0..x1, y0..y1, z0..z1`` of a grid whose cells are numbered from
    ``cell_base``, skipping (with ``test``) those that primitive ``prim`` does not really meet:
    count the primitive in each cell's ``row_end`` or, with ``fill``, write it just before that
    end and move the end down (the two passes of a counting sort)."""
    nx, ny = res[0], res[1]
    hx = 0.5 * cell_size[0] * (1.0 + 2.0 * CELL_PAD)
    hy = 0.5 * cell_size[1] * (1.0 + 2.0 * CELL_PAD)
    hz = 0.5 * cell_size[2] * (1.0 + 2.0 * CELL_PAD)
    for z in range(z0, z1 + 1):
        for y in range(y0, y1 + 1):
            for x in range(x0, x1 + 1):
                if test:
                    cx = grid_lo[0] + (x + 0.5) * cell_size[0]
                    cy = grid_lo[1] + (y + 0.5) * cell_size[1]
                    cz = grid_lo[2] + (z + 0.5) * cell_size[2]
                    if not prim_overlaps_box(kind, geom, prim, cx, cy, cz, hx, hy, hz):
                        continue
                cell = cell_base + x + nx * (y + ny * z)
                if fill:
                    row_end[cell] -= 1
                    cell_prims[row_end[cell]] = prim
                else:
                    row_end[cell] += 1


@parallel_kernel
def _insert(prim_lo, prim_hi, kind, geom, exact, grid_lo, cell_size, res, slab_depth, slab_first, slab_prims,
            row_end, cell_prims, fill):
    """Insert every primitive into the cells it overlaps with :func:`insert_prim` (``fill`` selects
    the pass). Slabs of cell layers run in parallel; each writes only to its own cells."""
    for slab in prange(slab_first.shape[0] - 1):
        slab_z0 = slab * slab_depth
        slab_z1 = slab_z0 + slab_depth - 1
        for k in range(slab_first[slab], slab_first[slab + 1]):
            prim = slab_prims[k]
            x0, x1, y0, y1, z0, z1 = prim_cells(prim_lo, prim_hi, prim, grid_lo, cell_size, res)
            test = exact and (x1 > x0 or y1 > y0 or z1 > z0)
            insert_prim(prim, kind, geom, test, grid_lo, cell_size, res, x0, x1, y0, y1, max(z0, slab_z0),
                        min(z1, slab_z1), 0, row_end, cell_prims, fill)


@parallel_kernel
def count_references(prim_lo, prim_hi, grid_lo, cell_size, res):
    """References a bounding-box insertion into this grid would store (an upper bound for
    exact insertion)."""
    total = 0
    for prim in prange(prim_lo.shape[0]):
        x0, x1, y0, y1, z0, z1 = prim_cells(prim_lo, prim_hi, prim, grid_lo, cell_size, res)
        total += (x1 - x0 + 1) * (y1 - y0 + 1) * (z1 - z0 + 1)
    return total


def capped_resolution(bounds, lo: np.ndarray, hi: np.ndarray, res: np.ndarray) -> np.ndarray:
    """``res``, made coarser until the grid stores at most ``REFERENCE_BUDGET`` references per
    primitive. Only scenes whose primitives span much of the grid (many copies of one big
    primitive, say) need it; without it their references, and build, grow as n times the cells."""
    res = np.asarray(res, dtype=np.int64)
    budget = REFERENCE_BUDGET * len(bounds.lo)
    while res.max() > 1 and count_references(bounds.lo, bounds.hi, lo, (hi - lo) / res, res) > budget:
        res = np.maximum(1, (res * 0.7).astype(np.int64))
    return res


def build_grid(bounds, lo: np.ndarray, hi: np.ndarray, kind: int, geom: np.ndarray, res: np.ndarray,
               exact: bool) -> GridArrays:
    """Insert the primitives into a grid of ``res`` cells over the box ``lo``..``hi``
    (the scene box padded by :func:`grid_box`)."""
    res = np.asarray(res, dtype=np.int64)
    cell_size = (hi - lo) / res
    n_cells = int(res.prod())
    slab_depth = max(1, int(res[2]) // (8 * thread_count()))
    n_slabs = -(-int(res[2]) // slab_depth)
    slab_first, slab_prims = _z_slabs(bounds.lo, bounds.hi, lo, cell_size, res, slab_depth, n_slabs)
    # cell_first[c + 1] counts cell c, then (prefix sum) holds the end of its row;
    # the fill pass decrements it to the row's start, and a shift by one
    # entry turns the ends of the previous rows into the starts.
    cell_first = np.zeros(n_cells + 1, dtype=np.int32)
    _insert(bounds.lo, bounds.hi, kind, geom, exact, lo, cell_size, res, slab_depth, slab_first, slab_prims,
            cell_first[1:], np.zeros(0, dtype=np.int32), False)
    n_references = int(cell_first.sum(dtype=np.int64))
    if n_references >= np.iinfo(np.int32).max:
        raise ValueError(f"the grid would hold {n_references:,} references, more than 2**31; use fewer cells")
    np.cumsum(cell_first, out=cell_first)
    cell_prims = np.empty(n_references, dtype=np.int32)
    _insert(bounds.lo, bounds.hi, kind, geom, exact, lo, cell_size, res, slab_depth, slab_first, slab_prims,
            cell_first[1:], cell_prims, True)
    cell_first[:-1] = cell_first[1:].copy()
    cell_first[-1] = n_references
    return GridArrays(lo, hi, res, cell_size, cell_first, cell_prims)


def build_density_grid(bounds, kind: int, geom: np.ndarray, density: float, exact: bool) -> GridArrays:
    """A grid over the padded scene box with about ``density * n`` cells, made coarser by
    :func:`capped_resolution` where needed."""
    lo, hi = grid_box(bounds.scene_lo, bounds.scene_hi)
    res = capped_resolution(bounds, lo, hi, resolution_for(hi - lo, density * len(geom)))
    return build_grid(bounds, lo, hi, kind, geom, res, exact)
